"""--overwrite replaces only what fieldloc can vouch for, and extract on a nearly full disk
(hostile review s55, group G1 of s56: W2, W5, D3, D11).

The refusals are cases of tests/test_faults.py (block "s56 group G1"); here what must still
work: a poses file's own twin and a --debug-images folder's own overlays are replaced with
--overwrite, an overlay a killed run drew (not yet in the record) is drawn again rather than
refused forever, and extract's disk checks: a disk that cannot hold the features file is
refused before any frame is kept, one that can is not refused, and a disk without inodes is
the full disk's line (tmpfs mounts: those tests skip where mounting is not allowed).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import pytest
import yaml
from test_full_disks_and_permissions import _small_disk  # the full-disk tests' tmpfs

from stages import extract, localize
from stages.common import artifacts, poses_file
from stages.common.artifacts import WRITTEN_FILES, record_text
from stages.common.errors import FieldlocError
from stages.common.features_file import (
    FRAME_DATASETS,
    FeaturesFile,
    file_bytes,
    frame_columns,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run(small_omni_run):
    """conftest's 2-frame omni dataset, its features, map and poses (read only here)."""
    return small_omni_run


def test_localize_overwrite_replaces_its_own_twin_and_records_it(run, tmp_path):
    """The poses file records its twin's size and SHA-256; --overwrite replaces a twin the
    poses beside it vouch for, and refuses one edited since (one line naming it), and a
    link at its name even to the twin as written (a link is the user's)."""
    out = tmp_path / "p.h5"
    localize.main({"method": "lut"}, run["ds"], run["map"], out, features=run["features"])
    tum = out.with_suffix(".tum")
    with h5py.File(out, "r") as f:
        entry = f.attrs[poses_file.TWIN_ATTR]
    assert artifacts.as_written(tum, entry)
    localize.main({"method": "lut"}, run["ds"], run["map"], out, features=run["features"],
                  overwrite=True)
    assert poses_file.twin_vouched(out)(tum)
    tum.write_text(tum.read_text() + "# my note\n")
    with pytest.raises(FieldlocError, match="p.tum is not the TUM twin of p.h5 as fieldloc"):
        localize.main({"method": "lut"}, run["ds"], run["map"], out,
                      features=run["features"], overwrite=True)
    assert tum.read_text().endswith("# my note\n")
    # a user's link at the twin's name (to the twin moved aside, as written) is the user's
    mine = tmp_path / "mine.tum"
    tum.rename(mine)
    mine.write_text(mine.read_text()[: -len("# my note\n")])
    tum.symlink_to(mine.name)
    with pytest.raises(FieldlocError, match="p.tum is not the TUM twin of p.h5 as fieldloc"):
        localize.main({"method": "lut"}, run["ds"], run["map"], out,
                      features=run["features"], overwrite=True)
    assert tum.is_symlink()


def _table(folder: Path) -> dict:
    return yaml.safe_load((folder / extract.DEBUG_RECORD).read_text())[WRITTEN_FILES]


def test_debug_overlays_are_recorded_and_replaced_as_drawn(run, tmp_path):
    """debug-images.yaml lists each overlay drawn; --overwrite draws them again. An overlay
    the record does not list (drawn by a run killed before it recorded it) but that carries
    fieldloc's mark is drawn again too, not refused forever; a listed one edited is refused."""
    dbg = tmp_path / "dbg"
    extract.main(None, run["ds"], tmp_path / "f.h5", debug_images=dbg)
    table = _table(dbg)
    assert sorted(table) == sorted([*(p.name for p in dbg.glob("*.png")), extract.DEBUG_RECORD])
    first = sorted(table)[0]
    # a run killed after drawing: its overlays are out of the record (which it wrote, as it
    # writes every record: vouching for itself)
    rec = yaml.safe_load((dbg / extract.DEBUG_RECORD).read_text())
    rec[WRITTEN_FILES] = {}
    (dbg / extract.DEBUG_RECORD).write_text(record_text(rec, extract.DEBUG_RECORD))
    extract.main(None, run["ds"], tmp_path / "f.h5", debug_images=dbg, overwrite=True)
    assert sorted(_table(dbg)) == sorted(table)
    with open(dbg / first, "ab") as f:
        f.write(b"mine")
    with pytest.raises(FieldlocError, match=f"dbg/{first} was edited since fieldloc wrote it"):
        extract.main(None, run["ds"], tmp_path / "f.h5", debug_images=dbg, overwrite=True)
    assert (dbg / first).read_bytes().endswith(b"mine")


def test_the_least_file_size_is_a_lower_bound_of_the_file(run, tmp_path):
    """The disk check before the first frame (the first frame's columns) is no more than the
    file takes, and the check before the merge (all frames' columns) no less than its
    chunks (within HDF5's own structure)."""
    feats = Path(run["features"])
    with FeaturesFile(feats) as f:
        frames = [{k: v for k, v in f.frame(n).items() if k in FRAME_DATASETS}
                  for n in f.names]
    least = file_bytes(frame_columns(frames[0]), len(frames))
    assert least <= feats.stat().st_size
    columns: dict = {}
    for fr in frames:
        for k, (rows, row) in frame_columns(fr).items():
            columns[k] = (columns.get(k, (0, row))[0] + rows, row)
    assert feats.stat().st_size - (32 << 10) <= file_bytes(columns, len(frames))


# ------------------------------------------------------------------ small disks (root)


def _fieldloc(*args, cwd) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "fieldloc_cli.main", *map(str, args)],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def _one_line(r: subprocess.CompletedProcess) -> str:
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, (r.returncode, r.stderr[-3000:])
    return lines[0]


def test_extract_onto_a_disk_too_small_for_the_file_is_refused_before_any_frame(run,
                                                                               tmp_path):
    """D3: the least the file takes (its index, and the storage chunks of the first frame's
    columns) is checked before anything is kept: nothing is left on the small disk."""
    with _small_disk(tmp_path / "full", "100k") as full:
        (full / "mine.txt").write_text("user-file")
        r = _fieldloc("-q", "extract", run["ds"], "-o", full / "f.h5", cwd=tmp_path)
        line = _one_line(r)
        assert f"extract into {full}/f.h5 would write about" in line, line
        assert sorted(os.listdir(full)) == ["mine.txt"]


def test_extract_onto_a_disk_just_large_enough_succeeds(run, tmp_path):
    """D3: a 300 kB disk holds a 2-frame omni extraction (its parts and the file): the check
    before the merge no longer asks for a fixed 256 KiB more than the file takes."""
    with _small_disk(tmp_path / "full", "300k") as full:
        r = _fieldloc("-q", "extract", run["ds"], "-o", full / "f.h5", cwd=tmp_path)
        assert r.returncode == 0, r.stderr[-3000:]
        assert sorted(os.listdir(full)) == ["f.h5"]


def test_extract_debug_images_without_inodes_is_the_full_disk_line(run, tmp_path):
    """D11: no inode left for an overlay: fieldloc's full-disk line (finished frames kept, a
    rerun resumes), not the system's text."""
    with _small_disk(tmp_path / "full", "20m", inodes=4) as full:
        r = _fieldloc("-q", "extract", run["ds"], "-o", tmp_path / "f.h5", "--debug-images",
                      full / "dbg", cwd=tmp_path)
        line = _one_line(r)
        assert "no space left on its disk" in line, line
        assert "No space left on device" not in line, line
