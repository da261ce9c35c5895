"""Method fit (stages/localize/fit.py): the fit itself on points placed on the map's lines, a
rendered run through the stage main with the CLI's defaults, the --points path, bad options."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stages.common.geometry import robot_to_field, wrap_angle
from stages.common.map_file import MapFile
from stages.localize import fit


def line_points(fm, pose, rng, n=60, max_range=3.5):
    """Robot-frame points on the field's lines within ``max_range`` of ``pose``: points every
    5 cm of the lines' segments and arcs, with 1 cm noise."""
    pts = []
    for (ax, ay), (bx, by) in fm.segments:
        k = max(2, int(math.hypot(bx - ax, by - ay) / 0.05))
        t = np.linspace(0, 1, k)
        pts.append(np.stack([ax + t * (bx - ax), ay + t * (by - ay)], 1))
    for cx, cy, r, a0, sweep in fm.arcs:
        a = a0 + np.linspace(0, sweep, max(2, int(r * sweep / 0.05)))
        pts.append(np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], 1))
    q = np.concatenate(pts)
    d = np.hypot(q[:, 0] - pose[0], q[:, 1] - pose[1])
    q = q[(d > 0.4) & (d < max_range)]
    q = q[rng.choice(len(q), size=min(n, len(q)), replace=False)]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rel = q - np.asarray(pose[:2])
    robot = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], 1)
    return robot + rng.normal(0, 0.01, robot.shape)


@pytest.fixture(scope="module")
def engine(msl2015_map):
    m = MapFile(msl2015_map)
    return m, fit.FitEngine(m)


def test_fit_converges_to_the_pose_of_points_on_the_lines(engine):
    """From starts 20-30 cm and 3 deg off, RPROP on E brings the pose back within 2 cm and
    0.5 deg; the points there lie on the lines."""
    m, eng = engine
    fm = m.field
    rng = np.random.default_rng(5)
    truth = np.array([-1.6, 1.4, 0.7])  # in the own half: halfway line, centre circle
    obs = fit.observation_from_points(line_points(fm, truth, rng))
    assert len(obs) >= 40
    for dx, dy, dth in [(0.2, -0.15, 0.05), (-0.25, 0.1, -0.05), (0.0, 0.3, 0.0)]:
        f = eng.fit(obs, truth + [dx, dy, dth])
        assert math.hypot(f.x - truth[0], f.y - truth[1]) < 0.02, (dx, dy, f.pose)
        assert abs(float(wrap_angle(f.theta - truth[2]))) < math.radians(0.5)
        assert f.inlier_share > 0.9
        d = fm.distance_to_lines(robot_to_field(f.pose, obs.points))
        assert np.median(d) < 0.02
    # the distance the kernels read equals the field's exact distance away from the lines' ends
    q = robot_to_field(truth, obs.points) + rng.normal(0, 0.05, obs.points.shape)
    got = np.array([eng.field.distance(x, y)[0] for x, y in q])
    assert np.median(np.abs(got - fm.distance_to_lines(q))) < 0.005


def test_global_search_finds_the_pose_or_its_mirror(engine):
    """Without a prior, the grid of starts at a known heading finds the pose (or, the field
    being point-symmetric, its mirror) as the best fix."""
    m, eng = engine
    fm = m.field
    rng = np.random.default_rng(6)
    truth = np.array([3.2, -1.1, -2.0])
    obs = fit.observation_from_points(line_points(fm, truth, rng))
    fixes = eng.global_search(obs, [(truth[2], 0.01)], temperature=0.5, separation=1.0,
                              mode="global")
    best = fixes[0].pose
    err = min(math.hypot(*(best[:2] - p[:2])) for p in (truth, fm.mirror_pose(truth)))
    assert err < 0.05, best


def _errors(poses, ds):
    from stages.common.dataset import read_csv
    from stages.common.poses_file import read_poses
    from stages.evaluate.metrics import frame_errors

    cols, attrs = read_poses(poses)
    e = frame_errors(cols, read_csv(ds / "truth.csv", "truth"), 0.02)
    return cols, attrs, np.asarray(e.position_error, float)  # failed frames: inf


def test_rendered_run_through_the_stage_main_with_the_cli_defaults(omni_default_rendered,
                                                                   msl2015_map, tmp_path):
    """`fieldloc localize DIR --map M --method fit` as a stage call (the conf the CLI resolves
    with no other option): the run is localised within 15 cm median and 90 % of the frames within
    40 cm (the set's calibration is off by up to 20 cm, which biases every pose: 12 cm median
    here), with ranked hypotheses and a confidence in the poses schema."""
    from stages import localize

    ds, features = omni_default_rendered
    conf = localize.resolve_localize_conf({"method": "fit"})
    assert conf == localize.confs["fit-default"]
    out = localize.main(conf, ds, msl2015_map, tmp_path / "poses-fit.h5", features=features)
    cols, attrs, pos = _errors(out, ds)
    assert attrs["conf"]["method"] == "fit"
    assert np.median(pos) <= 0.15, np.median(pos)
    assert np.mean(pos <= 0.4) >= 0.9
    h = cols["hypotheses"]
    ok = ~np.asarray(cols["failed"], bool)
    assert h.ndim == 3 and h.shape[2] == 4
    assert np.all(np.diff(h[ok, :, 3], axis=1)[np.isfinite(np.diff(h[ok, :, 3], axis=1))] <= 1e-9)
    conf_v = np.asarray(cols["confidence"], float)
    assert np.all((conf_v >= 0) & (conf_v <= 1)) and np.allclose(conf_v[ok], h[ok, 0, 3])


def test_cli_points_path(omni_default_rendered, msl2015_map, tmp_path):
    """`--method fit --points FILE.csv`: a team's robot-frame points give poses too."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages.common.features_file import FeaturesFile

    ds, features = omni_default_rendered
    rows = ["frame,x,y"]
    with FeaturesFile(features) as ff:
        for name in ff.names[:15]:
            rows += [f"{name},{x:.4f},{y:.4f}" for x, y in ff.frame(name)["points"]]
    csv_path = tmp_path / "points.csv"
    csv_path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "poses-points.h5"
    res = CliRunner().invoke(cli, ["localize", str(ds), "--map", str(msl2015_map), "--method",
                                   "fit", "--points", str(csv_path), "-o", str(out)])
    assert res.exit_code == 0, res.output
    # every dataset frame has a row; the 25 the points file names no point of failed
    assert "40 frames" in res.output and "25 failed" in res.output
    cols, attrs, pos = _errors(out, ds)
    assert attrs["inputs"]["points"] == str(csv_path)
    failed = np.asarray(cols["failed"], bool)
    assert failed[15:].all() and (~failed[:15]).sum() >= 10  # the frames with points
    assert np.median(pos[:15]) <= 0.2


@pytest.mark.parametrize("args, words", [
    (["-c", "c=0.3"], "unknown conf key 'c'"),  # a tuned constant (fit.C_M), no user key
    (["-c", "min_confidence=2"], "conf 'min_confidence' must be >= 0 and <= 1"),
    (["--init", "uniform"], "--init applies to --method mcl"),
    (["-c", "nope=1"], "nope"),
])
def test_a_bad_option_gives_one_clear_line(omni_default_rendered, msl2015_map, tmp_path, args,
                                           words):
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    ds, features = omni_default_rendered
    res = CliRunner().invoke(cli, ["localize", str(ds), "--map", str(msl2015_map), "--method",
                                   "fit", "--features", str(features), "-o",
                                   str(tmp_path / "p.h5"), *args])
    assert res.exit_code != 0
    lines = [ln for ln in res.output.strip().splitlines() if ln.strip()]
    assert "Traceback" not in res.output
    assert words in res.output, res.output
    assert len([ln for ln in lines if "rror" in ln]) == 1, res.output
    assert not (tmp_path / "p.h5").exists()
