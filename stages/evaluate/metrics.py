"""Localisation errors against ground truth: stamp matching, per-frame errors, statistics.

Conventions (also written into every report.json under ``conventions``):

- Frames are matched to truth rows by stamp: the nearest truth stamp within a tolerance. A frame
  with no truth row that close is *unmatched*; it is counted but takes no part in the errors.
  Truth rows with a non-finite x, y or theta (e.g. motion capture lost the robot) are dropped
  before matching. Several frames may match the same truth row (truth at a lower rate).
- A frame the method could not localise (``failed``) is a failure, never a pose: its position
  and heading errors are infinite. Failures therefore never count as "within" a threshold, they
  make ``max`` and ``mean`` infinite, and they push the median and p90 up (a median of inf means
  more than half of the matched frames failed). The same statistics over the localised (not
  failed) matched frames are given separately.
- Percentiles interpolate linearly between order statistics as numpy's default does; an
  interpolation that touches an infinite value gives inf.
- Heading error is the absolute difference wrapped to [0, pi] (an error of 350 deg is 10 deg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stages.common.errors import FieldlocError
from stages.common.geometry import wrap_angle


@dataclass
class FrameErrors:
    """Per-frame comparison of a pose track with truth. Arrays of length N (frames).

    ``truth_index`` is -1 for unmatched frames; their truth columns and errors are NaN.
    ``position_error`` and ``heading_error`` (m, rad) are inf for matched failed frames."""

    name: np.ndarray
    stamp: np.ndarray
    x: np.ndarray
    y: np.ndarray
    theta: np.ndarray
    failed: np.ndarray
    mode: np.ndarray
    runtime: np.ndarray  # s
    truth_index: np.ndarray
    truth_stamp: np.ndarray
    truth_x: np.ndarray
    truth_y: np.ndarray
    truth_theta: np.ndarray
    position_error: np.ndarray  # m
    heading_error: np.ndarray  # rad, in [0, pi]

    @property
    def matched(self) -> np.ndarray:
        return self.truth_index >= 0

    def __len__(self) -> int:
        return len(self.stamp)


def match_by_stamp(stamps, truth_stamps, tolerance: float) -> np.ndarray:
    """For each stamp, the index of the nearest truth stamp if it is within ``tolerance`` (s),
    else -1. ``truth_stamps`` need not be sorted; on a tie the earlier truth stamp wins."""
    stamps = np.asarray(stamps, dtype=float)
    truth_stamps = np.asarray(truth_stamps, dtype=float)
    out = np.full(stamps.shape, -1, dtype=np.int64)
    if truth_stamps.size == 0 or stamps.size == 0:
        return out
    order = np.argsort(truth_stamps, kind="stable")
    ts = truth_stamps[order]
    right = np.searchsorted(ts, stamps, side="left").clip(0, len(ts) - 1)
    left = (right - 1).clip(0, len(ts) - 1)
    d_left = np.abs(stamps - ts[left])
    d_right = np.abs(ts[right] - stamps)
    nearest = np.where(d_left <= d_right, left, right)
    dist = np.minimum(d_left, d_right)
    ok = np.isfinite(stamps) & (dist <= tolerance)
    out[ok] = order[nearest[ok]]
    return out


def heading_error(theta, truth_theta) -> np.ndarray:
    """Absolute heading difference (rad) wrapped to [0, pi]."""
    return np.abs(wrap_angle(np.asarray(theta, float) - np.asarray(truth_theta, float)))


def frame_errors(columns: dict, truth: dict, tolerance: float) -> FrameErrors:
    """Match a pose track (columns as read by ``read_poses``) with truth (``read_csv(...,
    "truth")``) and compute per-frame errors. Raises FieldlocError when no frame matches."""
    stamp = np.asarray(columns["stamp"], dtype=float)
    n = len(stamp)
    if n == 0:
        raise FieldlocError("the poses file holds no frames")
    t_ok = np.isfinite(truth["stamp"]) & np.isfinite(truth["x"]) & np.isfinite(truth["y"])
    t_ok &= np.isfinite(truth["theta"])
    if not np.any(t_ok):
        raise FieldlocError("the truth file holds no rows with finite stamp, x, y and theta")
    t_rows = np.flatnonzero(t_ok)
    idx_ok = match_by_stamp(stamp, truth["stamp"][t_rows], tolerance)
    idx = np.where(idx_ok >= 0, t_rows[idx_ok.clip(0)], -1)
    matched = idx >= 0
    if not np.any(matched):
        raise FieldlocError(
            f"no frame has a truth stamp within {tolerance:g} s (stamp_tolerance): frames span"
            f" {np.nanmin(stamp):.3f}..{np.nanmax(stamp):.3f} s, truth spans"
            f" {np.min(truth['stamp'][t_rows]):.3f}..{np.max(truth['stamp'][t_rows]):.3f} s"
        )

    def pick(col):
        v = np.full(n, np.nan)
        v[matched] = np.asarray(truth[col], float)[idx[matched]]
        return v

    x = np.asarray(columns["x"], float)
    y = np.asarray(columns["y"], float)
    theta = np.asarray(columns["theta"], float)
    failed = np.asarray(columns["failed"], bool).copy()
    # A pose that is not finite was not localised, whatever the flag says.
    failed |= ~(np.isfinite(x) & np.isfinite(y) & np.isfinite(theta))
    tx, ty, tth = pick("x"), pick("y"), pick("theta")
    pos = np.full(n, np.nan)
    head = np.full(n, np.nan)
    ok = matched & ~failed
    pos[ok] = np.hypot(x[ok] - tx[ok], y[ok] - ty[ok])
    head[ok] = heading_error(theta[ok], tth[ok])
    pos[matched & failed] = np.inf
    head[matched & failed] = np.inf
    mode = columns.get("mode")
    runtime = columns.get("runtime")
    names = columns.get("name")
    return FrameErrors(
        name=np.asarray(names if names is not None else [str(i) for i in range(n)], dtype=object),
        stamp=stamp,
        x=x,
        y=y,
        theta=theta,
        failed=failed,
        mode=np.asarray(mode if mode is not None else [""] * n, dtype=object),
        runtime=np.asarray(runtime if runtime is not None else np.full(n, np.nan), float),
        truth_index=idx,
        truth_stamp=pick("stamp"),
        truth_x=tx,
        truth_y=ty,
        truth_theta=tth,
        position_error=pos,
        heading_error=head,
    )


def percentile(values, q: float) -> float:
    """The q-th percentile (0..100) with linear interpolation between order statistics, where
    infinite values are allowed (an interpolation touching inf is inf). NaN if empty."""
    v = np.sort(np.asarray(values, dtype=float).ravel())
    if v.size == 0:
        return math.nan
    pos = (v.size - 1) * q / 100.0
    lo = int(math.floor(pos))
    hi = min(lo + 1, v.size - 1)
    frac = pos - lo
    if frac == 0.0 or v[lo] == v[hi]:
        return float(v[lo])
    if not (math.isfinite(v[lo]) and math.isfinite(v[hi])):
        return math.inf
    return float(v[lo] + (v[hi] - v[lo]) * frac)


def error_stats(values, scale: float = 1.0) -> dict:
    """median, mean, p90, max and rmse of ``values * scale`` (inf allowed; NaN if empty)."""
    v = np.asarray(values, dtype=float).ravel() * scale
    if v.size == 0:
        return {k: math.nan for k in ("median", "mean", "p90", "max", "rmse")}
    return {
        "median": percentile(v, 50),
        "mean": float(np.mean(v)),
        "p90": percentile(v, 90),
        "max": float(np.max(v)),
        "rmse": float(np.sqrt(np.mean(v * v))),
    }


def threshold_key(t: float) -> str:
    """'0.1' for 0.1 m: the key of a threshold in ``within``."""
    return f"{float(t):g}"


def within_shares(position_error, thresholds) -> dict:
    """Share (0..1) of the given frames whose position error is <= each threshold (m).
    Failures (inf) are never within."""
    e = np.asarray(position_error, dtype=float)
    return {
        threshold_key(t): (float(np.mean(e <= t)) if e.size else math.nan) for t in thresholds
    }


def mirrored_frames(fe: FrameErrors, threshold: float) -> int:
    """Frames whose estimate is off by more than ``threshold`` but whose mirror image under the
    field's 180 deg symmetry is within it: the symmetric-field confusion."""
    ok = fe.matched & ~fe.failed
    mx, my = -fe.x[ok], -fe.y[ok]
    mirror_err = np.hypot(mx - fe.truth_x[ok], my - fe.truth_y[ok])
    return int(np.sum((fe.position_error[ok] > threshold) & (mirror_err <= threshold)))


def summarize(fe: FrameErrors, thresholds) -> dict:
    """The numbers of a report: counts, error statistics (failures as inf, and over localised
    frames only), shares within thresholds, runtime, modes."""
    m = fe.matched
    ok = m & ~fe.failed
    deg = 180.0 / math.pi
    rt = fe.runtime[np.isfinite(fe.runtime)] * 1000.0
    dt = np.abs(fe.stamp[m] - fe.truth_stamp[m])
    modes, counts = np.unique(fe.mode.astype(str), return_counts=True)
    thresholds = sorted(float(t) for t in thresholds)
    return {
        "frames": int(len(fe)),
        "matched": int(m.sum()),
        "unmatched": int((~m).sum()),
        "failures": int(fe.failed.sum()),
        "matched_failures": int((m & fe.failed).sum()),
        "failure_rate": float(fe.failed.mean()),
        "position_error_m": error_stats(fe.position_error[m]),
        "heading_error_deg": error_stats(fe.heading_error[m], deg),
        "within": within_shares(fe.position_error[m], thresholds),
        "localised": {
            "frames": int(ok.sum()),
            "position_error_m": error_stats(fe.position_error[ok]),
            "heading_error_deg": error_stats(fe.heading_error[ok], deg),
            "within": within_shares(fe.position_error[ok], thresholds),
        },
        "mirrored": mirrored_frames(fe, max(thresholds)) if thresholds else 0,
        "runtime_ms": {
            "median": percentile(rt, 50),
            "mean": float(np.mean(rt)) if rt.size else math.nan,
            "p90": percentile(rt, 90),
            "max": float(np.max(rt)) if rt.size else math.nan,
        },
        "stamp_difference_ms": {
            "median": percentile(dt * 1000.0, 50),
            "max": float(np.max(dt) * 1000.0),
        },
        "modes": {str(k) or "(none)": int(c) for k, c in zip(modes, counts)},
    }
