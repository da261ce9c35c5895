"""Interruptions: kill -9 of every long stage at a random moment, in a subprocess.

For simulate, extract, build-map and localize: a finished artifact of an earlier run is at the
target, the stage is started over it (``--overwrite``, or extract resuming it) and killed with
SIGKILL at a random moment of its work (seeded, so a failure can be replayed with
FIELDLOC_KILL_SEED). Afterwards the earlier artifact is byte-identical; the next run removes the
killed run's temporary parts (no stray part is left) and, for extract, resumes the frames the
killed run had finished; and its result equals an uninterrupted run's. The inputs are tiny (a
few frames, spl at coarse cells) but run the same code as large ones.
"""

from __future__ import annotations

import hashlib
import os
import queue
import random
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from stages import build_map, extract, localize, simulate
from stages.common.dataset import write_csv

SEED = int(os.environ.get("FIELDLOC_KILL_SEED", "8"))
# the interruptions below (stage, signal): the README states their number
INTERRUPTIONS = [("simulate", "SIGKILL"), ("extract", "SIGKILL"), ("extract", "SIGINT"),
                 ("build-map", "SIGKILL"), ("localize", "SIGKILL")]
FIELDLOC = [sys.executable, "-c", "from fieldloc_cli.main import cli; cli()"]


@pytest.fixture(scope="module")
def rng():
    return random.Random(SEED)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    root = tmp_path_factory.mktemp("kill")
    ds = simulate.main(dict(simulate.confs["omni-default"], frames=16, seed=5), "spl",
                       root / "ds")
    features = extract.main(None, ds, root / "ds-features.h5")
    the_map = build_map.main({"resolution": 0.2}, "spl", root / "spl.map.h5")
    return {"root": root, "ds": ds, "features": features, "map": the_map}


# ---------------------------------------------------------------------------- helpers


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Run:
    """A fieldloc subprocess whose stderr lines are collected as they come."""

    def __init__(self, args, cwd):
        # SIGINT as a terminal's foreground process has it: a job started in the background
        # of a non-interactive shell (a CI runner's) inherits it ignored, and Python keeps an
        # ignored SIGINT ignored, so a Ctrl-C would never arrive
        self.proc = subprocess.Popen([*FIELDLOC, *args], cwd=cwd, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True,
                                     start_new_session=True, preexec_fn=_default_sigint)
        self.lines: queue.Queue = queue.Queue()
        self.seen: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def stderr(self) -> str:
        """Everything the process wrote on stderr (after it ended)."""
        self._reader.join(timeout=10)
        while not self.lines.empty():
            self.seen.append(self.lines.get())
        return "".join(self.seen)

    def _read(self):
        for line in self.proc.stderr:
            self.lines.put(line)

    def wait_for(self, pattern: str = None, path_glob: tuple | None = None, timeout=60.0):
        """Until a stderr line matches ``pattern`` or ``path_glob`` (folder, glob, count)
        finds at least count files; False if the process ended first."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.01)
                self.seen.append(line)
                if pattern and re.search(pattern, line):
                    return True
            except queue.Empty:
                pass
            if path_glob is not None:
                folder, glob, count = path_glob
                if sum(1 for _ in Path(folder).glob(glob)) >= count:
                    return True
            if self.proc.poll() is not None and self.lines.empty():
                return False
        raise AssertionError(f"timeout; stderr so far: {''.join(self.seen)}")

    def kill_after(self, delay: float) -> int:
        time.sleep(delay)
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
        return self.proc.wait(timeout=60)

    def signal_after(self, delay: float, sig) -> int:
        time.sleep(delay)
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.proc.wait(timeout=60)


def tree_hashes(path: Path) -> dict[str, str]:
    path = Path(path)
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    # exact same-run: files left alone, or written by runs here
    return {str(p.relative_to(path.parent)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in files}


def parts_beside(target: Path) -> list[str]:
    return sorted(p.name for p in target.parent.iterdir()
                  if p.name.startswith(f".{target.name}."))


def h5_content(path, skip_attrs=("created", "inputs", "dataset"), skip=("runtime",)) -> dict:
    """Every dataset and attribute of an HDF5 file except run-specific ones."""
    out = {}
    with h5py.File(path, "r") as f:
        for k, v in f.attrs.items():
            if k not in skip_attrs:
                out[f"@{k}"] = v
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and name.split("/")[-1] not in skip:
                out[name] = obj[()]
            for k, v in obj.attrs.items():
                out[f"{name}@{k}"] = v
        f.visititems(visit)
    return out


def assert_same_content(a: dict, b: dict):
    assert sorted(a) == sorted(b)
    for k in a:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        if x.dtype.kind in "fc":
            # exact same-run: a resumed run and an uninterrupted one, here
            np.testing.assert_array_equal(x, y, err_msg=k)
        else:
            assert x.tolist() == y.tolist(), k


# ---------------------------------------------------------------------------- the stages


def test_kill_simulate(inputs, tmp_path, rng, monkeypatch, caplog):
    target = tmp_path / "data"
    simulate.main(dict(simulate.confs["omni-default"], frames=2, seed=1), "spl", target)
    earlier = tree_hashes(target)
    args = ["simulate", "omni", "--field", "spl", "-o", "data", "--frames", "10", "--seed", "2",
            "--overwrite"]
    run = Run(["-v", *args], tmp_path)
    started = run.wait_for(path_glob=(tmp_path, ".data.fieldloc-*.part/images/*.png", 1))
    delay = rng.uniform(0.0, 0.25)
    rc = run.kill_after(delay)
    assert started and rc == -signal.SIGKILL, (rc, delay, "".join(run.seen))
    assert tree_hashes(target) == earlier  # the earlier dataset, byte for byte
    assert parts_beside(target), "the killed run left its part (the next run removes it)"
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    monkeypatch.chdir(tmp_path)  # the same relative -o as the killed run
    with caplog.at_level("WARNING"):
        res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert "left by an interrupted run writing data" in caplog.text
    assert parts_beside(target) == []
    reference = simulate.main(dict(simulate.confs["omni-default"], frames=10, seed=2), "spl",
                              tmp_path / "reference")
    got = {k.split("/", 1)[1]: v for k, v in tree_hashes(target).items()}
    want = {k.split("/", 1)[1]: v for k, v in tree_hashes(reference).items()}
    assert got == want  # byte-identical to an uninterrupted run


def _frames_dataset(inputs, folder: Path, n: int) -> Path:
    """A dataset of n frames made of the rendered ones repeated (extraction runs the same code
    on each), with its frames.csv."""
    src = inputs["ds"]
    (folder / "images").mkdir(parents=True)
    shutil.copyfile(src / "calib.yaml", folder / "calib.yaml")
    rendered = sorted((src / "images").iterdir())
    names = []
    for i in range(n):
        shutil.copyfile(rendered[i % len(rendered)], folder / "images" / f"{i:06d}.png")
        names.append(f"{i:06d}.png")
    write_csv(folder / "frames.csv", "frames", {"name": names, "stamp": np.arange(n) / 10.0})
    return folder


def test_kill_extract_resumes(inputs, tmp_path, rng):
    """An earlier features file of the first 40 frames; extract of all N frames resumes it and
    is killed; the next run keeps the earlier file's frames and the killed run's, extracts the
    rest, and ends with the features of an uninterrupted run. N is large enough, and the kill's
    window short enough, that neither run can finish inside its signal's window on a fast or a
    busy machine (with 120, a run sometimes finished before the kill landed)."""
    n = 400
    part = _frames_dataset(inputs, tmp_path / "first40", 40)
    ds = _frames_dataset(inputs, tmp_path / "ds", n)
    target = ds / "features.h5"
    extract.main(None, part, target)
    earlier = tree_hashes(target)
    parts_dir = ds / ".features.h5.parts"
    run = Run(["-v", "extract", str(ds)], tmp_path)
    started = run.wait_for(path_glob=(parts_dir, "*.npz", 3))
    delay = rng.uniform(0.0, 0.05)
    rc = run.kill_after(delay)
    assert started and rc == -signal.SIGKILL, (rc, delay, "".join(run.seen))
    assert tree_hashes(target) == earlier
    kept = len(list(parts_dir.glob("*.npz")))
    assert 3 <= kept < n - 140, kept  # the next run has frames left to be interrupted in
    # a Ctrl-C of the next run keeps what it finished too, and says so
    run = Run(["extract", str(ds)], tmp_path)
    run.wait_for(path_glob=(parts_dir, "*.npz", kept + 2))
    rc = run.signal_after(rng.uniform(0.0, 0.1), signal.SIGINT)
    assert rc == 130 and "extract resumes where it stopped" in run.stderr(), (rc, run.stderr())
    assert tree_hashes(target) == earlier
    resumed = len(list(parts_dir.glob("*.npz")))
    assert resumed >= kept
    import logging

    logging.getLogger("stages").setLevel(logging.INFO)
    records = []
    handler = logging.Handler()
    handler.emit = records.append
    logging.getLogger("stages").addHandler(handler)
    try:
        extract.main(None, ds, target)
    finally:
        logging.getLogger("stages").removeHandler(handler)
    messages = [r.getMessage() for r in records]
    assert any(f"resuming {resumed} frames finished by an interrupted run" in m
               for m in messages), messages
    assert any(f"{n - 40 - resumed} frames extracted, {40 + resumed} already done" in m
               for m in messages), messages
    assert parts_beside(target) == []
    reference = extract.main(None, ds, tmp_path / "reference.h5")
    assert_same_content(h5_content(target), h5_content(reference))


def test_kill_build_map(inputs, tmp_path, rng):
    target = tmp_path / "spl.map.h5"
    shutil.copyfile(inputs["map"], target)
    earlier = tree_hashes(target)
    run = Run(["-v", "build-map", "spl", "--resolution", "0.1", "-o", str(target),
               "--overwrite"], tmp_path)
    started = run.wait_for(pattern=r"build-map spl: \d+ x \d+ cells")
    delay = rng.uniform(0.0, 0.4)
    rc = run.kill_after(delay)
    assert started and rc in (-signal.SIGKILL, 0), (rc, "".join(run.seen))
    if rc == 0:  # finished before the kill: the map was replaced whole
        pytest.fail(f"build-map finished within {delay:.2f} s; make the input larger")
    assert tree_hashes(target) == earlier
    build_map.main({"resolution": 0.1}, "spl", target, overwrite=True)
    assert parts_beside(target) == []
    reference = build_map.main({"resolution": 0.1}, "spl", tmp_path / "reference.h5")
    assert_same_content(h5_content(target), h5_content(reference))


def test_kill_localize(inputs, tmp_path, rng):
    target = tmp_path / "poses.h5"
    localize.main({"method": "lut", "hypotheses": 2}, inputs["ds"], inputs["map"], target,
                  features=inputs["features"])
    earlier = {**tree_hashes(target), **tree_hashes(target.with_suffix(".tum"))}
    args = ["localize", str(inputs["ds"]), "--map", str(inputs["map"]), "--features",
            str(inputs["features"]), "-o", str(target), "--overwrite"]
    run = Run(["-v", *args], tmp_path)
    started = run.wait_for(pattern=r"localize .* with lut: 16 frames")
    delay = rng.uniform(0.0, 0.2)
    rc = run.kill_after(delay)
    assert started and rc == -signal.SIGKILL, (rc, delay, "".join(run.seen))
    assert {**tree_hashes(target), **tree_hashes(target.with_suffix(".tum"))} == earlier
    localize.main({"method": "lut"}, inputs["ds"], inputs["map"], target,
                  features=inputs["features"], overwrite=True)
    assert parts_beside(target) == [] and parts_beside(target.with_suffix(".tum")) == []
    reference = localize.main({"method": "lut"}, inputs["ds"], inputs["map"],
                              tmp_path / "reference.h5", features=inputs["features"])
    assert_same_content(h5_content(target), h5_content(reference))
    assert target.with_suffix(".tum").read_bytes() == reference.with_suffix(".tum").read_bytes()
