"""s54 group H5: concurrent runs. Two runs writing one output at once: the second to finish
refuses in one line instead of silently replacing the first one's result
(stages.common.artifacts.commit_file / commit_dir), and Ctrl-C on ``batch --workers`` ends in
one line, without Dask's lines or a traceback.

The race is made deterministic with the test-only gate of stages.common.artifacts
(``FIELDLOC_TEST_COMMIT_GATE``): the first run stops just before its commit until the second
one has finished, whatever the load of the machine."""

from __future__ import annotations

import copy
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest
import yaml

from stages.common.artifacts import TEST_COMMIT_GATE, commit_dir
from stages.common.errors import FieldlocError
from stages.common.report_file import load_report

FIELDLOC = [sys.executable, "-c", "from fieldloc_cli.main import cli; cli()"]
WAIT_S = 300  # a loaded 2-core machine compiles and imports slowly


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _race(tmp_path: Path, first: list[str], second: list[str]):
    """Start ``first`` with the commit gate closed, run ``second`` to its end while ``first``
    waits before its commit, then open the gate. Returns both CompletedProcess-like results."""
    gate = tmp_path / "gate"
    gate.touch()
    env = {**os.environ, TEST_COMMIT_GATE: str(gate)}
    a = subprocess.Popen([*FIELDLOC, *first], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + WAIT_S
        while not Path(str(gate) + ".reached").exists():
            assert a.poll() is None, f"the first run ended before its commit: {a.stderr.read()}"
            assert time.monotonic() < end, "the first run never reached its commit"
            time.sleep(0.1)
        b = subprocess.run([*FIELDLOC, *second], cwd=tmp_path, capture_output=True, text=True,
                           timeout=WAIT_S)
    finally:
        gate.unlink()
    out, err = a.communicate(timeout=WAIT_S)
    Path(str(gate) + ".reached").unlink()
    return subprocess.CompletedProcess(a.args, a.returncode, out, err), b


def _no_leftovers(folder: Path) -> None:
    hidden = [p for p in folder.rglob(".*")]
    assert not hidden, hidden


def test_two_build_maps_into_one_file_the_later_commit_refuses(tmp_path):
    a, b = _race(tmp_path, ["build-map", "spl", "--resolution", "0.5", "-o", "m.h5"],
                 ["build-map", "msl-2015", "--resolution", "0.5", "-o", "m.h5"])
    assert b.returncode == 0, b.stderr
    assert a.returncode == 1, a.stderr
    assert a.stderr.count("\n") == 1 and "Traceback" not in a.stderr
    assert a.stderr.startswith("fieldloc: error: m.h5 was written by another run meanwhile")
    with h5py.File(tmp_path / "m.h5", "r") as f:  # whole, and the second run's
        assert "msl" in str(f.attrs["inputs"]).lower()
    _no_leftovers(tmp_path)


def test_two_evaluates_into_one_folder_the_later_commit_refuses(tmp_path):
    from test_evaluate import HAND, write_track, write_truth

    write_track(tmp_path / "a.h5", HAND, method="lut")
    write_track(tmp_path / "b.h5", HAND, method="mcl")
    write_truth(tmp_path / "truth.csv", [0, 1, 2, 3, 4])
    a, b = _race(tmp_path, ["evaluate", "a.h5", "--truth", "truth.csv", "-o", "R"],
                 ["evaluate", "b.h5", "--truth", "truth.csv", "-o", "R"])
    assert b.returncode == 0, b.stderr
    assert a.returncode == 1, a.stderr
    assert a.stderr.count("\n") == 1 and "Traceback" not in a.stderr
    assert "was written by another run meanwhile" in a.stderr
    report = load_report(tmp_path / "R")
    assert report["method"] == "mcl" and Path(report["poses"]).name == "b.h5"
    assert all((tmp_path / "R" / f).is_file() for f in report["files"]["plots"])
    _no_leftovers(tmp_path)


def test_two_simulates_into_one_folder_the_later_commit_refuses(tmp_path):
    common = ["omni", "--frames", "2", "-o", "S"]
    a, b = _race(tmp_path, ["simulate", *common, "--field", "spl", "--seed", "1"],
                 ["simulate", *common, "--field", "msl-2015", "--seed", "2"])
    assert b.returncode == 0, b.stderr
    assert a.returncode == 1, a.stderr
    assert a.stderr.count("\n") == 1 and "Traceback" not in a.stderr
    assert a.stderr.startswith("fieldloc: error: S was written by another run meanwhile")
    record = yaml.safe_load((tmp_path / "S" / "simulation.yaml").read_text())
    assert record["seed"] == 2 and len(list((tmp_path / "S" / "images").iterdir())) == 2
    _no_leftovers(tmp_path)


def test_with_overwrite_the_later_run_replaces(tmp_path):
    a, b = _race(tmp_path, ["build-map", "spl", "--resolution", "0.5", "-o", "m.h5",
                            "--overwrite"],
                 ["build-map", "msl-2015", "--resolution", "0.5", "-o", "m.h5"])
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    with h5py.File(tmp_path / "m.h5", "r") as f:
        assert "spl" in str(f.attrs["inputs"]).lower()


def test_a_folder_is_never_committed_over_one_written_meanwhile(tmp_path):
    """commit_dir without replacing: onto a missing or empty folder it renames, onto a folder
    another run filled meanwhile it refuses and leaves that folder as it was."""
    for target, kept in ((tmp_path / "new", None), (tmp_path / "empty", None),
                         (tmp_path / "full", "theirs")):
        if kept is None and target.name == "empty":
            target.mkdir()
        if kept:
            target.mkdir()
            (target / "x").write_text(kept)
        part = tmp_path / f".{target.name}.part"
        part.mkdir()
        (part / "x").write_text("ours")
        if kept:
            with pytest.raises(FieldlocError, match="written by another run meanwhile"):
                commit_dir(part, target, replace=False)
            assert (target / "x").read_text() == kept and part.is_dir()
        else:
            commit_dir(part, target, replace=False)
            assert (target / "x").read_text() == "ours" and not part.exists()


@pytest.mark.skipif(sys.platform != "linux", reason="LocalCluster on loopback, Linux")
@pytest.mark.parametrize("delay", [1.0, 4.0])  # while datasets are made; while runs run
def test_ctrl_c_on_batch_workers_says_one_line(tmp_path, delay):
    """SIGINT to the process group of ``batch --workers 2`` (a terminal's Ctrl-C) once the
    cluster runs: at most a couple of lines after it, no traceback, no Dask log lines, and a
    non-zero exit."""
    spec = {"field": "kidsize", "build_map": {"resolution": 0.2},
            "datasets": [{"name": n, "simulate": {"preset": "omni-clean", "field": "kidsize",
                                                  "frames": 30, "seed": s}}
                         for n, s in (("a", 1), ("b", 2))],
            "methods": ["lut", {"method": "mcl", "conf": ["particles_max=500"]}]}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(spec))
    p = subprocess.Popen([*FIELDLOC, "batch", "s.yaml", "-o", "R", "--workers", "2"],
                         cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, start_new_session=True, preexec_fn=_default_sigint)
    before = []
    for line in p.stderr:  # up to the line saying the cluster runs
        before.append(line)
        if line.startswith("running "):
            break
    time.sleep(delay)
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=WAIT_S)
    after = err.splitlines()
    assert p.returncode != 0
    assert len(after) <= 2, "".join(before) + err
    assert "Traceback" not in err and "distributed" not in err and "Warning" not in err, err
    assert any("interrupted" in line for line in after), err


def test_a_users_file_saved_at_the_output_meanwhile_is_kept_under_overwrite(tmp_path):
    """--overwrite replaces an output only if fieldloc wrote it, and that is asked again at the
    commit: a user's file saved at the output's name while the run works is kept, and the run
    refuses in one line (s54 hostile trial C, C3)."""
    assert subprocess.run([*FIELDLOC, "build-map", "spl", "--resolution", "0.5", "-o", "m.h5"],
                          cwd=tmp_path, capture_output=True, timeout=WAIT_S).returncode == 0
    gate = tmp_path / "gate"
    gate.touch()
    env = {**os.environ, TEST_COMMIT_GATE: str(gate)}
    a = subprocess.Popen([*FIELDLOC, "build-map", "spl", "--resolution", "0.5", "-o", "m.h5",
                          "--overwrite"], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + WAIT_S
        while not Path(str(gate) + ".reached").exists():
            assert a.poll() is None, a.stderr.read()
            assert time.monotonic() < end, "the run never reached its commit"
            time.sleep(0.1)
        (tmp_path / "m.h5").write_text("my notes, saved here meanwhile\n")
    finally:
        gate.unlink()
    _out, err = a.communicate(timeout=WAIT_S)
    assert a.returncode == 1 and err.count("\n") == 1, err
    assert "was replaced meanwhile by a file fieldloc did not write" in err
    assert (tmp_path / "m.h5").read_text() == "my notes, saved here meanwhile\n"


@pytest.fixture(scope="module")
def four_frames(tmp_path_factory):
    """4 rendered omni-clean frames: too few sure frames to calibrate from (5 at least), so
    localize --smooth has no second round."""
    from stages import simulate

    conf = copy.deepcopy(simulate.confs["omni-clean"])
    conf.update(frames=4, seed=2)
    return simulate.main(conf, "msl-2015", tmp_path_factory.mktemp("sim") / "four")


def test_smooth_without_a_second_round_never_replaces_a_poses_file_written_meanwhile(
        four_frames, msl2015_map, tmp_path):
    """localize --smooth whose first round gives no calibration moves that round onto the
    output: as every commit, without replacing a poses file another run wrote there
    meanwhile (s54 hostile trial C, C1)."""
    shutil.copytree(four_frames, tmp_path / "ds")
    common = ["localize", "ds", "--map", str(msl2015_map), "--features", "f.h5", "-o", "p.h5"]
    assert subprocess.run([*FIELDLOC, "extract", "ds", "-o", "f.h5"], cwd=tmp_path,
                          capture_output=True, timeout=WAIT_S).returncode == 0
    # the map's lookup cache built first: the gate then stops the run at its first round's
    # poses, not at a cache file (whose lock the other run would wait for)
    warm = [*common[:-1], "warm.h5"]
    assert subprocess.run([*FIELDLOC, *warm], cwd=tmp_path, capture_output=True,
                          timeout=WAIT_S).returncode == 0
    a, b = _race(tmp_path, [*common, "--smooth"], common)
    assert b.returncode == 0, b.stderr
    assert a.returncode == 1 and "was written by another run meanwhile" in a.stderr, a.stderr
    with h5py.File(tmp_path / "p.h5", "r") as f:  # the other run's poses, not smoothed
        assert "smoothed" not in {m.decode() if isinstance(m, bytes) else m
                                  for m in f["poses/mode"][()]}
