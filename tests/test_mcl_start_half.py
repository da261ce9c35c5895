"""mcl's start half carried by the odometry (start_half.StartHalf): a uniform start told the half
the robot started in keeps telling a pose from its mirror image after the robot has walked,
for the poses the filter adds later as for its first particles."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.common.field import load_field
from stages.common.geometry import compose, wrap_angle
from stages.common.observations import Observations
from stages.localize import mcl
from stages.localize.observation_model import ObservationModel
from stages.localize.start_half import StartHalf
from stages.simulate.synthetic_observations import synthetic_observations

NOISELESS = {"pitch_noise": 0.0, "roll_noise": 0.0, "point_noise": 0.0, "bearing_noise": 0.0,
             "orientation_noise": 0.0, "p_miss_line": 0.0, "p_miss_crossing": 0.0,
             "p_miss_post": 0.0, "false_lines": 0.0, "false_crossings": 0.0,
             "false_posts": 0.0, "p_type_confusion": 0.0}

steps = st.lists(st.tuples(st.floats(-0.15, 0.15), st.floats(-0.05, 0.05),
                           st.floats(-0.3, 0.3)), min_size=0, max_size=40)


def _mirror(p: np.ndarray) -> np.ndarray:
    q = p.copy()
    q[:, 0:2] *= -1.0
    q[:, 2] = wrap_angle(q[:, 2] + math.pi)
    return q


def _carried(half: str, odometry) -> StartHalf:
    h = StartHalf(half, 1e-3)
    for inc in odometry:
        h.move(inc, 0.1)
    return h


@settings(max_examples=40, deadline=None)
@given(steps, st.floats(-4.5, -0.3), st.floats(-3.0, 3.0), st.floats(-math.pi, math.pi),
       st.sampled_from(["own", "opponent"]))
def test_the_odds_favour_the_pose_whose_walk_began_on_the_half(odometry, x0, y0, th0, half):
    """A walk begun on the named half (own: x < 0; opponent: its mirror image), carried by
    its odometry: the pose it reaches is favoured over that pose's mirror image, by exactly
    the odds the mirror image is disfavoured (the prior is of the pair), and the odds never
    pass those of start_half_error."""
    start = np.array([x0, y0, th0]) if half == "own" else -np.array([x0, y0, -th0])
    start[2] = wrap_angle(start[2] if half == "own" else th0 + math.pi)
    pose = start
    for inc in odometry:
        pose = compose(pose, np.asarray(inc))
    h = _carried(half, odometry)
    p = pose[None, :]
    odds = h.log_odds(p)[0]
    assert odds > 0.0
    assert h.log_odds(_mirror(p))[0] == pytest.approx(-odds, abs=1e-9)
    assert odds <= math.log((1 - 1e-3) / 1e-3) + 1e-9


@settings(max_examples=20, deadline=None)
@given(st.floats(0.3, 2.0), st.integers(1, 30))
def test_the_odds_weaken_as_the_robot_walks(x0, frames):
    """The same first pose, reached after a longer walk, tells its side less surely: the
    odometry's error grows with the path."""
    odds = []
    for n in (frames, frames + 10):
        h = _carried("own", [(0.1, 0.0, 0.05)] * n)
        pose = np.array([-x0, 0.5, 0.0])
        for _ in range(n):
            pose = compose(pose, np.array([0.1, 0.0, 0.05]))
        odds.append(h.log_odds(pose[None, :])[0])
    assert odds[0] > odds[1] > 0.0


def test_sided_takes_the_mirror_image_only_where_the_odds_decide():
    """``sided``: a pose on the start's side stays; one on the other side far enough from
    the centre line becomes its mirror image; one on the line (odds near 1) stays."""
    h = StartHalf("own", 1e-3)
    poses = np.array([[-2.0, 1.0, 0.3], [2.0, 1.0, 0.3], [0.0, 1.0, 0.3]])
    out = h.sided(poses)
    np.testing.assert_allclose(out[0], poses[0])
    np.testing.assert_allclose(out[1], [-2.0, -1.0, wrap_angle(0.3 + math.pi)])
    np.testing.assert_allclose(out[2], poses[2])


def test_a_robot_that_crossed_the_centre_line_before_it_saw_anything():
    """A uniform start with ``start_half: own`` whose robot walks across the centre line
    before its first frame with observations: the first frame's places are searched past the
    line as far as the robot may have walked, and each is taken on the side the start half
    favours, so the belief lands on the truth, not on its mirror image on the own half."""
    kidsize = load_field("kidsize")
    model = ObservationModel.from_field(kidsize)
    conf = dict(copy.deepcopy(mcl.confs["uniform"]), start_half="own")
    pf = mcl.ParticleFilter(model, conf)
    pf.initialise()
    rng = np.random.default_rng(1890)
    pose, inc = np.array([-0.6, 1.2, 0.0]), np.array([0.1, 0.0, 0.0])
    pf.step(inc, 0.1, Observations.empty(), first=True)
    for _ in range(16):  # 1.6 m along x: the robot is now on the opponent half
        pose = compose(pose, inc)
        pf.step(inc, 0.1, Observations.empty())
    assert pose[0] > 0.8
    for _ in range(12):
        pose = compose(pose, inc)
        est, _ = pf.step(inc, 0.1, synthetic_observations(kidsize, pose, rng, NOISELESS))
    assert math.hypot(est.pose[0] - pose[0], est.pose[1] - pose[1]) < 0.3
    assert est.confidence > 0.5


def test_the_warning_judges_where_the_accepted_poses_put_the_start():
    """localize's warning that the frames overruled the given half (symmetry
    .start_half_warning): a robot told to start on the own half that walked 2 m across the
    halfway line before its first accepted frames is not warned of, given the odometry (the
    first pose those frames imply is on the own half); the same poses without the odometry,
    and a track whose implied start is on the other half, are."""
    from stages.localize.symmetry import start_half_warning

    n, inc = 30, np.array([0.1, 0.0, 0.0])
    x = -1.0 + 0.1 * np.arange(n)  # from x = -1 m along +x, one frame a tenth of a second
    cols = {"x": x, "y": np.full(n, 1.0), "theta": np.zeros(n), "stamp": 0.1 * np.arange(n),
            "accepted": np.arange(n) >= 22}  # accepted from x = 1.2 m on
    increments = np.tile(inc, (n, 1))
    conf = {"conf": {"start_half": "own"}}
    assert start_half_warning(cols, conf, increments) is None
    assert start_half_warning(cols, conf) is not None  # where the poses lie: the other half
    mirrored = dict(cols, x=-x, y=-cols["y"], theta=np.full(n, math.pi))
    msg = start_half_warning(mirrored, {"conf": {"start_half": "opponent"}}, increments)
    assert msg is None
    assert "place its start in the opponent half" in start_half_warning(
        dict(cols, x=x + 3.0), conf, increments)
