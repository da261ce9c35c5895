"""Full disks and read-only folders: a failed write leaves the outputs as they were.

- D6: localize's poses.h5 and its TUM twin are one pair: both written in full before either
  is committed; a failure while writing either leaves the old pair as it was and no part.
- D8, D13: evaluate builds the whole report folder beside the output and commits it in one
  rename: a failure (a full disk) leaves the old report exactly as it was and nothing new; a
  read-only plots/ is refused up front.
- D7: a folder replaced by ``commit_dir`` that cannot be removed is named in one warning, and
  a later run removes it when it can.
- D3, D11: extract names the file of every failed write, checks the least it writes before
  the first frame, and a run that fails before any frame finished leaves nothing.

Full disks are simulated in-process (the write that fails raises ENOSPC); the read-only cases
run the CLI without root's DAC override (setpriv), skipped where that is not possible.
"""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import subprocess
import sys
from collections import namedtuple
from pathlib import Path

import h5py
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import extract
from stages.common import artifacts, poses_file
from stages.common.errors import FieldlocError

ROOT = Path(__file__).resolve().parents[1]


def _snapshot(folder: Path) -> dict[str, str]:
    """Every file and folder under ``folder`` (hidden ones too), files with their SHA-256."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        out[rel] = "folder"
        if p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()  # exact bytes: files on disk
    return out


def _enospc(*_a, **_k):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.fixture(scope="module")
def run(small_omni_run):
    """conftest's 2-frame omni dataset, its features, map and poses (read only here)."""
    return small_omni_run


# ---------------------------------------------------------------------------- D6


def _track() -> poses_file.PoseTrack:
    t = poses_file.PoseTrack()
    t.add("000000", 0.0, (0.5, 0.25, 0.1), confidence=0.9)
    t.add("000001", 0.1, None)
    return t


@pytest.mark.parametrize("fails", ["tum", "h5"])
def test_a_poses_pair_is_committed_together(tmp_path, monkeypatch, fails):
    """D6: a full disk met while writing either file of the pair: one line naming it, the old
    pair exactly as it was, no part left; a new pair: nothing at all."""
    out = tmp_path / "p.h5"
    poses_file.write_poses(out, _track(), {"schema": poses_file.SCHEMA, "schema_version": 1})
    before = _snapshot(tmp_path)
    if fails == "tum":
        monkeypatch.setattr(poses_file, "write_tum_to", _enospc)
    else:
        monkeypatch.setattr(h5py.Group, "create_dataset", _enospc)
    for target, old in ((out, before), (tmp_path / "new" / "q.h5", {})):
        target.parent.mkdir(exist_ok=True)
        with pytest.raises(FieldlocError, match="no space left") as e:
            poses_file.write_poses(target, _track(), {"schema": poses_file.SCHEMA})
        assert str(target) in str(e.value)  # the output given, whichever file failed
        assert _snapshot(target.parent) == old
    assert _snapshot(tmp_path) == {**before, "new": "folder"}


def test_localize_on_a_full_disk_leaves_no_half_pair(run, tmp_path, monkeypatch):
    """D6 through the CLI: the twin's write fails; no p.h5 is left, so the rerun (space
    freed) is not refused."""
    out = tmp_path / "p.h5"
    args = ["-q", "localize", str(run["ds"]), "--map", str(run["map"]), "--features",
            str(run["features"]), "--method", "lut", "-o", str(out)]
    monkeypatch.setattr(poses_file, "write_tum_to", _enospc)
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 1 and f"cannot write {out}: no space" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert os.listdir(tmp_path) == []
    monkeypatch.undo()
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    assert out.is_file() and out.with_suffix(".tum").is_file()


# ---------------------------------------------------------------------------- D8, D13


def _evaluate(run, out, *extra):
    return CliRunner().invoke(cli, ["-q", "evaluate", str(run["poses"]), "--truth",
                                    str(run["ds"]), "-o", str(out), *extra])


def test_evaluate_failing_keeps_the_old_report_whole(run, tmp_path, monkeypatch):
    """D8/D13: a full disk met while drawing a plot of the new report (after errors.csv and
    truth.tum were written): the old report folder exactly as it was, nothing beside it; a new
    report folder is not made at all."""
    rep = tmp_path / "rep"
    assert _evaluate(run, rep).exit_code == 0
    before = _snapshot(tmp_path)
    calls = []

    def full_at_the_second(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            _enospc()
        return save(*a, **k)

    from stages.show import report_plots

    save = report_plots.save_figure
    monkeypatch.setattr(report_plots, "save_figure", full_at_the_second)
    r = _evaluate(run, rep, "--overwrite", "--stamp-tolerance", "0.02")
    assert r.exit_code == 1 and "no space left" in r.stderr, r.output
    assert len(r.stderr.strip().splitlines()) == 1 and ".fieldloc-" not in r.stderr, r.stderr
    assert f"cannot write {rep}" in r.stderr and r.stderr.count("no space left") == 1
    assert _snapshot(tmp_path) == before
    calls.clear()
    r = _evaluate(run, tmp_path / "new")
    assert r.exit_code == 1 and not (tmp_path / "new").exists()
    assert _snapshot(tmp_path) == before
    monkeypatch.undo()
    old_report = os.stat(rep / "report.json").st_ino
    assert _evaluate(run, rep, "--overwrite", "--stamp-tolerance", "0.02").exit_code == 0
    # written anew (its bytes may equal the first report's: the same conf within the same
    # second of its `created` stamp), and nothing left beside it
    assert os.stat(rep / "report.json").st_ino != old_report
    assert sorted(os.listdir(tmp_path)) == ["rep"]


def test_evaluate_into_a_folder_with_a_users_files_keeps_them(run, tmp_path):
    """A report folder that also holds a user's notes: the report's files are replaced one by
    one, the notes kept."""
    rep = tmp_path / "rep"
    assert _evaluate(run, rep).exit_code == 0
    (rep / "notes.txt").write_text("mine")
    r = _evaluate(run, rep, "--overwrite", "--stamp-tolerance", "0.02")
    assert r.exit_code == 0, r.output
    assert (rep / "notes.txt").read_text() == "mine"
    assert (rep / "report.json").is_file() and len(os.listdir(rep / "plots")) == 4
    assert sorted(os.listdir(tmp_path)) == ["rep"]


# ---------------------------------------------------------------------------- D7


def test_a_replaced_folder_that_cannot_be_removed_is_named(tmp_path, monkeypatch, caplog):
    """D7: commit_dir moved the old folder aside and the system refuses its removal: one
    warning names it and says to remove it; it is not taken for an interrupted replacement;
    a later run (another pid) removes it when it can."""
    path, new = tmp_path / "ds", tmp_path / "new"
    (path / "images").mkdir(parents=True)
    (path / "images" / "0.png").write_bytes(b"old")
    new.mkdir()
    (new / "a").write_text("new")
    rmtree = shutil.rmtree

    def refuse(p, ignore_errors=False, **k):
        if not ignore_errors:
            raise PermissionError(errno.EACCES, "Permission denied", "0.png")

    monkeypatch.setattr(artifacts.shutil, "rmtree", refuse)
    artifacts.commit_dir(new, path, replace=True)
    monkeypatch.setattr(artifacts.shutil, "rmtree", rmtree)
    left = [p for p in tmp_path.iterdir() if p.name.startswith(".ds.fieldloc-")]
    assert len(left) == 1 and (path / "a").is_file()
    said = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(said) == 1 and f"beside it to {left[0].name} " in said[0], said
    assert "remove it" in said[0]
    assert "\n" not in said[0]
    shutil.rmtree(path)  # the real name gone: the leftover is no replacement to restore
    artifacts.restore_interrupted_replacement(path)
    assert not path.exists()
    dead = left[0].with_name(left[0].name.replace(f"-{os.getpid()}-", "-999999999-"))
    left[0].rename(dead)
    assert artifacts.remove_stale_parts(path) == [dead] and not dead.exists()


# ---------------------------------------------------------------------------- D3, D11


def _extract(ds, out, *extra):
    return CliRunner().invoke(cli, ["-q", "extract", str(ds), "-o", str(out), *extra])


def test_extract_checks_the_least_it_writes_before_the_first_frame(run, tmp_path,
                                                                    monkeypatch):
    """D3: a disk without room even for the features file's own structure is refused before
    any frame is extracted, and nothing is written."""
    from stages.common import resources

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(resources.shutil, "disk_usage", lambda p: usage(10**6, 10**6, 4096))
    monkeypatch.setattr(extract, "read_frame", lambda *a: pytest.fail("a frame was read"))
    r = _extract(run["ds"], tmp_path / "f.h5")
    assert r.exit_code == 1 and f"extract into {tmp_path / 'f.h5'} would write" in r.stderr
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("where", ["run.json", "first image", "first overlay"])
def test_extract_failing_before_a_frame_leaves_nothing(run, tmp_path, monkeypatch, where):
    """D3/D11: a failure before any frame finished (the parts' run.json on a full disk, an
    unreadable first image, a full disk under the debug overlays) ends in one line naming the
    file and leaves no parts folder, nor the debug folder it made."""
    out = tmp_path / "f.h5"
    extra = []
    if where == "run.json":
        monkeypatch.setattr(Path, "write_text", _enospc)
        said = f"cannot write {out}: no space left"
    elif where == "first image":
        image = run["ds"] / "images" / "000000.png"

        def unreadable(path, *a, **k):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        monkeypatch.setattr(extract, "read_frame", unreadable)
        said = f"{image}: Permission denied"
    else:
        extra = ["--debug-images", str(tmp_path / "dbg")]
        monkeypatch.setattr(extract, "with_mark", _enospc)
        said = f"cannot write {tmp_path / 'dbg' / '000000.png'}: no space left"
    r = _extract(run["ds"], out, *extra)
    assert r.exit_code == 1 and said in r.stderr, r.output
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert os.listdir(tmp_path) == []


def test_an_os_error_while_writing_names_the_file(tmp_path):
    """``writing``: a system error without a file (EIO from a write) is given the file."""
    with pytest.raises(OSError) as e, artifacts.writing(tmp_path / "x.h5"):
        raise OSError(errno.EIO, "Input/output error")
    assert e.value.filename == str(tmp_path / "x.h5")


# ---------------------------------------------------------------------------- read-only


NP = ["setpriv", "--inh-caps=-dac_override,-dac_read_search",
      "--bounding-set=-dac_override,-dac_read_search"]


def _without_override(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv to drop the DAC override")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([*NP, sys.executable, "-m", "fieldloc_cli.main", "-q", *args],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def test_evaluate_overwrite_into_a_read_only_plots_folder_is_refused(run, tmp_path):
    """D8 for real: plots/ read-only (root without its override): refused up front in one
    line, the old report exactly as it was."""
    rep = tmp_path / "rep"
    assert _evaluate(run, rep).exit_code == 0
    (rep / "plots").chmod(0o555)
    before = _snapshot(tmp_path)
    try:
        r = _without_override(["evaluate", str(run["poses"]), "--truth", str(run["ds"]), "-o",
                               str(rep), "--overwrite", "--stamp-tolerance", "0.02"], tmp_path)
        assert r.returncode == 1, r.stderr
        assert r.stderr.strip() == (f"fieldloc: error: cannot write into {rep / 'plots'}: the"
                                    " folder is not writable"), r.stderr
        assert _snapshot(tmp_path) == before
    finally:
        (rep / "plots").chmod(0o755)


def test_simulate_overwrite_with_read_only_images_says_what_is_left(tmp_path):
    """D7 for real: the old dataset's images/ read-only: the run succeeds, one WARNING line
    names the copy left; once images/ is writable again, the next run removes it."""
    conf = ["simulate", "omni", "--field", "spl", "--frames", "1", "-o", str(tmp_path / "ds")]
    assert CliRunner().invoke(cli, ["-q", *conf, "--seed", "1"]).exit_code == 0
    (tmp_path / "ds" / "images").chmod(0o555)
    try:
        r = _without_override([*conf, "--seed", "2", "--overwrite"], tmp_path)
        assert r.returncode == 0, r.stderr
        left = [p for p in tmp_path.iterdir() if p.name.startswith(".ds.fieldloc-")]
        assert len(left) == 1, os.listdir(tmp_path)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "WARNING" in lines[0] and left[0].name in lines[0], lines
        for p in left[0].rglob("*"):
            if p.is_dir():
                p.chmod(0o755)
        r = _without_override([*conf, "--seed", "3", "--overwrite"], tmp_path)
        assert r.returncode == 0, r.stderr
        assert not left[0].exists() and left[0].name in r.stderr
    finally:
        for p in tmp_path.rglob("*"):
            if p.is_dir():
                p.chmod(0o755)


def test_extract_debug_images_in_a_read_only_folder_is_refused_up_front(run, tmp_path):
    """D11 for real: --debug-images d/dbg with d read-only: refused before anything is
    written (no parts folder, no lock)."""
    (tmp_path / "d").mkdir(mode=0o555)
    try:
        r = _without_override(["extract", str(run["ds"]), "-o", str(tmp_path / "f.h5"),
                               "--debug-images", str(tmp_path / "d" / "dbg")], tmp_path)
        assert r.returncode == 1, r.stderr
        assert r.stderr.strip() == (f"fieldloc: error: cannot write {tmp_path / 'd' / 'dbg'}:"
                                    f" folder {tmp_path / 'd'} is not writable"), r.stderr
        assert os.listdir(tmp_path) == ["d"] and os.listdir(tmp_path / "d") == []
    finally:
        (tmp_path / "d").chmod(0o755)
