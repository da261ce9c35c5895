"""Ranked hypotheses with probabilities (poses schema v2), the calibration figures of
evaluate, lut's null and independent frames, the online radial correction and the point fit."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest
from test_localize_lut import Dataset, SyntheticFrames, drive, observe, random_pose

from stages.common.geometry import field_to_robot, wrap_angle
from stages.common.map_file import MapFile
from stages.common.poses_file import PoseTrack, read_poses, write_poses
from stages.evaluate.metrics import auroc, reliability
from stages.localize import lut
from stages.localize.point_fit import PointFit
from stages.localize.radial_correction import RadialCorrection


@pytest.fixture(scope="module")
def search(msl2015_map):
    return lut.table_search(MapFile(msl2015_map),
                            lut.SEARCH)


# ---------------------------------------------------------------------------- poses schema


def test_poses_v2_round_trip_and_v1_files_still_read(tmp_path):
    t = PoseTrack()
    h = np.array([[1.0, 2.0, 0.5, 0.6], [-1.0, -2.0, 0.5 - math.pi, 0.3]])
    t.add("a", 0.0, (1.0, 2.0, 0.5), confidence=0.6, hypotheses=h, accepted=False)
    t.add("b", 0.1, None, flags="uninformative")
    t.add("c", 0.2, (0.0, 0.0, 0.0), confidence=0.9)
    p = write_poses(tmp_path / "p.h5", t, {"schema": "fieldloc.poses", "schema_version": 2})
    cols, _ = read_poses(p)
    assert cols["accepted"].tolist() == [False, False, True]
    assert cols["hypotheses"].shape == (3, 2, 4)
    np.testing.assert_allclose(cols["hypotheses"][0], h)
    assert np.isnan(cols["hypotheses"][1]).all()  # a failed frame has none
    np.testing.assert_allclose(cols["hypotheses"][2, 0], [0, 0, 0, 0.9])
    tum = np.loadtxt(p.with_suffix(".tum"))
    assert tum.shape == (8,)  # the accepted frame only
    # a version 1 file: no accepted column, no /hypotheses
    with h5py.File(p, "a") as f:
        f.attrs["schema_version"] = 1
        del f["hypotheses"], f["poses/accepted"]
    cols, _ = read_poses(p)
    assert cols["accepted"].tolist() == [True, False, True]
    np.testing.assert_allclose(cols["hypotheses"][0, 0], [1.0, 2.0, 0.5, 0.6])


# ---------------------------------------------------------------------------- calibration


def test_auroc_and_reliability_by_hand():
    conf = np.array([0.9, 0.8, 0.3, 0.1, 0.3])
    correct = np.array([True, True, False, True, True])
    # correct frames above the wrong one (0.3): 0.9, 0.8 yes, 0.1 no, 0.3 tie = half
    assert auroc(conf, correct) == pytest.approx((1 + 1 + 0 + 0.5) / 4)
    assert math.isnan(auroc(conf, np.ones(5, bool)))
    rows = reliability(conf, correct)
    assert [r["bin"] for r in rows] == [[0.1, 0.2], [0.3, 0.4], [0.8, 0.9], [0.9, 1.0]]
    assert [r["frames"] for r in rows] == [1, 2, 1, 1]
    assert rows[1]["observed"] == 0.5 and rows[1]["confidence"] == pytest.approx(0.3)


# ---------------------------------------------------------------------------- lut


class Frames(SyntheticFrames):
    """SyntheticFrames from prepared (radial, spiral) pairs."""

    def __init__(self, pairs):
        self.names = [f"{i:04d}" for i in range(len(pairs))]
        self.stamps = np.arange(len(pairs)) * 0.1
        self._frames = {n: {"radial": r, "spiral": s} for n, (r, s) in zip(self.names, pairs)}


def test_random_observations_are_uninformative_not_a_pose(search, msl2015_map):
    """Crossings at random distances on random scan lines (no field in view), eight draws:
    the frame and its random-bearing null copies are alike, so at most by chance does the
    frame beat the null, and then barely: most fail as uninformative and none gets a
    confidence near acceptance; a real view of the same size is localised."""
    sl = search.scanlines
    pairs = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        r = np.full((72, 4), np.nan)
        r[rng.permutation(72)[:40], 0] = rng.uniform(sl.robot_radius + 0.1, sl.max_range, 40)
        pairs.append((r, np.full((2, 72), np.nan)))
    pose = (-2.0, 1.0, 0.3)
    pairs.append(observe(search.field, sl, pose, np.random.default_rng(3)))
    frames = Frames(pairs)
    n = len(pairs)
    ds = Dataset(truth={"stamp": frames.stamps, "x": [0.0] * (n - 1) + [pose[0]],
                        "y": [0.0] * (n - 1) + [pose[1]], "theta": [0.0] * (n - 1) + [pose[2]]})
    conf = dict(lut.confs["default"], heading="truth", independent=True)
    c = lut.run(conf, ds, frames, MapFile(msl2015_map)).arrays()
    noise = slice(0, n - 1)
    failed = c["failed"][noise]
    assert failed.sum() >= 4, c["flags"][noise]
    assert all(f.endswith("uninformative") for f in c["flags"][noise][failed])
    assert np.nanmax(np.where(failed, 0.0, c["confidence"][noise])) < 0.5, c["confidence"]
    assert not c["accepted"][noise].any()
    assert not c["failed"][-1] and math.hypot(c["x"][-1] - pose[0], c["y"][-1] - pose[1]) < 0.1


def test_independent_frames_without_heading_list_the_mirror_at_equal_probability(
        search, msl2015_map):
    """--independent --heading histogram on snapshots at unknown poses of a symmetric field:
    every frame is localised globally on its own; the top two hypotheses are the pose and its
    mirror image with the same probability (so none is accepted at 0.8)."""
    rng = np.random.default_rng(5)
    poses = [random_pose(rng, search.field) for _ in range(4)]
    frames = Frames([observe(search.field, search.scanlines, p, rng) for p in poses])
    conf = dict(lut.confs["default"], heading="histogram", independent=True)
    c = lut.run(conf, Dataset(), frames, MapFile(msl2015_map)).arrays()
    for k, p in enumerate(poses):
        h = c["hypotheses"][k]
        mirror = search.field.mirror_pose(h[0, :3])
        assert np.allclose(h[1, :3], mirror, atol=1e-6)
        assert h[0, 3] == pytest.approx(h[1, 3])
        near = [math.hypot(q[0] - p[0], q[1] - p[1]) < 0.15 for q in h[:2]]
        assert any(near), (k, np.round(h[:2], 2), p)
        assert not c["accepted"][k]


def test_start_half_leaves_the_mirror_listed_at_probability_near_zero(search, msl2015_map):
    rng = np.random.default_rng(22)
    poses, t = drive()
    frames = SyntheticFrames(search, poses, rng)
    conf = dict(lut.confs["default"], heading="histogram", start_half="own")
    c = lut.run(conf, Dataset(), frames, MapFile(msl2015_map)).arrays()
    ok = ~c["failed"]
    assert (c["x"][ok] < 0).all()
    for h in c["hypotheses"][ok]:  # the mirror of the top, listed with a small probability
        m = search.field.mirror_pose(h[0, :3])
        k = [j for j in range(1, len(h)) if np.allclose(h[j, :3], m, atol=1e-6)]
        assert len(k) == 1 and h[k[0], 3] < 0.01, np.round(h, 3)


# ---------------------------------------------------------------------------- point fit


def test_point_fit_recovers_a_pose_from_points_on_the_lines():
    from stages.common.field import load_field

    fm = load_field("msl-2015")
    pf = PointFit(fm)
    truth = np.array([-2.3, 1.1, 0.7])
    pts = []
    for a, b in fm.segments:
        a, b = np.asarray(a), np.asarray(b)
        for u in np.linspace(0, 1, 300):
            q = a + u * (b - a)
            if np.hypot(*(q - truth[:2])) < 4.0:
                pts.append(q)
    robot = field_to_robot(truth, np.array(pts))
    w = np.ones(len(robot))
    pose, cost, normal = pf.refine(robot, w, truth + [0.08, -0.06, 0.03])
    assert math.hypot(*(pose[:2] - truth[:2])) < 0.01
    assert abs(float(wrap_angle(pose[2] - truth[2]))) < 0.002
    assert cost < pf.cost(robot, w, truth + [0.08, -0.06, 0.03])
    assert np.all(np.linalg.eigvalsh(normal) > 0)
    # within a box the fit stays in it
    pose, _, _ = pf.refine(robot, w, truth + [0.3, 0.0, 0.0], max_shift=0.1)
    assert abs(pose[0] - (truth[0] + 0.3)) <= 0.1 + 1e-9


# ---------------------------------------------------------------------------- radial correction


def test_radial_correction_learns_a_mirror_error_and_removes_it():
    rc = RadialCorrection(robot_radius=0.25, min_points=200)
    rng = np.random.default_rng(0)
    truth = lambda d: 0.02 * (d - 0.25) + 0.015 * (d - 0.25) ** 2  # noqa: E731
    for _ in range(60):
        d_true = rng.uniform(0.3, 4.0, 40)
        observed = d_true + truth(d_true) + rng.normal(0, 0.02, 40)
        clutter = rng.uniform(0.3, 4.0, 5)  # other lines, far from their prediction
        rc.update(np.r_[observed, clutter], np.r_[d_true, clutter + 0.6])
    assert rc.active
    for d in (1.0, 2.0, 3.0, 3.8):  # e is a function of the distance as observed
        seen = d + truth(d)
        assert abs(float(rc.error(seen)) - truth(d)) < 0.01, (d, float(rc.error(seen)))
    d = np.array([1.0, 3.0])
    np.testing.assert_allclose(rc.correct(d + truth(d)), d, atol=0.01)
    assert RadialCorrection(robot_radius=0.25).error(2.0) == 0.0  # inactive without data


def test_lut_learns_the_calibration_error_of_a_rendered_set(tmp_path, msl2015_map):
    """omni-default writes a team-like miscalibrated calib.yaml; tracking with the IMU learns
    the distance error of its crossings (summary in poses.h5's method_report). The tracks
    teach it from the frames they hold at 0.99; the whole-field belief (``--preset grid``)
    from the same threshold of its own confidence (its report is there too)."""
    import json

    import h5py as _h5

    from stages import extract, localize, simulate

    conf = dict(simulate.confs["omni-default"], frames=60, seed=8)
    ds = simulate.main(conf, "msl-2015", tmp_path / "sim")
    feats = extract.main(None, ds, ds / "features.h5")
    out = localize.main({"method": "lut", "heading": "imu", "belief": "tracks"}, ds,
                        msl2015_map, tmp_path / "p.h5", features=feats)
    with _h5.File(out) as f:
        rep = json.loads(f.attrs["method_report"])["radial_correction"]
    assert rep["active"] and rep["points"] > 300
    assert max(abs(v) for v in rep["error_m"].values()) > 0.02  # it found an error
    grid = localize.main({"method": "lut", "heading": "imu", "belief": "grid"}, ds,
                         msl2015_map, tmp_path / "g.h5", features=feats)
    with _h5.File(grid) as f:
        assert "radial_correction" in json.loads(f.attrs["method_report"])


def test_global_evidence_is_checked(search, msl2015_map):
    """A mistyped global_evidence is one clear error, not a silent fallback."""
    from stages.common.errors import FieldlocError

    frames = Frames([observe(search.field, search.scanlines, (0.0, 0.0, 0.0),
                             np.random.default_rng(0))])
    conf = dict(lut.confs["default"], heading="truth", global_evidence="rays")
    ds = Dataset(truth={"stamp": frames.stamps, "x": [0.0], "y": [0.0], "theta": [0.0]})
    with pytest.raises(FieldlocError, match="global_evidence"):
        lut.run(conf, ds, frames, MapFile(msl2015_map))
