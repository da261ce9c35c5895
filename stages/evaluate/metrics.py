"""Localisation errors against ground truth: stamp matching, per-frame errors, statistics.

Conventions (also written into every report.json under ``conventions``):

- Frames are matched to truth rows by stamp: the nearest truth stamp within a tolerance. A frame
  with no truth row that close is *unmatched*; it is counted but takes no part in the errors.
  Truth rows with a non-finite x, y or theta (e.g. motion capture lost the robot) are dropped
  before matching. Several frames may match the same truth row (truth at a lower rate).
- A frame the method could not localise (``failed``) is a failure, never a pose: its position
  and heading errors are infinite. Failures therefore never count as "within" a threshold, they
  make ``max`` and ``mean`` infinite, and they push the median and p90 up (a median of inf means
  more than half of the matched frames failed). The same statistics over the localised
  matched frames (those with an accepted pose, see below) are given separately.
- Percentiles interpolate linearly between order statistics as numpy's default does; an
  interpolation that touches an infinite value gives inf.
- Heading error is the absolute difference wrapped to [0, pi] (an error of 350 deg is 10 deg).
- Hypotheses (poses v2): a frame that did not fail has a ranked list of hypotheses, the first
  being its pose, with probabilities; its confidence is the probability of the first. A frame
  is *accepted* when the method's confidence reached its acceptance threshold. The error
  statistics and the within shares count every matched frame without an accepted pose as a
  failure (infinite error); ``hypotheses`` gives the accuracy of the top hypothesis over all
  frames that have one (accepted or not), of the best of the top K, and the share of frames
  whose truth is the mirror image of the top hypothesis.
- Calibration: over the matched frames that have a hypothesis, a frame is *correct* when its
  top hypothesis lies within ``calibration_threshold`` (0.4 m) of the truth. ``reliability``
  bins the confidence in tenths and gives per bin the frames, the mean confidence and the
  observed share of correct frames (with its binomial standard error); ``auroc`` is the area
  under the ROC curve of the confidence as a detector of correct frames (equivalently of
  1 - confidence for "error > threshold"): the probability that a correct frame has a higher
  confidence than a wrong one, ties counting half; NaN when all frames are correct or all
  wrong. ``confidently_wrong`` counts accepted frames more than 1 m off.
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
    # poses v2 (v1 files: accepted = not failed, one hypothesis per frame)
    accepted: np.ndarray | None = None  # bool
    confidence: np.ndarray | None = None  # probability of the top hypothesis
    top_error: np.ndarray | None = None  # m, position error of the top hypothesis (inf: none)
    best_error: np.ndarray | None = None  # m, of the best of the frame's hypotheses
    top_mirrored: np.ndarray | None = None  # bool, the truth is the top's mirror image

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


def frame_errors(columns: dict, truth: dict, tolerance: float,
                 mirror_threshold: float = 0.4, *, up_to_mirror: bool = False) -> FrameErrors:
    """Match a pose track (columns as read by ``read_poses``) with truth (``read_csv(...,
    "truth")``) and compute per-frame errors. Raises FieldlocError when no frame matches.

    ``up_to_mirror``: judge what a frame decides on a point-symmetric field (the pose up to
    the field's 180 deg turn, stages.localize.symmetry): each frame is scored against the
    truth or its mirror image (-x, -y, theta + pi), whichever its pose is nearer, and its
    acceptance and confidence are ``accepted_up_to_mirror`` and ``confidence_up_to_mirror``."""
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
    if up_to_mirror:  # the truth's mirror image where the pose is nearer to it
        flip = np.hypot(x + tx, y + ty) < np.hypot(x - tx, y - ty)
        tx, ty = np.where(flip, -tx, tx), np.where(flip, -ty, ty)
        tth = np.where(flip, wrap_angle(tth + math.pi), tth)
    pos = np.full(n, np.nan)
    head = np.full(n, np.nan)
    ok = matched & ~failed
    pos[ok] = np.hypot(x[ok] - tx[ok], y[ok] - ty[ok])
    head[ok] = heading_error(theta[ok], tth[ok])
    pos[matched & failed] = np.inf
    head[matched & failed] = np.inf
    accepted_col = "accepted_up_to_mirror" if up_to_mirror else "accepted"
    accepted = np.asarray(columns.get(accepted_col, columns.get("accepted", ~failed)),
                          bool) & ~failed
    top_error = pos.copy()
    # the statistics count frames without an accepted pose as failures
    pos[matched & ~accepted] = np.inf
    head[matched & ~accepted] = np.inf
    hyps = columns.get("hypotheses")
    if hyps is None:
        hyps = np.stack([x, y, theta, np.asarray(columns.get("confidence", ~failed), float)],
                        axis=1)[:, None, :]
    hyps = np.asarray(hyps, float)
    hd = np.hypot(hyps[..., 0] - tx[:, None], hyps[..., 1] - ty[:, None])
    if up_to_mirror:
        hd = np.minimum(hd, np.hypot(hyps[..., 0] + tx[:, None], hyps[..., 1] + ty[:, None]))
    hd[~np.isfinite(hd)] = np.inf
    best_error = np.where(matched, hd.min(axis=1), np.nan)
    best_error[matched & failed] = np.inf
    top_mirrored = ok & (np.hypot(-x - tx, -y - ty) <= mirror_threshold) & (
        top_error > mirror_threshold)
    conf_col = np.asarray(columns.get("confidence", np.where(failed, 0.0, 1.0)), float)
    if up_to_mirror:
        conf_col = np.asarray(columns.get("confidence_up_to_mirror", conf_col), float)
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
        accepted=accepted,
        confidence=conf_col,
        top_error=top_error,
        best_error=best_error,
        top_mirrored=top_mirrored,
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


def start_half_contradicted(fe: FrameErrors, attrs: dict, margin: float) -> str | None:
    """One line when the poses' conf gave a ``start_half`` (own: x < 0, opponent: x > 0) and
    the truth starts on the other half, more than ``margin`` m from the halfway line (nearer,
    the half is no claim a frame could contradict). No frame of a symmetric field can tell
    a wrong start half from a right one; the truth can. None otherwise."""
    half = (attrs.get("conf") or {}).get("start_half")
    if half not in ("own", "opponent") or not fe.matched.any():
        return None
    first = np.flatnonzero(fe.matched)[np.argmin(fe.stamp[fe.matched])]
    x0 = float(fe.truth_x[first])
    if not (x0 > margin if half == "own" else x0 < -margin):
        return None
    m = fe.matched & ~fe.failed
    mirror = int(np.sum(fe.top_mirrored[m])) if fe.top_mirrored is not None else 0
    return (f"the run was given start_half {half}, but the truth starts at x = {x0:.2f} m, in"
            f" the {'opponent' if x0 > 0 else 'own'} half; {mirror} of {int(m.sum())} frames'"
            " top hypotheses are the truth's mirror image (localise again with --start-half"
            " any or the other half)")


def reliability(confidence, correct, bins: int = 10) -> list[dict]:
    """Reliability table: confidence in ``bins`` equal bins over [0, 1] (the last closed);
    per non-empty bin the frames, the mean confidence, the observed share of correct frames
    and its binomial standard error."""
    c = np.asarray(confidence, float)
    ok = np.asarray(correct, bool)
    k = np.clip((c * bins).astype(int), 0, bins - 1)
    out = []
    for b in range(bins):
        sel = k == b
        n = int(sel.sum())
        if not n:
            continue
        share = float(ok[sel].mean())
        out.append({"bin": [b / bins, (b + 1) / bins], "frames": n,
                    "confidence": float(c[sel].mean()), "observed": share,
                    "stderr": float(math.sqrt(max(share * (1 - share), 0.25 / n) / n))})
    return out


def auroc(score, positive) -> float:
    """Area under the ROC curve of ``score`` as a detector of ``positive``: the probability
    that a positive scores higher than a negative, ties counting half (Mann-Whitney U / n1 n0).
    NaN without positives or without negatives."""
    s = np.asarray(score, float)
    y = np.asarray(positive, bool)
    n1, n0 = int(y.sum()), int((~y).sum())
    if n1 == 0 or n0 == 0:
        return math.nan
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(len(s))
    sorted_s = s[order]
    # average ranks of ties
    i = 0
    while i < len(s):
        j = i
        while j + 1 < len(s) and sorted_s[j + 1] == sorted_s[i]:
            j += 1
        ranks[order[i:j + 1]] = 0.5 * (i + j) + 1.0
        i = j + 1
    u = ranks[y].sum() - n1 * (n1 + 1) / 2.0
    return float(u / (n1 * n0))


def calibration(fe: FrameErrors, threshold: float = 0.4, bins: int = 10) -> dict:
    """Reliability and AUROC of the confidence (module doc), over the matched frames that
    have a hypothesis."""
    sel = fe.matched & ~fe.failed
    correct = fe.top_error[sel] <= threshold
    conf = fe.confidence[sel]
    table = reliability(conf, correct, bins)
    gaps = [abs(r["observed"] - r["confidence"]) for r in table]
    return {"threshold_m": float(threshold), "frames": int(sel.sum()),
            "correct": int(correct.sum()), "auroc": auroc(conf, correct),
            "max_gap": float(max(gaps)) if gaps else math.nan,
            "brier": float(np.mean((conf - correct) ** 2)) if sel.any() else math.nan,
            "reliability": table}


def summarize(fe: FrameErrors, thresholds) -> dict:
    """The numbers of a report: counts, error statistics (failures as inf, and over localised
    frames only), shares within thresholds, runtime, modes."""
    m = fe.matched
    ok = m & fe.accepted  # localised: an accepted pose (not failed, confidence reached)
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
        "accepted": int((m & fe.accepted).sum()),
        "not_accepted": int((m & ~fe.accepted).sum()),
        "hypotheses": {
            "frames": int((m & ~fe.failed).sum()),
            "top_within": within_shares(fe.top_error[m], thresholds),
            "best_within": within_shares(fe.best_error[m], thresholds),
            "top_mirrored": float(fe.top_mirrored[m].mean()) if m.any() else math.nan,
        },
        "calibration": calibration(fe, max(thresholds) if thresholds else 0.4),
        "confidently_wrong": int((m & fe.accepted & (fe.top_error > 1.0)).sum()),
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
