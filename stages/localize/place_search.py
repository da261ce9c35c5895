"""The places where one frame's observations fit best, by brute force over the field with mcl's
observation model (stages.localize.observation_model): the log-likelihood on a grid of poses,
the best grid poses that are other places (farther apart than ``PLACE_M`` or ``PLACE_DEG``,
a pose's mirror image under the field's 180 deg symmetry counted with it), each refined on two
finer local grids (to 1 cm x 0.25 deg after a 0.1 m x 3 deg grid).

Two readers: ``fieldloc bench --only mcl-hulks`` decides with it what each still frame says
(stages.pipelines.bench.mcl_hulks.decided: 0.1 m x 3 deg over the field), and mcl's uniform
start places its first particles at the places a coarser grid finds (mcl.ParticleFilter:
0.2 m x 6 deg over the world, each grid pose scored as a pose anywhere in its cell,
``cell_model``).
"""

from __future__ import annotations

import math

import numpy as np

from stages.common.geometry import wrap_scalar

from ..common.jit import njit

PLACE_M, PLACE_DEG = 1.0, 30.0  # poses farther apart than this are other places
# the local grids of ``refine``: half width (m), step (m), half turn (deg), turn step (deg)
REFINE = ((0.1, 0.02, 3.0, 0.5), (0.02, 0.005, 0.5, 0.125))


def grid_poses(bounds, step: float, turn_deg: float) -> np.ndarray:
    """Poses (G, 3) on a grid over ``bounds`` (x0, x1, y0, y1), ``step`` m apart, headings
    ``turn_deg`` apart from -180 deg."""
    x0, x1, y0, y1 = bounds
    xs, ys = np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step)
    ths = np.radians(np.arange(-180.0, 180.0, turn_deg))
    X, Y, T = np.meshgrid(xs, ys, ths, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), T.ravel()], axis=1)


def same_place(a, b, mirror: bool = True) -> bool:
    """Whether poses ``a`` and ``b`` (or ``b``'s mirror image) are one place: within
    ``PLACE_M`` and ``PLACE_DEG``."""
    return bool(_same(float(a[0]), float(a[1]), float(a[2]), np.asarray(b, float), mirror,
                      PLACE_M, math.radians(PLACE_DEG)))


def separate(poses: np.ndarray, ll: np.ndarray, count: int, mirror: bool = True,
             limit: int | None = None) -> np.ndarray:
    """Indices of the best ``count`` poses that are other places (``same_place``), best first:
    each the best pose not within a place of those before it (among the ``limit`` best poses
    when given)."""
    order = np.argsort(-np.asarray(ll, float), kind="stable")
    if limit is not None:
        order = order[:limit]
    return _separate(np.ascontiguousarray(poses, dtype=float), order, int(count), bool(mirror),
                     PLACE_M, math.radians(PLACE_DEG))


def within_places(poses: np.ndarray, places: np.ndarray, mirror: bool = True) -> np.ndarray:
    """Whether each of ``poses`` (G, 3) is one place (``same_place``) with one of ``places``
    (M, 3)."""
    return _within(np.ascontiguousarray(poses, dtype=float),
                   np.ascontiguousarray(places, dtype=float).reshape(-1, 3), bool(mirror),
                   PLACE_M, math.radians(PLACE_DEG))


@njit(cache=True, nogil=True, inline="always")
def _same(x, y, th, q, mirror, place_m, place_turn):
    """``same_place`` of the pose (x, y, th) and ``q``."""
    for side in range(2 if mirror else 1):
        qx, qy, qt = (q[0], q[1], q[2]) if side == 0 else (
            -q[0], -q[1], (q[2] + math.pi + math.pi) % (2.0 * math.pi) - math.pi)  # mirror_pose
        if abs(x - qx) > place_m or abs(y - qy) > place_m:  # (the cheap test first)
            continue
        turn = abs((th - qt + math.pi) % (2.0 * math.pi) - math.pi)
        if math.hypot(x - qx, y - qy) <= place_m and turn <= place_turn:
            return True
    return False


@njit(cache=True, nogil=True)
def _separate(poses, order, count, mirror, place_m, place_turn):
    """``separate``'s greedy pass over the poses in ``order`` (best first)."""
    out = np.empty(count, np.int64)
    n = 0
    for i in order:
        if n == count:
            break
        taken = False
        for j in range(n):
            if _same(poses[i, 0], poses[i, 1], poses[i, 2], poses[out[j]], mirror, place_m,
                     place_turn):
                taken = True
                break
        if not taken:
            out[n] = i
            n += 1
    return out[:n]


@njit(cache=True, nogil=True)
def _within(poses, places, mirror, place_m, place_turn):
    out = np.zeros(len(poses), np.bool_)
    for i in range(len(poses)):
        for j in range(len(places)):
            if _same(poses[i, 0], poses[i, 1], poses[i, 2], places[j], mirror, place_m,
                     place_turn):
                out[i] = True
                break
    return out


def refine(model, prep, pose, stages=REFINE) -> tuple[np.ndarray, float]:
    """``pose`` moved to the best pose of local grids around it (``stages``: half width, step,
    half turn and turn step, each grid around the best so far), and its log-likelihood."""
    best, val = np.asarray(pose, float), -math.inf
    for half, step, turn, dstep in stages:
        d = np.arange(-half, half + 1e-9, step)
        a = np.radians(np.arange(-turn, turn + 1e-9, dstep))
        DX, DY, DA = np.meshgrid(d, d, a, indexing="ij")
        v = model.log_likelihood(best[0] + DX.ravel(), best[1] + DY.ravel(),
                                 best[2] + DA.ravel(), prep)
        k = int(np.argmax(v))
        if v[k] > val:
            val = float(v[k])
            best = np.array([best[0] + DX.ravel()[k], best[1] + DY.ravel()[k],
                             best[2] + DA.ravel()[k]])
    return best, val


def cell_model(model, step: float, turn_deg: float):
    """``model`` for poses anywhere within a grid cell of ``step`` and ``turn_deg`` around a
    grid pose: each sigma of a distance widened in quadrature by half the step, each sigma of
    an angle by half the turn (a coarse grid at the frame's sharp peaks would otherwise miss
    a place whose peak falls between its poses)."""
    t = model.tuning
    half, turn = 0.5 * step, 0.5 * math.radians(turn_deg)
    wide = {key: math.hypot(float(getattr(t, key)), add) for key, add in (
        ("sigma_range", half), ("sigma_line", half), ("sigma_extent", half),
        ("sigma_bearing", turn), ("sigma_line_angle", turn),
        ("sigma_crossing_orientation", turn))}
    return model.with_conf(model.conf, t._replace(**wide))


def best_places(model, prep, bounds, step: float, turn_deg: float, count: int,
                mirror: bool = True, limit: int | None = None, stages=REFINE,
                cells: bool = False) -> list[tuple[np.ndarray, float]]:
    """The ``count`` best places of the prepared observations ``prep`` (a PreparedObservations
    of ``model``) on the grid over ``bounds`` (``grid_poses``; ``separate``, with ``limit``),
    each refined (``refine``), as (pose, log-likelihood), best first. ``cells``: the grid
    poses are scored by ``cell_model`` (a pose anywhere in its cell), the refinement by
    ``model``."""
    return search(model, prep, bounds, step, turn_deg, count, mirror, limit, stages, cells)[0]


def search(model, prep, bounds, step: float, turn_deg: float, count: int,
           mirror: bool = True, limit: int | None = None, stages=REFINE,
           cells: bool = False) -> tuple[list[tuple[np.ndarray, float]], float]:
    """``best_places`` and the share of the grid's likelihood (its sum over the grid poses)
    that lies outside the places found: the frame's posterior share of "elsewhere" (a uniform
    prior over the grid)."""
    poses = grid_poses(bounds, step, turn_deg)
    grid_model = cell_model(model, step, turn_deg) if cells else model
    grid_prep = grid_model.prepare(prep.obs, usable=True) if cells else prep
    ll = grid_model.log_likelihood(poses[:, 0], poses[:, 1], poses[:, 2], grid_prep)
    chosen = separate(poses, ll, count, mirror, limit)
    found = sorted((refine(model, prep, poses[i], stages) for i in chosen),
                   key=lambda e: -e[1])
    w = np.exp(ll - ll.max())
    some = np.flatnonzero(w > 1e-9)  # the poses that count in the sum (the rest < 1e-4 of it)
    inside = within_places(poses[some], poses[chosen], mirror)
    elsewhere = float(w[some[~inside]].sum() / w[some].sum())
    return found, elsewhere


def local_posterior(model, prep, pose, stage=REFINE[0]) -> tuple[np.ndarray, np.ndarray]:
    """The mean and covariance (3, 3) of the frame's posterior (a uniform prior) on a local
    grid around ``pose`` (``stage``: half width, step, half turn and turn step, as ``refine``'s),
    with the grid's quantisation (a cell's variance, step^2 / 12) added: where the particles of
    a place go."""
    half, step, turn, dstep = stage
    d = np.arange(-half, half + 1e-9, step)
    a = np.radians(np.arange(-turn, turn + 1e-9, dstep))
    D = np.stack([v.ravel() for v in np.meshgrid(d, d, a, indexing="ij")], axis=1)
    ll = model.log_likelihood(pose[0] + D[:, 0], pose[1] + D[:, 1], pose[2] + D[:, 2], prep)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    mean = w @ D
    dev = D - mean
    cov = (dev * w[:, None]).T @ dev
    cov += np.diag([step * step / 12.0, step * step / 12.0, math.radians(dstep) ** 2 / 12.0])
    out = np.asarray(pose, float) + mean
    out[2] = wrap_scalar(out[2])
    return out, cov
