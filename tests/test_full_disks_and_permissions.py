"""Full disks, files fieldloc may not read, caches it cannot write (trial
D1's findings). What the case table of test_faults cannot express: a command run as a user
runs it (its own process: a segmentation fault, Dask's workers and matplotlib print on the
process's stderr), without root's override of file modes (``setpriv``; a user who is not root
has none), or on a small disk (a tmpfs: where mounting is not allowed, as for a CI user who is
not root, those tests skip)."""

from __future__ import annotations

import contextlib
import errno
import importlib
import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from stages import build_map, extract, simulate
from stages.common import artifacts
from stages.common.errors import DiskFullError, FieldlocError

ROOT = Path(__file__).resolve().parents[1]
MODES_CAPS = "-dac_override,-dac_read_search"  # root's overrides of file modes


def _fieldloc(*args, cwd, env: dict | None = None, unprivileged: bool = False,
              timeout: float = 300) -> subprocess.CompletedProcess:
    """The fieldloc of this tree run as a user runs it (its own process and stderr); with
    ``unprivileged``, without root's override of file modes."""
    prefix = _without_overrides() if unprivileged else []
    env = {**os.environ, **(env or {}), "PYTHONPATH": str(ROOT)}
    return subprocess.run([*prefix, sys.executable, "-m", "fieldloc_cli.main",
                           *map(str, args)], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def _without_overrides() -> list[str]:
    """The prefix that runs a command without root's override of file modes (none for a user
    who is not root); skips where root cannot drop it."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("root without setpriv: file modes cannot be tested")
    return [setpriv, f"--inh-caps={MODES_CAPS}", f"--bounding-set={MODES_CAPS}"]


@contextlib.contextmanager
def _small_disk(folder: Path, size: str = "3m", left: int | None = None,
                inodes: int | None = None):
    """A tmpfs of ``size`` mounted at ``folder`` (made), filled up to ``left`` bytes free if
    given; unmounted after. Skips where mounting is not allowed."""
    folder.mkdir()
    opts = f"size={size}" + (f",nr_inodes={inodes}" if inodes else "")
    try:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(folder)],
                           capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as e:
        pytest.skip(f"cannot mount a tmpfs here ({e})")
    if r.returncode:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip()[:80]})")
    try:
        if left is not None:
            fill = folder / "fill"
            with open(fill, "wb", buffering=0) as f, contextlib.suppress(OSError):
                while True:
                    f.write(b"\0" * 4096)
            os.truncate(fill, max(0, fill.stat().st_size - left))
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True, timeout=30)


def _one_line(r: subprocess.CompletedProcess, rc: int = 1) -> str:
    lines = r.stderr.strip().splitlines()
    assert r.returncode == rc and len(lines) == 1, (r.returncode, r.stderr[-3000:])
    assert lines[0].startswith("fieldloc: error: "), r.stderr
    return lines[0]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A coarse spl map, a 2-frame omni dataset and its features (shared, read-only)."""
    root = tmp_path_factory.mktemp("f3")
    p = {"root": root}
    p["map"] = build_map.main({"resolution": 0.5}, "spl", root / "spl.map.h5")
    p["omni"] = simulate.main(dict(simulate.confs["omni-default"], frames=2, seed=5), "spl",
                              root / "omni")
    p["features"] = extract.main(None, p["omni"], root / "omni.f.h5")
    return p


def _localize(p, out) -> list:
    return ["-q", "localize", p["omni"], "--map", p["map"], "--features", p["features"],
            "--method", "lut", "-o", out]


# ---------------------------------------------------------------- D1, D2: HDF5 on a full disk

@pytest.mark.parametrize("left_kb", [4, 8, 12])
def test_localize_onto_a_nearly_full_disk_is_one_line(inputs, tmp_path, left_kb):
    """HDF5 meeting a full disk could neither write nor close its file: h5py's "Exception
    ignored" tracebacks for each object, a RuntimeError through click, or a segmentation
    fault at exit. An artifact is built in memory and written in one plain write now: one
    line naming the output, no temporary part left."""
    with _small_disk(tmp_path / "full", left=left_kb * 1024) as full:
        r = _fieldloc(*_localize(inputs, full / "p.h5"), cwd=tmp_path)
        line = _one_line(r)
        assert f"cannot write {full}/p." in line and "no space left on its disk" in line
        assert not [f for f in os.listdir(full) if ".part" in f or f.startswith(".p.")]


@pytest.mark.parametrize("left_kb", [4, 40])
def test_build_templates_onto_a_nearly_full_disk_is_one_line(inputs, tmp_path, left_kb):
    """build-templates printed the right line, then died of SIGSEGV at exit (HDF5 closing
    the file its failed write had left open)."""
    with _small_disk(tmp_path / "full", left=left_kb * 1024) as full:
        r = _fieldloc("-q", "build-templates", inputs["omni"], "-o", full / "t.h5",
                      cwd=tmp_path)
        line = _one_line(r)
        assert f"cannot write {full}/t.h5: no space left on its disk" in line
        assert sorted(os.listdir(full)) == ["fill"]


def test_an_artifact_that_fails_while_written_leaves_no_part(tmp_path):
    """The file is written once, after the block: a block that fails leaves nothing (and
    HDF5 held nothing on disk to close); a full disk on that write is DiskFullError naming
    the target."""
    target = tmp_path / "x.h5"
    with pytest.raises(ValueError):
        with artifacts.write_artifact(target, {"schema": "fieldloc.poses"}) as f:
            f.create_dataset("a", data=np.arange(3))
            raise ValueError("stop")
    assert os.listdir(tmp_path) == []
    with artifacts.write_artifact(target, {"schema": "fieldloc.poses"}) as f:
        f.create_dataset("a", data=np.arange(3))
    with h5py.File(target, "r") as f:
        assert list(f["a"][()]) == [0, 1, 2] and f.attrs["schema"] == "fieldloc.poses"


# ---------------------------------------------------------------- D15: numba's cache

def test_a_kernel_cache_that_cannot_be_written_is_no_error(tmp_path, monkeypatch, caplog):
    """numba raised the OSError of its cache's write (a full disk) out of the kernel's first
    call: the command failed with "No space left on device". fieldloc's njit compiles and runs
    the kernel all the same, and says so once at INFO."""
    from numba.core import caching

    from stages.common import jit

    def full(self, name, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(caching.IndexDataCacheFile, "_save_data", full)
    monkeypatch.setattr(jit, "_told", False)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "f3_kernel.py").write_text(
        "from stages.common.jit import njit\n\n\n@njit(cache=True)\n"
        "def twice(x):\n    return 2 * x\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("f3_kernel")
    with caplog.at_level(logging.INFO, logger="stages.common.jit"):
        assert mod.twice(21) == 42
    notes = [r for r in caplog.records if r.name == "stages.common.jit"]
    assert len(notes) == 1 and notes[0].levelno == logging.INFO, caplog.text
    assert "cannot be written" in notes[0].getMessage()


def test_every_kernel_takes_fieldlocs_njit():
    """The guard is in place before any kernel compiles only if every module takes njit
    from stages.common.jit."""
    direct = [str(p.relative_to(ROOT)) for p in (ROOT / "stages").rglob("*.py")
              if p.name != "jit.py" and "from numba import njit" in p.read_text()]
    assert direct == []


# ---------------------------------------------------------------- D4: batch's workers

def test_a_run_failing_in_a_worker_is_fieldlocs_line_only(inputs, tmp_path):
    """A run that failed inside a Dask worker printed the worker's "Compute Failed" block
    (with a traceback text) and WARNING lines before fieldloc's own line."""
    spec = tmp_path / "s.yaml"
    spec.write_text(f"map: {inputs['map']}\ndatasets: [{{path: {inputs['omni']}}}]\n"
                    "methods: [lut]\n")
    with _small_disk(tmp_path / "full", left=16 * 1024) as full:
        r = _fieldloc("-q", "batch", spec, "-o", full / "res", "--workers", "1",
                      cwd=tmp_path)
        assert "distributed" not in r.stderr and "Compute Failed" not in r.stderr, r.stderr
        assert "no space left" in _one_line(r)
        run = json.loads((full / "res" / "runs" / "omni" / "lut-default" / "run.json")
                         .read_text())
        assert run["status"] == "failed", run  # in the worker


# ---------------------------------------------------------------- D5, D9: unreadable files

def test_an_unreadable_input_is_one_line_of_fieldlocs(inputs, tmp_path):
    """click's check of a readable file gave its 3-line usage error (exit 2); the readers
    called an unreadable file "not an HDF5 file (corrupt ...)". One line now, naming the file
    and the reason."""
    m = tmp_path / "m.h5"
    shutil.copyfile(inputs["map"], m)
    m.chmod(0)
    r = _fieldloc("-q", "localize", inputs["omni"], "--map", m, "--features",
                  inputs["features"], "-o", tmp_path / "p.h5", cwd=tmp_path,
                  unprivileged=True)
    assert _one_line(r) == f"fieldloc: error: cannot read {m}: permission denied"
    spec = tmp_path / "s.yaml"
    spec.write_text(f"map: {m}\ndatasets: [{{path: {inputs['omni']}}}]\nmethods: [lut]\n")
    r = _fieldloc("-q", "batch", spec, "-o", tmp_path / "res", cwd=tmp_path,
                  unprivileged=True)
    assert f"cannot read {m}: permission denied" in _one_line(r)
    assert not (tmp_path / "res").exists() and not (tmp_path / "p.h5").exists()


def test_an_unreadable_output_given_overwrite_is_named_as_such(inputs, tmp_path):
    """--overwrite of fieldloc's own output that cannot be read was "not written by
    fieldloc" / "no simulation.yaml marker"; an existing unreadable -o was click's usage
    error."""
    m2 = build_map.main({"resolution": 0.5}, "spl", tmp_path / "m2.h5")
    m2.chmod(0)
    r = _fieldloc("-q", "build-map", "spl", "--resolution", "0.5", "-o", m2, "--overwrite",
                  cwd=tmp_path, unprivileged=True)
    assert _one_line(r) == f"fieldloc: error: cannot read {m2}: permission denied"
    ds = simulate.main(dict(simulate.confs["omni-default"], frames=1), "spl", tmp_path / "ds")
    (ds / "simulation.yaml").chmod(0)
    r = _fieldloc("-q", "simulate", "omni", "--field", "spl", "--frames", "1", "-o", ds,
                  "--overwrite", cwd=tmp_path, unprivileged=True)
    assert _one_line(r) == (f"fieldloc: error: cannot read {ds / 'simulation.yaml'}:"
                            " permission denied")


def test_the_readers_say_permission_denied(tmp_path, monkeypatch):
    """The checks that tell fieldloc's files from others' (and the HDF5 opener) raise the one
    line for a file they may not read, rather than answering "not ours" or "corrupt"."""
    from stages.common.batch_file import read_json

    f = tmp_path / "x"
    f.write_bytes(b"\x89HDF\r\n\x1a\n")

    def refused(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied", str(f))

    monkeypatch.setattr("builtins.open", refused)
    monkeypatch.setattr(Path, "read_text", refused)
    for check in (artifacts.fieldloc_wrote, lambda p: artifacts.starts_with(p, b"#"),
                  lambda p: artifacts.open_artifact(p, "fieldloc.map", 9), read_json):
        with pytest.raises(FieldlocError, match=f"cannot read {f}: permission denied"):
            check(f)
    with pytest.raises(FieldlocError, match="simulation.yaml: permission denied"):
        (tmp_path / "simulation.yaml").touch()
        artifacts.written_by(tmp_path, "simulation.yaml", "fieldloc simulate")


# ---------------------------------------------------------------- D10: matplotlib's caches

@pytest.mark.parametrize("where", ["HOME", "MPLCONFIGDIR"])
def test_an_unwritable_matplotlib_folder_says_nothing_under_q(inputs, tmp_path, where):
    """matplotlib's 400-character WARNING about the temporary folder it used instead of an
    unwritable HOME or MPLCONFIGDIR was printed under -q by every picture."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    env = {k: v for k, v in os.environ.items()
           if k not in ("MPLCONFIGDIR", "XDG_CACHE_HOME", "XDG_CONFIG_HOME")}
    env[where] = str(ro)
    prefix = _without_overrides()
    r = subprocess.run([*prefix, sys.executable, "-m", "fieldloc_cli.main", "-q", "show",
                        "map", str(inputs["map"]), "-o", str(tmp_path / "m.png")],
                       cwd=tmp_path, env={**env, "PYTHONPATH": str(ROOT)},
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert (tmp_path / "m.png").is_file()


# ---------------------------------------------------------------- D14: what a full disk names

def test_simulate_onto_a_full_disk_names_its_output(tmp_path):
    """simulate named its hidden temporary folder (removed by then) and said "finished files
    were kept" when none was; cv2.imwrite's failure gave no reason at all."""
    with _small_disk(tmp_path / "full", size="20m", inodes=5) as full:
        r = _fieldloc("-q", "simulate", "omni", "--field", "spl", "--frames", "4", "-o",
                      full / "ds", cwd=tmp_path)
        line = _one_line(r)
        assert line.startswith(f"fieldloc: error: cannot write {full / 'ds'}: no space left")
        assert ".part" not in line and "kept" not in line
        assert os.listdir(full) == []


def test_import_rosbag_onto_a_full_disk_names_its_output(tmp_path):
    pytest.importorskip("rosbags")
    from stages.ingest.bag_writer import write_bag

    rng = np.random.default_rng(0)
    frames = [(100.0 + 0.1 * i, (rng.integers(0, 256, (64, 64, 3), dtype=np.uint8), "bgr8"))
              for i in range(6)]
    bag = write_bag(tmp_path / "b.bag", "ros1", frames=frames)
    with _small_disk(tmp_path / "full", size="20m", inodes=5) as full:
        r = _fieldloc("-q", "import", "rosbag", bag, "-o", full / "d", "--image-topic",
                      "/camera/image", cwd=tmp_path)
        line = _one_line(r)
        assert line.startswith(f"fieldloc: error: cannot write {full / 'd'}: no space left")
        assert ".part" not in line and "kept" not in line


def test_a_full_disk_names_the_outermost_output(tmp_path):
    """A file written inside a temporary folder of an output is reported as the output's."""
    def full():
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(DiskFullError) as e:
        with artifacts.writing(tmp_path / "ds"):
            with artifacts.writing(tmp_path / ".ds.fieldloc-1-x.part" / "truth.csv"):
                full()
    assert str(e.value).startswith(f"cannot write {tmp_path / 'ds'}: no space left")
    assert "kept" not in str(e.value)
