"""The matching and pose of the SURF template paper (section II-B), between a query's ground
features and one template's: FLANN matching with a ratio test and equal Laplacian sign, the pose of
equation 4 by the paper's coordinate descent or in closed form, outlier removal against the spread
of the pair distances, and the likelihood of the pairs (the template method's confidence rests on
it).

Pose. A template and a query each hold keypoints in their robot frame (metres). The pose sought
is A(dx, dy, dtheta) of the SURF template paper's eq. 3, which carries a query point q into the
template's frame: t ~ R(dtheta) q + (dx, dy); it is the query robot's pose in the template robot's
frame, so the query's field pose is the template's pose composed with it. Equation 4:

    E(dx, dy, dtheta) = sum_i || t_i - A(dx, dy, dtheta) q_i ||^2

``descent`` is the paper's search "similar to Gibbs sampling": from (0, 0, 0), the best dtheta
with (dx, dy) fixed, then the best dy, then the best dx, until none changes (by more than
``tol``); each step is exact: dtheta = atan2(sum q x (t - d), sum q . (t - d)), dy and dx the
mean residual along their axis. ``closed_form`` is the least-squares rigid fit of Kabsch (1976)
and Umeyama (1991) in 2D (no scale): the same minimum in one step, from the pairs' centroids
and their cross-covariance. Both minimise the same convex-in-translation,
single-minimum-in-angle E, so they agree (a test holds them to it); the descent needs more
steps the farther the pairs lie from the robot (the angle and the translation are coupled
through the centroid).

Outliers (the paper: "variance of distance of matching pairs is calculated and eliminate wrong
matching pairs based on the variance"): after a fit the pair distances r_i = ||t_i - A q_i||
are compared with their spread, robustly: a pair is removed when r_i exceeds
median(r) + ``outlier_sigmas`` x 1.4826 MAD(r) (the MAD scaled to a standard deviation, so that
one wrong match cannot inflate the spread it is judged by as it would inflate the variance),
and never when r_i <= ``min_outlier_m`` (pairs this close fit within the features' own
precision); the pose is estimated again from the rest, and this is repeated ``outlier_passes``
times or until no pair is removed (the paper does one pass).

Consensus (``consensus_fit``, what localize's template method uses). On the weakly textured
floor the correct matches are often fewer than half of the pairs, and a fit from all pairs,
judged by the spread of its own pair distances, then settles between the wrong ones. With both
point sets turned to the field's axes (the rotation between them only the heading's error),
correct pairs agree on one translation t - q and wrong ones scatter: the pairs within
``radius`` of the densest translation are fitted as above (descent or closed form, the outlier
rule), every pair within the final outlier limit is taken back, and the pose estimated once
more.

Matching. A template's own descriptors (about a hundred) are compared with all the query's
exactly (one matrix product, faster than FLANN's trees at that size, ``BRUTE_FORCE_ROWS``); the
whole database's, for the vote when lost, are searched by FLANN (kd-trees; LSH for ORB).

Likelihood (what the confidence rests on; stages.localize.templates). A query keypoint matched
to a template either is the same floor point (its pair distance after the fit is Gaussian with
sigma ``pair_sigma_m`` per axis) or a wrong match, which lands anywhere on the ground image
(uniform over its area A): with prior ``inlier_prior`` for the first,

    log-likelihood ratio of a pair  l_i = log(1 + p / (1 - p) * A * N2(r_i; sigma))

against "no pair means anything" (all uniform), and the evidence of a pose is L = sum_i l_i
over its pairs, in nats. ``evidence`` computes it; a pose the matches do not support has L
near 0, one supported by n pairs within sigma about n (log(A / (2 pi sigma^2)) - 1/2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..common.errors import FieldlocError
from ..common.jit import njit

SOLVERS = ("descent", "closed-form")
# L2 groups up to this many descriptors are searched exhaustively (one matrix product) rather
# than by FLANN's trees: exact, and faster at a template's size (~100 features)
BRUTE_FORCE_ROWS = 1000


# ---------------------------------------------------------------------------- matching


class FeatureIndex:
    """A FLANN index over a set of descriptors (a template's, or a whole database's), one per
    sign of the Laplacian so that a query feature is only ever matched to features of its own
    sign (SIFT and ORB carry sign 0: one group). ``metric`` 'l2' (kd-trees) or 'hamming'
    (LSH, ORB's bytes). FLANN's randomised trees and hash tables draw from OpenCV's random
    generator (cv::theRNG of the thread): it is seeded with ``seed`` before each build, so an
    index, and the matches it gives, do not depend on what the process drew before."""

    def __init__(self, descriptors: np.ndarray, laplacian: np.ndarray, metric: str = "l2",
                 *, trees: int = 4, checks: int = 32, seed: int = 0):
        self.metric = metric
        self.checks = int(checks)
        lap = np.asarray(laplacian).astype(np.int8)
        desc = np.ascontiguousarray(descriptors)
        self.size = len(desc)
        self.groups: dict[int, tuple[np.ndarray, object, np.ndarray]] = {}
        for sign in np.unique(lap):
            rows = np.flatnonzero(lap == sign)
            d = np.ascontiguousarray(desc[rows])
            if metric == "hamming":
                params = dict(algorithm=6, table_number=6, key_size=12, multi_probe_level=1)
                d = d.astype(np.uint8)
            else:
                params = dict(algorithm=1, trees=int(trees))
                d = d.astype(np.float32)
            # FLANN needs 2 rows to build an index; a single feature, and a group small enough
            # that comparing with all of it is cheaper than the tree (one template's, for L2),
            # is compared directly (exactly)
            direct = len(d) < 2 or (metric != "hamming" and len(d) <= BRUTE_FORCE_ROWS)
            if not direct:
                cv2.setRNGSeed(int(seed))
            self.groups[int(sign)] = (rows, None if direct else cv2.flann_Index(d, params), d)

    def knn(self, descriptors: np.ndarray, laplacian: np.ndarray, k: int = 2):
        """(indices (N, k) into the indexed set, -1 where there are fewer, distances (N, k)):
        the k nearest of the same Laplacian sign (sign 0 in the index matches any)."""
        n = len(descriptors)
        idx = np.full((n, k), -1, np.int64)
        dist = np.full((n, k), np.inf)
        if not n or not self.groups:
            return idx, dist
        lap = np.asarray(laplacian).astype(np.int8)
        for sign, (rows, flann, d) in self.groups.items():
            sel = np.flatnonzero(lap == sign) if sign != 0 else np.arange(n)
            if not len(sel):
                continue
            q = np.ascontiguousarray(descriptors[sel]).astype(d.dtype)
            kk = min(k, len(rows))
            if flann is None:
                dd = _distances(q, d)
                j = np.argpartition(dd, kk - 1, axis=1)[:, :kk] if kk < dd.shape[1] else \
                    np.tile(np.arange(dd.shape[1]), (len(dd), 1))
                j = np.take_along_axis(j, np.argsort(np.take_along_axis(dd, j, axis=1),
                                                     axis=1), axis=1)
                dj = np.take_along_axis(dd, j, axis=1)
            else:
                j, dj = flann.knnSearch(q, kk, params=dict(checks=self.checks))
                j = j.astype(np.int64)
                dj = np.asarray(dj, float)
                if self.metric == "l2":
                    dj = np.sqrt(np.maximum(dj, 0.0))  # FLANN's L2 is squared
            bad = (j < 0) | (j >= len(rows))
            j = np.where(bad, 0, j)
            got = np.where(bad, -1, rows[j])
            # a sign-0 group is one of several only for a mixed index; keep the nearest
            if sign == 0 and len(self.groups) > 1:
                got, dj = _merge_nearest(idx[sel], dist[sel], got, np.where(bad, np.inf, dj), k)
                idx[sel], dist[sel] = got, dj
            else:
                idx[sel, :kk] = got
                dist[sel, :kk] = np.where(bad, np.inf, dj)
        return idx, dist


def _distances(q: np.ndarray, d: np.ndarray) -> np.ndarray:
    if q.dtype == np.uint8:
        x = np.unpackbits(q[:, None, :] ^ d[None, :, :], axis=-1)
        return x.sum(-1).astype(float)
    q = q.astype(np.float32)
    d2 = (q * q).sum(1)[:, None] + (d * d).sum(1)[None, :] - 2.0 * (q @ d.T)
    return np.sqrt(np.maximum(d2, 0.0)).astype(float)


def _merge_nearest(ia, da, ib, db, k):
    i = np.concatenate([ia, ib], axis=1)
    d = np.concatenate([da, db], axis=1)
    o = np.argsort(d, axis=1, kind="stable")[:, :k]
    return np.take_along_axis(i, o, axis=1), np.take_along_axis(d, o, axis=1)


def ratio_matches(idx: np.ndarray, dist: np.ndarray, ratio: float):
    """(query rows, matched rows, distances) of the nearest neighbours that pass Lowe's ratio
    test (nearest < ``ratio`` x second nearest; a feature with one candidate passes)."""
    ok = idx[:, 0] >= 0
    if idx.shape[1] > 1:
        ok &= ~(dist[:, 0] >= ratio * dist[:, 1])
    rows = np.flatnonzero(ok)
    return rows, idx[rows, 0], dist[rows, 0]


def match(query, index: FeatureIndex, ratio: float):
    """(query rows, template rows, descriptor distances) of ``query`` (GroundFeatures) matched
    into ``index`` (one template's): nearest of equal Laplacian sign, ratio test, and each
    template feature used once (the nearest query feature keeps it)."""
    idx, dist = index.knn(query.descriptors, query.laplacian, 2)
    qi, ti, d = ratio_matches(idx, dist, ratio)
    if len(ti) > 1:  # one-to-one: the nearest query feature keeps a template feature
        o = np.lexsort((d, ti))
        first = np.ones(len(o), bool)
        first[1:] = ti[o][1:] != ti[o][:-1]
        keep = np.sort(o[first])
        qi, ti, d = qi[keep], ti[keep], d[keep]
    return qi, ti, d


# ---------------------------------------------------------------------------- pose


def transform(pose, q: np.ndarray) -> np.ndarray:
    """A(dx, dy, dtheta) q for points q (N, 2)."""
    dx, dy, th = (float(v) for v in pose)
    c, s = math.cos(th), math.sin(th)
    q = np.asarray(q, float)
    return np.stack([c * q[:, 0] - s * q[:, 1] + dx, s * q[:, 0] + c * q[:, 1] + dy], axis=1)


def matching_error(pose, t: np.ndarray, q: np.ndarray) -> float:
    """The SURF template paper's eq. 4: sum of squared pair distances (m^2)."""
    r = np.asarray(t, float) - transform(pose, q)
    return float(np.sum(r * r))


def descent(t: np.ndarray, q: np.ndarray, start=(0.0, 0.0, 0.0), *, tol: float = 1e-9,
            max_steps: int = 10000) -> tuple[np.ndarray, int]:
    """(pose (dx, dy, dtheta), rounds) minimising eq. 4 by the paper's coordinate descent (module
    doc), from ``start``, until no coordinate changes by more than ``tol`` (m, rad) in a round.
    The sums it needs are computed once: each step is O(1) (compiled, ``_descent_rounds``)."""
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    n = len(t)
    if n == 0:
        return np.asarray(start, float).copy(), 0
    sq = q.sum(0)
    st = t.sum(0)
    # sums of q.t and q x t (for the angle step: sum q.(t - d) = a - d.sq, q x (t - d) = b - ...)
    a = float(np.sum(q[:, 0] * t[:, 0] + q[:, 1] * t[:, 1]))
    b = float(np.sum(q[:, 0] * t[:, 1] - q[:, 1] * t[:, 0]))
    dx, dy, th = (float(v) for v in start)
    dx, dy, th, k = _descent_rounds((float(sq[0]), float(sq[1]), float(st[0]), float(st[1]), a,
                                     b, float(n)), (dx, dy, th), float(tol), int(max_steps))
    return np.array([dx, dy, th]), int(k)


@njit(cache=True)
def _descent_rounds(sums, start, tol, max_steps):
    """The rounds of ``descent`` on the pairs' sums (compiled: a fit takes 100-200 rounds when
    the pairs lie metres from the robot). ``sums``: (sum q_x, sum q_y, sum t_x, sum t_y,
    sum q.t, sum q x t, n); ``start``: (dx, dy, dtheta)."""
    sq0, sq1, st0, st1, a, b, n = sums
    dx, dy, th = start
    for k in range(1, max_steps + 1):
        # best dtheta with (dx, dy) fixed
        dot = a - (dx * sq0 + dy * sq1)
        cross = b - (sq0 * dy - sq1 * dx)
        th_new = math.atan2(cross, dot) if (dot != 0.0 or cross != 0.0) else th
        c, s = math.cos(th_new), math.sin(th_new)
        # best dy with (dx, dtheta) fixed, then best dx with (dy, dtheta) fixed
        dy_new = (st1 - (s * sq0 + c * sq1)) / n
        dx_new = (st0 - (c * sq0 - s * sq1)) / n
        dth = (th_new - th + math.pi) % (2 * math.pi) - math.pi
        change = max(abs(dth), abs(dy_new - dy), abs(dx_new - dx))
        dx, dy, th = dx_new, dy_new, th_new
        if change <= tol:
            return dx, dy, th, k
    return dx, dy, th, max_steps


def closed_form(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The least-squares rigid fit (2D Kabsch/Umeyama without scale) of eq. 4: (dx, dy,
    dtheta)."""
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    if len(t) == 0:
        return np.zeros(3)
    mt, mq = t.mean(0), q.mean(0)
    qc, tc = q - mq, t - mt
    sxx = float(np.sum(qc[:, 0] * tc[:, 0] + qc[:, 1] * tc[:, 1]))
    sxy = float(np.sum(qc[:, 0] * tc[:, 1] - qc[:, 1] * tc[:, 0]))
    th = math.atan2(sxy, sxx) if (sxx or sxy) else 0.0
    c, s = math.cos(th), math.sin(th)
    d = mt - np.array([c * mq[0] - s * mq[1], s * mq[0] + c * mq[1]])
    return np.array([d[0], d[1], th])


def solve(t, q, solver: str, *, tol: float = 1e-9) -> tuple[np.ndarray, int]:
    """(pose, descent rounds or 1) of eq. 4 by ``solver`` ('descent' or 'closed-form')."""
    if solver == "descent":
        return descent(t, q, tol=tol)
    if solver == "closed-form":
        return closed_form(t, q), 1
    raise FieldlocError(f"unknown pose_solver '{solver}' (known: {', '.join(SOLVERS)})")


@dataclass
class Fit:
    """A pose fitted to the pairs of one template, with its inliers."""

    pose: np.ndarray  # (dx, dy, dtheta): the query in the template's robot frame
    inliers: np.ndarray  # (M,) bool over the pairs given
    residuals: np.ndarray  # (M,) m, pair distances at ``pose``
    rounds: int  # descent rounds summed over the fits (1 per fit for the closed form)
    removed: int  # pairs removed as outliers


def robust_fit(t, q, *, solver: str = "descent", outlier_sigmas: float = 3.0,
               min_outlier_m: float = 0.05, outlier_passes: int = 3, min_pairs: int = 2,
               tol: float = 1e-9) -> Fit | None:
    """Eq. 4 fitted, outliers removed against the spread of the pair distances, fitted again
    (module doc); None with fewer than ``min_pairs`` pairs (left)."""
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    keep = np.ones(len(t), bool)
    if len(t) < min_pairs:
        return None
    pose, rounds = solve(t, q, solver, tol=tol)
    removed = 0
    for _ in range(int(outlier_passes)):
        r = np.hypot(*(t - transform(pose, q)).T)
        rk = r[keep]
        med = float(np.median(rk))
        spread = 1.4826 * float(np.median(np.abs(rk - med)))
        limit = max(med + outlier_sigmas * spread, min_outlier_m)
        new = keep & (r <= limit)
        if new.sum() == keep.sum():
            break
        if new.sum() < min_pairs:
            return None
        removed += int(keep.sum() - new.sum())
        keep = new
        pose, k = solve(t[keep], q[keep], solver, tol=tol)
        rounds += k
    r = np.hypot(*(t - transform(pose, q)).T)
    return Fit(pose=pose, inliers=keep, residuals=r, rounds=rounds, removed=removed)


def consensus(t: np.ndarray, q: np.ndarray, radius: float) -> np.ndarray:
    """(M,) bool: the pairs that agree on the translation t - q with the most others (within
    ``radius`` m of it). For pairs whose frames share their axes (the query and the template
    turned to the field's axes by their headings, so that the rotation between them is only
    the heading's error), the correct pairs agree on one translation, wrong ones scatter: the
    densest translation, counted pair by pair, is the correct pairs' even when they are a
    minority, where the median of the pair distances after a fit from all pairs is not."""
    u = np.asarray(t, float) - np.asarray(q, float)
    if len(u) == 0:
        return np.zeros(0, bool)
    d2 = ((u[:, None, :] - u[None, :, :]) ** 2).sum(-1)
    near = d2 <= radius * radius
    best = int(np.argmax(near.sum(1)))
    centre = u[near[best]].mean(0)
    return ((u - centre) ** 2).sum(1) <= radius * radius


def consensus_fit(t, q, *, radius: float, solver: str = "descent", outlier_sigmas: float = 3.0,
                  min_outlier_m: float = 0.05, outlier_passes: int = 3, min_pairs: int = 2,
                  tol: float = 1e-9) -> Fit | None:
    """``robust_fit`` on the pairs of the densest translation (``consensus``), then every pair
    within the final fit's outlier limit taken back in and the pose estimated once more; None
    with fewer than ``min_pairs`` pairs in the consensus."""
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    sel = consensus(t, q, radius)
    if sel.sum() < min_pairs:
        return None
    rows = np.flatnonzero(sel)
    f = robust_fit(t[rows], q[rows], solver=solver, outlier_sigmas=outlier_sigmas,
                   min_outlier_m=min_outlier_m, outlier_passes=outlier_passes,
                   min_pairs=min_pairs, tol=tol)
    if f is None:
        return None
    r = np.hypot(*(t - transform(f.pose, q)).T)
    ri = r[rows[f.inliers]]
    med = float(np.median(ri))
    limit = max(med + outlier_sigmas * 1.4826 * float(np.median(np.abs(ri - med))),
                min_outlier_m)
    keep = r <= limit
    pose, k = solve(t[keep], q[keep], solver, tol=tol)
    r = np.hypot(*(t - transform(pose, q)).T)
    return Fit(pose=pose, inliers=keep, residuals=r, rounds=f.rounds + k,
               removed=int(len(t) - keep.sum()))


# ---------------------------------------------------------------------------- likelihood


def pair_evidence(residuals: np.ndarray, sigma: float, area: float,
                  inlier_prior: float) -> np.ndarray:
    """Log-likelihood ratio (nats) of each pair distance against a wrong match (module doc)."""
    r = np.asarray(residuals, float)
    gauss = np.exp(-0.5 * (r / sigma) ** 2) / (2 * math.pi * sigma * sigma)
    odds = inlier_prior / (1.0 - inlier_prior)
    return np.log1p(odds * area * gauss)


def evidence(residuals: np.ndarray, sigma: float, area: float, inlier_prior: float) -> float:
    """The evidence (nats) of a pose from its pairs' distances: the sum of pair_evidence."""
    return float(pair_evidence(residuals, sigma, area, inlier_prior).sum())

