"""Seed 004's template method: template captures on a grid (simulate), the template database
(build-templates, schema fieldloc.templates), localisation against it (localize --method
templates) and its pose solvers."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import simulate
from stages.common.dataset import open_dataset, read_csv
from stages.common.errors import FieldlocError
from stages.common.field import load_field
from stages.simulate import trajectory


def grid_conf(seed=3, calib_seed=None, **grid):
    """A rendered template grid of a few nodes on spl (coarse world texture: fast)."""
    conf = copy.deepcopy(simulate.confs["omni-default"])
    conf["seed"] = seed
    conf["calib_seed"] = calib_seed
    conf["scene"]["texture_resolution"] = 0.02
    conf["trajectory"].update(kind="grid", **grid)
    return conf


# ---------------------------------------------------------------------------- grid captures


def test_grid_poses_cover_the_field_at_multiples_of_the_spacing():
    spl = load_field("spl")  # 9 x 6 m
    p = trajectory.grid_poses(spl, {"grid_spacing": 1.5, "grid_headings": 4})
    xs, ys = np.unique(p[:, 0]), np.unique(p[:, 1])
    assert np.allclose(xs, np.arange(-4.5, 4.6, 1.5)) and np.allclose(ys, np.arange(-3, 3.1, 1.5))
    assert len(p) == len(xs) * len(ys) * 4
    assert np.allclose(np.degrees(p[:4, 2]), [0, 90, -180, -90])  # the headings of a node
    # a window around a point: spaced from its centre, clipped to the field
    w = trajectory.grid_poses(spl, {"grid_spacing": 0.5, "grid_centre": [4.0, 0.2],
                                    "grid_half_size": 1.0})
    assert np.allclose(np.unique(w[:, 0]), [3.0, 3.5, 4.0, 4.5])
    assert np.allclose(np.unique(w[:, 1]), [-0.8, -0.3, 0.2, 0.7, 1.2])
    with pytest.raises(FieldlocError, match="grid_spacing > 0"):
        trajectory.grid_poses(spl, {"grid_spacing": 0})
    with pytest.raises(FieldlocError, match="no node"):
        trajectory.grid_poses(spl, {"grid_centre": [20.0, 0.0], "grid_half_size": 1.0})


def test_simulate_grid_writes_one_frame_per_placement_and_no_odometry(tmp_path):
    conf = grid_conf(seed=5, calib_seed=2, grid_spacing=1.0, grid_centre=[1.0, 0.0],
                     grid_half_size=0.5, grid_headings=2)
    out = simulate.main(conf, "spl", tmp_path / "grid")
    ds = open_dataset(out)
    truth = read_csv(out / "truth.csv", "truth")
    assert len(ds.names) == 2 and len(truth["x"]) == 2  # one node, two headings
    assert np.allclose(truth["x"], 1.0) and np.allclose(truth["y"], 0.0)
    assert np.allclose(np.cos(truth["theta"]), [1.0, -1.0])
    assert not (out / "odometry.csv").exists() and (out / "imu.csv").exists()
    # calib_seed: the calibration of another dataset of the same robot (seed 2)
    other = simulate.main({**copy.deepcopy(simulate.confs["omni-default"]), "frames": 1,
                           "seed": 2, "scene": conf["scene"]}, "spl", tmp_path / "run")
    assert (out / "calib.yaml").read_text() == (other / "calib.yaml").read_text()
    own = simulate.main({**grid_conf(seed=5, grid_spacing=1.0, grid_centre=[1.0, 0.0],
                                     grid_half_size=0.5)}, "spl", tmp_path / "own")
    assert (own / "calib.yaml").read_text() != (other / "calib.yaml").read_text()


def test_cli_simulate_grid_options(tmp_path):
    r = CliRunner().invoke(cli, ["simulate", "omni", "--field", "spl", "-o",
                                 str(tmp_path / "g"), "--grid", "1", "--frames", "3"])
    assert r.exit_code == 2 and "--frames and --trajectory do not apply" in r.output
    r = CliRunner().invoke(cli, ["simulate", "omni", "--field", "spl", "-o",
                                 str(tmp_path / "g"), "--grid-headings", "3"])
    assert r.exit_code == 2 and "--grid-headings applies to --grid" in r.output
