"""Method ``fit``: line points fitted to the map's distance table (Lauer, Lange and
Riedmiller 2006, the Tribots method most MSL teams run).

The error of a pose (x, y, theta) of a frame's robot-frame line points p_i (within
``MAX_RANGE_M``, weights w_i, 1 unless ``RANGE_SCALE_M`` is set) is

    E = sum_i w_i rho(d(q_i)),   q_i = (x, y) + R(theta) p_i,
    rho(d) = 1 - c^2 / (c^2 + d^2) = d^2 / (c^2 + d^2),   c = 0.25 m (``C_M``, Lauer et al.'s),

d the distance to the nearest line, read from the map's ``/tables/distance`` and
``/tables/distance_gradient`` (exact on straight lines between the 10 cm nodes;
fit_kernels.py). E is minimised by RPROP (Riedmiller's resilient propagation, as in the
paper: first steps 4 cm and 0.05 rad, at most ``RPROP.iterations`` = 20 gradient evaluations)
over x, y and the heading, with the measured heading (IMU, histogram or truth) as a Gaussian
prior on theta. Tracking: each track of the belief (tracking.TrackBank, as lut's) is fitted
from its prior (last pose moved by odometry), its fix weighed with the Gauss-Newton covariance
of E (tempered: ``TEMPERATURE`` points per nat, a tracked frame's evidence divided by
``TRACK_CORRELATION``, and the points of one white structure worth at most
``EVIDENCE.per_structure`` = 6 independent points, as lut's observations) and fused by the
bank's Kalman filter. With ``TRACKED_PRIOR`` the fit minimises E / T plus the prior's
Mahalanobis^2 / 2 (the posterior's mode m, so a frame of few or stray points cannot pull the
track into another basin), and the filter gets the measurement z the points alone make,
z = m + R info (m - prior), so the prior is not counted twice.

Global mode (no track, lost, or every ``GLOBAL_EVERY`` frames as a check): a multi-start search
from a grid of starts, not random restarts (reproducible): positions every ``GLOBAL.step`` =
0.25 m over the field and ``GLOBAL.margin`` = 0.5 m around it (77 x 53 = 4081 on msl-2015), at
the frame's heading when it is known (IMU, truth; the histogram's four peaks otherwise), else
every ``GLOBAL.heading_step`` = 10 deg (36 headings). Every start is ranked by E with a wider
c (``GLOBAL.c`` = 0.5 m, a blurred floor: wider basins) on 32 of the points; the 16 best
starts more than ``tracking.AMBIGUITY_DISTANCE_M`` apart are fitted by RPROP, and one fix per
basin is kept. A global search costs far more than a tracked fit (many times more again with an
unknown heading), hence tracking between them; docs/results.md has the times.

Null and confidence as lut's: the same points with their bearing sectors shuffled
(``NULL_SECTORS`` sectors of 5 deg, seeded) are fitted the same way (from the strongest track's
prior, or by the same global search); the bank's posterior over tracks, new fixes, the mirror
pose and the null gives ranked hypotheses and the top one's probability, the confidence
(poses schema of stages.common.poses_file). A frame with fewer than ``MIN_POINTS`` points, or
whose every fix explains no more than the null, is recorded as failed. The radial correction
(radial_correction.py) learns the calibration's range error from confident tracked frames, as
lut's.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..common.conf import check_bounds
from ..common.errors import FieldlocError, real_path
from ..common.field import FieldModel
from ..common.geometry import wrap_angle
from ..common.map_file import MapFile
from ..common.poses_file import PoseTrack
from . import bank_smoothing, radial_correction, tracking
from . import fit_kernels as K
from . import heading as heading_mod
from .lut_kernels import inlier_sums, structure_sizes
from .lut_matching import MatchingParams, Observation, RadialTable
from .lut_search import EVIDENCE
from .lut_tables import radial_table
from .radial_correction import DEFAULTS as RADIAL_DEFAULTS
from .radial_correction import PathCalibration, RadialCorrection
from .smooth import LOCAL_REACH_M, FrameCandidates
from .tracking import Candidate, FrameFailed, TrackBank, near_pose

log = logging.getLogger(__name__)

camera_kinds = ("omni",)  # the features it reads (line points of the scan lines, or --points)

confs = {
    # what a user chooses: the heading source, what is known of the start, the recording's
    # clock tolerance, the radial correction switch and the belief's keys (tracking.DEFAULTS);
    # the fit's tuned constants are named below (C_M, TEMPERATURE, RPROP, GLOBAL, ...)
    "default": {
        "heading": "imu",  # imu | histogram | truth: the heading prior of the fit
        "imu_alignment": "field",  # field: imu yaw is field-aligned (+ small bias) | vision
        "start_half": "any",  # own (x < 0) | opponent (x > 0) | any: where the first fix is
        "start_half_error": 1e-3,  # probability that start_half is wrong
        "stamp_tolerance": 0.02,  # s, imu/truth row to frame matching (the recording's clocks)
        "radial_correction": dict(RADIAL_DEFAULTS),
        # with smooth: learn the camera's calibration from the smoothed poses, extract the
        # frames again with it and smooth again (stages.pipelines.images_to_poses, two rounds)
        "recalibrate": True,
        **{k: (dict(v) if isinstance(v, dict) else v) for k, v in tracking.DEFAULTS.items()},
    },
}
confs["no-fusion"] = {**confs["default"], "fusion": {**confs["default"]["fusion"],
                                                       "enabled": False}}
confs["independent"] = {**confs["default"], "independent": True}

NULL_SECTORS = 72  # bearing sectors of the null copies (the scan lines' 5 deg)


# The fit's tuned constants (module doc; the values the default preset held: Lauer et al.'s
# where marked, the rest chosen and calibrated on the rendered tuning sets, docs/results.md).
# The heading sources' are heading.py's, the belief's tracking.py's, the evidence weighting
# lut_search.EVIDENCE (as lut's observations).
MIN_POINTS = 4  # fewer line points: the frame fails (the null judges the rest)
MAX_RANGE_M = 4.0  # m, line points farther from the robot are not used
C_M = 0.25  # m, rho(d) = d^2 / (c^2 + d^2) (Lauer et al.: 250 mm)
# m: weight 1 / (1 + (r / RANGE_SCALE_M)^2), nearer points weigh more; None: every point
# weighs 1 (Lauer et al.'s default)
RANGE_SCALE_M = None
INLIER_ERROR_M = 0.125  # m, a point this close to a line is an inlier (rho = 0.2)
TEMPERATURE = 0.5  # evidence (full-weight points) per nat
TRACK_CORRELATION = 4.0  # a tracked frame's evidence counts 1 / TRACK_CORRELATION
REACH_M = 0.5  # m, how far from a prior the fit finds the robot (its basin)
# the tracked fit minimises E / T plus the track's position prior (its Mahalanobis^2 / 2): the
# posterior's mode; False: E alone from the prior
TRACKED_PRIOR = True
GLOBAL_EVERY = 5  # frames between global searches while tracking
NULL_COPIES = 1  # random-bearing copies of the points (median)
VISION_SIGMA_XY_M = 0.01  # m, floor of a fix's position sigma
VISION_INFLATION = 1.0  # the Laplace covariance times this (calibrated)


class RpropTuning(NamedTuple):
    """The RPROP minimisation of E (module doc)."""

    iterations: int  # gradient evaluations per fit (Lauer et al.: 10-20)
    step_xy: float  # m, first step (Lauer et al.: 40 mm)
    step_theta: float  # rad, first heading step
    min_step_xy: float  # m: stop when every step is below these
    min_step_theta: float  # rad


RPROP = RpropTuning(iterations=20, step_xy=0.04, step_theta=0.05, min_step_xy=1e-4,
                    min_step_theta=1e-5)


class GlobalTuning(NamedTuple):
    """The multi-start global search (module doc)."""

    step: float  # m, grid of starts over the field and its margin
    margin: float  # m, how far beyond the outer lines a start may lie
    heading_step: float  # rad, start headings when none is known
    c: float  # m, scale of rho ranking the starts (a blurred floor: wider basins)
    max_points: int  # line points ranking the starts (evenly subsampled)
    starts: int  # best separated starts fitted


GLOBAL = GlobalTuning(step=0.25, margin=0.5, heading_step=math.radians(10.0), c=0.5,
                      max_points=32, starts=16)


# ---------------------------------------------------------------------------- the distance


class DistanceField:
    """The map's distance table and its gradient, ready for ``fit_kernels.line_distance``:
    float32 (ny, nx) and (2, ny, nx), the grid's origin and resolution. A node on a line
    (distance 0, no gradient in the map) takes the gradient of the neighbour (of 8) whose
    nearest line passes closest to it, so its prediction grows across that line."""

    def __init__(self, map_file: MapFile):
        for name in ("distance", "distance_gradient"):
            if not map_file.has_table(name):
                raise FieldlocError(f"{map_file.path}: no '{name}' table for method fit")
        d = np.ascontiguousarray(map_file.table("distance"), dtype=np.float32)
        g = np.array(map_file.table("distance_gradient"), dtype=np.float32)
        if g.shape != (2, *d.shape):
            from ..common.errors import SchemaError

            raise SchemaError(f"{map_file.path}: distance_gradient {g.shape} does not match"
                              f" the distance table {d.shape}")
        grid = map_file.grid
        self.origin = (float(grid.origin[0]), float(grid.origin[1]))
        self.resolution = float(grid.resolution)
        self.dist = d
        self.grad = np.ascontiguousarray(_fill_on_line(d, g, self.resolution))
        ny, nx = d.shape
        self.bounds = (self.origin[0], self.origin[0] + (nx - 1) * self.resolution,
                       self.origin[1], self.origin[1] + (ny - 1) * self.resolution)

    def args(self) -> tuple:
        """The kernels' first arguments: the tables and the grid (x0, y0, resolution)."""
        return self.dist, self.grad, (self.origin[0], self.origin[1], self.resolution)

    def distance(self, x: float, y: float) -> tuple[float, float, float]:
        """(d, dd/dx, dd/dy) at a field point (fit_kernels.line_distance)."""
        return K.distance_at(*self.args(), float(x), float(y))


def _fill_on_line(d: np.ndarray, g: np.ndarray, res: float) -> np.ndarray:
    """The gradient table with every zero-gradient node given a neighbour's (class doc)."""
    ny, nx = d.shape
    on = np.hypot(g[0], g[1]) < 0.5
    best = np.full((ny, nx), np.inf)
    out = g.copy()
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if not (di or dj):
                continue
            # node (i, j) and its neighbour (i + di, j + dj), where both exist
            i0, i1, j0, j1 = max(0, -di), ny - max(0, di), max(0, -dj), nx - max(0, dj)
            nd = d[i0 + di:i1 + di, j0 + dj:j1 + dj]
            ng = g[:, i0 + di:i1 + di, j0 + dj:j1 + dj]
            # how far the node lies from the neighbour's nearest line: d_n + g_n . (-di, -dj)
            off = np.abs(nd - (ng[0] * dj + ng[1] * di) * res)
            take = (on[i0:i1, j0:j1] & ~on[i0 + di:i1 + di, j0 + dj:j1 + dj]
                    & (off < best[i0:i1, j0:j1]))
            best[i0:i1, j0:j1][take] = off[take]
            for k in range(2):
                out[k, i0:i1, j0:j1][take] = ng[k][take]
    return out


# ---------------------------------------------------------------------------- observations


@dataclass
class FitObservation:
    """One frame's line points for the fit: robot-frame points (N, 2) within the range, their
    range, their weights in the fit (the range weight 1 / (1 + (r / range_scale)^2), 1 by
    default) and ``evidence``, the share of the weighted points that count as independent
    evidence: the points of one white structure are one correlated measurement, worth at most
    ``EVIDENCE.per_structure`` points (the frame's temperature is divided by it, the fit's
    optimum is Lauer et al.'s)."""

    points: np.ndarray
    distance: np.ndarray
    weight: np.ndarray
    evidence: float = 1.0

    def __len__(self):
        return len(self.distance)

    @property
    def total_weight(self) -> float:
        return float(self.weight.sum())

    def rotated(self, turns: np.ndarray) -> FitObservation:
        """The points each turned about the robot by ``turns`` (rad, per point)."""
        c, s = np.cos(turns), np.sin(turns)
        p = self.points
        q = np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]], axis=1)
        return FitObservation(points=np.ascontiguousarray(q), distance=self.distance,
                              weight=self.weight)

    def random_bearings(self, perm: np.ndarray) -> FitObservation:
        """The null copy: the bearing sectors (``NULL_SECTORS`` of them) shuffled by
        ``perm``, each point turned with its sector, so every sector keeps its points (their
        ranges, their shape within it) and their bearings carry no information (as lut's
        copies shuffle whole scan lines)."""
        n = len(perm)
        step = 2 * math.pi / n
        bearing = np.arctan2(self.points[:, 1], self.points[:, 0]) % (2 * math.pi)
        sector = np.minimum((bearing / step).astype(np.int64), n - 1)
        return self.rotated((perm[sector] - sector) * step)

    def subsample(self, k: int) -> FitObservation:
        """At most ``k`` points, evenly spread over the list, their weights scaled up to the
        same total."""
        if len(self) <= k:
            return self
        idx = np.linspace(0, len(self) - 1, k).round().astype(np.int64)
        w = self.weight[idx] * (self.total_weight / max(float(self.weight[idx].sum()), 1e-12))
        return FitObservation(points=np.ascontiguousarray(self.points[idx]),
                              distance=self.distance[idx], weight=np.ascontiguousarray(w))


def observation_from_points(points, radial: RadialCorrection | None = None
                            ) -> FitObservation:
    """A frame's line points (N, 2, robot frame) as a FitObservation (within ``MAX_RANGE_M``,
    weighted by ``RANGE_SCALE_M`` and lut_search.EVIDENCE); with an active ``radial``
    correction each point's range r is moved to r - e(r) along its ray."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    r = np.hypot(p[:, 0], p[:, 1])
    keep = np.isfinite(r) & (r > 0) & (r <= MAX_RANGE_M)
    p, r = p[keep], r[keep]
    if radial is not None and radial.active and len(r):
        rc = np.maximum(radial.correct(r), 1e-3)
        p, r = p * (rc / r)[:, None], rc
    p = np.ascontiguousarray(p)
    r = np.ascontiguousarray(r)
    rs = RANGE_SCALE_M
    w = np.ones(len(r)) if rs is None else 1.0 / (1.0 + (r / float(rs)) ** 2)
    ev = EVIDENCE
    share = 1.0
    if len(p) and ev.per_structure is not None:
        size = structure_sizes(p, r, float(ev.link), float(ev.link_per_m))
        cap = np.minimum(1.0, float(ev.per_structure) / size)
        share = float(np.sum(w * cap) / max(float(np.sum(w)), 1e-12))
    return FitObservation(points=p, distance=r, weight=np.ascontiguousarray(w),
                          evidence=share)


# the scan-line matching of lut (Ribeiro et al. 2015) where fit reads scan lines: a frame
# without line points, and the radial crossings a fix should have seen (FitScorer)
MATCHING = MatchingParams()


def scanline_observation(fr: dict, scanlines, spiral: bool = False) -> Observation:
    """A features frame's scan-line crossings (radial, and spiral when ``spiral``) as lut's
    observations."""
    return Observation.from_scanlines(fr.get("radial", np.zeros((0, 4))),
                                      fr.get("spiral") if spiral else None, MATCHING,
                                      scanlines.max_range, scanlines.spiral_end_radius,
                                      scanlines.robot_radius)


def frame_points(fr: dict, scanlines) -> np.ndarray:
    """The line points of a frame: ``points`` (every crossing of the scan lines, or a team's
    own points), else the scan-line crossings as points."""
    pts = fr.get("points")
    if pts is not None:
        return np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    return scanline_observation(fr, scanlines, spiral=True).points(scanlines)


# ---------------------------------------------------------------------------- the engine


@dataclass
class Fix:
    """A pose the fit converged to: E (the weighted error term) and E / total weight, the
    Gauss-Newton matrix of E there, its inliers (points within ``INLIER_ERROR_M`` of a line)
    and their weighted rms distance."""

    x: float
    y: float
    theta: float
    error: float
    error_norm: float
    normal: np.ndarray
    inliers: int = 0
    observations: int = 0
    inlier_rms: float = math.nan
    mode: str = ""

    @property
    def pose(self) -> np.ndarray:
        return np.array([self.x, self.y, self.theta])

    @property
    def inlier_share(self) -> float:
        return self.inliers / max(self.observations, 1)


class FitEngine:
    """The fits of one map: ``fit`` (RPROP from a start), ``global_search`` (multi-start),
    ``vision_covariance``, ``ray_ranges`` (the module's constants C_M, INLIER_ERROR_M, RPROP,
    GLOBAL, VISION_*)."""

    def __init__(self, map_file: MapFile):
        self.field = DistanceField(map_file)
        self.c = C_M
        self.inlier_error = INLIER_ERROR_M
        rp = RPROP
        self.iterations = rp.iterations
        self.step_xy, self.step_theta = rp.step_xy, rp.step_theta
        self.min_step = (rp.min_step_xy, rp.min_step_theta)
        g = GLOBAL
        self.global_step = g.step
        # the starts: where a robot can stand, the field and ``GLOBAL.margin`` around it
        fm = map_file.field
        hx = min(fm.length / 2 + g.margin, self.field.bounds[1])
        hy = min(fm.width / 2 + g.margin, self.field.bounds[3])
        self.grid_xs = np.arange(-hx, hx + 1e-9, self.global_step)
        self.grid_ys = np.arange(-hy, hy + 1e-9, self.global_step)

    def fit(self, obs: FitObservation, start, *, heading=None, position=None,
            temperature: float = 1.0, mode: str = "", step_theta: float | None = None) -> Fix:
        """E minimised by RPROP from ``start`` (x, y, theta). ``heading`` (theta, sigma) adds
        the Gaussian prior of a measured heading: wrap(theta - theta0)^2 / (2 sigma^2) nats,
        in E's units times ``temperature``; ``position`` ((x, y), information (2, 2)) adds a
        Gaussian prior on the position the same way (the track's prior: the fit then finds
        the posterior's mode, not a basin the prior rules out)."""
        out = np.empty(3)
        if heading is None:
            pth, pw = 0.0, 0.0
        else:
            pth, pw = float(heading[0]), float(temperature) / float(heading[1]) ** 2
        if position is None:
            px = py = ixx = ixy = iyy = 0.0
        else:
            (px, py), info = position
            ixx, ixy, iyy = (float(temperature) * float(v)
                             for v in (info[0][0], info[0][1], info[1][1]))
        st = self.step_theta if step_theta is None else float(step_theta)
        K.rprop(*self.field.args(), obs.points, obs.weight,
                (float(start[0]), float(start[1]), float(start[2])), self.c * self.c,
                (self.iterations, self.step_xy, st, self.min_step[0], self.min_step[1]),
                (pth, pw, float(px), float(py), ixx, ixy, iyy), out)
        return self.fix_at(obs, out, mode=mode)

    def fix_at(self, obs: FitObservation, pose, *, mode: str = "") -> Fix:
        """The Fix of the points at ``pose`` (no fitting)."""
        normal = np.empty((3, 3))
        dists = np.empty(len(obs))
        K.normal_matrix(*self.field.args(), obs.points, obs.weight,
                        (float(pose[0]), float(pose[1]), float(pose[2])), self.c * self.c,
                        normal, dists)
        c2 = self.c * self.c
        e = float(np.sum(obs.weight * dists * dists / (c2 + dists * dists)))
        n_in, w_in, _rho, sq = inlier_sums(dists, obs.weight, self.inlier_error, c2)
        return Fix(x=float(pose[0]), y=float(pose[1]), theta=float(wrap_angle(pose[2])),
                   error=e, error_norm=e / max(obs.total_weight, 1e-12), normal=normal,
                   inliers=int(n_in), observations=len(obs),
                   inlier_rms=math.sqrt(sq / w_in) if w_in > 0 else math.nan, mode=mode)

    def starts(self, obs: FitObservation, headings: np.ndarray, k: int,
               separation: float) -> list[tuple[float, float, float]]:
        """The ``k`` best starts of the grid (``GLOBAL.step`` over the map's world) at the
        ``headings``, ranked by E with the wider scale ``GLOBAL.c`` on at most
        ``GLOBAL.max_points`` points, each more than ``separation`` m or 1.5 heading steps
        from the ones before."""
        g = GLOBAL
        sub = obs.subsample(g.max_points)
        hs = np.ascontiguousarray(headings, dtype=np.float64)
        costs = np.empty((len(hs), len(self.grid_ys), len(self.grid_xs)))
        K.grid_costs(*self.field.args(), sub.points, sub.weight,
                     np.ascontiguousarray(self.grid_xs), np.ascontiguousarray(self.grid_ys),
                     hs, g.c ** 2, costs)
        flat = costs.ravel()
        pool = min(flat.size, 32 * k)
        cand = np.argpartition(flat, pool - 1)[:pool]
        cand = cand[np.argsort(flat[cand], kind="stable")]
        hi, rest = np.divmod(cand, costs.shape[1] * costs.shape[2])
        yi, xi = np.divmod(rest, costs.shape[2])
        heading_gap = 1.5 * g.heading_step if len(hs) > 1 else math.inf
        chosen: list[tuple[float, float, float]] = []
        for h, i, j in zip(hi, yi, xi):
            x, y, th = float(self.grid_xs[j]), float(self.grid_ys[i]), float(hs[h])
            if all((x - a) ** 2 + (y - b) ** 2 > separation ** 2
                   or abs(float(wrap_angle(th - t))) > heading_gap for a, b, t in chosen):
                chosen.append((x, y, th))
                if len(chosen) == k:
                    break
        return chosen

    def global_search(self, obs: FitObservation, headings, *, temperature: float,
                      separation: float, mode: str) -> list[Fix]:
        """Fixes from the multi-start global search, best first, one per basin: ``headings``
        a list of (theta, sigma) (each the start heading and its prior), or None (start
        headings every ``GLOBAL.heading_step``, no prior)."""
        g = GLOBAL
        if headings is None:
            hs = np.arange(0.0, 2 * math.pi - 1e-9, g.heading_step)
            sigma = {}
        else:
            hs = np.array([h for h, _s in headings])
            sigma = {float(h): s for h, s in headings}
        out: list[Fix] = []
        for x, y, th in self.starts(obs, hs, g.starts, separation):
            s = sigma.get(th)
            f = self.fit(obs, (x, y, th), heading=None if s is None else (th, s),
                         temperature=temperature, mode=mode,
                         step_theta=None if s is not None else 0.5 * g.heading_step)
            out.append(f)
        out.sort(key=lambda f: f.error)
        kept: list[Fix] = []
        for f in out:
            if not any(near_pose(k.pose, f.pose, tracking.SAME_BASIN_M, tracking.SAME_BASIN_RAD)
                       for k in kept):
                kept.append(f)
        return kept

    def vision_covariance(self, fix: Fix, temperature: float, heading_sigma: float | None
                          ) -> np.ndarray:
        """Covariance (3, 3) of a fix for the fusion: the inverse of the tempered likelihood's
        Hessian (Gauss-Newton matrix / temperature) with the heading prior's information
        (1 / sigma^2), times ``VISION_INFLATION``; the position's eigenvalues between
        ``VISION_SIGMA_XY_M``^2 and 1 m^2."""
        info = fix.normal / float(temperature)
        if heading_sigma is not None:
            info = info + np.diag([0.0, 0.0, 1.0 / float(heading_sigma) ** 2])
        info = 0.5 * (info + info.T) + np.diag([1e-6, 1e-6, 1e-6])
        cov = np.linalg.inv(info) * VISION_INFLATION
        w, v = np.linalg.eigh(cov[:2, :2])
        w = np.clip(w, VISION_SIGMA_XY_M ** 2, 1.0)
        cov[:2, :2] = (v * w) @ v.T
        cov[2, 2] = min(max(cov[2, 2], 1e-8), math.pi ** 2)
        return 0.5 * (cov + cov.T)

    def ray_ranges(self, obs: FitObservation, pose, max_distance: float) -> np.ndarray:
        """Per point the range at which its ray meets its nearest line at ``pose``
        (fit_kernels.ray_ranges), NaN where that is not well defined."""
        out = np.empty(len(obs))
        K.ray_ranges(*self.field.args(), obs.points,
                     (float(pose[0]), float(pose[1]), float(pose[2])), 0.3, float(max_distance),
                     out)
        return out


# ---------------------------------------------------------------------------- the method


# the ranges fit's numeric keys must lie in to run at all (common.conf.check_bounds): the
# belief's (its count of hypotheses and its acceptance threshold), a clock tolerance of at
# least 0
BOUNDS = {**tracking.BOUNDS, "stamp_tolerance": (0, None)}


def check_conf(conf: dict) -> None:
    """The method's keys checked without a dataset (FieldlocError): at run time, and where a
    batch SPEC names the method, before anything runs."""
    check_bounds(conf, BOUNDS)
    heading_mod.check_keys(conf)
    tracking.check_conf(conf)


@dataclass(kw_only=True)
class FitCandidate(Candidate):
    """A tracking Candidate with the fit's own numbers: ``score`` (tracked: nll plus the
    prior's capped Mahalanobis term, what the null is compared with) and the heading sigma
    of its fit."""

    score: float = 0.0
    heading_sigma: float | None = None
    prior: tuple | None = None  # tracked: (prior pose, prior position covariance)


class FitLocaliser:
    """The per-frame loop of method fit (module doc): the engine's fixes as candidates of the
    tracking bank."""

    def __init__(self, conf: dict, engine: FitEngine, field_model, scanlines, *, yaw,
                 collision, truth_heading, seed: int = 0):
        self.conf = conf
        self.engine = engine
        self.scanlines = scanlines
        self.yaw, self.collision, self.truth_heading = yaw, collision, truth_heading
        self.alignment = heading_mod.ImuAlignment(
            variance=(heading_mod.IMU_SIGMA_RAD ** 2 + math.radians(2.0) ** 2),
            known=conf["imu_alignment"] == "field")
        self.heading_sigma = heading_mod.SOURCE_SIGMA_RAD[conf["heading"]]
        self.T_frame = TEMPERATURE
        self.T_track = self.T_frame * TRACK_CORRELATION
        self.T = self.T_frame
        x0, x1, y0, y1 = engine.field.bounds
        reach = REACH_M
        res = engine.field.resolution
        self.bank = TrackBank(conf, area=(x1 - x0) * (y1 - y0), reach=reach,
                              reach_cells=int((2 * round(reach / res) + 1) ** 2),
                              symmetric=field_model.is_point_symmetric())
        self.symmetric = self.bank.symmetric
        self.rng = np.random.default_rng(seed)
        self._perms = np.stack([self.rng.permutation(NULL_SECTORS) for _ in range(64)])
        self._next_perm = 0
        self.last_global = -10**9
        self.last_confident = True  # the last frame's belief, up to the mirror (TrackBank)
        self.field_heading = heading_mod.field_aligned(conf)  # rules the mirror out
        self.fixed_once = False
        self._offset_updates = 0
        rc = conf["radial_correction"]
        self.radial = (RadialCorrection(robot_radius=float(scanlines.robot_radius))
                       if rc["enabled"] and not conf["independent"] else None)

    # ------------------------------------------------------------------ heading
    def _frame_heading(self, i: int, col: bool):
        """(heading, sigma) of every hypothesis this frame when the source gives one (imu,
        truth; the IMU yaw on a collision frame with ``heading.UNSURE_HEADING_SIGMA_RAD``), None
        when each track has its own (histogram) or it is unknown."""
        conf = self.conf
        if conf["heading"] == "truth":
            if not np.isfinite(self.truth_heading[i]):
                raise FrameFailed("no-truth-heading")
            return float(self.truth_heading[i]), heading_mod.TRUTH_SIGMA_RAD
        if conf["heading"] == "imu":
            if not np.isfinite(self.yaw[i]):
                raise FrameFailed("no-imu-row")
            self.alignment.predict()
            if not self.alignment.known:
                return None
            sigma = math.sqrt(heading_mod.IMU_SIGMA_RAD ** 2 + self.alignment.variance)
            if col:  # the IMU yaw jolts on collisions
                sigma = max(sigma, heading_mod.UNSURE_HEADING_SIGMA_RAD)
            return self.alignment.heading(float(self.yaw[i])), sigma
        return None

    def _track_heading(self, prior_pose, obs: FitObservation, base, flags):
        """(heading, sigma) of a track's fit this frame."""
        conf = self.conf
        if base is not None:
            return base
        if conf["heading"] == "histogram":
            th, sharp = heading_mod.histogram_heading(
                obs.points, float(prior_pose[2]), window=heading_mod.HISTOGRAM_WINDOW_RAD,
                step=heading_mod.HISTOGRAM_STEP_RAD, bin=heading_mod.HISTOGRAM_BIN_M,
                max_distance=MAX_RANGE_M, score=heading_mod.HISTOGRAM_SCORE)
            jump = abs(float(wrap_angle(th - prior_pose[2]))) if np.isfinite(th) else np.inf
            if (sharp >= heading_mod.HISTOGRAM_MIN_SHARPNESS
                    and jump <= heading_mod.HISTOGRAM_GATE_RAD):
                return th, heading_mod.HISTOGRAM_SIGMA_RAD
        flags.append("heading-vision")  # the fit's own heading, from the track's
        return float(prior_pose[2]), heading_mod.UNSURE_HEADING_SIGMA_RAD

    def _global_headings(self, obs: FitObservation, base):
        """The headings a global search starts from: the frame's (imu, truth), the four
        histogram peaks (histogram), or None (every ``GLOBAL.heading_step``)."""
        conf = self.conf
        if base is not None:
            return [base]
        if conf["heading"] != "histogram":
            return None
        th, sharp = heading_mod.histogram_heading(
            obs.points, 0.0, window=math.pi / 4, step=heading_mod.HISTOGRAM_STEP_RAD,
            bin=heading_mod.HISTOGRAM_BIN_M, max_distance=MAX_RANGE_M,
            score=heading_mod.HISTOGRAM_SCORE)
        if not np.isfinite(th) or sharp < heading_mod.HISTOGRAM_MIN_SHARPNESS:
            return None
        return [(float(wrap_angle(th + k * math.pi / 2)), heading_mod.HISTOGRAM_SIGMA_RAD)
                for k in range(4)]

    # ------------------------------------------------------------------ candidates
    def _tracked(self, t, prior, obs, base, flags) -> FitCandidate:
        prior_pose, prior_cov = prior
        th, sigma = self._track_heading(prior_pose, obs, base, flags)
        start = np.array([prior_pose[0], prior_pose[1], th])
        info = self.bank.innovation_information(prior_cov)
        fix = self.engine.fit(obs, start, heading=(th, sigma), temperature=self.T,
                              position=self._position_prior(prior_pose, info), mode="local")
        R = self.engine.vision_covariance(fix, self.T, sigma)
        nll = fix.error / self.T
        d = fix.pose[:2] - np.asarray(prior_pose[:2], float)
        score = nll + self.bank.prior_term(d, info)
        if TRACKED_PRIOR:
            # the fix is the posterior's mode m; what the points alone say is the measurement
            # z with m = the Kalman update of the prior by z (covariance R): z = m + R info
            # (m - prior), so the filter does not count the prior twice
            z = fix.pose[:2] + R[:2, :2] @ info @ d
            fix = dataclasses.replace(fix, x=float(z[0]), y=float(z[1]))
            d = z - np.asarray(prior_pose[:2], float)
        return FitCandidate(fix=fix, R=R, nll=nll, track=t, mirror=t.mirror,
                            log_prior=self.bank.tracked_log_prior(t, d, prior_cov, R),
                            score=score, heading_sigma=sigma, prior=prior)

    def _position_prior(self, prior_pose, info):
        """The track's prior on the position for the tracked fit (``tracked_prior``), or None
        (the fit sees the points alone, the Kalman filter the prior)."""
        if not TRACKED_PRIOR:
            return None
        return (float(prior_pose[0]), float(prior_pose[1])), info

    def _null_copy(self, obs: FitObservation) -> FitObservation:
        perm = self._perms[self._next_perm % len(self._perms)]
        self._next_perm += 1
        return obs.random_bearings(perm)

    def _tracked_null(self, obs, tracked: list[FitCandidate], base) -> float:
        """The score of the null in a tracked frame: random-bearing copies of the points fitted
        from the strongest track's prior as its fix was (median over ``null_copies``)."""
        top = max(tracked, key=lambda c: c.log_prior - c.nll)
        prior_pose, prior_cov = top.prior
        info = self.bank.innovation_information(prior_cov)
        out = []
        for _ in range(NULL_COPIES):
            nobs = self._null_copy(obs)
            th = top.fix.theta if base is None else base[0]
            f = self.engine.fit(nobs, np.array([prior_pose[0], prior_pose[1], th]),
                                heading=(th, top.heading_sigma), temperature=self.T,
                                position=self._position_prior(prior_pose, info))
            d = f.pose[:2] - np.asarray(prior_pose[:2], float)
            out.append(f.error / self.T + self.bank.prior_term(d, info))
        return float(np.median(out))

    def _global_null(self, obs, headings) -> float:
        """The nll of the null in a global frame: the best fix of the global search on
        random-bearing copies (median over ``null_copies``)."""
        out = []
        for _ in range(NULL_COPIES):
            fixes = self.engine.global_search(self._null_copy(obs), headings,
                                              temperature=self.T, mode="null",
                                              separation=tracking.AMBIGUITY_DISTANCE_M)
            out.append(fixes[0].error / self.T if fixes else math.inf)
        return float(np.median(out))

    def _global(self, obs, headings, flags, log_prior: float, *,
                field_heading: bool = False) -> list[FitCandidate]:
        """New-track candidates from the multi-start search at ``headings``; ``field_heading``:
        the one heading is field-aligned (rules the mirror out), otherwise a candidate's mirror
        image explains the frame as well (TrackBank.finish_global)."""
        conf = self.conf
        mode = "global" if headings is not None and len(headings) == 1 else "global-heading"
        fixes = self.engine.global_search(obs, headings, temperature=self.T,
                                          separation=tracking.AMBIGUITY_DISTANCE_M, mode=mode)
        out: list[FitCandidate] = []
        sigmas = {} if headings is None else {round(h, 9): s for h, s in headings}
        for f in fixes:
            nll = f.error / self.T
            if self.bank.near_track(f.pose) or self.bank.fold(out, f.pose, nll):
                continue
            sigma = sigmas.get(round(f.theta, 9)) if len(sigmas) == 1 else None
            if sigma is None and headings is not None and len(headings) == 1:
                sigma = headings[0][1]
            out.append(FitCandidate(fix=f, R=self.engine.vision_covariance(f, self.T, sigma),
                                    nll=nll, log_prior=log_prior, heading_sigma=sigma))
        self.bank.finish_global(out, heading_known=field_heading)
        if not self.fixed_once and conf["start_half"] != "any":
            for c in out:
                if self.bank.start_half(c, conf["start_half"], conf["start_half_error"],
                                        lambda c, pose: self._refit_mirrored(obs, c, pose)):
                    flags.append("start-half")
        return out

    def _refit_mirrored(self, obs, c: FitCandidate, pose):
        f = self.engine.fit(obs, pose, temperature=self.T, mode=c.fix.mode,
                            heading=None if c.heading_sigma is None
                            else (pose[2], c.heading_sigma))
        c.fix, c.nll = f, f.error / self.T
        c.R = self.engine.vision_covariance(f, self.T, c.heading_sigma)

    # ------------------------------------------------------------------ one frame
    def frame(self, i: int, fr: dict, dt: float, odo, flags: list):
        """Localise frame i: (hypotheses (k, 4), the top candidate, pose, covariance,
        accepted), or FrameFailed."""
        conf, bank = self.conf, self.bank
        col = bool(self.collision[i])
        if conf["independent"]:
            bank.reset()
            dt, odo = 0.0, None
        raw = frame_points(fr, self.scanlines)
        obs = observation_from_points(raw, self.radial)
        if len(obs) < MIN_POINTS:
            raise FrameFailed("too-few-observations")
        base = self._frame_heading(i, col)
        # correlated points count as the independent evidence they carry (FitObservation)
        self.T = (self.T_track if bank.tracks else self.T_frame) / max(obs.evidence, 1e-6)
        other_prior = bank.other_prior()
        tracked: list[FitCandidate] = []
        lost = False
        for t in bank.tracks:
            prior = bank.prior(t, dt, odo, col)
            lost |= bank.lost(prior[1])
            tracked.append(self._tracked(t, prior, obs, base, flags))
        new: list[FitCandidate] = []
        headings = None
        if (not tracked or not self.last_confident or lost
                or i - self.last_global >= GLOBAL_EVERY):
            headings = self._global_headings(obs, base)
            if (headings is None and tracked and self.last_confident
                    and conf["heading"] != "imu"):
                top = max(tracked, key=lambda c: c.log_prior - c.nll)
                headings = [(top.fix.theta, heading_mod.UNSURE_HEADING_SIGMA_RAD)]
            new = self._global(obs, headings, flags, bank.global_log_prior(other_prior),
                               field_heading=base is not None and self.field_heading)
            self.last_global = i
            if tracked:
                flags.append("global-check")
        if tracked:
            null_score = self._tracked_null(obs, tracked, base)
            for c in tracked:
                c.beats_null = c.score < null_score
            if not any(c.beats_null for c in tracked) and not new:
                raise FrameFailed("uninformative")
        null_nll = None
        if new or not tracked:
            null_nll = self._global_null(obs, headings)
            if not tracked and (not new or min(c.nll for c in new) >= null_nll):
                raise FrameFailed("uninformative")
        other = bank.posterior(tracked, new, other_prior, null_nll)
        top = bank.update(i, tracked + new, other, dt, odo, col)
        hyps = bank.hypotheses()
        pose, cov, confidence, accepted = bank.conclude(hyps, top, bool(tracked), flags)
        self._track_imu_offset(i, obs, top, col)
        self._learn_radial(raw, hyps, top, col)
        self.fixed_once = True
        self.last_confident = bank.confident()
        return hyps, top, pose, cov, accepted

    def failed(self, dt: float, odo, col: bool):
        self.last_confident = False
        self.bank.failed(dt, odo, col)

    # ------------------------------------------------------------------ learning
    def _learn_radial(self, raw_points, hyps, top, col):
        """The line points of a confident tracked frame, as observed, against where their rays
        meet the lines at the fused pose, into the radial correction (radial_correction.py)."""
        rc = self.radial
        pose = None if rc is None else rc.teaching_pose(self.bank, top, hyps, col)
        if pose is None:
            return
        obs = observation_from_points(raw_points)
        pred = self.engine.ray_ranges(obs, pose, rc.max_residual)
        ok = np.isfinite(pred)
        if ok.any():
            rc.update(obs.distance[ok], pred[ok])

    def _track_imu_offset(self, i, obs, top, col):
        """IMU alignment: initialised from the first fix (``imu_alignment: vision``), then
        updated from the vision heading (a fit without the IMU prior) every
        ``imu_offset_every`` frames on clean tracked frames."""
        conf = self.conf
        if conf["heading"] != "imu" or not np.isfinite(self.yaw[i]):
            return
        if not self.alignment.known:
            var = max(math.radians(1.5) ** 2, heading_mod.IMU_SIGMA_RAD ** 2)
            theta = self.bank.tracks[0].pose[2] if self.bank.tracks else top.fix.theta
            self.alignment.initialise(float(theta), float(self.yaw[i]), var)
            return
        every = heading_mod.IMU_OFFSET_EVERY
        if every <= 0 or col or top.track is None or top.fix.inlier_share < 0.5:
            return
        self._offset_updates += 1
        if i % every and self._offset_updates > every:
            return
        f = self.engine.fit(obs, top.fix.pose, temperature=self.T)
        var = self.engine.vision_covariance(f, self.T, None)[2, 2]
        if abs(float(wrap_angle(f.theta - top.fix.theta))) < 3 * math.sqrt(var) + 0.02:
            self.alignment.update(f.theta, float(self.yaw[i]), var)


_ENGINES: dict = {}


def fit_engine(map_file: MapFile) -> FitEngine:
    """The FitEngine of a map (the last one is kept)."""
    p = real_path(map_file.path)
    key = (str(p), p.stat().st_mtime_ns)
    if key not in _ENGINES:
        _ENGINES.clear()
        _ENGINES[key] = FitEngine(map_file)
    return _ENGINES[key]


class FitScorer(PathCalibration):
    """Method fit's candidates for the smoother (smooth.Scorer) after a causal run, with what
    that run learnt of the whole recording (the IMU's alignment, the radial correction): the
    multi-start global search's fixes and the fits from given starts, as the tracks' are (at
    the frame's heading with its prior), their nll the fit's error with the map crossings
    the radial lines should have seen and did not (lut_matching.unseen_error) at the tracked
    temperature (the module doc), their covariance ``FitEngine.vision_covariance``."""

    def __init__(self, loc: FitLocaliser, features, radial_table: RadialTable):
        self.loc = loc
        self.features = features
        self.names = list(features.names)
        self.frames = len(self.names)
        # the map's radial crossings, for the ones a fix's radial lines should have seen
        # (lut_matching.unseen_error)
        self.radial_table = radial_table
        self.mirrored = loc.symmetric and not (loc.field_heading
                                              and loc.conf["heading"] != "histogram")
        self._cache: dict = {}
        self._raw: dict = {}
        # the distance correction: the causal run's, until one learnt from the smoothed path
        # explains the path better (smooth.py)
        self.radial = loc.radial
        self.robot_radius = loc.scanlines.robot_radius

    def _raw_points(self, i: int):
        """Frame i's line points, as read (None when the frame cannot be read)."""
        return self._read(i)[0]

    def _read(self, i: int):
        """(line points, radial scan-line observations or None) of frame i as read, before any
        distance correction; read once."""
        if i not in self._raw:
            try:
                fr = self.features.frame(self.names[i])
            except (KeyError, OSError):
                fr = None
            self._raw[i] = ((None, None) if fr is None else
                            (frame_points(fr, self.loc.scanlines),
                             scanline_observation(fr, self.loc.scanlines)
                             if "radial" in fr else None))
        return self._raw[i]

    def _corrected(self, i: int):
        """(FitObservation of the line points, radial observations or None) of frame i with
        the calibration's distance correction; cached until the calibration changes
        (PathCalibration drops ``_cache``)."""
        if i not in self._cache:
            points, scan = self._read(i)
            if points is None:
                self._cache[i] = (None, None)
            else:
                if scan is not None and self.radial is not None and self.radial.active:
                    scan = dataclasses.replace(scan, distance=self.radial.correct(scan.distance))
                self._cache[i] = (observation_from_points(points, self.radial), scan)
        return self._cache[i]

    def _obs(self, i: int):
        return self._corrected(i)[0]

    def _unseen(self, i: int, pose) -> float:
        """The map crossings frame i's radial lines should have seen at ``pose`` and did not
        (lut_matching.unseen_error; the distances corrected as the points are), 0 for a frame
        of a team's own points without scan lines."""
        scan = self._corrected(i)[1]
        if scan is None or not len(scan):
            return 0.0
        return self.radial_table.unseen_error(scan, pose, MATCHING)

    def _crossings(self, i: int, pose):
        """Frame i's line points' ranges as observed and where their rays meet the lines at
        ``pose``."""
        loc = self.loc
        obs = observation_from_points(self._raw_points(i))
        pred = loc.engine.ray_ranges(obs, pose, radial_correction.MAX_RESIDUAL_M)
        ok = np.isfinite(pred)
        return obs.distance[ok], pred[ok]

    def _heading(self, i: int):
        """(heading, sigma) where the frame's source gives one (the IMU's as aligned at the
        end of the run), else None."""
        loc, conf = self.loc, self.loc.conf
        if conf["heading"] == "truth":
            th = loc.truth_heading[i]
            return (float(th), heading_mod.TRUTH_SIGMA_RAD) if np.isfinite(th) else None
        if conf["heading"] == "imu" and loc.alignment.known and np.isfinite(loc.yaw[i]):
            sigma = math.sqrt(heading_mod.IMU_SIGMA_RAD ** 2 + loc.alignment.variance)
            if loc.collision[i]:
                sigma = max(sigma, heading_mod.UNSURE_HEADING_SIGMA_RAD)
            return loc.alignment.heading(float(loc.yaw[i])), sigma
        return None

    def _temperature(self, obs) -> float:
        return self.loc.T_track / max(obs.evidence, 1e-6)

    def failed(self, i: int) -> str | None:
        obs = self._obs(i)
        if obs is None:
            return "unreadable-features"
        return "too-few-observations" if len(obs) < MIN_POINTS else None

    def _row(self, i: int, fix: Fix, T: float, sigma):
        """(pose, nll, covariance, e_norm) of a fix: its nll the fit's error and the map
        crossings its radial lines should have seen and did not, at the frame's temperature."""
        nll = (fix.error + self._unseen(i, fix.pose)) / T
        return (fix.pose, nll, self.loc.engine.vision_covariance(fix, T, sigma),
                fix.error_norm)

    def global_candidates(self, i: int) -> FrameCandidates:
        loc, engine = self.loc, self.loc.engine
        obs = self._obs(i)
        T = self._temperature(obs)
        base = self._heading(i)
        headings = loc._global_headings(obs, base)
        fixes = engine.global_search(obs, headings, temperature=T, mode="global",
                                     separation=tracking.AMBIGUITY_DISTANCE_M)
        sigma = None if headings is None else headings[0][1]
        rows = [self._row(i, f, T, sigma) for f in fixes]
        if self.mirrored:  # the mirror image explains the frame as well: fitted there too
            for f in fixes:
                m = FieldModel.mirror_pose(f.pose)
                g = engine.fit(obs, m, temperature=T, mode="global",
                               heading=None if sigma is None else (m[2], sigma))
                rows.append(self._row(i, g, T, sigma))
        return FrameCandidates.from_rows(rows)

    def local_candidates(self, i: int, starts: np.ndarray) -> FrameCandidates:
        loc = self.loc
        obs = self._obs(i)
        T = self._temperature(obs)
        base = self._heading(i)
        rows = []
        for p in starts:
            th, sigma = loc._track_heading(p, obs, base, [])
            fix = loc.engine.fit(obs, np.array([p[0], p[1], th]), heading=(th, sigma),
                                 position=((p[0], p[1]), np.eye(2) / LOCAL_REACH_M ** 2),
                                 temperature=T, mode="local")
            rows.append(self._row(i, fix, T, sigma))
        return FrameCandidates.from_rows(rows, start=range(len(rows)))


def run(conf: dict, dataset, features, map_file: MapFile, progress=False) -> PoseTrack:
    """Localise every frame of ``features`` (names, stamps, frame(name) with ``points``, or
    ``radial`` and ``spiral``) on ``map_file``'s distance table, with the odometry, IMU and
    truth of ``dataset`` (stages.common.dataset.Dataset or None). ``progress``: tqdm."""
    check_conf(conf)
    heading_mod.check_conf(conf, dataset)
    engine = fit_engine(map_file)
    sensors = tracking.frame_sensors(conf, dataset, features.stamps)
    loc = FitLocaliser(conf, engine, map_file.field, map_file.scanlines, yaw=sensors.yaw,
                       collision=sensors.collision, truth_heading=sensors.truth_heading)
    loc.bank.has_odometry = bool(np.any(sensors.has_odometry))
    track = tracking.localise_frames(loc, features, sensors, desc="localize fit",
                                     progress=progress)
    if not conf["smooth"]:
        return track
    scorer = FitScorer(loc, features, radial_table(map_file))
    x0, x1, y0, y1 = engine.field.bounds
    track = bank_smoothing.smoothed(scorer, track, conf, increments=sensors.increments,
                                    has_odometry=sensors.has_odometry, stamps=features.stamps,
                                    collision=sensors.collision, area=(x1 - x0) * (y1 - y0))
    if scorer.radial is not None:
        track.meta["radial_correction"] = scorer.radial.summary()
    return track
