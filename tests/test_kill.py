"""Interruptions: kill -9 of every long stage at a random moment, in a subprocess.

For simulate, extract, build-map and localize: a finished artifact of an earlier run is at the
target, the stage is started over it (``--overwrite``, or extract resuming it) and killed with
SIGKILL at a random moment of its work (seeded, so a failure can be replayed with
FIELDLOC_KILL_SEED). Afterwards the earlier artifact is byte-identical; the next run removes the
killed run's temporary parts (no stray part is left) and, for extract, resumes the frames the
killed run had finished; and its result equals an uninterrupted run's. For the two rounds of
``localize --smooth`` (a chain writing seven artifacts one after the other), the kill lands in a
phase of the chain the seed picks, and each earlier artifact is byte-identical or replaced
whole (test_kill_two_rounds). The inputs are tiny (a few frames, spl at coarse cells) but run
the same code as large ones.
"""

from __future__ import annotations

import json
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
from unchanged_files import tree_hashes

from stages import build_map, extract, localize, simulate
from stages.common.dataset import write_csv
from stages.common.features_file import CHUNK_FRAMES

SEED = int(os.environ.get("FIELDLOC_KILL_SEED", "8"))
# the interruptions below (stage, signal): the README states their number
INTERRUPTIONS = [("simulate", "SIGKILL"), ("extract", "SIGKILL"), ("extract", "SIGINT"),
                 ("build-map", "SIGKILL"), ("localize", "SIGKILL"),
                 ("localize --smooth", "SIGKILL")]
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
        self.stamped: list[tuple[float, str]] = []  # (time.monotonic() when read, line)
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
            self.stamped.append((time.monotonic(), line))
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


def _committed_frames(parts_dir) -> int:
    """The frames in extract's committed chunk files (each lists its frames' names)."""
    count = 0
    for p in parts_dir.glob("*.npz"):
        with np.load(p) as z:
            count += len(z["names"])
    return count


def test_kill_extract_resumes(inputs, tmp_path, rng):
    """An earlier features file of the first 40 frames; extract of all N frames resumes it and
    is killed; the next run keeps the earlier file's frames and the killed run's, extracts the
    rest, and ends with the features of an uninterrupted run. N is large enough, and the kill's
    window short enough, that neither run can finish inside its signal's window on a fast or a
    busy machine (with 120, a run sometimes finished before the kill landed; with 400, once
    PNG frames decoded in 40 % of OpenCV's time, two half-second chunks held 360 frames)."""
    n = 1200
    ds = _frames_dataset(inputs, tmp_path / "ds", 40)  # the recording's first 40 frames...
    target = ds / "features.h5"
    extract.main(None, ds, target)
    shutil.rmtree(ds / "images")  # ... then all n of them (a resume needs its own folder)
    _frames_dataset(inputs, ds, n)
    earlier = tree_hashes(target)
    parts_dir = ds / ".features.h5.parts"
    run = Run(["-v", "extract", str(ds)], tmp_path)
    started = run.wait_for(path_glob=(parts_dir, "*.npz", 2))  # two chunks committed
    delay = rng.uniform(0.0, 0.05)
    rc = run.kill_after(delay)
    assert started and rc == -signal.SIGKILL, (rc, delay, "".join(run.seen))
    assert tree_hashes(target) == earlier
    chunks = len(list(parts_dir.glob("*.npz")))
    kept = _committed_frames(parts_dir)
    # the next run has frames left to be interrupted in: a full chunk and more after the one
    # it waits for (a chunk is CHUNK_SECONDS of work or CHUNK_FRAMES frames, whichever is less)
    assert 2 <= kept <= n - 2 * CHUNK_FRAMES, kept
    # a Ctrl-C of the next run keeps what it finished too (its last chunk as well), and says so
    run = Run(["extract", str(ds)], tmp_path)
    run.wait_for(path_glob=(parts_dir, "*.npz", chunks + 1))
    rc = run.signal_after(rng.uniform(0.0, 0.1), signal.SIGINT)
    assert rc == 130 and "a rerun resumes where it stopped" in run.stderr(), (rc, run.stderr())
    assert tree_hashes(target) == earlier
    resumed = _committed_frames(parts_dir)
    assert resumed > kept
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


# ---------------------------------------------------------------------------- the two rounds

# The phases of `localize --smooth` with lut or fit on an omni dataset (stages.pipelines.
# images_to_poses), in the order the chain runs them: the -v line that opens each, and the
# artifacts (what follows the output's stem) it renames into place before the next one opens.
# The round-1 features are resumed and found finished: that phase writes no artifact, only
# extract's lock and parts folder, which it removes again.
TWO_ROUNDS_PHASES = [
    ("round-1 features", r"no features given: extracting", ()),
    ("first round", r"localize \S+ with (?:lut|fit): \d+ frames on", (".first-round.h5",
                                                              ".first-round.tum")),
    ("calibration", r"-> \S*/poses\.first-round\.h5$", (".recalibrated.yaml",)),
    ("re-extraction", r"second round: extracting", (".recalibrated.features.h5",)),
    ("second round", r"-> \S*/poses\.recalibrated\.features\.h5$", (".h5", ".tum")),
]
TWO_ROUNDS_END = r"localize (?:lut|fit): .* -> \S*/poses\.h5$"  # the last artifact is in place
TWO_ROUNDS_ARTIFACTS = (".features.h5", ".first-round.h5", ".first-round.tum",
                        ".recalibrated.yaml", ".recalibrated.features.h5", ".h5", ".tum")


def _without_seconds(report):
    """A method report (JSON) without the seconds its steps took (keys ending in ``_s``)."""
    if isinstance(report, dict):
        return {k: _without_seconds(v) for k, v in report.items() if not k.endswith("_s")}
    return report


def _artifact_content(path: Path):
    """What two runs of the same command on the same inputs write alike: an HDF5 artifact's
    datasets and attributes but those a run stamps (its creation time, the seconds its steps
    took, and its inputs' paths and content hashes, which change with the creation time of the
    first round's poses and of the learnt calib.yaml); a calib.yaml's mapping but its creation
    time; a .tum's text."""
    if path.suffix == ".h5":
        out = h5_content(path, skip_attrs=("created", "inputs", "dataset", "calib_hash"))
        if "@method_report" in out:
            out["@method_report"] = _without_seconds(json.loads(out["@method_report"]))
        return out
    if path.suffix == ".yaml":
        import yaml

        calib = yaml.safe_load(path.read_text())
        calib["calibration"].pop("created")
        return calib
    return path.read_text()


def _assert_same_artifact(got, want, name: str):
    if name.endswith(".h5"):
        assert_same_content(got, want)
    else:  # the same run's numbers printed as text by the same code: equal as written
        assert got == want, name


def _phase_window(stamped: list[tuple[float, str]], index: int) -> float:
    """How long phase ``index`` of TWO_ROUNDS_PHASES lasted in a run's stamped stderr: from
    its opening line to the next phase's (the last phase: to TWO_ROUNDS_END)."""
    opens = [p for _name, p, _written in TWO_ROUNDS_PHASES] + [TWO_ROUNDS_END]
    start = next(t for t, line in stamped if re.search(opens[index], line))
    end = next(t for t, line in stamped if t >= start and re.search(opens[index + 1], line))
    return end - start


@pytest.mark.parametrize("method", ["lut", "fit"])
def test_kill_two_rounds(inputs, tmp_path, method):
    """`localize --smooth` from the images (lut and fit, so two rounds: the first round, the
    calibration learnt from its poses, the frames extracted again with it, the second round)
    over the artifacts of an earlier finished run of the same command, started with
    --overwrite and killed (SIGKILL) in the phase SEED picks (round robin over
    TWO_ROUNDS_PHASES, so any five consecutive seeds aim at every phase), at a moment drawn
    uniformly over that phase's length in the earlier run (a run a little faster or slower
    than the earlier one may be killed in the next phase: the test prints the phase the kill
    landed in, read from the killed run's log).

    What holds after the kill, and why. The chain writes its artifacts one after the other,
    each to a part beside it that is renamed into place when whole; so each artifact of the
    earlier run is either byte-identical, or was replaced whole by the killed run: readable,
    and with the earlier run's content but for what a run stamps (_artifact_content: the same
    command on the same inputs). Only an artifact of a phase the killed run had opened (its -v
    line printed) can have been replaced; those of later phases are byte-identical, and so is
    the round-1 features file, which the run resumes, finds finished and leaves alone. No
    other file lies under an artifact's name: what the killed run left (its parts, extract's
    parts folder and lock) starts with ``.<artifact name>.``. The dataset, its calib.yaml
    included, is byte-identical. The next run (--overwrite) leaves no part beside any
    artifact, and its poses and companions are the earlier, uninterrupted run's."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    ds = inputs["ds"]
    out = tmp_path / "poses.h5"
    arts = {s: out.with_name("poses" + s) for s in TWO_ROUNDS_ARTIFACTS}
    dataset_before = tree_hashes(ds)
    # the round-1 features as extract makes them from the images, put in place before the
    # earlier run (which resumes them) so that its phases last as long as the killed run's
    shutil.copyfile(inputs["features"], arts[".features.h5"])
    args = ["localize", str(ds), "--map", str(inputs["map"]), "--method", method, "--smooth",
            "-o", str(out)]
    first = Run(["-v", *args], tmp_path)
    assert first.proc.wait(timeout=120) == 0, first.stderr()
    assert "second round: extracting" in first.stderr()  # the chain runs both rounds here
    earlier = {s: tree_hashes(p) for s, p in arts.items()}
    content = {s: _artifact_content(p) for s, p in arts.items()}

    rng = random.Random(f"two-rounds-{method}-{SEED}")
    # fit one phase on from lut, so that one seed kills the two methods in different phases
    index = (SEED + (method == "fit")) % len(TWO_ROUNDS_PHASES)
    phase, opens, _written = TWO_ROUNDS_PHASES[index]
    delay = rng.uniform(0.0, _phase_window(first.stamped, index))
    run = Run(["-v", *args, "--overwrite"], tmp_path)
    started = run.wait_for(pattern=opens)
    rc = run.kill_after(delay)
    log = run.stderr()
    assert started and rc == -signal.SIGKILL, (rc, phase, delay, log)
    reached = max(i for i, (_n, p, _w) in enumerate(TWO_ROUNDS_PHASES) if re.search(p, log, re.M))
    print(f"\ntwo rounds, seed {SEED}: killed {delay:.3f} s into the {phase} phase; the run had"
          f" reached the {TWO_ROUNDS_PHASES[reached][0]} phase"
          + (" and written every artifact" if re.search(TWO_ROUNDS_END, log, re.M) else ""))
    may_change = {s for _n, _p, written in TWO_ROUNDS_PHASES[:reached + 1] for s in written}
    replaced = []
    for s, path in arts.items():
        if tree_hashes(path) == earlier[s]:
            continue
        assert s in may_change, f"{path.name} replaced before its phase opened:\n{log}"
        _assert_same_artifact(_artifact_content(path), content[s], path.name)
        replaced.append(path.name)
    print(f"replaced whole: {replaced}; parts left:"
          f" {[x for p in arts.values() for x in parts_beside(p)]}")
    names = sorted(p.name for p in tmp_path.iterdir())
    left = sorted(x for p in arts.values() for x in parts_beside(p))
    assert names == sorted([*left, *(p.name for p in arts.values())]), names
    assert tree_hashes(ds) == dataset_before  # calib.yaml and every file of the recording

    res = CliRunner().invoke(cli, [*args, "--overwrite"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in arts.values())
    assert tree_hashes(arts[".features.h5"]) == earlier[".features.h5"]
    for s, path in arts.items():
        _assert_same_artifact(_artifact_content(path), content[s], path.name)
    assert tree_hashes(ds) == dataset_before


# ---- s54 group H4: files and interruptions


def test_kill_extract_with_debug_images_resumes(inputs, tmp_path, rng):
    """extract --debug-images killed: its overlays of frames not yet committed were in the
    folder, and the rerun refused them ("D/000000.png exists") and left the killed run's part
    of an overlay. The rerun now draws those again (they are newer than the parts folder it
    resumes), and ends with every frame's overlay and no part."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    n = 400
    ds = _frames_dataset(inputs, tmp_path / "ds", n)
    dbg = tmp_path / "dbg"
    run = Run(["extract", str(ds), "--debug-images", str(dbg)], tmp_path)
    started = run.wait_for(path_glob=(dbg, "*.png", 1))  # before its first chunk, mostly
    rc = run.kill_after(rng.uniform(0.0, 0.3))
    assert started and rc == -signal.SIGKILL, (rc, "".join(run.seen))
    res = CliRunner().invoke(cli, ["extract", str(ds), "--debug-images", str(dbg)])
    assert res.exit_code == 0, res.output
    names = [f"{i:06d}.png" for i in range(n)]
    assert sorted(p.name for p in dbg.iterdir()) == sorted([*names, "debug-images.yaml"])
    assert parts_beside(ds / "features.h5") == []


def test_kill_evaluate_leaves_no_report_json_without_its_plots(inputs, tmp_path, rng):
    """evaluate killed while drawing left report.json (written before the plots) beside some
    of them: a folder that looked finished. report.json now comes last, and the whole report
    is built beside the folder (s55 D13) and put in place in one rename: a killed run leaves
    no folder or a whole one, and the rerun writes it (removing the killed run's part)."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages.common.report_file import PLOT_NAMES

    poses = localize.main({"method": "lut"}, inputs["ds"], inputs["map"],
                          tmp_path / "poses.h5", features=inputs["features"])
    r = tmp_path / "r"
    args = ["evaluate", str(poses), "--truth", str(inputs["ds"] / "truth.csv"), "-o", str(r)]
    run = Run(args, tmp_path)
    started = run.wait_for(path_glob=(tmp_path, ".r.fieldloc-*.part/plots/*", 1))
    rc = run.kill_after(rng.uniform(0.0, 0.5))
    assert started, "".join(run.seen)
    plots = {p.name for p in (r / "plots").glob("*.png") if not p.name.startswith(".")}
    if (r / "report.json").exists():
        assert plots == set(PLOT_NAMES), (rc, plots)
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert {p.name for p in (r / "plots").iterdir()} == set(PLOT_NAMES)
    assert sorted(p.name for p in r.iterdir()) == ["errors.csv", "plots", "report.json",
                                                    "truth.tum"]
    assert not list(tmp_path.glob(".r.*"))  # the killed run's part removed
