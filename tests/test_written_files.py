"""A fieldloc folder's files replaced only as fieldloc wrote them (C4), and
a poses file's TUM twin that never disagrees with it after an interruption (C6).

The refusals of edited files are cases of tests/test_faults.py (block "s55 group F1"); here
what must still work: --overwrite of folders left as fieldloc wrote them (a record of an older
fieldloc without hashes is refused whole), and localize stopped between its two commits.
"""

from __future__ import annotations

import json

import pytest
import yaml

from stages import evaluate, localize, simulate
from stages.common import artifacts, poses_file
from stages.common.artifacts import WRITTEN_FILES
from stages.common.poses_file import read_poses


@pytest.fixture(scope="module")
def run(small_omni_run):
    """conftest's 2-frame omni dataset, its features, map and poses (read only here)."""
    return small_omni_run


def test_overwrite_of_folders_as_fieldloc_wrote_them(run, tmp_path):
    """A report and a dataset left as written are replaced with --overwrite, and their
    records list what was written, with sizes and hashes."""
    rep = evaluate.main(None, run["poses"], run["ds"], tmp_path / "rep")
    table = json.loads((rep / "report.json").read_text())[WRITTEN_FILES]
    assert set(table) >= {"errors.csv", "truth.tum"}
    evaluate.main(None, run["poses"], run["ds"], rep, overwrite=True)
    conf = dict(simulate.confs["omni-clean"], frames=1, seed=1814)
    data = simulate.main(conf, "spl", tmp_path / "data")
    table = yaml.safe_load((data / "simulation.yaml").read_text())[WRITTEN_FILES]
    assert "truth.csv" in table and "images/000000.png" in table
    assert int(table["truth.csv"].split()[0]) == (data / "truth.csv").stat().st_size
    simulate.main(conf, "spl", data, overwrite=True)
    # what the table is for: an edit that keeps the file's size is still told from it
    truth = bytearray((data / "truth.csv").read_bytes())
    truth[-2] = ord("7") if truth[-2] != ord("7") else ord("3")
    (data / "truth.csv").write_bytes(bytes(truth))
    from stages.common.errors import FieldlocError

    with pytest.raises(FieldlocError, match="truth.csv was edited since fieldloc wrote it"):
        simulate.main(conf, "spl", data, overwrite=True)
    assert (data / "truth.csv").read_bytes() == bytes(truth)  # the user's edit is kept


def test_a_record_without_hashes_vouches_for_nothing(tmp_path):
    """A dataset of an older simulate (no WRITTEN_FILES): its CSV files carry no mark, and
    calib.yaml's mark survives an edit, so fieldloc cannot tell them from a user's edit:
    --overwrite refuses the folder in one line naming it, and leaves it as it was (s56 W2)."""
    conf = dict(simulate.confs["omni-clean"], frames=1, seed=1815)
    data = simulate.main(conf, "spl", tmp_path / "data")
    rec = yaml.safe_load((data / "simulation.yaml").read_text())
    del rec[WRITTEN_FILES]
    (data / "simulation.yaml").write_text(yaml.safe_dump(rec, sort_keys=False))
    before = {p: p.read_bytes() for p in data.rglob("*") if p.is_file()}
    from stages.common.errors import FieldlocError

    with pytest.raises(FieldlocError, match="data's simulation.yaml lists no written_files"):
        simulate.main(conf, "spl", data, overwrite=True)
    assert {p: p.read_bytes() for p in data.rglob("*") if p.is_file()} == before


def test_localize_stopped_between_poses_and_twin_leaves_no_stale_twin(run, tmp_path,
                                                                      monkeypatch):
    """C6: localize --overwrite stopped after committing poses.h5 and before its TUM twin
    left the new poses beside the previous run's poses.tum. The old twin now goes just
    before the new poses are committed: an interruption leaves new poses without a twin,
    never a twin that disagrees with them."""
    out = tmp_path / "p.h5"
    localize.main({"method": "lut"}, run["ds"], run["map"], out, features=run["features"])
    assert read_poses(out)[0]["hypotheses"].shape[1] != 3
    assert out.with_suffix(".tum").is_file()

    commit = artifacts.commit_file

    def stopped(tmp, path):  # the twin's commit comes after the poses': stopped there
        if str(path).endswith(".tum"):
            raise KeyboardInterrupt
        commit(tmp, path)

    monkeypatch.setattr(artifacts, "commit_file", stopped)
    with pytest.raises(KeyboardInterrupt):
        localize.main({"method": "lut", "hypotheses": 3}, run["ds"], run["map"], out,
                      features=run["features"], overwrite=True)
    assert read_poses(out)[0]["hypotheses"].shape[1] == 3  # the new poses were committed
    assert not out.with_suffix(".tum").exists()  # and no twin of the old ones beside them
    monkeypatch.undo()
    localize.main({"method": "lut"}, run["ds"], run["map"], out, features=run["features"],
                  overwrite=True)
    assert poses_file.is_fieldloc_tum(out.with_suffix(".tum"))


def test_a_users_file_named_as_the_twin_is_never_removed(run, tmp_path):
    """drop_twin removes only a twin fieldloc wrote."""
    out = tmp_path / "p.h5"
    out.with_suffix(".tum").write_text("my own trajectory\n")
    poses_file.drop_twin(out)
    assert out.with_suffix(".tum").read_text() == "my own trajectory\n"
