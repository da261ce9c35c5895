"""The placement bound (stages.localize.start_bound): the Bayes posterior over a walk's first
pose on a grid over mcl's placement prior, carried by the truth's relative motion. What must
hold: with nothing seen the posterior is the prior (checked against draws of the placement
itself, an independent reckoning), which decides no frame; a frame that sees the centre
circle's crossing decides the pose; naming the touch line never lowers the mass at the
truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stages.common.field import load_field
from stages.common.geometry import wrap_angle
from stages.common.observations import Observations
from stages.localize import mcl, start_bound
from stages.localize.mcl_start import placement_poses
from stages.localize.observation_model import ObservationModel

CONF = mcl.confs["default"]
# a robot 1 m from the centre line on the left touch line, 0.1 m inside it, facing the field
START = np.array([-1.0, 2.9, -math.pi / 2])


@pytest.fixture(scope="module")
def model():
    return ObservationModel.from_field(load_field("spl"), CONF["observation"])


def _placement(model, **change):
    return start_bound.placement_start(model.field, dict(CONF, **change), START)


def _standing(n: int) -> np.ndarray:
    return np.repeat(START[None], n, axis=0)


def test_nothing_seen_leaves_the_prior(model):
    mass = start_bound.decidable_mass(model, [Observations.empty()] * 3, _standing(3),
                                       _placement(model))
    # the placement's own draws: the share in mcl's cluster around the truth (the grid's sum stands
    # for the same integral; 200k draws give it to about +-0.002, the grid's cells to ~0.01)
    draws = placement_poses(200_000, np.random.default_rng(1), model.field, CONF)
    want = np.mean((np.hypot(*(draws[:, :2] - START[:2]).T) <= mcl.CLUSTER_RADIUS)
                   & (np.abs(wrap_angle(draws[:, 2] - START[2])) <= mcl.CLUSTER_HEADING))
    np.testing.assert_allclose(mass, want, atol=0.02)
    assert np.all(mass < CONF["min_confidence"])  # a placement alone decides nothing


def _centre_x(pose: np.ndarray) -> Observations:
    """The centre circle's crossing with the centre line on the robot's own side (0, 0.75) as
    seen from ``pose``: an X crossing (type 2) by distance and bearing, arms along the line."""
    dx, dy = 0.0 - pose[0], 0.75 - pose[1]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    fx, fy = c * dx + s * dy, -s * dx + c * dy
    orient = math.remainder(math.pi / 2 - pose[2], math.pi / 2)
    return Observations(np.zeros((0, 4)), None,
                        np.array([[2, math.hypot(fx, fy), math.atan2(fy, fx), orient, 1.0]]),
                        np.zeros((0, 3)))


def test_the_centre_circle_decides_the_pose(model):
    frames = [_centre_x(START)] * 8  # one crossing a frame: it decides within a few frames
    mass = start_bound.decidable_mass(model, frames, _standing(8), _placement(model))
    assert mass[0] < 0.5 and mass[-1] >= 0.85  # 0.14 and 0.92 today; acceptance at 0.8
    assert np.all(np.diff(mass) >= -1e-9)  # the same evidence again never lowers it


def test_naming_the_touch_line_never_lowers_the_mass(model):
    frames = [Observations.empty(), _centre_x(START)]
    anyside = start_bound.decidable_mass(model, frames, _standing(2), _placement(model))
    named = start_bound.decidable_mass(model, frames, _standing(2),
                                       _placement(model, start_side="left"))
    assert np.all(named >= anyside - 1e-9)
    assert named[0] > anyside[0] + 0.05  # and the prior on one line holds more at the truth


def test_frames_and_truth_must_pair(model):
    with pytest.raises(ValueError, match="2 frames for 3 truth poses"):
        start_bound.decidable_mass(model, [Observations.empty()] * 2, _standing(3),
                                   _placement(model))


def test_a_uniform_start_without_its_half_decides_only_up_to_the_mirror(model):
    """On the point-symmetric SPL field a pose and its mirror image explain every frame alike:
    from a uniform start without ``start_half`` the truth holds half of what the pair holds."""
    bounds = (-5.2, 5.2, -3.7, 3.7)
    frames = [_centre_x(START)] * 3
    start = start_bound.uniform_start(bounds, dict(CONF, start_half="any"), START)
    pose = start_bound.decidable_mass(model, frames, _standing(3), start)
    pair = start_bound.decidable_mass(model, frames, _standing(3), start, up_to_mirror=True)
    np.testing.assert_allclose(pose, pair / 2, rtol=1e-6)
    assert pair[-1] > pair[0]
    own = start_bound.uniform_start(bounds, dict(CONF, start_half="own"), START)
    assert start_bound.decidable_mass(model, frames, _standing(3), own)[-1] > pose[-1] * 1.9
