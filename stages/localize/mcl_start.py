"""The particle filter's initial belief (mcl.py): where the particles lie before the first frame,
and where a uniform start's first frame with observations places them.

Three starts (the conf's ``init``):

- ``placement`` (the default): as robots enter a game, on the own half (the opponent's with
  ``start_half: opponent``) at either touch line (the one ``start_side`` names), facing into
  the field, on the line or inside it by a half-normal of ``init_spread``'s first value and
  turned by its last (``placement_poses`` draws it, ``placement_log_density`` is its density
  for the smoother). It breaks the field's 180 deg symmetry, which no observation can;
- ``pose``: a Gaussian of ``init_spread`` around ``init_pose``;
- ``uniform``: anywhere in the world (the field and its margin), or on the half ``start_half``
  names (``start_half_error`` of the particles on the other). On a point-symmetric field with
  no start half and no IMU heading each particle stands for itself and its mirrored pose
  (``SYMMETRIC_PAIRS``; "paired"), so the filter holds half as many.

A uniform start's first frame with observations is scored on a coarse grid (``START_GRID``,
each pose as anywhere in its cell: place_search.cell_model), and the ``START_PLACES`` best
distinct places (1 m or 30 deg apart, up to the mirror), refined on two local grids
(place_search.search), each get an *equal* share of the particles, drawn from the frame's
posterior around it; the grid's likelihood outside them is drawn uniformly (or
``START_UNIFORM_SHARE``). Drawn uniformly, the particles of a sharp peak are few and off it;
drawn by the first frame's likelihood, a broad plateau outweighs a sharp peak: either way
chance picks among places the first frames explain alike. Equal shares keep each place alive
until the frames decide. With ``start_half`` the places are searched on that half and as far
past the centre line as the robot may have walked before that frame (``StartHalf.reach``),
each on the side the start half favours (``StartHalf``).

The particle count of the initial belief (``INIT_PARTICLES``) is larger than the tracking
one: a wide belief needs more particles (a stand-in for KLD sampling, Fox (2003); the
resampling narrows it to ``particles_min`` .. ``particles_max``, mcl_resampling.py).

A placement or pose start says where the robot stands, up to its spread: its first frame with
observations weights ``START_DENSITY`` times the particles drawn from it and keeps the
particle count by resampling (the start's prior sampled as finely as that frame's likelihood
needs), and until its belief first narrows the poses the filter adds (augmented MCL's, the
sensor resets') weigh as much as the chance that the start was wrong (``START_ERROR``): they
are a defensive proposal (Hesterberg 1995), not the belief.
"""

from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

from ..common.errors import FieldlocError
from ..common.geometry import wrap_angle
from . import place_search
from .start_half import StartHalf

# particles of the initial belief by the start (``init``), kept until its spread falls below
# mcl_resampling.SPREAD_HIGH
INIT_PARTICLES = MappingProxyType({"placement": 1000, "uniform": 4000, "pose": 1000})
# a placement or pose start draws this many times its particles; its first frame with
# observations weights them all and resampling keeps INIT_PARTICLES. The start's belief is
# long and thin where the first frame's likelihood is narrow (heading, distance to the lines
# seen): drawn at the tracking count, few particles lie where that frame fits, and the belief
# reached the place the frames had already decided some ten frames late on NAO tuning walks
# (docs/results.md, "A known start: dense first frame, light new particles")
START_DENSITY = MappingProxyType({"placement": 16, "uniform": 1, "pose": 16})
# probability that a placement or pose start is not where the robot stood: the weight share
# of the poses the filter adds while that start's belief is still wide (augmented MCL's and
# the sensor resets', mcl_resampling). They are a defensive proposal (Hesterberg 1995): drawn
# to find the robot where the start is wrong, weighted by how likely that is. Weighted as the
# belief's own particles, they said "elsewhere" with their share (up to a quarter of the
# particles a frame) and held the confidence of a right belief below the acceptance threshold
START_ERROR = 1e-3
SYMMETRIC_PAIRS = True  # a symmetric prior on a symmetric field keeps its symmetry
# a uniform start's first frame with observations places the particles at the places
# where that frame fits best (place_search: the observation model on a coarse grid over
# the world, the best poses that are other places, each refined), an equal share each,
# the grid's likelihood share outside them uniform: every place that explains the frame
# holds particles at its best pose, and the frames that follow decide between them,
# where particles drawn uniformly or placed by one observation reached one of them first
# and held it (module doc)
START_PLACES = 16  # places searched for (0: a uniform belief)
START_GRID = (0.2, 6.0)  # m, deg: the coarse grid's step and turn
START_UNIFORM_SHARE = None  # share of the first particles drawn uniformly; None: the
# grid's share of the likelihood outside the places found
# the conf's start_side: the touch line of a placement (FieldModel.touchline_pose's side)
START_SIDES = MappingProxyType({"any": 0.0, "left": 1.0, "right": -1.0})
# probability that a start_side given is wrong: that share of a placement's particles stands
# at the other touch line (as start_half_error's default: a slip of the user's, not a prior
# that decides against the frames)
START_SIDE_ERROR = 1e-3
# m: the soft edges of a placement in its density (placement_log_density): past the ends of
# its half's stretch of the touch line, or beyond the line. The draw puts no pose there, but a
# pose fitted a few centimetres past an edge is still one of the placement's
PLACEMENT_EDGE = 0.1


def is_paired(mode: str, conf: dict, symmetric: bool, imu_heading: bool) -> bool:
    """Whether the particles of the start ``mode`` stand for themselves and their mirrored
    poses: a uniform start on a point-symmetric field that no start half and no IMU heading
    tell from its mirror (``SYMMETRIC_PAIRS``)."""
    return (mode == "uniform" and bool(SYMMETRIC_PAIRS) and symmetric
            and conf["start_half"] == "any" and not imu_heading)


def held_count(n: int, paired: bool) -> int:
    """Particles held for a belief of ``n``: half when each stands for a mirrored pair."""
    return max(n // 2, 1) if paired else n


def initial_count(mode: str, conf: dict) -> int:
    """The particles of the start ``mode``'s belief (``INIT_PARTICLES``; ``particles_max``
    for a mode it does not list)."""
    return int(INIT_PARTICLES.get(mode, conf["particles_max"]))


def is_known(mode: str) -> bool:
    """Whether the start ``mode`` says where the robot stands (placement or pose), so that
    the poses added while its belief is wide carry START_ERROR."""
    return mode in ("placement", "pose")


def density(mode: str) -> int:
    """How many times its particles the start ``mode`` draws for its first frame with
    observations (``START_DENSITY``; 1 for a mode it does not list)."""
    return max(int(START_DENSITY.get(mode, 1)), 1)


def searches_places(mode: str) -> bool:
    """Whether the start ``mode`` places its belief at the first frame's best places."""
    return mode == "uniform" and int(START_PLACES) > 0


def initial_poses(mode: str, n: int, rng, field, bounds: tuple, conf: dict,
                  pose=None) -> np.ndarray:
    """The ``n`` poses (n, 3) of the initial belief of ``mode`` in the world ``bounds`` (x0,
    x1, y0, y1); ``pose``: the centre of a ``pose`` start (the conf's ``init_pose`` by
    default)."""
    if mode == "uniform":
        return uniform_poses(n, rng, bounds, conf["start_half"], conf["start_half_error"])
    if mode == "placement":
        return placement_poses(n, rng, field, conf)
    if mode == "pose":
        pose = conf["init_pose"] if pose is None else pose
        if pose is None:
            raise FieldlocError("init=pose needs init_pose=[x, y, theta]")
        check_init_pose(pose, bounds)
        s = np.asarray(conf["init_spread"], float)
        p = np.asarray(pose, float) + rng.standard_normal((n, 3)) * s
        p[:, 2] = wrap_angle(p[:, 2])
        return p
    raise FieldlocError(f"unknown init '{mode}' (placement, uniform or pose)")


def check_init_pose(pose, bounds: tuple) -> None:
    """FieldlocError unless ``pose`` is [x, y, theta] within the world ``bounds`` (x0, x1, y0,
    y1: the field and its margin) and a heading within +-2 pi: checked whenever an init_pose
    is given, whatever the start mode (init_pose=[1e9, 0, 0] ran on silently unless init was
    pose: trial N8)."""
    if len(pose) != 3:
        raise FieldlocError("init=pose needs init_pose=[x, y, theta]")
    x0, x1, y0, y1 = bounds
    if not (x0 <= float(pose[0]) <= x1 and y0 <= float(pose[1]) <= y1):
        raise FieldlocError(
            f"init_pose ({float(pose[0]):.4g}, {float(pose[1]):.4g}) m lies off the"
            f" field and its margin (x within {x0:g}..{x1:g}, y within {y0:g}..{y1:g})")
    if not abs(float(pose[2])) <= 2 * math.pi:
        raise FieldlocError(f"init_pose heading {float(pose[2]):.4g} rad is not within"
                            " +-2 pi (radians, not degrees?)")


def uniform_poses(n: int, rng, bounds: tuple, half: str = "any",
                  half_error: float = 0.0) -> np.ndarray:
    """``n`` poses drawn uniformly over the world ``bounds``; over the half ``half`` names
    (own: x < 0, opponent: x > 0) where it names one, ``half_error`` of them on the other."""
    x0, x1, y0, y1 = bounds
    u = rng.random((n, 3))
    p = np.stack([x0 + (x1 - x0) * u[:, 0], y0 + (y1 - y0) * u[:, 1],
                  -math.pi + 2 * math.pi * u[:, 2]], axis=1)
    if half != "any":
        sign = -1.0 if half == "own" else 1.0
        wrong = rng.random(n) < float(half_error)
        # folded onto the half (the world is symmetric about x = 0), or off it
        p[:, 0] = np.where(wrong, -sign, sign) * np.abs(p[:, 0])
    return p


def placement_sign(conf: dict) -> float:
    """The sign of x on the half a placement stands on: the opponent half when
    ``start_half`` says so, else the own half."""
    return 1.0 if conf["start_half"] == "opponent" else -1.0


def placement_sides(n: int, rng, conf: dict) -> np.ndarray:
    """The touch line (+1: y > 0, -1: y < 0) of each of ``n`` placement poses: the one
    ``start_side`` names (START_SIDE_ERROR of them at the other), else either alike."""
    named = START_SIDES[conf.get("start_side", "any")]
    if named == 0.0:
        return np.where(rng.random(n) < 0.5, 1.0, -1.0)
    return np.where(rng.random(n) < START_SIDE_ERROR, -named, named)


def placement_poses(n: int, rng, field, conf: dict) -> np.ndarray:
    """``n`` poses on the start's half (``start_half``; own, x < 0, for any), at the touch line
    ``start_side`` names (either for any), facing into the field: a placed robot stands on
    the line or inside it, never beyond it, so its centre lies inside the line by a
    half-normal distance of ``init_spread[0]``'s scale (mean 0.8 of it)."""
    s_across, s_heading = float(conf["init_spread"][0]), float(conf["init_spread"][2])
    side = placement_sides(n, rng, conf)
    x = -placement_sign(conf) * rng.uniform(-field.length / 2, 0.0, n)
    inset = np.abs(rng.standard_normal(n)) * s_across
    turn = rng.standard_normal(n) * s_heading
    p = field.touchline_pose(x, side, inset=inset)
    p[:, 2] = wrap_angle(p[:, 2] + turn)
    return p


def placement_log_density(p: np.ndarray, field, conf: dict) -> np.ndarray:
    """The log density (up to a constant) of the poses ``p`` (N, 3) under the placement that
    placement_poses draws: on its half's stretch of the touch lines (the centre line to the
    goal line; beyond either end by d, -d^2 / (2 ``PLACEMENT_EDGE``^2)), at either touch line
    (``start_side``'s, the other at ``START_SIDE_ERROR``) facing into the field, inside the
    line by the half-normal of ``init_spread[0]`` (beyond it as beyond the stretch's ends) and
    turned by ``init_spread[2]``."""
    spread = np.asarray(conf["init_spread"], float)
    best = np.full(len(p), -np.inf)
    named = START_SIDES[conf.get("start_side", "any")]
    for side in (1.0, -1.0):
        at = field.touchline_pose(p[:, 0], side)
        inset = side * (at[:, 1] - p[:, 1])  # inside the line: > 0
        across = np.where(inset >= 0.0, inset / spread[0], inset / PLACEMENT_EDGE)
        turn = wrap_angle(p[:, 2] - at[:, 2]) / spread[2]
        odds = 0.0 if named in (0.0, side) else math.log(START_SIDE_ERROR)
        best = np.maximum(best, odds - 0.5 * (across ** 2 + turn ** 2))
    along = placement_sign(conf) * p[:, 0]
    beyond = np.maximum(-along, 0.0) + np.maximum(along - 0.5 * field.length, 0.0)
    return best - 0.5 * (beyond / PLACEMENT_EDGE) ** 2


def search_bounds(bounds: tuple, half: str, paired: bool, reach: float = 0.0) -> tuple:
    """Where a uniform start's places are searched: the half ``half`` names and ``reach`` m
    past the centre line (how far the robot may have walked since the first frame,
    StartHalf.reach), the half x <= 0 while particles stand for mirrored pairs, else the
    world ``bounds``."""
    x0, x1, y0, y1 = bounds
    if paired:
        return (x0, 0.0, y0, y1)
    if half == "own":
        return (x0, min(x1, reach), y0, y1)
    if half == "opponent":
        return (max(x0, -reach), x1, y0, y1)
    return bounds


def placed_start(model, prep, n: int, rng, bounds: tuple, conf: dict, *, symmetric: bool,
                 paired: bool, start_half: StartHalf | None = None) -> np.ndarray | None:
    """A uniform start's belief of ``n`` particles from its first frame with observations
    ``prep`` (the observation model's prepared observations): the places where the frame fits
    best (place_search.search: ``START_PLACES`` of them on the coarse grid ``START_GRID``
    over ``search_bounds``, each refined), an equal share of the particles around each (a
    Gaussian of the frame's posterior near it, place_search.local_posterior), and the grid's
    share of the likelihood outside them uniform over the world (or ``START_UNIFORM_SHARE``
    when given). With ``start_half`` (a start half carried by the odometry) each place's
    poses are on the side it favours. None where the search finds no place (the belief
    stays)."""
    step, turn = (float(v) for v in START_GRID)
    reach = 0.0 if start_half is None else start_half.reach()
    places, elsewhere = place_search.search(
        model, prep, search_bounds(bounds, conf["start_half"], paired, reach), step, turn,
        int(START_PLACES), mirror=symmetric, cells=True)
    if not places:
        return None
    if START_UNIFORM_SHARE is not None:
        elsewhere = float(START_UNIFORM_SHARE)
    n_uni = int(round(n * min(max(elsewhere, 0.0), 1.0)))
    counts = np.full(len(places), (n - n_uni) // len(places))
    counts[:(n - n_uni) - int(counts.sum())] += 1
    drawn = [uniform_poses(n_uni, rng, bounds, conf["start_half"], conf["start_half_error"])]
    for (pose, _ll), m in zip(places, counts):
        mean, cov = place_search.local_posterior(model, prep, pose)
        q = mean + rng.standard_normal((int(m), 3)) @ np.linalg.cholesky(cov).T
        if symmetric and not paired and conf["start_half"] == "any":
            # the place or its mirror image, alike
            flip = rng.random(len(q)) < 0.5
            q[flip] = model.field.mirror_pose(q[flip])
        elif start_half is not None:
            q = start_half.sided(q)
        drawn.append(q)
    p = np.concatenate(drawn)
    p[:, 2] = wrap_angle(p[:, 2])
    return p

