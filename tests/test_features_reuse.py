"""A features file written when the extractor's preset still held its tuned numbers stored
them in its conf. Extract resumes such a file, and localize reuses it, only when every stored
number equals the named constant that replaced it: a user's old override of a now-constant key
makes another conf."""

import json
import os
import shutil

import h5py
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import extract
from stages.common.artifacts import as_stored


def _dataset_with_stored_conf(src, tmp_path, **changes):
    """A copy of the rendered dataset ``src`` (images linked) whose features.h5 stores the
    former full conf: the user keys, the extractor's former layout, then ``changes``."""
    ds = tmp_path / "ds"
    ds.mkdir()
    for f in src.iterdir():
        if f.name == "images":
            (ds / "images").symlink_to(f.resolve())
        elif f.is_file():
            shutil.copy(f, ds / f.name)
    with h5py.File(ds / "features.h5", "r+") as h5:
        stored = json.loads(h5.attrs["conf"])
        full = {**as_stored(extract.kind_module("omni").former_layout()), **stored, **changes}
        full["colour"] = {**as_stored(extract.kind_module("omni").former_layout())["colour"],
                          **stored["colour"]}
        h5.attrs["conf"] = json.dumps(full, sort_keys=True)
        # as extracted in this folder: a resume continues only its own folder's features
        h5.attrs["dataset"] = os.path.realpath(ds)
    return ds


def _localize(ds, map_path, out):
    return CliRunner().invoke(cli, ["-q", "localize", str(ds), "--map", str(map_path),
                                    "-o", str(out)])


def test_a_former_full_conf_at_the_constants_values_is_resumed_and_reused(
        omni_default_rendered, msl2015_map, tmp_path):
    ds = _dataset_with_stored_conf(omni_default_rendered[0], tmp_path)
    res = CliRunner().invoke(cli, ["-q", "extract", str(ds)])
    assert res.exit_code == 0, res.output
    out = tmp_path / "poses.h5"
    res = _localize(ds, msl2015_map, out)
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "poses.features.h5").exists()  # the dataset's own file was used


@pytest.mark.parametrize("changes", [{"min_white_px": 2}, {"sample_step_px": 0.25}])
def test_a_former_override_of_a_now_constant_key_is_another_conf(
        omni_default_rendered, msl2015_map, tmp_path, changes):
    ds = _dataset_with_stored_conf(omni_default_rendered[0], tmp_path, **changes)
    res = CliRunner().invoke(cli, ["extract", str(ds)])
    assert res.exit_code != 0
    assert "extracted with another conf" in res.output
    out = tmp_path / "poses.h5"
    res = _localize(ds, msl2015_map, out)
    assert res.exit_code == 0, res.output
    assert (tmp_path / "poses.features.h5").is_file()  # extracted again beside the poses
