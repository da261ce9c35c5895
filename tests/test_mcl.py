"""Particle filter of Schulz et al. (2011) (stages.localize.mcl with its observation and motion
models) and the belief picture, on synthetic observations generated from the field model."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from oracles import observation_model as oracle

from stages.common.crossing_tables import crossing_association_tables
from stages.common.field import load_field
from stages.common.map_file import Grid, write_map
from stages.common.observations import Observations
from stages.common.scanlines import ScanLines
from stages.localize import mcl, mcl_rivals, mcl_start, motion_model
from stages.localize.observation_model import TUNING, ObservationModel
from stages.simulate.synthetic_observations import (
    synthetic_observations,
    synthetic_walk,
    write_synthetic_run,
)

NOISELESS = {"pitch_noise": 0.0, "roll_noise": 0.0, "point_noise": 0.0, "bearing_noise": 0.0,
             "orientation_noise": 0.0, "p_miss_line": 0.0, "p_miss_crossing": 0.0,
             "p_miss_post": 0.0, "false_lines": 0.0, "false_crossings": 0.0,
             "false_posts": 0.0, "p_type_confusion": 0.0}


@pytest.fixture(scope="module")
def kidsize():
    return load_field("kidsize")


@pytest.fixture(scope="module")
def model(kidsize):
    return ObservationModel.from_field(kidsize)


@pytest.fixture(scope="module")
def map_path(kidsize, tmp_path_factory):
    """A map holding the field and its crossing tables (the tables mcl reads)."""
    grid = Grid.around(kidsize, kidsize.border, 0.1)
    path = tmp_path_factory.mktemp("map") / "kidsize.map.h5"
    from stages.common.artifacts import root_attrs
    from stages.common.map_file import SCHEMA, VERSION

    write_map(path, kidsize, grid, ScanLines(), crossing_association_tables(kidsize, grid),
              root_attrs(SCHEMA, VERSION))
    return path


def _errors(poses, truth):
    return np.hypot(poses[:, 0] - truth[:, 0], poses[:, 1] - truth[:, 1])


def _run_walk(fm, model, conf, n=150, seed=3, obs_conf=None, start=None):
    truth, odom, stamps = synthetic_walk(fm, n, seed=seed, start=start)
    rng = np.random.default_rng(seed + 100)
    if conf["observation"] != model.conf:
        model = model.with_conf(conf["observation"])
    pf = mcl.ParticleFilter(model, conf)
    pf.initialise()
    poses, flags = [], []
    for i in range(n):
        obs = synthetic_observations(fm, truth[i], rng, obs_conf)
        est, _frame = pf.step(odom[i], 0.1, obs, first=i == 0)
        poses.append(est.pose)
        flags.append(est.flags)
    return np.array(poses), truth, flags


# ---------------------------------------------------------------------------- observation model


@pytest.mark.parametrize("field_name", ["kidsize", "spl"])
@pytest.mark.parametrize("change", [{}, {"crossing_type_confusion": 0.0},
                                    {"sigma_crossing_orientation": 0.0},
                                    {"line_extent": False, "arc_lines": False}])
def test_kernel_matches_the_oracle(field_name, change):
    """The compiled observation model (mcl_kernels) gives the oracle's log-likelihood
    (tests/oracles/observation_model.py: the equations in float64), part by part, near the
    true pose and anywhere. Tolerance: both sides are float64 and differ only in the order of
    operations and in the kernel's pruning of alternatives worth < exp(-39): 1e-9 absolute
    on sums of ~10 terms of order 1 (rounding gives ~1e-14)."""
    fm = load_field(field_name)
    m = ObservationModel.from_field(fm, tuning=TUNING._replace(**change))
    rng = np.random.default_rng(7)
    for _ in range(6):
        pose = np.array([rng.uniform(-4, 4), rng.uniform(-3, 3), rng.uniform(-3, 3)])
        obs = synthetic_observations(fm, pose, rng, {"false_crossings": 0.3, "false_posts": 0.3,
                                                     "p_type_confusion": 0.3})
        p = np.concatenate([pose + rng.normal(0.0, 0.3, (200, 3)),
                            rng.uniform([-5, -4, -3.2], [5, 4, 3.2], (200, 3))])
        fast = m.log_likelihood(p[:, 0], p[:, 1], p[:, 2], obs, parts=True)
        ref = oracle.log_likelihood(m, p[:, 0], p[:, 1], p[:, 2], obs)
        for k in ref:
            np.testing.assert_allclose(fast[k], ref[k], rtol=1e-9, atol=1e-9, err_msg=k)


def _mirrored_field(fm) -> bool:
    """Whether the field is point-symmetric about the centre spot: its segments, arcs (as
    sampled points), crossings and goal posts map onto themselves under p -> -p."""
    def same(a, b):
        a, b = np.round(np.asarray(a, float), 6) + 0.0, np.round(np.asarray(b, float), 6) + 0.0
        return set(map(tuple, a)) == set(map(tuple, b))

    seg = np.round(np.asarray(fm.segments, float).reshape(-1, 2, 2), 6) + 0.0
    ends = sorted(tuple(sorted(map(tuple, s))) for s in seg)
    mirrored = sorted(tuple(sorted(map(tuple, s))) for s in -seg + 0.0)
    arc_pts = np.concatenate([np.stack([cx + r * np.cos(a0 + np.linspace(0, sw, 9)),
                                        cy + r * np.sin(a0 + np.linspace(0, sw, 9))], axis=1)
                              for cx, cy, r, a0, sw in np.asarray(fm.arcs, float)])
    return (ends == mirrored and same(arc_pts, -arc_pts)
            and same(fm.crossings, -np.asarray(fm.crossings, float))
            and same(fm.goal_posts, -np.asarray(fm.goal_posts, float)))


@settings(max_examples=30, deadline=None)
@given(x=st.floats(-4.5, 4.5), y=st.floats(-3.0, 3.0), theta=st.floats(-math.pi, math.pi),
       seed=st.integers(0, 2 ** 31))
def test_a_pose_and_its_mirror_score_alike(kidsize, model, x, y, theta, seed):
    """On a point-symmetric field a pose (x, y, theta) and its mirror (-x, -y, theta + pi)
    see the same field, so the same egocentric observations score alike: lines and goal
    posts within 1e-9 (float64 rounding of the mirrored pose, ~1e-13 measured). Crossings go
    through the crossing tables, whose association is a decision per 10 cm cell (a cell
    equally near two crossings keeps one of them): test_crossings_of_a_mirrored_pose bounds
    those."""
    assert _mirrored_field(kidsize)
    rng = np.random.default_rng(seed)
    obs = synthetic_observations(kidsize, (x, y, theta), rng)
    p = np.array([x, y, theta]) + rng.normal(0.0, 0.3, (20, 3))
    a = model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], obs, parts=True)
    b = model.log_likelihood(-p[:, 0], -p[:, 1], p[:, 2] + math.pi, obs, parts=True)
    for k in ("lines", "posts"):
        np.testing.assert_allclose(a[k], b[k], rtol=1e-9, atol=1e-9, err_msg=k)


def test_crossings_of_a_mirrored_pose(kidsize, model):
    """The crossings' part at a pose and at its mirror: equal within 1e-9 except where the
    crossing tables associate the two cells differently (a decision at ties); those are a
    small share (2.2 % of 15,000 poses measured; bounded at 5 %)."""
    rng = np.random.default_rng(1)
    differ = total = 0
    for _ in range(300):
        pose = np.array([rng.uniform(-4.5, 4.5), rng.uniform(-3, 3), rng.uniform(-3.2, 3.2)])
        obs = synthetic_observations(kidsize, pose, rng)
        p = pose + rng.normal(0.0, 0.3, (50, 3))
        a = model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], obs, parts=True)["crossings"]
        b = model.log_likelihood(-p[:, 0], -p[:, 1], p[:, 2] + math.pi, obs,
                                 parts=True)["crossings"]
        differ += int(np.sum(~np.isclose(a, b, rtol=1e-9, atol=1e-9)))
        total += len(p)
    assert differ <= 0.05 * total, (differ, total)


@settings(max_examples=30, deadline=None)
@given(x=st.floats(-4.5, 4.5), y=st.floats(-3.0, 3.0), theta=st.floats(-math.pi, math.pi),
       seed=st.integers(0, 2 ** 31), order=st.integers(0, 2 ** 31))
def test_permuting_the_observations_keeps_the_likelihood(kidsize, model, x, y, theta, seed,
                                                          order):
    """The likelihood is a product over observations: their order does not matter. Within
    rtol 1e-12 (a sum of ~10 float64 terms in another order)."""
    rng = np.random.default_rng(seed)
    obs = synthetic_observations(kidsize, (x, y, theta), rng,
                                 {"false_crossings": 0.3, "false_posts": 0.3})
    p = np.array([x, y, theta]) + rng.normal(0.0, 0.3, (20, 3))
    shuffle = np.random.default_rng(order).permutation
    li, ci, pi = shuffle(len(obs.lines)), shuffle(len(obs.crossings)), shuffle(len(obs.posts))
    permuted = Observations(obs.lines[li], None if obs.line_ends is None else obs.line_ends[li],
                            obs.crossings[ci], obs.posts[pi])
    a = model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], obs, parts=True)
    b = model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], permuted, parts=True)
    for k in a:
        np.testing.assert_allclose(b[k], a[k], rtol=1e-12, atol=1e-12, err_msg=k)


def test_likelihood_peaks_at_the_true_pose(kidsize, model):
    pose = np.array([-1.2, -0.8, 0.5])
    obs = synthetic_observations(kidsize, pose, np.random.default_rng(0), NOISELESS)
    assert len(obs.lines) >= 2 and len(obs.crossings) >= 1
    d = np.linspace(-0.5, 0.5, 21)
    dth = np.linspace(-0.3, 0.3, 13)
    gx, gy, gt = np.meshgrid(d, d, dth, indexing="ij")
    ll = model.log_likelihood(pose[0] + gx.ravel(), pose[1] + gy.ravel(),
                              pose[2] + gt.ravel(), obs)
    k = int(np.argmax(ll))
    assert abs(gx.ravel()[k]) <= 0.051 and abs(gy.ravel()[k]) <= 0.051
    assert abs(gt.ravel()[k]) <= 0.051
    # each kind of observation on its own also prefers the truth to a pose 40 cm off
    parts_true = model.log_likelihood([pose[0]], [pose[1]], [pose[2]], obs, parts=True)
    parts_off = model.log_likelihood([pose[0] + 0.4], [pose[1] - 0.2], [pose[2]], obs,
                                     parts=True)
    for kind in ("lines", "crossings"):
        assert parts_true[kind][0] > parts_off[kind][0] + 1.0


def test_oriented_line_distance_tells_front_from_behind(kidsize, model):
    """A line seen 1 m ahead: a robot 1 m inside the right touch line facing it explains this;
    one 1 m outside it facing the same way has the line 1 m behind, which must not explain it,
    although the distance to the line and its direction are the same."""
    ahead = Observations(np.array([[1.0, 0.0, 2.0, 1.0]]), np.array([[1.0, -1.0, 1.0, 1.0]]),
                         np.zeros((0, 5)), np.zeros((0, 3)))
    front = model.log_likelihood([0.5], [-2.0], [-math.pi / 2], ahead)[0]
    behind = model.log_likelihood([0.5], [-4.0], [-math.pi / 2], ahead)[0]
    floor = math.log(model.tuning.uniform_floor)
    assert front > -0.5
    assert behind == pytest.approx(floor, abs=0.05)
    # eq. 5 proper: near the line the perpendiculars are short, and opposite ones are excluded
    near = Observations(np.array([[0.2, 0.0, 2.0, 1.0]]), None, np.zeros((0, 5)),
                        np.zeros((0, 3)))
    tuning = model.tuning._replace(oriented_tolerance=0.0)
    strict = model.with_conf(model.conf, tuning)
    assert strict.log_likelihood([-0.2], [2.0], [0.0], near)[0] > -0.5
    # robot 0.05 m past the halfway line: |l_e - l_o| is only 0.25 m, but the line is behind
    assert strict.log_likelihood([0.05], [2.0], [0.0], near)[0] == pytest.approx(
        math.log(tuning.uniform_floor), abs=1e-4)


def test_crossing_association_uses_orientation(kidsize, model):
    """An L seen 1 m ahead with its arms opening towards the robot: at a pose 1 m in front of
    the field corner (-4.5, -3), facing it, the corner explains it; a pose at the same spot
    facing the other way (where the observation would land on no L of that orientation) does
    not."""
    corner = np.array([-4.5, -3.0])
    heading = math.atan2(-1.0, -1.0)  # facing the corner from inside the field
    pos = corner - np.array([math.cos(heading), math.sin(heading)])
    # the corner's bisector is 45 deg; in the robot frame:
    orient = math.remainder(math.pi / 4 - heading, 2 * math.pi)
    obs = Observations(np.zeros((0, 4)), None, np.array([[0, 1.0, 0.0, orient, 1.0]]),
                       np.zeros((0, 3)))
    good = model.log_likelihood([pos[0]], [pos[1]], [heading], obs)[0]
    assert good > -0.3
    # an observation of an L turned by 180 deg belongs to another set: no L that way nearby
    turned = Observations(np.zeros((0, 4)), None,
                          np.array([[0, 1.0, 0.0, orient + math.pi, 1.0]]), np.zeros((0, 3)))
    assert model.log_likelihood([pos[0]], [pos[1]], [heading], turned)[0] < good - 2.0


def test_low_confidence_observations_count_less(kidsize, model):
    pose = np.array([1.0, 1.0, -2.0])
    obs = synthetic_observations(kidsize, pose, np.random.default_rng(1), NOISELESS)
    off = pose + [0.6, 0.3, 0.2]
    sure = model.log_likelihood([pose[0], off[0]], [pose[1], off[1]], [pose[2], off[2]], obs)
    unsure = dataclasses.replace(obs, lines=obs.lines.copy(), crossings=obs.crossings.copy(),
                                 posts=obs.posts.copy())
    unsure.lines[:, 3] = 0.1
    unsure.crossings[:, 4] = 0.1
    unsure.posts[:, 2] = 0.1
    weak = model.log_likelihood([pose[0], off[0]], [pose[1], off[1]], [pose[2], off[2]],
                                unsure)
    assert sure[0] - sure[1] > weak[0] - weak[1] > 0


# ---------------------------------------------------------------------------- motion model


def test_motion_model_follows_odometry():
    p = np.array([[1.0, 2.0, math.pi / 2]] * 2000)
    rng = np.random.default_rng(0)
    out = motion_model.sample_motion(p, (0.5, 0.0, 0.1), 0.1, rng)
    mean = out.mean(axis=0)
    assert mean[0] == pytest.approx(1.0, abs=0.01)  # moved along +y (heading 90 deg)
    assert mean[1] == pytest.approx(2.5, abs=0.01)
    assert np.std(out[:, 1]) > 0.01  # with noise
    inc, has = motion_model.accumulate_odometry(
        {"stamp": np.array([0.1, 0.15, 0.2]), "dx": np.array([1.0, 1.0, 0.0]),
         "dy": np.zeros(3), "dtheta": np.array([0.0, math.pi / 2, 0.0])},
        np.array([0.1, 0.2]))
    assert has.tolist() == [True, True]
    assert np.allclose(inc[0], [1.0, 0.0, 0.0])
    assert np.allclose(inc[1], [1.0, 0.0, math.pi / 2])  # turn after the step


def test_imu_collisions_and_yaw_per_frame():
    """Collision flags since the previous frame, and the yaw change across the +-pi seam."""
    imu = {"stamp": np.array([0.0, 0.05, 0.1, 0.15, 0.2]),
           "yaw": np.array([3.1, 3.12, -3.12, -3.1, -3.08]),
           "collision": np.array([0, 0, 0, 1, 0])}
    coll, dyaw = motion_model.imu_per_frame(imu, np.array([0.0, 0.1, 0.2, 0.3]))
    assert coll.tolist() == [False, False, True, False]
    assert dyaw[0] == 0.0
    assert dyaw[1] == pytest.approx(2 * math.pi - 6.22, abs=1e-9)
    assert dyaw[2] == pytest.approx(0.04, abs=1e-9)
    assert np.isnan(dyaw[3])  # past the end of the IMU's record
    s_t, s_r = motion_model.motion_sigmas((0.02, 0.0, 0.0), 0.1)
    s_tc, s_rc = motion_model.motion_sigmas((0.02, 0.0, 0.0), 0.1, collision=True)
    assert s_tc > s_t + 0.05 and s_rc > s_r + 0.2  # without the IMU's yaw: much wider


# ---------------------------------------------------------------------------- the filter


def test_converges_from_the_initial_placement(kidsize, model):
    conf = copy.deepcopy(mcl.confs["default"])
    poses, truth, _ = _run_walk(kidsize, model, conf, n=150, seed=3)
    err = _errors(poses, truth)[20:]
    assert np.median(err) < 0.10
    assert np.mean(err < 0.4) >= 0.95


def test_converges_from_uniform_up_to_symmetry(kidsize, model):
    conf = copy.deepcopy(mcl.confs["uniform"])
    poses, truth, flags = _run_walk(kidsize, model, conf, n=150, seed=4)
    mirrored = np.array([kidsize.mirror_pose(p) for p in poses])
    err = np.minimum(_errors(poses, truth), _errors(mirrored, truth))[40:]
    assert np.median(err) < 0.15
    assert np.mean(err < 0.4) >= 0.9
    # both goals are white: the filter says so instead of picking a side silently
    assert all("mirror-ambiguous" in f for f in flags[40:])


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from(["any", "left", "right"]))
def test_a_placement_stands_on_its_touch_line_or_inside_it(kidsize, seed, side):
    """A placed robot stands on the line or inside the field, never beyond the line: its
    distance inside is half-normal with init_spread[0]'s scale (mean sqrt(2 / pi) of it;
    4000 draws hold the mean within 4 standard errors), facing into the field."""
    conf = dict(copy.deepcopy(mcl.confs["default"]), start_side=side)
    p = mcl_start.placement_poses(4000, np.random.default_rng(seed), kidsize, conf)
    inset = 0.5 * kidsize.width - np.abs(p[:, 1])
    assert inset.min() >= 0.0 and np.all(p[:, 0] <= 0.0)
    scale = conf["init_spread"][0]
    assert abs(inset.mean() - scale * math.sqrt(2 / math.pi)) < 4 * scale * 0.6 / math.sqrt(4000)
    if side != "any":  # the named line (y > 0 is left) holds all but START_SIDE_ERROR of them
        sign = 1.0 if side == "left" else -1.0
        assert np.mean(np.sign(p[:, 1]) == sign) > 0.99
        facing = -sign * math.pi / 2
        assert np.median(np.abs(np.angle(np.exp(1j * (p[:, 2] - facing))))) < 0.2


def test_placement_start_is_not_mirror_ambiguous(kidsize, model):
    conf = copy.deepcopy(mcl.confs["default"])
    _poses, _truth, flags = _run_walk(kidsize, model, conf, n=60, seed=5)
    assert sum("mirror-ambiguous" in f for f in flags[20:]) <= 2


def test_a_known_start_is_drawn_densely_for_its_first_observations(kidsize, model):
    """A placement's prior is long and thin: the frames before its first observations carry
    ``START_DENSITY`` times its particles, the first frame with observations weighs them all
    and keeps the start's count (a count the caller gives is held from the start)."""
    conf = copy.deepcopy(mcl.confs["default"])
    truth, odom, _ = synthetic_walk(kidsize, 2, seed=3)
    pf = mcl.ParticleFilter(model, conf)
    pf.initialise()
    n = mcl_start.initial_count("placement", conf)
    assert mcl_start.density("placement") > 1
    assert len(pf.particles) == n * mcl_start.density("placement")
    pf.step(odom[0], 0.1, Observations.empty(), first=True)
    assert len(pf.particles) == n * mcl_start.density("placement")
    obs = synthetic_observations(kidsize, truth[1], np.random.default_rng(0), NOISELESS)
    pf.step(odom[1], 0.1, obs)
    assert len(pf.particles) <= n
    pf.initialise("placement", n=500)  # a count given is held as given
    assert len(pf.particles) == 500


@pytest.mark.parametrize("init", ["placement", "uniform"])
def test_new_particles_of_a_wide_known_start_weigh_its_error(kidsize, model, init,
                                                             monkeypatch):
    """While a placement's belief is wide, the poses augmented MCL and sensor resetting add
    stand for "the start was wrong" and weigh together ``START_ERROR``; after a uniform start
    they are the belief and weigh their share of the particles."""
    conf = copy.deepcopy(mcl.confs["default"])
    truth, _, _ = synthetic_walk(kidsize, 1, seed=3)
    pf = mcl.ParticleFilter(model, conf)
    pf.initialise(init)
    obs = synthetic_observations(kidsize, truth[0], np.random.default_rng(0), NOISELESS)
    frame = pf.correct(obs)
    monkeypatch.setattr(pf.averages, "share", lambda: 0.2)  # augmented MCL injects
    k = sum(pf.resample(frame, spread=3.0))
    n = len(pf.weights)
    assert k > 0.1 * n
    assert math.isclose(float(pf.weights.sum()), 1.0, rel_tol=1e-9)
    expected = mcl_start.START_ERROR if init == "placement" else k / n
    assert math.isclose(float(pf.weights[-k:].sum()), expected, rel_tol=1e-6)


def test_without_lines_still_localises(kidsize, model):
    conf = copy.deepcopy(mcl.confs["no-lines"])
    poses, truth, _ = _run_walk(kidsize, model, conf, n=150, seed=3)
    err = _errors(poses, truth)[20:]
    assert np.median(err) < 0.25


def test_frame_without_observations_keeps_the_predicted_belief(kidsize, model):
    conf = copy.deepcopy(mcl.confs["default"])
    pf = mcl.ParticleFilter(model, conf)
    pf.initialise("pose", [0.0, 1.0, 0.3])
    pf.weights = np.random.default_rng(2).random(len(pf.weights))
    pf.weights /= pf.weights.sum()
    before_p, before_w = pf.particles.copy(), pf.weights.copy()
    state = copy.deepcopy(pf.rng.bit_generator.state)
    est, _frame = pf.step((0.05, 0.0, 0.02), 0.1, Observations.empty())
    rng = np.random.default_rng()
    rng.bit_generator.state = state
    predicted = motion_model.sample_motion(before_p, (0.05, 0.0, 0.02), 0.1, rng)
    # exact same-run: the same motion model and generator state, here
    assert np.array_equal(pf.particles, predicted)
    assert np.array_equal(pf.weights, before_w)  # exact same-run: left as they were
    assert "no-observations" in est.flags and est.mode == "predicted"


def test_same_seed_same_poses(kidsize, model):
    conf = copy.deepcopy(mcl.confs["default"])
    a, _, _ = _run_walk(kidsize, model, conf, n=30, seed=7)
    b, _, _ = _run_walk(kidsize, model, conf, n=30, seed=7)
    assert np.array_equal(a, b)  # exact same-run: one seed twice
    conf["seed"] = 1
    c, _, _ = _run_walk(kidsize, model, conf, n=30, seed=7)
    assert not np.allclose(a, c, rtol=0, atol=1e-6)  # another seed: other poses


def test_recovers_after_kidnapping(kidsize, model):
    """Start tracking at a wrong pose (placement on the other touch line): augmented MCL
    injects particles and finds the robot again (up to the field's symmetry)."""
    conf = copy.deepcopy(mcl.confs["default"])
    conf["init"] = "pose"
    conf["init_pose"] = [-2.0, 2.8, -math.pi / 2]
    conf["init_spread"] = [0.1, 0.1, 0.05]
    start = [-2.0, -2.8, math.pi / 2]
    poses, truth, _ = _run_walk(kidsize, model, conf, n=150, seed=8, start=start)
    mirrored = np.array([kidsize.mirror_pose(p) for p in poses])
    err = np.minimum(_errors(poses, truth), _errors(mirrored, truth))
    assert np.median(err[-50:]) < 0.2


def test_asymmetric_field_is_not_paired(kidsize):
    extra = np.concatenate([kidsize.segments, [[[1.0, 1.0], [2.0, 1.0]]]])
    fm = dataclasses.replace(kidsize, segments=extra)
    assert kidsize.is_point_symmetric()
    assert not fm.is_point_symmetric()


# ---------------------------------------------------------------------------- the stage


def test_localize_main_with_mcl(kidsize, map_path, tmp_path):
    from stages import localize
    from stages.common.poses_file import read_poses

    data = tmp_path / "walk"
    features = write_synthetic_run(kidsize, data, 120, seed=11)
    out = localize.main({"method": "mcl"}, data, map_path, tmp_path / "poses.h5",
                        features=features)
    cols, attrs = read_poses(out)
    assert attrs["method"] == "mcl" and attrs["conf"]["init"] == "placement"
    assert len(cols["name"]) == 120 and not cols["failed"].any()
    truth = np.loadtxt(data / "truth.csv", delimiter=",", skiprows=1)
    err = np.hypot(cols["x"] - truth[:, 1], cols["y"] - truth[:, 2])[20:]
    assert np.median(err) < 0.1
    assert np.all(np.isfinite(cols["covariance"][20:]))
    assert np.all((cols["confidence"] >= 0) & (cols["confidence"] <= 1))


def test_mcl_refuses_omni_features(kidsize, map_path, tmp_path):
    from stages.common.errors import FieldlocError
    from stages.common.features_file import FeaturesFile

    data = tmp_path / "walk"
    features = write_synthetic_run(kidsize, data, 3, seed=1)
    import h5py

    with h5py.File(features, "a") as h5:
        h5.attrs["camera_kind"] = "omni"
    from stages.common.map_file import MapFile

    with FeaturesFile(features) as ff, MapFile(map_path) as mf:
        with pytest.raises(FieldlocError, match="perspective"):
            mcl.run(mcl.confs["default"], None, ff, mf)


def test_show_belief_cli(kidsize, map_path, tmp_path):
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    data = tmp_path / "walk"
    write_synthetic_run(kidsize, data, 5, seed=2)
    out = tmp_path / "belief.png"
    res = CliRunner().invoke(cli, ["show", "belief", str(data), "--frame", "3", "--map",
                                   str(map_path), "--resolution", "0.25", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # a missing frame is one clear error line
    res = CliRunner().invoke(cli, ["show", "belief", str(data), "--frame", "99", "--map",
                                   str(map_path), "-o", str(tmp_path / "x.png")])
    assert res.exit_code == 1 and "out of range" in res.output


def test_belief_grid_peaks_near_truth(kidsize, model):
    from stages.localize.belief import belief_grid

    pose = np.array([2.0, 1.0, 2.5])
    obs = synthetic_observations(kidsize, pose, np.random.default_rng(3), NOISELESS)
    grid = belief_grid(model, obs, resolution=0.2, heading_step=math.radians(10))
    ll = grid["all"]
    i, j = np.unravel_index(int(np.argmax(ll)), ll.shape)
    best = np.array([grid["xs"][j], grid["ys"][i]])
    # the best cell is the truth or its mirror image (both goals look the same)
    d = min(np.hypot(*(best - pose[:2])), np.hypot(*(best + pose[:2])))
    assert d <= 0.21


# ---------------------------------------------------------------------------- a rendered walk


@pytest.fixture(scope="module")
def rendered_walk(tmp_path_factory, map_path):
    """A short rendered KidSize walk (perspective simulator), extracted and localised with
    mcl three times: from the initial placement, without lines, from a uniform start."""
    from stages import extract, localize, simulate
    from stages.common.dataset import read_csv
    from stages.common.poses_file import read_poses

    root = tmp_path_factory.mktemp("kid")
    conf = copy.deepcopy(simulate.confs["perspective-default"])
    conf.update(frames=40, seed=1)
    data = simulate.main(conf, "kidsize", root / "walk")
    features = extract.main(None, data, root / "features.h5")
    truth = read_csv(data / "truth.csv", "truth")
    out = {}
    for preset in ("default", "no-lines", "uniform"):
        path = localize.main(f"mcl-{preset}", data, map_path,
                             root / f"poses-{preset}.h5", features=features)
        cols, _ = read_poses(path)
        i = np.searchsorted(truth["stamp"], cols["stamp"] - 1e-6)
        tx, ty = truth["x"][i], truth["y"][i]
        err = np.hypot(cols["x"] - tx, cols["y"] - ty)
        mirrored = np.hypot(cols["x"] + tx, cols["y"] + ty)
        out[preset] = (err, mirrored, cols)
    out["paths"] = (data, features)
    return out


def test_rendered_walk_from_the_initial_placement(rendered_walk):
    """The issue's goals (median <= 10 cm, >= 95 % within 40 cm) are for a walk of a few
    hundred frames (the bench); on these 40 frames the first ones, while the robot walks along
    the touch line where it entered, are left out of the median."""
    err, _, cols = rendered_walk["default"]
    assert not cols["failed"].any()
    assert np.mean(err <= 0.40) >= 0.95
    assert np.median(err[20:]) <= 0.10


def test_rendered_walk_without_lines(rendered_walk):
    """The paper's ablation (crossings and goal posts only): lines make the poses better."""
    err, _, cols = rendered_walk["no-lines"]
    with_lines, _, _ = rendered_walk["default"]
    assert not cols["failed"].any() and np.all(np.isfinite(err))
    assert np.median(err) > np.median(with_lines)
    assert np.mean(err <= 0.4) <= np.mean(with_lines <= 0.4)


def test_rendered_walk_from_a_uniform_start(rendered_walk):
    err, mirrored, cols = rendered_walk["uniform"]
    folded = np.minimum(err, mirrored)[10:]
    assert np.median(folded) <= 0.15
    assert np.mean(folded <= 0.40) >= 0.9
    assert all("mirror-ambiguous" in f for f in cols["flags"][10:])


def test_cli_start_half_breaks_the_symmetry_of_a_uniform_start(rendered_walk, map_path,
                                                               tmp_path):
    """``fieldloc localize --method mcl --init uniform --start-half H``: the belief is drawn on
    the named half, so the pose itself (not only up to the mirror) is decided and accepted.
    The walk starts on the own half: ``own`` gives the truth, accepted on >= 90 % of the
    frames from frame 10 on (every frame on this walk today); ``opponent`` (wrong) gives the
    mirrored track (which no frame can contradict: ``evaluate`` with the truth says so);
    without it no frame is accepted, every one up to the mirror."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages.common.dataset import read_csv
    from stages.common.poses_file import read_poses

    data, features = rendered_walk["paths"]
    truth = read_csv(data / "truth.csv", "truth")
    assert truth["x"][0] < 0  # the walk enters on the own half
    runs = {}
    for half in ("own", "opponent"):
        out = tmp_path / f"{half}.h5"
        res = CliRunner().invoke(cli, ["localize", str(data), "--map", str(map_path),
                                       "--features", str(features), "--method", "mcl",
                                       "--init", "uniform", "--start-half", half, "-o",
                                       str(out)])
        assert res.exit_code == 0, res.output
        cols, attrs = read_poses(out)
        assert attrs["conf"]["start_half"] == half
        i = np.searchsorted(truth["stamp"], cols["stamp"] - 1e-6)
        err = np.hypot(cols["x"] - truth["x"][i], cols["y"] - truth["y"][i])
        mirrored = np.hypot(cols["x"] + truth["x"][i], cols["y"] + truth["y"][i])
        runs[half] = (cols, err, mirrored)
    cols, err, _ = runs["own"]
    assert np.mean(cols["accepted"][10:] & (err[10:] <= 0.4)) >= 0.9
    assert not np.any(cols["accepted"] & (err > 1.0))
    cols, err, mirrored = runs["opponent"]
    assert np.mean(cols["accepted"][10:] & (mirrored[10:] <= 0.4)) >= 0.9
    _, _, cols = rendered_walk["uniform"]
    assert not cols["accepted"].any() and np.mean(cols["accepted_up_to_mirror"][10:]) >= 0.9


def test_cli_start_side_holds_the_placement_to_its_touch_line(rendered_walk, map_path,
                                                               tmp_path):
    """``fieldloc localize --method mcl --start-side S``: the placement stands on the touch
    line S names, so the first frame's top pose lies on that side of the field whichever the
    frame favours (a wrong side named holds it there); named right, no accepted frame is more
    than 1 m off."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages.common.dataset import read_csv
    from stages.common.poses_file import read_poses

    data, features = rendered_walk["paths"]
    truth = read_csv(data / "truth.csv", "truth")
    own = "left" if truth["y"][0] > 0 else "right"
    runs = {}
    for side in ("left", "right"):
        out = tmp_path / f"{side}.h5"
        res = CliRunner().invoke(cli, ["-q", "localize", str(data), "--map", str(map_path),
                                       "--features", str(features), "--method", "mcl",
                                       "--start-side", side, "-o", str(out)])
        assert res.exit_code == 0, res.output
        cols, attrs = read_poses(out)
        assert attrs["conf"]["start_side"] == side
        assert np.sign(cols["y"][0]) == (1.0 if side == "left" else -1.0)
        i = np.searchsorted(truth["stamp"], cols["stamp"] - 1e-6)
        runs[side] = (cols, np.hypot(cols["x"] - truth["x"][i], cols["y"] - truth["y"][i]))
    cols, err = runs[own]
    assert not np.any(cols["accepted"] & (err > 1.0))


def test_cli_imu_heading_decides_a_uniform_start(rendered_walk, map_path, tmp_path):
    """``-c imu_heading_sigma=0.2``: the IMU's yaw (field-aligned, as lut's default takes it)
    weights the particles, and a pose and its mirror have headings pi apart, so a uniform
    start without ``start_half`` decides the pose itself: accepted within 40 cm on >= 90 % of
    the frames from frame 10 on, none accepted more than 1 m off. The same walk with the
    IMU's yaw turned by pi decides the mirrored track: the IMU decides, not the chain's luck.
    """
    import shutil

    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages.common.dataset import read_csv, write_csv
    from stages.common.geometry import wrap_angle
    from stages.common.poses_file import read_poses

    data, features = rendered_walk["paths"]
    turned = tmp_path / "turned"
    shutil.copytree(data, turned)
    imu = read_csv(data / "imu.csv", "imu")
    write_csv(turned / "imu.csv", "imu", {**imu, "yaw": wrap_angle(imu["yaw"] + math.pi)})
    truth = read_csv(data / "truth.csv", "truth")
    for folder, sign in ((data, 1.0), (turned, -1.0)):
        out = tmp_path / f"{folder.name}.h5"
        res = CliRunner().invoke(cli, ["localize", str(folder), "--map", str(map_path),
                                       "--features", str(features), "--method", "mcl",
                                       "--init", "uniform", "-c", "imu_heading_sigma=0.2",
                                       "-o", str(out)])
        assert res.exit_code == 0, res.output
        cols, attrs = read_poses(out)
        assert attrs["conf"]["imu_heading_sigma"] == 0.2
        i = np.searchsorted(truth["stamp"], cols["stamp"] - 1e-6)
        err = np.hypot(cols["x"] - sign * truth["x"][i], cols["y"] - sign * truth["y"][i])
        assert np.mean(cols["accepted"][10:] & (err[10:] <= 0.4)) >= 0.9, folder.name
        assert not np.any(cols["accepted"] & (err > 1.0)), folder.name


def test_cli_refuses_bad_mcl_conf_values_in_one_line(kidsize, map_path, tmp_path):
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    data = tmp_path / "walk"
    features = write_synthetic_run(kidsize, data, 5, seed=4)
    for bad in ("start_half=sideways", "start_side=middle", "start_half_error=2",
                "imu_heading_sigma=0",
                "imu_heading_sigma=true", "imu_heading_sigma=-1",
                # no particles (a division by zero at the first resampling), a hundred million
                # (hours a run), fewer allowed than required
                "particles_max=0", "particles_max=100000000", "particles_min=2000",
                # tuned constants of the filter and its models are no conf keys
                "init_particles=500", "cluster_radius=0.5",
                "observation.sigma_range=0.05", "motion=1"):
        res = CliRunner().invoke(cli, ["localize", str(data), "--map", str(map_path),
                                       "--features", str(features), "--method", "mcl", "-c",
                                       bad, "-o", str(tmp_path / "p.h5")])
        assert res.exit_code != 0
        assert bad.split("=")[0] in res.output and "Traceback" not in res.output
        assert not (tmp_path / "p.h5").exists()


def test_a_new_rival_is_scored_on_the_frames_before(kidsize, model):
    """A rival found now holds the sums it would have had if followed since the frames the
    belief weighed before (moved back by the odometry), not this frame's ratio alone: on a
    robot walking straight ahead along a frame sequence, a place found at the last frame
    whose moved-back poses explain the earlier frames as the belief's reference did holds
    odds of about 0 from them; one whose earlier poses fit worse holds negative odds."""
    conf = copy.deepcopy(mcl.confs["uniform"])
    pf = mcl.ParticleFilter(model, conf)
    pf.initialise()
    rivals = pf.rivals
    truth = np.array([-2.0, -1.0, 0.3])
    step = np.array([0.1, 0.0, 0.0])
    poses = [truth]
    for _ in range(5):
        poses.append(motion_model.moved(poses[-1][None], *step)[0])
    rng = np.random.default_rng(3)
    for k, pose in enumerate(poses[:-1]):
        prep = model.prepare(synthetic_observations(kidsize, pose, rng))
        ll = float(model.log_likelihood(*pose[:, None], prep)[0])
        rivals.since_recent = step.copy() if k else np.zeros(3)
        rivals.recent.append((prep, ll, ll, rivals.since_recent))
        rivals.since_recent = np.zeros(3)
    rivals.since_recent = step.copy()
    far = np.array([3.0, 2.0, -2.0])
    evidence, odds = rivals.retro_odds(np.array([poses[-1], far]), 1.0)
    assert abs(odds[0]) < 1e-6 and abs(evidence[0]) < 1e-6
    assert odds[1] < -10.0 and evidence[1] < -10.0
    # forgetting weighs each earlier frame by keep_share per frame back
    _, halved = rivals.retro_odds(np.array([far]), 0.5)
    assert odds[1] < halved[0] < 0.0


def test_map_without_crossing_tables_still_works(kidsize, tmp_path):
    """An older map without the association tables: the model computes them on its grid."""
    from stages.common.artifacts import root_attrs
    from stages.common.map_file import SCHEMA, VERSION, MapFile

    grid = Grid.around(kidsize, kidsize.border, 0.1)
    path = write_map(tmp_path / "bare.map.h5", kidsize, grid, ScanLines(), {},
                     root_attrs(SCHEMA, VERSION))
    tabs = crossing_association_tables(kidsize, grid)
    with MapFile(path) as mf:
        m = ObservationModel.from_map(mf)
    # exact integers: crossing indices
    assert np.array_equal(m.lut[:4 * m._cells], tabs["crossing_lut_L"][0].ravel())
    # exact integers: crossing indices
    assert np.array_equal(m.lut[4 * m._cells:], tabs["crossing_lut_T"][0].ravel())


def test_localize_cli_init_uniform(kidsize, map_path, tmp_path):
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages.common.poses_file import read_poses

    data = tmp_path / "walk"
    features = write_synthetic_run(kidsize, data, 30, seed=4)
    out = tmp_path / "poses.h5"
    args = ["localize", str(data), "--map", str(map_path), "--features", str(features),
            "--method", "mcl", "--init", "uniform", "-o", str(out)]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    cols, attrs = read_poses(out)
    assert attrs["conf"]["init"] == "uniform"
    assert all("mirror-ambiguous" in f for f in cols["flags"][5:])
    # --init belongs to mcl
    res = CliRunner().invoke(cli, args[:-6] + ["--method", "lut", "--init", "uniform", "-o",
                                               str(tmp_path / "x.h5")])
    assert res.exit_code != 0 and "--init applies to --method mcl" in res.output


def test_rendered_nao_walk_with_the_cli_defaults(tmp_path):
    """The NAO goals: a short rendered NAO walk (``perspective-nao``: 640 x 480, the SPL field, hall
    lighting, other robots, people and balls) localised by ``fieldloc localize --method mcl``
    with its defaults, from the game's placement. The camera height comes from the dataset's
    calib.yaml (0.45 m, not the model's 0.5). Stated error, 40 frames: from frame 10 on
    >= 90 % within 40 cm and median <= 10 cm (seed 2 today: 100 %, 6.5 cm; before the
    kidnap share, the line-placed poses and the posts' own floor: 53 %); never accepted more
    than 1 m off. The 300-frame goals are the bench's (``mcl-nao-accuracy``)."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages import build_map, extract, simulate
    from stages.common.dataset import read_csv
    from stages.common.poses_file import read_poses

    conf = copy.deepcopy(simulate.confs["perspective-nao"])
    conf.update(frames=40, seed=2)
    data = simulate.main(conf, "spl", tmp_path / "nao")
    features = extract.main(None, data, tmp_path / "features.h5")
    map_path = build_map.main(None, "spl", tmp_path / "spl.map.h5")
    out = tmp_path / "poses.h5"
    res = CliRunner().invoke(cli, ["-q", "localize", str(data), "--map", str(map_path),
                                   "--features", str(features), "--method", "mcl", "-o",
                                   str(out)])
    assert res.exit_code == 0, res.output
    cols, attrs = read_poses(out)
    assert attrs["conf"]["init"] == "placement"
    assert attrs["conf"]["observation"]["camera_height"] is None  # resolved from calib.yaml
    truth = read_csv(data / "truth.csv", "truth")
    i = np.searchsorted(truth["stamp"], cols["stamp"] - 1e-6)
    err = np.hypot(cols["x"] - truth["x"][i], cols["y"] - truth["y"][i])
    assert not cols["failed"].any()
    assert np.mean(err[10:] <= 0.40) >= 0.9
    assert np.median(err[10:]) <= 0.10
    assert not np.any(cols["accepted"] & (err > 1.0))


def test_rivals_sum_their_evidence_over_frames(kidsize, model):
    """After a uniform start, a place that explains each frame 2 nats better than the belief
    (far below the ~13 nats the kidnap prior asks of one frame) becomes "elsewhere" after a
    few frames; one inside the belief's cluster is dropped; from the placement none is kept."""
    conf = copy.deepcopy(mcl.confs["uniform"])
    pf = mcl.ParticleFilter(model, conf)
    pf.initialise()
    last = np.array([2.0, 1.0, 0.0])  # the belief's pose
    rivals = pf.rivals
    rival = np.array([[-3.0, -1.5, 1.0]])
    inside = np.array([[2.1, 1.0, 0.05]])
    rivals.update(np.concatenate([rival, inside]), np.array([-1.0, -1.0]), np.zeros(0), 0.0,
                  last_pose=last)
    assert len(rivals.poses) == 1 and rivals.evidence[0] == 0.0
    shares = []
    for _ in range(12):
        rivals.update(np.zeros((0, 3)), np.zeros(0), np.array([2.0]), 0.0, last_pose=last)
        share, placed_at = rivals.kidnap_share(pf.averages.share(), 0.0, np.array([2.0]))
        shares.append(share)
    assert shares[0] < 1e-3 < 0.5 < shares[-1]
    np.testing.assert_allclose(placed_at, rival[0])
    # forgetting: the evidence of a constant 2 nats a frame stays below 2 * RIVAL_MEMORY
    assert rivals.evidence[0] < 2.0 * mcl_rivals.RIVAL_MEMORY
    placed = mcl.ParticleFilter(model, copy.deepcopy(mcl.confs["default"]))
    placed.initialise()
    placed.rivals.update(rival, np.array([-1.0]), np.zeros(0), 0.0)
    assert len(placed.rivals.poses) == 0


def test_place_search_separates_places_as_the_scalar_rule():
    """place_search.separate (the compiled greedy pass) picks the poses the scalar rule does:
    in order of the likelihood, each pose that is no place (same_place, up to the mirror) of
    those picked before, among the ``limit`` best when given (ties too)."""
    from stages.localize import place_search

    rng = np.random.default_rng(1)
    poses = place_search.grid_poses((-5, 5, -3.5, 3.5), 0.3, 10.0)
    for trial in range(6):
        ll = rng.normal(size=len(poses)).round(1)
        limit = 3000 if trial % 2 else None
        got = place_search.separate(poses, ll, 8, limit=limit)
        order = np.argsort(-ll, kind="stable")[:limit]
        want = []
        for i in order:
            if not any(place_search.same_place(poses[i], poses[q]) for q in want):
                want.append(i)
                if len(want) == 8:
                    break
        assert list(got) == want
        inside = place_search.within_places(poses[::37], poses[got])
        assert list(inside) == [any(place_search.same_place(p, poses[q]) for q in got)
                                for p in poses[::37]]


def test_uniform_start_searches_its_places_once(kidsize, model, monkeypatch):
    """A uniform start runs the place search on its first frame with observations only (not
    per frame: the update stays a particle update), a start from the placement never; the
    first belief holds particles at the truth's place (or its mirror)."""
    from stages.localize import place_search

    calls = []
    search = place_search.search

    def counted(*args, **kwargs):
        out = search(*args, **kwargs)
        calls.append(out)
        return out

    monkeypatch.setattr(place_search, "search", counted)
    truth, odom, _stamps = synthetic_walk(kidsize, 8, seed=4)
    rng = np.random.default_rng(104)
    for preset, searches in (("uniform", 1), ("default", 0)):  # the default: placement
        calls.clear()
        pf = mcl.ParticleFilter(model, copy.deepcopy(mcl.confs[preset]))
        pf.initialise()
        pf.step(odom[0], 0.1, Observations.empty(), first=True)  # nothing seen: no search
        assert not calls
        for i in range(1, 8):
            obs = synthetic_observations(kidsize, truth[i], rng, NOISELESS)
            pf.step(odom[i], 0.1, obs)
            if i == 1 and preset == "uniform":
                p = pf.particles
                near = [np.hypot(p[:, 0] - t[0], p[:, 1] - t[1]) < 0.3
                        for t in (truth[i], kidsize.mirror_pose(truth[i]))]
                assert (near[0] | near[1]).sum() >= 20
        assert len(calls) == searches
