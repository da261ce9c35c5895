"""The robot's heading for the table search (Ribeiro et al. 2015, section V): from the IMU, from the
histograms of the line points, or from the ground truth (for ablations).

IMU (``imu.csv``: stamp, yaw, collision). A real IMU reports yaw in its own frame: zero where it
was switched on or magnetic north, plus a bias that drifts. The field heading is
``yaw + offset``; the offset is

- ``imu_alignment: field``: assumed zero at the start (the IMU was aligned with the field, as
  the simulator writes it: field-frame yaw plus a small bias), or
- ``imu_alignment: vision``: taken from the first global localisation with unknown heading
  (offset = found heading - yaw on that frame; on a symmetric field that fix may be the mirror
  pose, which then stays consistent with the IMU);

and in both cases tracked by ``ImuAlignment``, a one-state Kalman filter on the offset
(random-walk bias) updated from the vision heading that the table search finds between its 5 deg
steps (TableSearch.refine_heading), so a slowly drifting bias does not turn into a position
error. Collision frames (flag set) are not used to update the offset (the yaw jolts).

Histograms (Ribeiro et al. 2015, V-B). Field lines are parallel to the field's x or y axis, so when
the line points (robot frame) are rotated by the right heading, their x coordinates pile up on the
vertical lines and their y coordinates on the horizontal ones. ``histogram_heading`` rotates the
points by every angle within +-40 deg (the largest turn between frames) of the last heading in
small steps, builds the x and y histograms (linear binning into bins of ``bin`` m), and scores
each angle by the sum of the two histograms' peak values; the best angle, refined by a parabola
through its neighbours, is the heading. A rotation by 90 deg swaps the histograms, so the score
repeats every 90 deg; the +-40 deg window around the tracked heading resolves the 90/180 deg
ambiguity.

The particle filter (mcl.py, with ``imu_heading_sigma``) takes the IMU's yaw as the field
heading, as ``imu_alignment: field`` does: ``frame_headings`` gives each frame's (yaw, sigma),
none on collision frames, and ``heading_log_likelihood`` the Gaussian term it adds to a pose's
log-likelihood, in the filter's weights and the smoother's candidates alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..common.errors import FieldlocError, shown
from ..common.geometry import wrap_angle, wrap_scalar

SOURCES = ("imu", "histogram", "truth")  # where a frame's heading comes from
START_HALVES = ("own", "opponent", "any")  # where the first fix lies (the field's symmetry)

# The heading sources' tuned constants, the same for lut and fit (the values their confs
# held; chosen on the rendered tuning sets, docs/results.md): each source's heading noise for
# the fusion, and how the histograms search and when they are believed.
IMU_SIGMA_RAD = 0.01  # rad, IMU heading noise for the fusion
IMU_OFFSET_EVERY = 5  # frames between vision updates of the IMU offset (0: never)
HISTOGRAM_WINDOW_RAD = math.radians(40.0)  # rad, +- around the last heading
HISTOGRAM_STEP_RAD = math.radians(0.5)  # rad
HISTOGRAM_BIN_M = 0.05  # m
HISTOGRAM_SIGMA_RAD = 0.02  # rad, histogram heading noise for the fusion
HISTOGRAM_SCORE = "peak"  # peak (Ribeiro et al. 2015) | energy (sum of squared counts)
HISTOGRAM_MIN_SHARPNESS = 1.7  # best score / mean score; below: heading by vision
HISTOGRAM_GATE_RAD = 0.15  # rad, largest accepted deviation from the predicted heading
TRUTH_SIGMA_RAD = 0.001  # rad, the truth's heading noise for the fusion
# rad, heading noise for the fusion where the source gives none or vision is unsure (the IMU
# on a collision frame, a histogram without straight lines)
UNSURE_HEADING_SIGMA_RAD = 0.1
# the heading noise of each source for the fusion
SOURCE_SIGMA_RAD = {"imu": IMU_SIGMA_RAD, "histogram": HISTOGRAM_SIGMA_RAD,
                    "truth": TRUTH_SIGMA_RAD}


def check_start_half(conf: dict) -> None:
    """``start_half`` (own, opponent or any) and ``start_half_error`` (a probability) of a
    method's conf checked (FieldlocError)."""
    if conf["start_half"] not in START_HALVES:
        raise FieldlocError(f"start_half must be one of {', '.join(START_HALVES)}, not"
                            f" {shown(conf['start_half'])}")
    e = conf["start_half_error"]
    if isinstance(e, bool) or not isinstance(e, (int, float)) or not 0.0 <= e <= 1.0:
        raise FieldlocError(f"start_half_error must lie in [0, 1], not {shown(e)}")


def check_keys(conf: dict) -> None:
    """The heading keys a method's conf holds (``heading``, ``imu_alignment``, ``start_half``
    and ``start_half_error``; mcl has only the last two) checked, without a dataset: what a
    batch SPEC's method can be refused for before anything runs (FieldlocError)."""
    if "heading" in conf and conf["heading"] not in SOURCES:
        raise FieldlocError(
            f"unknown heading source {shown(conf['heading'])} (use {', '.join(SOURCES)})")
    if "imu_alignment" in conf and conf["imu_alignment"] not in ("field", "vision"):
        raise FieldlocError("imu_alignment must be 'field' or 'vision'")
    if "start_half" in conf:
        check_start_half(conf)


def check_conf(conf: dict, dataset) -> None:
    """``check_keys``, and the file the heading source reads present in ``dataset``
    (FieldlocError)."""
    check_keys(conf)
    need = {"imu": "imu", "truth": "truth"}.get(conf["heading"])
    if need and (dataset is None or dataset.optional(need) is None):
        where = dataset.root if dataset is not None else "the dataset"
        raise FieldlocError(
            f"--heading {conf['heading']} needs {need}.csv in {where}; use --heading histogram")

def field_aligned(conf: dict) -> bool:
    """Whether a method's heading source tells a heading from its opposite: the truth, or an
    IMU aligned with the field (``imu_alignment: field``). Only such a heading rules out the
    mirror pose on a point-symmetric field; a histogram's, or a vision-aligned IMU's, does
    not."""
    return conf["heading"] == "truth" or (
        conf["heading"] == "imu" and conf["imu_alignment"] == "field")


# ---------------------------------------------------------------------------- per-frame lookup


def nearest_rows(stamps_src: np.ndarray, stamps_dst: np.ndarray, tolerance: float) -> np.ndarray:
    """For each destination stamp the index of the nearest source stamp, -1 if none is within
    ``tolerance`` seconds."""
    src = np.asarray(stamps_src, dtype=float)
    dst = np.asarray(stamps_dst, dtype=float)
    if len(src) == 0:
        return np.full(len(dst), -1, dtype=np.int64)
    order = np.argsort(src, kind="stable")
    s = src[order]
    j = np.clip(np.searchsorted(s, dst), 1, max(len(s) - 1, 1))
    lo = np.clip(j - 1, 0, len(s) - 1)
    hi = np.clip(j, 0, len(s) - 1)
    pick = np.where(np.abs(s[lo] - dst) <= np.abs(s[hi] - dst), lo, hi)
    out = order[pick]
    out[np.abs(src[out] - dst) > tolerance] = -1
    return out


def truth_heading(truth: dict, stamps: np.ndarray, tolerance: float) -> np.ndarray:
    """Heading (rad) per frame from truth.csv columns; NaN where no truth row is near."""
    idx = nearest_rows(truth["stamp"], stamps, tolerance)
    th = np.asarray(truth["theta"], dtype=float)
    return np.where(idx >= 0, th[np.maximum(idx, 0)], np.nan)


def imu_per_frame(imu: dict, stamps: np.ndarray, tolerance: float):
    """(yaw (rad, NaN where no row is near), collision (bool)) per frame from imu.csv columns."""
    idx = nearest_rows(imu["stamp"], stamps, tolerance)
    yaw = np.asarray(imu["yaw"], dtype=float)
    col = np.asarray(imu["collision"], dtype=float) > 0.5
    ok = idx >= 0
    return (np.where(ok, yaw[np.maximum(idx, 0)], np.nan),
            np.where(ok, col[np.maximum(idx, 0)], False))


# ---------------------------------------------------------------------------- IMU alignment

@dataclass
class ImuAlignment:
    """Offset between IMU yaw and field heading, a one-state Kalman filter (random walk)."""

    offset: float = 0.0  # rad, field heading = yaw + offset
    variance: float = math.radians(2.0) ** 2  # rad^2
    drift: float = math.radians(0.05) ** 2  # rad^2 added per frame (bias random walk)
    known: bool = True  # False until initialised (alignment "vision")

    def heading(self, yaw: float) -> float:
        return wrap_scalar(float(yaw) + self.offset)

    def initialise(self, field_heading: float, yaw: float, variance: float):
        self.offset = float(wrap_angle(field_heading - yaw))
        self.variance = float(variance)
        self.known = True

    def predict(self):
        self.variance += self.drift

    def update(self, vision_heading: float, yaw: float, variance: float) -> float:
        """Correct the offset with a vision heading of the given variance; returns the
        innovation (rad). Innovations beyond 3 sigma are rejected (a wrong vision fix)."""
        innovation = float(wrap_angle(vision_heading - yaw - self.offset))
        s = self.variance + variance
        if innovation * innovation > 9.0 * s:
            return innovation
        k = self.variance / s
        self.offset = float(wrap_angle(self.offset + k * innovation))
        self.variance = (1 - k) * self.variance
        return innovation


# ---------------------------------------------------------------------------- histograms


def histogram_scores(points: np.ndarray, angles: np.ndarray, *, bin: float = 0.05,
                     extent: float = 8.0, weights: np.ndarray | None = None,
                     score: str = "peak") -> np.ndarray:
    """Score per candidate heading of the x and y histograms of the points (robot frame)
    rotated into the field frame by that heading: ``peak`` (Ribeiro et al. 2015) the sum of the two
    histograms' peak values, ``energy`` the sum of their squared bin counts (every line
    counts, not only the longest). Linear binning (each point split between its two nearest
    bins) keeps the score smooth in the angle."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    a = np.asarray(angles, dtype=float)
    na = len(a)
    if len(p) == 0 or na == 0:
        return np.zeros(na)
    w = np.ones(len(p)) if weights is None else np.asarray(weights, dtype=float)
    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
    if score not in ("peak", "energy"):
        raise ValueError(f"histogram score must be 'peak' or 'energy', not {score!r}")
    nb = int(math.ceil(2 * extent / bin)) + 2
    out = np.zeros(na)
    for coord in (c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]):  # field x, field y
        u = np.clip((coord + extent) / bin, 0, nb - 2)
        b0 = np.floor(u).astype(np.int64)
        f = u - b0
        base = (np.arange(na) * nb)[:, None]
        hist = np.bincount((base + b0).ravel(), (w * (1 - f)).ravel(), minlength=na * nb)
        hist += np.bincount((base + b0 + 1).ravel(), (w * f).ravel(), minlength=na * nb)
        hist = hist.reshape(na, nb)
        out += hist.max(axis=1) if score == "peak" else np.square(hist).sum(axis=1)
    return out


def histogram_heading(points: np.ndarray, last_heading: float, *, window: float = math.radians(40),
                      step: float = math.radians(0.5), bin: float = 0.05,
                      max_distance: float = 4.0, min_points: int = 10,
                      score: str = "peak") -> tuple[float, float]:
    """Heading (rad) from the line points (N, 2, robot frame) within ``window`` of the last
    heading, and its score's sharpness (peak over mean, >= 1; 0 if too few points).
    Returns (nan, 0) with fewer than ``min_points`` points within ``max_distance``."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    p = p[np.hypot(p[:, 0], p[:, 1]) <= max_distance]
    if len(p) < min_points:
        return math.nan, 0.0
    n = int(round(window / step))
    offsets = np.arange(-n, n + 1) * step
    scores = histogram_scores(p, last_heading + offsets, bin=bin, extent=max_distance + bin,
                              score=score)
    best = int(np.argmax(scores))
    off = offsets[best]
    if 0 < best < len(scores) - 1:
        lo, mid, hi = scores[best - 1], scores[best], scores[best + 1]
        den = lo - 2 * mid + hi
        if den < 0:
            off += float(np.clip(0.5 * (lo - hi) / den, -0.5, 0.5)) * step
    sharp = float(scores[best] / max(scores.mean(), 1e-12))
    return float(wrap_angle(last_heading + off)), sharp


# s: an imu.csv row this near a frame gives the frame's heading (the particle filter's,
# ``frame_headings``)
IMU_STAMP_TOLERANCE = 0.05


def frame_headings(imu: dict | None, stamps: np.ndarray, collision: np.ndarray,
                   sigma: float | None) -> list:
    """Per frame the IMU's field heading (yaw, ``sigma``) rad, or None: without
    ``imu_heading_sigma``, without an imu.csv row within IMU_STAMP_TOLERANCE of the frame,
    and on collision frames (the yaw jolts)."""
    if sigma is None or imu is None:
        return [None] * len(stamps)
    yaw, _col = imu_per_frame(imu, stamps, IMU_STAMP_TOLERANCE)
    return [(float(y), float(sigma)) if np.isfinite(y) and not c else None
            for y, c in zip(yaw, collision)]


def heading_log_likelihood(theta: np.ndarray, heading: tuple[float, float]) -> np.ndarray:
    """log N(theta; yaw, sigma^2) of poses' headings under the IMU's field heading (yaw, sigma),
    up to a constant: the term a frame's IMU heading adds to its particles' weights."""
    yaw, sigma = heading
    return -0.5 * (wrap_angle(np.asarray(theta, float) - yaw) / sigma) ** 2
