"""How much of a walk any filter could accept: a bound that tells the frames mcl leaves
unaccepted from the frames that cannot be decided.

From a touch line the penalty area's lines look like the centre line's from the other touch
line (docs/manual.md, mcl's placement), so a placed robot's first frames often fit two places
alike; from a uniform start many places fit the first frames. The bound is the Bayes posterior
over the walk's first pose under mcl's start prior (the placement,
``mcl_start.placement_log_density``, or a uniform start over the world with ``start_half``'s
odds) on a grid, each grid pose carried through the walk by the truth's own relative motion
(odometry without noise, which no filter has) and weighted frame by frame by mcl's observation
model. Frame t is *decidable* when that posterior holds ``min_confidence`` (mcl's acceptance
threshold) within a cluster of mcl's (``mcl.CLUSTER_RADIUS`` and ``CLUSTER_HEADING``, what its
confidence counts) around the truth (or, up to the mirror, around the truth or its mirror
image): the confidence mcl would state with its cluster on the truth, had it weighed every
place the model allows. A frame that is not decidable is one the model's evidence leaves open;
a filter that accepts it states more than that evidence (right by luck where the alternatives
it dropped were wrong, as resampling drops them). The truth's own first pose is one of the
grid's poses, while the grid's other poses lie up to half a cell from their best fit; both
favour the truth.

It needs the truth, so it is a measurement (``fieldloc bench``'s ``mcl-walks-bound`` rows), not
a localiser.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import logsumexp

from ..common.geometry import between, wrap_angle
from .mcl import CLUSTER_HEADING, CLUSTER_RADIUS
from .mcl_start import PLACEMENT_EDGE, placement_log_density, placement_sign

# the placement's grid: STEP m along and across the touch line, TURN rad of heading, SPAN
# standard deviations of init_spread across the line and in heading (the prior's mass beyond
# them is below 1 %), and the stretch's ends widened by EDGES x PLACEMENT_EDGE
STEP, TURN, SPAN, EDGES = 0.05, math.radians(3.0), 3.0, 2.0
# a uniform start's grid over the world: UNIFORM_STEP m, UNIFORM_TURN rad (coarser: at the
# placement's cells the world would take some 30 times its 110k poses; coarser cells favour
# the truth more, see the module doc)
UNIFORM_STEP, UNIFORM_TURN = 0.1, math.radians(6.0)
# nats: a grid pose this far below the best is dropped (a weight below e^-PRUNE of the best;
# coming back would take that much evidence against the best, more than a whole walk's
# look-alikes gather, docs/results.md)
PRUNE = 60.0


def placement_start(field, conf: dict, first) -> tuple[np.ndarray, np.ndarray]:
    """The placement's grid poses (N, 3) and their prior log densities: both touch lines (the
    prior weighs the one ``start_side`` names), along its half's stretch and across the line
    every STEP, turned every TURN, out to SPAN of ``init_spread``; and the pose ``first`` (the
    truth's first pose)."""
    spread = np.asarray(conf["init_spread"], float)
    edge = EDGES * PLACEMENT_EDGE
    along = placement_sign(conf) * np.arange(-edge, field.length / 2 + edge + STEP / 2, STEP)
    inset = np.arange(-edge, SPAN * spread[0] + STEP / 2, STEP)
    turn = np.arange(-SPAN * spread[2], SPAN * spread[2] + TURN / 2, TURN)
    x, i, t = (g.ravel() for g in np.meshgrid(along, inset, turn, indexing="ij"))
    grid = []
    for side in (1.0, -1.0):
        p = field.touchline_pose(x, side, inset=i)
        p[:, 2] = wrap_angle(p[:, 2] + t)
        grid.append(p)
    grid = np.concatenate([*grid, np.reshape(first, (1, 3))])
    return grid, placement_log_density(grid, field, conf).astype(float)


def uniform_start(bounds: tuple, conf: dict, first) -> tuple[np.ndarray, np.ndarray]:
    """A uniform start's grid poses (N, 3) over the world ``bounds`` (x0, x1, y0, y1) every
    UNIFORM_STEP and UNIFORM_TURN, and the pose ``first`` (the truth's first pose) and its
    mirror image (so that the grid stays point-symmetric, as the world is), with their prior
    log densities: alike, or with ``start_half`` the other half's at ``start_half_error`` (as
    mcl_start.uniform_poses draws them)."""
    x0, x1, y0, y1 = bounds
    xs = np.arange(x0 + UNIFORM_STEP / 2, x1, UNIFORM_STEP)
    ys = np.arange(y0 + UNIFORM_STEP / 2, y1, UNIFORM_STEP)
    ts = np.arange(-math.pi, math.pi, UNIFORM_TURN)
    grid = np.stack([g.ravel() for g in np.meshgrid(xs, ys, ts, indexing="ij")], axis=1)
    x, y, heading = (float(v) for v in first)
    grid = np.concatenate([grid, [[x, y, heading], [-x, -y, wrap_angle(heading + math.pi)]]])
    prior = np.zeros(len(grid))
    if conf["start_half"] in ("own", "opponent"):
        sign = -1.0 if conf["start_half"] == "own" else 1.0
        prior[sign * grid[:, 0] < 0] = math.log(float(conf["start_half_error"]))
    return grid, prior


def _carried(first: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """The poses ``first`` (N, 3) moved by ``motion`` (dx, dy, dtheta) in each pose's frame."""
    c, s = np.cos(first[:, 2]), np.sin(first[:, 2])
    return np.stack([first[:, 0] + c * motion[0] - s * motion[1],
                     first[:, 1] + s * motion[0] + c * motion[1],
                     wrap_angle(first[:, 2] + motion[2])], axis=1)


def _in_cluster(p: np.ndarray, centre) -> np.ndarray:
    """Whether each pose of ``p`` (N, 3) lies in mcl's cluster around ``centre``."""
    x, y, heading = centre
    return ((np.hypot(p[:, 0] - x, p[:, 1] - y) <= CLUSTER_RADIUS)
            & (np.abs(wrap_angle(p[:, 2] - heading)) <= CLUSTER_HEADING))


def decidable_mass(model, frames, truth: np.ndarray, start: tuple[np.ndarray, np.ndarray], *,
                   up_to_mirror: bool = False) -> np.ndarray:
    """Per frame, the posterior mass within mcl's cluster (CLUSTER_RADIUS, CLUSTER_HEADING)
    of ``truth`` (N, 3) (of the truth or its mirror image with ``up_to_mirror``) of the walk's
    first pose given frames 0..t: the grid
    poses and prior log densities ``start`` (``placement_start`` or ``uniform_start``), each
    carried by the truth's relative motion,
    weighted by ``model`` (an ObservationModel) on ``frames`` (one Observations or
    PreparedObservations per truth pose)."""
    truth = np.asarray(truth, float)
    if len(frames) != len(truth):
        raise ValueError(f"{len(frames)} frames for {len(truth)} truth poses")
    grid, log_post = start
    mass = np.zeros(len(truth))
    for t, obs in enumerate(frames):
        p = _carried(grid, between(truth[0], truth[t]))
        log_post = log_post + model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], obs)
        near = _in_cluster(p, truth[t])
        if up_to_mirror:
            x, y, heading = truth[t]
            near |= _in_cluster(p, (-x, -y, heading + math.pi))
        mass[t] = math.exp(logsumexp(log_post[near]) - logsumexp(log_post))
        keep = log_post >= log_post.max() - PRUNE
        grid, log_post = grid[keep], log_post[keep]
    return mass
