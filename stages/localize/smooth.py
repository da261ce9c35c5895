"""Offline smoothing (``smooth: true``, ``fieldloc localize --smooth``): every frame decided with
the whole recording, not only with the frames before it.

A causal localiser decides frame t from frames 0..t, as a robot must; a wrong first fix can then
hold for tens of frames although later frames and the odometry between them rule it out
(docs/lut-belief.md: the evidence bound). An offline tool has the whole recording. This module
runs two passes over a method's candidates (docs/smoothing.md):

1. **Discrete pass** (a hidden Markov model over candidate poses; Rabiner 1989). Per frame a
   short list of candidate poses, each with the frame's tempered negative log-likelihood
   (``nll``, the method's own, in nats) and covariance: the method's global search on every
   frame, and two beams (``candidate_sets``): every candidate of the previous frame moved by the
   odometry and fixed again in its basin (the fix combined with where the odometry moved it,
   ``_fused``: along the only lines a frame sees, a fix says nothing), the
   ``MAX_CANDIDATES`` best kept by the forward message, and the same from the next frame by
   the backward message, so a place found once is followed through the whole recording and
   one the first frames misjudge is carried back.
   Candidates in one basin (``SAME_BASIN_M``, ``SAME_BASIN_RAD``) are one. Transitions: the
   odometry increment with its noise plus both candidates' spreads (``state_cov``: their
   covariances, capped), a Gaussian, mixed with an outlier floor (the method's kidnap
   probability: the robot is anywhere on the world the tables cover, any heading: slips,
   kidnaps, placements). Forward-backward gives each candidate's posterior from the whole
   recording; Viterbi the most probable path. Where the scorer can, the camera's distance error
   is then learnt again from the path and the pass run again with it (``_recalibrated``).
   **Correlated frames.** Consecutive frames see the same lines from nearly the same place
   through the same calibration error, so the log-likelihood ratio between two places
   changes slowly from frame to frame. Summed as if independent, n frames count as n pieces
   of evidence where they hold about n / tau (tau the ratio's integrated autocorrelation
   time; Sokal 1997), and a look-alike that every frame favours by a nat or two outweighs the
   jump model within a few seconds. Each frame's nll is divided by T
   (``evidence_temperature``: a method's correlation time over the frame interval), the
   magnitude adjustment of a composite likelihood (Varin, Reid and Firth 2011). The
   transitions are not divided, so T is set below tau where the full time let them lead the
   path astray (lut.SMOOTH_CORRELATION_S).
   A frame's place is the posterior mass of the candidates whose fix covers its smoothed
   pose (``basin_mass``): on a point-symmetric field without a field-aligned heading a pose and
   its mirror share it, as in the causal methods.
2. **Continuous pass** (pose_graph.py): the path refined as a factor graph (GTSAM), with
   marginal covariances; frames without a fix get their pose from the odometry between fixed
   frames.

A frame's confidence is the probability that the robot stood within ``CONFIDENCE_RADIUS_M``
of its smoothed pose: its place's posterior mass times the probability, under its marginal
covariance, that the pose lies that near (``_inside``). A path the recording's frames favour
but pin loosely (frames of one to three observations, along a single line) is then the right
place at a wide pose, not a sure one.

The output is the poses schema with mode ``smoothed`` (frames with no vision of their own:
flag ``odometry-only``; frames the pose graph moved out of their path candidate's place:
``moved-by-graph``), ranked hypotheses from the posteriors, so evaluate, export, report
and batch read it unchanged.

A method supports smoothing by a *scorer* (``Scorer``): its global candidates of a frame and
its fixes from given start poses, both as ``FrameCandidates``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..common.geometry import inverse, wrap_angle
from ..common.poses_file import PoseTrack
from .kalman import model_sigma_xy
from .motion_model import Motion, moved
from .tracking import SAME_BASIN_M, SAME_BASIN_RAD

log = logging.getLogger(__name__)

# candidates kept per frame, best nll first: the global search's separated minima, their mirror
# images and what the neighbours' candidates lead to (a field has a few dozen look-alike basins
# at most; more are poses no frame supports)
MAX_CANDIDATES = 24
# a frame's confidence: the posterior mass of candidates this close to the path's (the basin
# of the pose: farther candidates are other places)
CONFIDENCE_RADIUS_M = 0.5
CONFIDENCE_RADIUS_RAD = 0.3
# ... or within this squared Mahalanobis distance of the candidate's own position covariance
# (chi-square, 2 degrees of freedom, 99 %)
COVER_GATE = 9.21
# A candidate stands for the state (the pose) in the transitions, up to how far a fix lies from
# the pose it fixes: its covariance, but no wider than this (m, rad). Along a line a fix's own
# covariance is metres wide (the frame says nothing there), and a chain of such candidates
# would slide along the line at no cost; each frame's candidate is fixed within a few table
# cells of where the odometry moves its neighbour (the scorers' local search), so the spread
# between a candidate and the pose is of that order.
STATE_SIGMA_M = 0.1
# rounds of learning the distance error from the path and fixing the path with it
# (_recalibrated): the estimate settles within three on the tuning renders
CALIBRATION_ROUNDS = 3
RECALIBRATE = True  # learn the distance error from the path (scorers that can)
STATE_SIGMA_RAD = 0.05
# m: how far from where the odometry moves a neighbour's candidate a scorer's local fix looks
# (lut: the half-width of the table search's window; fit: the spread of a Gaussian prior on
# the position, as its tracks' fits have). The odometry's slip over a frame is centimetres; a
# few table cells also find the basin's minimum when the candidate sat on its rim. Unbounded,
# a fit in a frame that sees a few points slid up to 2 m along the lines (tuning seed 21 of
# omni-hard, frames 51-64) and the chain of candidates at the truth broke.
LOCAL_REACH_M = 0.3


@dataclass
class FrameCandidates:
    """Candidate poses of one frame: ``poses`` (K, 3) field frame, ``nll`` (K,) the frame's
    tempered negative log-likelihood at each (nats), ``cov`` (K, 3, 3) each fix's covariance
    (field frame), ``error`` (K,) the method's error term (recorded as poses' ``error``).
    ``start`` (K,) int, local fixes only (Scorer.local_candidates): the index of the start
    each fix was started from; None otherwise."""

    poses: np.ndarray
    nll: np.ndarray
    cov: np.ndarray
    error: np.ndarray
    start: np.ndarray | None = None

    def __len__(self):
        return len(self.nll)

    @classmethod
    def empty(cls) -> FrameCandidates:
        return cls(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3, 3)), np.zeros(0))

    @classmethod
    def concat(cls, parts: list[FrameCandidates]) -> FrameCandidates:
        parts = [p for p in parts if p is not None and len(p)]
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, k) for p in parts])
                     for k in ("poses", "nll", "cov", "error")))

    @classmethod
    def from_rows(cls, rows: list, start=None) -> FrameCandidates:
        """From (pose, nll, cov, error) rows; ``start``: each row's start index (local
        fixes), or None."""
        if not rows:
            return cls.empty()
        poses, nll, cov, err = zip(*rows)
        return cls(np.array(poses, float).reshape(-1, 3), np.array(nll, float),
                   np.array(cov, float).reshape(-1, 3, 3), np.array(err, float),
                   None if start is None else np.asarray(start, dtype=np.int64))

    def state_cov(self) -> np.ndarray:
        """(K, 3, 3) the covariances with their position eigenvalues clipped to
        STATE_SIGMA_M^2 and the heading variance to STATE_SIGMA_RAD^2 (the transitions')."""
        out = np.array(self.cov, float, copy=True).reshape(-1, 3, 3)
        if len(out):
            w, v = np.linalg.eigh(0.5 * (out[:, :2, :2] + np.swapaxes(out[:, :2, :2], 1, 2)))
            w = np.clip(w, 0.0, STATE_SIGMA_M ** 2)
            out[:, :2, :2] = np.einsum("kij,kj,klj->kil", v, w, v)
            out[:, 2, 2] = np.minimum(out[:, 2, 2], STATE_SIGMA_RAD ** 2)
        return out

    def take(self, idx) -> FrameCandidates:
        return FrameCandidates(self.poses[idx], self.nll[idx], self.cov[idx], self.error[idx],
                               None if self.start is None else self.start[idx])

    def distinct(self, limit: int = MAX_CANDIDATES) -> FrameCandidates:
        """One candidate per basin (the lowest nll of those within SAME_BASIN_M and
        SAME_BASIN_RAD of each other), at most ``limit``, best first."""
        order = np.argsort(self.nll, kind="stable")
        order = order[np.isfinite(self.nll[order])]
        p = self.poses[order]
        same = ((np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
                 < SAME_BASIN_M)
                & (np.abs(wrap_angle(p[:, None, 2] - p[None, :, 2])) < SAME_BASIN_RAD))
        keep: list[int] = []
        for k in range(len(order)):
            if keep and same[k, keep].any():
                continue
            keep.append(k)
            if len(keep) >= limit:
                break
        return self.take(order[np.array(keep, dtype=int)])


class Scorer(Protocol):
    """What a method gives the smoother (module doc). ``frames``: how many; ``failed(i)``: the
    frame has too little to be fixed (its reason) or None; ``global_candidates(i)`` and
    ``local_candidates(i, starts)``: FrameCandidates, the local ones with ``start`` naming
    each row's start (any number of rows per start); ``mirrored``: whether a pose's mirror
    image explains a frame as well (a point-symmetric field without a field-aligned
    heading)."""

    frames: int
    mirrored: bool

    def failed(self, i: int) -> str | None: ...

    def global_candidates(self, i: int) -> FrameCandidates: ...

    def local_candidates(self, i: int, starts: np.ndarray) -> FrameCandidates: ...


def motion_of(increments: np.ndarray, has_odometry: np.ndarray, stamps: np.ndarray,
              fusion: dict, collision: np.ndarray) -> Motion:
    """The run's Motion from the sensors and a method's ``fusion`` noise (kalman.FusionParams:
    slip proportional to the increment, never zero; where a frame has no odometry row, a
    random walk of up to ``max_speed`` / ``max_turn_rate`` over the frame interval). Where the
    IMU flags a collision the wheels slip or are blocked: the increment's position noise grows
    by the fusion's process noise (``model_xy`` per second, growing with the speed: how far
    the robot may deviate from the motion it reads, the causal fusion's prediction), its
    heading is free up to ``max_turn_rate``. A collision is not a kidnap: a random walk at
    ``max_speed`` over a collision of five frames let the path wander 1.5 m at one sigma,
    onto a look-alike the frames after it then held (fit, omni-hard tuning seed 211: the
    penalty area's line taken for the halfway line after a collision, 20 frames at 0.999)."""
    n = len(increments)
    has = np.asarray(has_odometry, bool)
    inc = np.where(has[:, None], np.asarray(increments, float), 0.0)
    dt = np.diff(np.asarray(stamps, float), prepend=float(stamps[0]) if n else 0.0)
    dist = np.hypot(inc[:, 0], inc[:, 1])
    sxy = np.maximum(fusion["odometry_min_xy"], fusion["odometry_xy"] * dist)
    sth = np.maximum(fusion["odometry_min_theta"], fusion["odometry_theta"] * np.abs(inc[:, 2]))
    hit = has & np.asarray(collision, bool)
    speed = dist / np.maximum(dt, 1e-3)
    model = model_sigma_xy(fusion["model_xy"], fusion["model_min_xy"], dt, speed)
    sxy = np.where(hit, np.hypot(sxy, model), sxy)
    sth = np.where(hit, np.maximum(sth, fusion["max_turn_rate"] * dt), sth)
    sxy = np.where(has, sxy, np.maximum(sxy, fusion["max_speed"] * dt))
    sth = np.where(has, sth, np.maximum(sth, fusion["max_turn_rate"] * dt))
    cov = np.zeros((n, 3, 3))
    cov[:, 0, 0] = cov[:, 1, 1] = sxy**2
    cov[:, 2, 2] = sth**2
    return Motion(inc, cov)


def evidence_temperature(stamps: np.ndarray, correlation_s: float) -> float:
    """T, the power 1/T to which the smoother raises each frame's likelihood (its nll divided
    by T): the frames over which a frame's evidence is correlated, ``correlation_s`` over the
    recording's median frame interval, at least 1 (module doc, "Correlated frames")."""
    s = np.asarray(stamps, float)
    dt = np.diff(s[np.isfinite(s)])
    dt = dt[dt > 0]
    if correlation_s <= 0 or not len(dt):
        return 1.0
    return max(1.0, float(correlation_s) / float(np.median(dt)))


def _tempered(cands: FrameCandidates, temperature: float) -> FrameCandidates:
    """``cands`` with their nll divided by ``temperature`` (evidence_temperature)."""
    if temperature == 1.0 or not len(cands):
        return cands
    return FrameCandidates(cands.poses, cands.nll / temperature, cands.cov, cands.error,
                           cands.start)


@dataclass(frozen=True)
class Transition:
    """The transition model's constants: ``log_outlier``, the log density of a jump anywhere
    (kidnap probability over the world's area and a full turn), ``log_keep`` = log(1 -
    kidnap probability)."""

    log_outlier: float
    log_keep: float

    @classmethod
    def of(cls, kidnap_probability: float, area: float) -> Transition:
        p = min(max(float(kidnap_probability), 1e-12), 0.5)
        return cls(math.log(p) - math.log(area * 2 * math.pi), math.log1p(-p))


def transition_log(a: FrameCandidates, b: FrameCandidates, step: tuple, model: Transition
                   ) -> np.ndarray:
    """log p(b_j | a_i) (len(a), len(b)): b_j against a_i moved by the step's increment, a
    Gaussian in x, y, theta with the step's covariance (rotated into the field frame at a_i)
    plus both candidates' state covariances (FrameCandidates.state_cov), mixed with the
    outlier floor."""
    inc, q = step
    pred = moved(a.poses, inc[0], inc[1], inc[2])  # (A, 3)
    th = a.poses[:, 2]
    c, s = np.cos(th), np.sin(th)
    # the step's xy covariance in the field frame at each a_i
    qxx = c * c * q[0, 0] - 2 * c * s * q[0, 1] + s * s * q[1, 1]
    qyy = s * s * q[0, 0] + 2 * c * s * q[0, 1] + c * c * q[1, 1]
    qxy = c * s * (q[0, 0] - q[1, 1]) + (c * c - s * s) * q[0, 1]
    ra, rb = a.state_cov(), b.state_cov()
    sxx = qxx[:, None] + ra[:, 0, 0][:, None] + rb[:, 0, 0][None, :]
    syy = qyy[:, None] + ra[:, 1, 1][:, None] + rb[:, 1, 1][None, :]
    sxy = qxy[:, None] + ra[:, 0, 1][:, None] + rb[:, 0, 1][None, :]
    stt = q[2, 2] + ra[:, 2, 2][:, None] + rb[:, 2, 2][None, :]
    dx = b.poses[None, :, 0] - pred[:, None, 0]
    dy = b.poses[None, :, 1] - pred[:, None, 1]
    dt = wrap_angle(b.poses[None, :, 2] - pred[:, None, 2])
    det = np.maximum(sxx * syy - sxy * sxy, 1e-12)
    m2 = (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det + dt * dt / stt
    log_gauss = -0.5 * m2 - 0.5 * np.log(det) - 0.5 * np.log(stt) - 1.5 * math.log(2 * math.pi)
    return np.logaddexp(model.log_keep + log_gauss, model.log_outlier)


@dataclass
class Passes:
    """What the discrete pass gives: per frame with candidates its FrameCandidates, their
    posterior (K,) and the path's candidate index."""

    frames: list  # index of each frame with candidates
    candidates: list  # FrameCandidates per such frame
    posterior: list  # (K,) per such frame
    path: np.ndarray  # (len(frames),) candidate index per such frame


def candidate_sets(scorer: Scorer, motion: Motion, model: Transition, log_prior0=None,
                   temperature: float = 1.0) -> tuple[list[int], list[FrameCandidates]]:
    """Every frame's candidates (module doc): the global search's, and two beams that follow
    them through the recording. The forward beam fixes the previous frame's beam again where
    the odometry moves it and keeps the ``MAX_CANDIDATES`` best by the filtered posterior
    (the forward message); the backward beam does the same from the next frame, ranked by
    the backward message. A place the first frames misjudge drops out of the forward beam
    and is carried back by the backward one. Each frame's set is the union, distinct. Every
    candidate's nll is divided by ``temperature`` (evidence_temperature)."""
    frames = [i for i in range(scorer.frames) if scorer.failed(i) is None]
    n = len(frames)
    glob = [_tempered(scorer.global_candidates(i), temperature)
            .distinct(limit=4 * MAX_CANDIDATES) for i in frames]
    forward: list = [None] * n
    backward: list = [None] * n
    for direction in (1, -1):
        beam, message = forward if direction == 1 else backward, None
        order = range(n) if direction == 1 else range(n - 1, -1, -1)
        for k in order:
            c = glob[k]
            j = k - direction
            if 0 <= j < n and len(beam[j]):
                # the odometry between the two frames, earlier to later (read once: the
                # starts, their spread and the transitions below)
                step = motion.between(*sorted((frames[j], frames[k])))
                inc = step[0] if direction == 1 else inverse(step[0])
                starts = moved(beam[j].poses, inc[0], inc[1], inc[2])
                more = _fused(_tempered(scorer.local_candidates(frames[k], starts),
                                        temperature), starts, step)
                c = FrameCandidates.concat([c, more]).distinct(limit=4 * MAX_CANDIDATES)
            if not len(c):
                beam[k], message = c, None
                continue
            if message is None:
                m = (np.zeros(len(c)) if direction == -1 or log_prior0 is None
                     or k != 0 else log_prior0(c))
            elif direction == 1:
                t = transition_log(beam[j], c, step, model)
                m = _logsumexp(message[:, None] + t, axis=0)
            else:
                t = transition_log(c, beam[j], step, model)
                m = _logsumexp(t + message[None, :], axis=1)
            score = m - c.nll
            keep = np.argsort(-score, kind="stable")[:MAX_CANDIDATES]
            beam[k] = c.take(keep)
            message = score[keep] - _logsumexp(score[keep])
    sets = [FrameCandidates.concat([forward[k], backward[k]]).distinct(limit=2 * MAX_CANDIDATES)
            for k in range(n)]
    # a frame left with no candidate at all has no fix: the passes go over it by the odometry
    kept = [k for k in range(n) if len(sets[k])]
    return [frames[k] for k in kept], [sets[k] for k in kept]


def _fused(more: FrameCandidates, starts: np.ndarray, step: tuple) -> FrameCandidates:
    """Local fixes combined with the poses they were started from (``more.start``), a Kalman
    update of each fix's position by its start (the start's spread: the step's odometry noise
    and STATE_SIGMA_M). Where a fix says little (a frame that sees only lines along one
    direction: its covariance is metres wide along them) the candidate stays where the
    odometry moved its neighbour, so a chain of candidates at one place follows the odometry
    instead of wandering along the line, which the transitions (no wider than STATE_SIGMA_M)
    would charge as if the robot had moved. Across the lines, and wherever the fix is sure,
    the fix stands. nll, covariance and error stay the fix's: the frame's evidence."""
    if not len(more) or not len(starts):
        return more
    if more.start is None or len(more.start) != len(more):
        raise ValueError("local candidates must name each row's start (FrameCandidates.start)")
    q = np.asarray(step[1], float)
    spread = float(np.max(np.linalg.eigvalsh(0.5 * (q[:2, :2] + q[:2, :2].T)))) \
        + STATE_SIGMA_M ** 2
    starts = np.asarray(starts, float).reshape(-1, 3)
    c = 0.5 * (more.cov[:, :2, :2] + np.swapaxes(more.cov[:, :2, :2], 1, 2))
    gain = c @ np.linalg.inv(c + spread * np.eye(2)[None])
    poses = np.array(more.poses, float, copy=True)
    poses[:, :2] += np.einsum("kij,kj->ki", gain, starts[more.start, :2] - poses[:, :2])
    return FrameCandidates(poses, more.nll, more.cov, more.error, more.start)


def discrete_pass(frames: list[int], sets: list[FrameCandidates], motion: Motion,
                  model: Transition, log_prior0: np.ndarray | None = None) -> Passes:
    """Forward-backward and Viterbi over the candidate sets (module doc). ``log_prior0``: a
    log prior over the first set's candidates (default: uniform)."""
    n = len(frames)
    if n == 0:
        return Passes([], [], [], np.zeros(0, dtype=int))
    trans = [transition_log(sets[k - 1], sets[k], motion.between(frames[k - 1], frames[k]),
                            model) for k in range(1, n)]
    emit = [-np.asarray(s.nll, float) for s in sets]
    prior0 = np.zeros(len(sets[0])) if log_prior0 is None else np.asarray(log_prior0, float)
    alpha = [prior0 + emit[0]]
    delta = [alpha[0].copy()]
    back = []
    for k in range(1, n):
        t = trans[k - 1]
        a = alpha[-1] - _logsumexp(alpha[-1])  # normalised, so the sums stay finite
        alpha.append(_logsumexp(a[:, None] + t, axis=0) + emit[k])
        d = delta[-1] - delta[-1].max()
        scores = d[:, None] + t
        back.append(np.argmax(scores, axis=0))
        delta.append(scores.max(axis=0) + emit[k])
    beta = [np.zeros(len(sets[-1]))]
    for k in range(n - 1, 0, -1):
        t = trans[k - 1]
        b = beta[0] + emit[k]
        b = b - b.max()
        beta.insert(0, _logsumexp(t + b[None, :], axis=1))
    posterior = []
    for k in range(n):
        g = alpha[k] + beta[k]
        g = np.exp(g - g.max())
        posterior.append(g / g.sum())
    path = np.zeros(n, dtype=int)
    path[-1] = int(np.argmax(delta[-1]))
    for k in range(n - 1, 0, -1):
        path[k - 1] = int(back[k - 1][path[k]])
    return Passes(frames, sets, posterior, path)


def _logsumexp(a: np.ndarray, axis=None):
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    out = np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True)) + m
    return out.squeeze() if axis is None else np.squeeze(out, axis=axis)


def basin_mass(cands: FrameCandidates, posterior: np.ndarray, pose) -> float:
    """The posterior mass of the candidates whose fix covers ``pose``: within
    CONFIDENCE_RADIUS_M of it, or within the ``COVER_GATE`` of the fix's own position
    covariance (a fix that sees parallel lines only is uncertain along them, and its
    candidates lie along the lines: one place), and within CONFIDENCE_RADIUS_RAD in heading."""
    return float(np.clip(posterior[_covers(cands, pose)].sum(), 0.0, 1.0))


def _covers(cands: FrameCandidates, pose) -> np.ndarray:
    dx = cands.poses[:, 0] - pose[0]
    dy = cands.poses[:, 1] - pose[1]
    a = np.abs(wrap_angle(cands.poses[:, 2] - pose[2]))
    sxx, syy, sxy = cands.cov[:, 0, 0], cands.cov[:, 1, 1], cands.cov[:, 0, 1]
    det = np.maximum(sxx * syy - sxy * sxy, 1e-12)
    m2 = (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det
    near = (np.hypot(dx, dy) <= CONFIDENCE_RADIUS_M) | (m2 <= COVER_GATE)
    return near & (a <= CONFIDENCE_RADIUS_RAD)


def ranked_hypotheses(cands: FrameCandidates, posterior: np.ndarray, top_pose, count: int
                      ) -> np.ndarray:
    """(k, 4) hypotheses: the smoothed pose with its basin's mass first, then the other
    candidates' basins ranked by posterior (each candidate's mass gathered onto the best
    candidate of its basin), at most ``count``."""
    out = [(*top_pose, basin_mass(cands, posterior, top_pose))]
    taken = [np.asarray(top_pose, float)]
    for k in np.argsort(-posterior, kind="stable"):
        if len(out) >= count:
            break
        p = cands.poses[k]
        if any(_covers(cands.take([k]), q)[0] for q in taken):
            continue
        out.append((*p, basin_mass(cands, posterior, p)))
        taken.append(p)
    return np.array(out, float)


def smooth_track(scorer: Scorer, causal: PoseTrack, motion: Motion, conf: dict, *,
                 kidnap_probability: float, area: float, log_prior0=None,
                 temperature: float = 1.0) -> PoseTrack:
    """The smoothed PoseTrack of a run (module doc) from a method's ``scorer``, the causal
    run's track (frame names, stamps and the failure reasons of frames with no candidates)
    and the run's Motion. ``conf``: the method's (min_confidence, hypotheses);
    ``kidnap_probability``: the method's per frame (the jump model's outlier floor);
    ``area``: m^2 of the world a kidnap may put the robot on; ``log_prior0``:
    callable (FrameCandidates) -> log prior over the first frame's candidates, or None;
    ``temperature``: what each frame's nll is divided by (evidence_temperature)."""
    from .pose_graph import refine_path

    t0 = time.process_time()
    model = Transition.of(kidnap_probability, area)
    frames, sets, passes = _discrete(scorer, motion, model, log_prior0, temperature)
    rounds = 1
    if RECALIBRATE and getattr(scorer, "learn_calibration", None) is not None and frames:
        if _recalibrated(scorer, frames, passes):
            frames, sets, passes = _discrete(scorer, motion, model, log_prior0, temperature)
            rounds = 2
    t1 = time.process_time()
    n = scorer.frames
    chosen = np.full((n, 3), np.nan)
    chosen_cov = np.full((n, 3, 3), np.nan)
    for k, i in enumerate(frames):
        c = passes.candidates[k]
        chosen[i] = c.poses[passes.path[k]]
        chosen_cov[i] = c.cov[passes.path[k]]
    poses, covs = refine_path(chosen, chosen_cov, motion)
    t2 = time.process_time()
    log.info("smoothed %d frames: candidates %.2f s, passes %.2f s CPU", n, t1 - t0, t2 - t1)
    out = PoseTrack(meta=dict(causal.meta))
    out.meta["smoothing"] = {"candidates_s": round(t1 - t0, 3), "passes_s": round(t2 - t1, 3),
                             "rounds": rounds, "temperature": round(float(temperature), 3),
                             "mean_candidates": float(np.mean([len(s) for s in sets]))
                             if sets else 0.0}
    index = {i: k for k, i in enumerate(frames)}
    conf_of = np.full(n, np.nan)
    for i, k in index.items():
        conf_of[i] = basin_mass(passes.candidates[k], passes.posterior[k], poses[i])
    runtime = (t2 - t0) / max(n, 1)
    min_conf = float(conf["min_confidence"])
    for i in range(n):
        name, stamp = causal.name[i], causal.stamp[i]
        if not np.all(np.isfinite(poses[i])):
            out.add(name, stamp, None, mode="failed", runtime=runtime,
                    flags=causal.flags[i] or "no-fix")
            continue
        if i in index:
            k = index[i]
            cands, post = passes.candidates[k], passes.posterior[k]
            hyps = ranked_hypotheses(cands, post, poses[i], int(conf["hypotheses"]))
            # each place's posterior, times the chance that the pose lies within the place's
            # radius of where the graph puts it (the frame's marginal covariance; the mirror's
            # is the same): a path held by frames that say little is the right place with a
            # wide pose
            hyps[:, 3] *= _inside(covs[i])
            confidence = float(hyps[0, 3])
            error = float(cands.error[passes.path[k]])
            # the pose graph moved the frame out of the place its path candidate stands for
            # (the odometry and the other frames overrule this frame's fix): the two passes
            # disagree, and the confidence (at the graph's pose) says how much
            moved = not _covers(cands.take([passes.path[k]]), poses[i])[0]
            flags = "moved-by-graph" if moved else ""
        else:  # no fix of its own: the neighbours' confidence, the lower of the two
            confidence = _neighbour_confidence(conf_of, i, covs[i])
            hyps = np.array([[*poses[i], confidence]])
            error, flags = math.nan, "odometry-only"
        out.add(name, stamp, poses[i], error=error, confidence=confidence, mode="smoothed",
                runtime=runtime, covariance=covs[i], flags=flags, hypotheses=hyps,
                accepted=confidence >= min_conf)
    return out


def _recalibrated(scorer: Scorer, frames: list[int], passes: Passes) -> bool:
    """The camera's distance error learnt from the whole path (module doc): the scorer's
    ``learn_calibration(path, sure)`` (frame -> pose, frame -> confidence) from the path's
    poses, the path's frames fixed again with it (their local fix), ``CALIBRATION_ROUNDS``
    times (a fix absorbs part of the error it is fixed with, so one round learns too little).
    The learnt calibration is kept (the scorer's ``calibration``) when the path's frames are
    likelier with it than with the scorer's first one (the summed nll of the same frames'
    local fixes, a likelihood ratio between two calibrations); returns whether it was."""
    path = {i: passes.candidates[k].poses[passes.path[k]] for k, i in enumerate(frames)}
    sure = {i: basin_mass(passes.candidates[k], passes.posterior[k], path[i])
            for k, i in enumerate(frames)}

    def refit(poses: dict) -> tuple[dict, float]:
        fixed = {i: scorer.local_candidates(i, np.asarray(p, float)[None]) for i, p in
                 poses.items()}
        return ({i: f.poses[0] for i, f in fixed.items()},
                float(sum(f.nll[0] for f in fixed.values())))

    first = scorer.calibration
    _poses, nll_first = refit(path)
    nll = math.inf
    for _ in range(CALIBRATION_ROUNDS):
        learnt = scorer.learn_calibration(path, sure)
        if learnt is None:
            break
        scorer.calibration = learnt
        path, nll = refit(path)
    if nll < nll_first:
        return True
    scorer.calibration = first
    return False


def _discrete(scorer: Scorer, motion: Motion, model: Transition, log_prior0,
              temperature: float):
    """Candidate sets (their nll divided by ``temperature``) and the discrete pass over them."""
    frames, sets = candidate_sets(scorer, motion, model, log_prior0, temperature)
    prior0 = log_prior0(sets[0]) if (log_prior0 is not None and sets) else None
    return frames, sets, discrete_pass(frames, sets, motion, model, prior0)


def start_half_prior(conf: dict, mirrored: bool):
    """The log prior over the first frame's candidates that ``start_half`` states (own: x <
    0, opponent: x > 0; a candidate on the other half has prior ``start_half_error``), or None
    where the conf has no such key or says ``any``."""
    half = conf.get("start_half", "any")
    if half == "any":
        return None
    wrong = math.log(max(float(conf["start_half_error"]), 1e-300))

    def prior(cands: FrameCandidates) -> np.ndarray:
        x = cands.poses[:, 0]
        other = x > 0 if half == "own" else x < 0
        return np.where(other, wrong, 0.0)

    return prior


def _neighbour_confidence(conf_of: np.ndarray, i: int, cov: np.ndarray) -> float:
    """A frame with no fix of its own: the lower of its fixed neighbours' confidences (the
    place), times the probability that its pose, reached by the odometry, lies within
    CONFIDENCE_RADIUS_M of where it is given (its marginal covariance's largest variance as an
    isotropic Gaussian: conservative), which falls as a gap grows."""
    before = conf_of[:i][np.isfinite(conf_of[:i])]
    after = conf_of[i + 1:][np.isfinite(conf_of[i + 1:])]
    vals = ([before[-1]] if len(before) else []) + ([after[0]] if len(after) else [])
    if not vals:
        return 0.0
    return float(min(vals) * _inside(cov))


def _inside(cov: np.ndarray) -> float:
    """The probability that a pose with covariance ``cov`` (3, 3; field frame) lies within
    CONFIDENCE_RADIUS_M of where it is given: its position's largest variance taken as an
    isotropic Gaussian (conservative: a Rayleigh distance), 1 - exp(-r^2 / (2 var))."""
    if not np.all(np.isfinite(cov[:2, :2])):
        return 0.0
    var = float(np.max(np.linalg.eigvalsh(0.5 * (cov[:2, :2] + cov[:2, :2].T))))
    return 1.0 - math.exp(-CONFIDENCE_RADIUS_M**2 / (2 * max(var, 1e-12)))
