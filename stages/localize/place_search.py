"""The places where one frame's observations fit best, by brute force over the field with mcl's
observation model (stages.localize.observation_model): the log-likelihood on a grid of poses,
the best grid poses that are other places (farther apart than ``PLACE_M`` or ``PLACE_DEG``,
a pose's mirror image under the field's 180 deg symmetry counted with it), each refined on two
finer local grids (to 1 cm x 0.25 deg after a 0.1 m x 3 deg grid).

``fieldloc bench --only mcl-hulks`` decides with it what each still frame says
(stages.pipelines.bench_mcl_hulks.decided: 0.1 m x 3 deg over the field).
"""

from __future__ import annotations

import math

import numpy as np

from stages.common.geometry import wrap_angle, wrap_scalar

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


def mirror_poses(p: np.ndarray) -> np.ndarray:
    """FieldModel.mirror_pose of poses (..., 3)."""
    p = np.asarray(p, float)
    return np.stack([-p[..., 0], -p[..., 1], wrap_angle(p[..., 2] + math.pi)], axis=-1)


def same_place(a, b, mirror: bool = True) -> bool:
    """Whether poses ``a`` and ``b`` (or ``b``'s mirror image) are one place."""
    for q in ((b, mirror_poses(b)) if mirror else (b,)):
        turn = abs(wrap_scalar(a[2] - q[2]))
        if math.hypot(a[0] - q[0], a[1] - q[1]) <= PLACE_M and turn <= math.radians(PLACE_DEG):
            return True
    return False


def separate(poses: np.ndarray, ll: np.ndarray, count: int, mirror: bool = True,
             limit: int | None = None) -> np.ndarray:
    """Indices of the best ``count`` poses that are other places (``same_place``), best first:
    each the best pose not within a place of those before it (among the ``limit`` best poses
    when given)."""
    score = np.asarray(ll, float).copy()
    if limit is not None and limit < len(score):
        score[np.argsort(-score, kind="stable")[limit:]] = -np.inf
    x, y, th = poses[:, 0], poses[:, 1], poses[:, 2]
    out = []
    while len(out) < count:
        i = int(np.argmax(score))
        if not np.isfinite(score[i]):
            break
        out.append(i)
        for q in ((poses[i], mirror_poses(poses[i])) if mirror else (poses[i],)):
            near = np.hypot(x - q[0], y - q[1]) <= PLACE_M
            near &= np.abs(wrap_angle(th - q[2])) <= math.radians(PLACE_DEG)
            score[near] = -np.inf
    return np.array(out, np.int64)


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


def best_places(model, prep, bounds, step: float, turn_deg: float, count: int,
                mirror: bool = True, limit: int | None = None,
                stages=REFINE) -> list[tuple[np.ndarray, float]]:
    """The ``count`` best places of the prepared observations ``prep`` (a PreparedObservations
    of ``model``) on the grid over ``bounds`` (``grid_poses``; ``separate``, with ``limit``),
    each refined (``refine``), as (pose, log-likelihood), best first."""
    poses = grid_poses(bounds, step, turn_deg)
    ll = model.log_likelihood(poses[:, 0], poses[:, 1], poses[:, 2], prep)
    found = [refine(model, prep, poses[i], stages)
             for i in separate(poses, ll, count, mirror, limit)]
    return sorted(found, key=lambda e: -e[1])

