"""The SURF template paper's template method: template captures on a grid (simulate), the template
database (build-templates, schema fieldloc.templates), localisation against it (localize --method
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


# ---------------------------------------------------------------------------- the database

GRID = dict(grid_spacing=1.0, grid_centre=[1.0, 0.0], grid_half_size=1.0)  # 3 x 3 nodes


@pytest.fixture(scope="module")
def grid_and_run(tmp_path_factory):
    """Template captures on a 3 x 3 grid of 1 m on msl-2015 and a slow 12-frame run among
    them, one robot (calib_seed) in one venue (world_seed), each session with its own seed
    (the venue's own texture resolution: the floor's detail is what the features see)."""
    d = tmp_path_factory.mktemp("templates")
    gconf = copy.deepcopy(simulate.confs["omni-default"])
    gconf.update(seed=5, calib_seed=9, world_seed=9)
    gconf["trajectory"].update(kind="grid", **GRID)
    grid = simulate.main(gconf, "msl-2015", d / "grid")
    run_conf = copy.deepcopy(simulate.confs["omni-default"])
    run_conf.update(frames=12, seed=6, calib_seed=9, world_seed=9)
    run_conf["trajectory"].update(start=[1.0, 0.0, 0.4], speed_min=0.2, speed_max=0.4)
    run = simulate.main(run_conf, "msl-2015", d / "run")
    from stages import build_templates

    db = build_templates.main(None, grid, d / "templates.h5")
    return grid, run, db


def test_build_templates_round_trip(grid_and_run, tmp_path):
    from stages import build_templates
    from stages.common import ground_features as gf
    from stages.common.dataset import read_image
    from stages.common.describe import describe_file
    from stages.common.templates import read_templates

    grid, _run, path = grid_and_run
    db = read_templates(path)
    truth = read_csv(grid / "truth.csv", "truth")
    ds = open_dataset(grid)
    assert db.feature_kind == "surf" and db.field_axes and db.field["name"] == "msl-2015"
    assert len(db) == 9 and db.names == ds.names
    assert np.allclose(db.poses, np.stack([truth["x"], truth["y"], truth["theta"]], 1))
    assert db.offsets[0] == 0 and db.offsets[-1] == len(db.points) == len(db.descriptors)
    assert db.descriptors.shape[1] == 64 and set(np.unique(db.laplacian)) <= {-1, 1}
    # template 4 is the features of its frame, described in the field's axes, in its robot
    # frame (metres)
    k = 4
    f = gf.ground_features(read_image(ds.images[k]), ds.camera(), db.ground_conf,
                           heading=float(db.poses[k, 2]))
    t = db.template(k)
    assert len(t) == len(f) >= build_templates.confs["default"]["min_features"]
    # exact same-run: the database built here
    assert np.allclose(t.points, f.points) and np.array_equal(t.descriptors, f.descriptors)
    assert np.max(np.abs(t.points)) < gf.reach(db.ground_conf)
    text = describe_file(path)
    assert "fieldloc.templates" in text and "/descriptors" in text and "[m]" in text
    # no truth: refused, nothing written
    (tmp_path / "g").mkdir()
    for p in ("images", "calib.yaml"):
        (tmp_path / "g" / p).symlink_to(grid / p)
    with pytest.raises(FieldlocError, match="no truth.csv"):
        build_templates.main(None, tmp_path / "g", tmp_path / "t.h5")
    assert not (tmp_path / "t.h5").exists()


def test_localize_templates_through_the_stage_main_with_the_cli_defaults(grid_and_run,
                                                                         tmp_path):
    """A rendered run among the templates localised within 5 cm and 1 deg (median), every
    frame within 25 cm (the first, a global fix, is the coarsest; measured 19 cm) and every
    frame after the first three within 5 cm (fused with the odometry), with the CLI's default
    conf."""
    from stages import localize
    from stages.common.conf import resolve_conf
    from stages.common.poses_file import read_poses

    _grid, run, db = grid_and_run
    conf = resolve_conf(localize.confs, "templates-default", {})
    out = localize.main(conf, run, None, tmp_path / "p.h5", templates=db)
    cols, attrs = read_poses(out)
    truth = read_csv(run / "truth.csv", "truth")
    assert len(cols["name"]) == 12 and not cols["failed"].any()
    err = np.hypot(cols["x"] - truth["x"], cols["y"] - truth["y"])
    dth = np.abs((cols["theta"] - truth["theta"] + np.pi) % (2 * np.pi) - np.pi)
    assert np.median(err) < 0.05 and np.max(err) < 0.25 and np.max(err[3:]) < 0.05, err
    assert np.degrees(np.median(dth)) < 1.0
    assert cols["accepted"].mean() >= 0.9 and cols["hypotheses"].shape[0] == 12
    assert attrs["method"] == "templates"


def test_a_corrupt_templates_file_is_one_clear_line(grid_and_run, tmp_path):
    import h5py

    _grid, run, db = grid_and_run
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5 at all" * 10)
    argv = ["localize", str(run), "--method", "templates", "--templates", str(bad), "-o",
            str(tmp_path / "p.h5")]
    r = CliRunner().invoke(cli, argv)
    assert r.exit_code == 1 and "not an HDF5 file" in r.output
    assert len(r.output.strip().splitlines()) == 1 and "Traceback" not in r.output
    # the schema, but arrays that do not agree
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(db.read_bytes())
    with h5py.File(damaged, "a") as f:
        del f["laplacian"]
        f["laplacian"] = np.zeros(3, np.int8)
    argv[5] = str(damaged)
    r = CliRunner().invoke(cli, argv)
    assert r.exit_code == 1 and "damaged 'fieldloc.templates' file" in r.output
    assert len(r.output.strip().splitlines()) == 1
    assert not (tmp_path / "p.h5").exists()
    r = CliRunner().invoke(cli, ["localize", str(run), "--method", "templates"])
    assert r.exit_code == 2 and "--templates" in r.output


# ---------------------------------------------------------------------------- pose solvers


def test_descent_and_closed_form_agree_on_the_same_pairs(grid_and_run):
    """The paper's coordinate descent from (0, 0, 0) reaches the closed-form (2D Kabsch)
    minimum of eq. 4, on synthetic pairs far from the robot and on matched pairs of a run
    frame against its nearest template."""
    from stages.common import ground_features as gf
    from stages.common.dataset import read_image
    from stages.common.templates import read_templates
    from stages.localize import template_matching as tm
    from stages.localize import templates as tmethod

    rng = np.random.default_rng(4)
    q = rng.uniform(-3, 3, (40, 2)) + [2.0, 1.0]
    true = np.array([0.4, -0.3, np.radians(25)])
    t = tm.transform(true, q) + rng.normal(0, 0.02, q.shape)
    d, rounds = tm.descent(t, q)
    c = tm.closed_form(t, q)
    assert np.allclose(d, c, atol=1e-7) and rounds > 1
    assert np.allclose(c, true, atol=0.02)
    assert tm.matching_error(d, t, q) <= tm.matching_error(true, t, q)
    # real pairs: a run frame against the template nearest to it
    _grid, run, path = grid_and_run
    db = read_templates(path)
    ds = open_dataset(run)
    truth = read_csv(run / "truth.csv", "truth")
    m = tmethod.TemplateMatcher(db, tmethod.confs["default"])
    i = 3
    k = int(np.argmin(np.hypot(db.poses[:, 0] - truth["x"][i], db.poses[:, 1] - truth["y"][i])))
    query = gf.ground_features(read_image(ds.images[i]), ds.camera(), db.ground_conf,
                               heading=float(truth["theta"][i]))
    fix = m.fit(query, k, float(truth["theta"][i]))
    assert fix is not None and fix.fit.inliers.sum() >= 5
    tt, qq = fix.pairs_t[fix.fit.inliers], fix.pairs_q[fix.fit.inliers]
    assert np.allclose(tm.descent(tt, qq)[0], tm.closed_form(tt, qq), atol=1e-7)
    assert np.hypot(fix.pose[0] - truth["x"][i], fix.pose[1] - truth["y"][i]) < 0.1


def test_consensus_finds_a_minority_of_correct_pairs():
    """40 % correct pairs among wrong ones: the consensus fit recovers the pose, the robust
    fit from all pairs alone (median and MAD of the pair distances) does not need to."""
    from stages.localize import template_matching as tm

    rng = np.random.default_rng(7)
    q = rng.uniform(-3, 3, (50, 2))
    true = np.array([0.3, 0.2, np.radians(2)])
    t = tm.transform(true, q) + rng.normal(0, 0.01, q.shape)
    wrong = rng.random(50) < 0.6
    t[wrong] = rng.uniform(-3, 3, (int(wrong.sum()), 2))
    f = tm.consensus_fit(t, q, radius=0.2, min_pairs=5)
    assert f is not None and np.allclose(f.pose, true, atol=0.02)
    assert not f.inliers[wrong].any() and f.inliers[~wrong].mean() > 0.9


def test_feature_index_does_not_depend_on_earlier_random_draws():
    """FLANN's randomised trees draw from OpenCV's generator: the index seeds it, so two
    indexes of the same descriptors give the same approximate matches whatever the process
    drew in between (without the seed, a second batch run in one worker moved frames)."""
    import cv2

    from stages.localize.template_matching import FeatureIndex

    rng = np.random.default_rng(5)
    desc = rng.normal(size=(3000, 64)).astype(np.float32)
    lap = np.ones(3000, np.int8)
    query = rng.normal(size=(400, 64)).astype(np.float32)
    first = FeatureIndex(desc, lap, checks=8).knn(query, np.ones(400, np.int8))
    cv2.randu(np.zeros((100, 100), np.uint8), 0, 255)  # other OpenCV work draws numbers
    second = FeatureIndex(desc, lap, checks=8).knn(query, np.ones(400, np.int8))
    np.testing.assert_array_equal(first[0], second[0])  # exact integers: neighbour indices
