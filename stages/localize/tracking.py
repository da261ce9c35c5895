"""The belief every pose-fixing method shares: a few Kalman-fused hypotheses (tracks) with a
probability each, the mass of "elsewhere", and the frame's ranked hypotheses and confidence.

A method (lut, fit, templates) is an *engine* that proposes poses; this module turns its
proposals into a belief. Per frame the engine gives

- for every track (``TrackBank.tracks``) one ``Candidate``: the fix it finds from the track's
  prior (``TrackBank.prior``: the last fused pose moved by the odometry, with the fusion's
  predicted covariance), with ``log_prior`` from ``TrackBank.tracked_log_prior`` (the track's
  weight, times 1 - ``KIDNAP_PROBABILITY``, times the odometry's agreement exp(-m^2 / 2), m the
  Kalman innovation of the fix against prior and fix covariance);
- when it searches globally (no track, a lost track, every few frames), new Candidates with
  ``log_prior`` = ``TrackBank.global_log_prior``: the mass of elsewhere spread uniformly over
  the world's ``AMBIGUITY_DISTANCE_M`` squares (``TrackBank.log_basins`` of them), those near a
  track left out (``TrackBank.near_track``), duplicates folded (``TrackBank.fold``);
- ``nll``: the frame's negative log-likelihood at each candidate, in nats and *tempered* (the
  engine states its temperature: observations of one frame are not independent), and the same
  for the null, what chance alone explains (``null_nll`` of a global search).

``TrackBank.posterior`` normalises log_prior - nll over the candidates and elsewhere (in a
global frame elsewhere explains what the null explains, as one basin; in a tracked frame
elsewhere keeps its share, scaled by how well the tracks explain the frame);
``TrackBank.update`` keeps the candidates as tracks (pruned below ``PRUNE_PROBABILITY``, merged
when in one basin, at most ``MAX_TRACKS``), fusing each tracked fix that beats the null
(``Candidate.beats_null``) into its track's decentralised Kalman filter (kalman.py);
``TrackBank.hypotheses`` lists tracks and, on a point-symmetric field, their mirror images
(each track carries the share of its weight that belongs to its mirror image, ``mirror``),
ranked, with the top's mirror always listed; ``TrackBank.conclude`` gives the frame's pose,
covariance, confidence (the top hypothesis's probability) and whether it is accepted
(confidence >= ``min_confidence``). A failed frame (``TrackBank.failed``) only predicts; after
``MAX_PREDICTED_FRAMES`` of them in a row the tracks are dropped.

The conf keys the bank reads are ``DEFAULTS`` (a method's confs start from them); its tuned
constants (``KIDNAP_PROBABILITY``, ``MAX_TRACKS``, ...) are named below them.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..common.field import FieldModel
from ..common.geometry import compose, wrap_scalar
from ..common.poses_file import PoseTrack
from .kalman import DecentralisedFusion, FusionParams

log = logging.getLogger(__name__)

# what a user chooses (a method's confs start from them; the rest are the constants below)
DEFAULTS = {
    "independent": False,  # every frame globally, no tracks, no odometry
    "smooth": False,  # decide every frame with the whole recording (smooth.py), offline
    "hypotheses": 5,  # hypotheses listed per frame
    "min_confidence": 0.8,  # a frame is accepted at this confidence
    "fusion": {"enabled": True},  # false: no Kalman fusion with the odometry (--preset no-fusion)
}

# the ranges the keys above must lie in (common.conf.check_bounds; a method adds them to its
# BOUNDS): a count of at least one and at most what a frame can carry, a probability
MAX_HYPOTHESES = 1000
BOUNDS = {"hypotheses": (1, MAX_HYPOTHESES), "min_confidence": (0, 1)}

# The bank's tuned constants (module doc). The values were chosen on the rendered tuning sets'
# calibration (docs/manual.md, docs/results.md) and hold for lut, fit and templates alike.
MAX_PREDICTED_FRAMES = 30  # failed frames in a row over which tracks are kept
KIDNAP_PROBABILITY = 1e-5  # per frame: the robot is not where its tracks say
AMBIGUITY_DISTANCE_M = 1.0  # m, separation of the global search's minima
MAX_TRACKS = 8  # hypotheses tracked at once
PRUNE_PROBABILITY = 1e-4  # tracks below this probability are dropped
PRIOR_OUTLIER_PROBABILITY = 0.01  # a track's prior is wrong beyond its covariance
# (a Gaussian with a uniform floor over the engine's reach: caps the Mahalanobis term)
GATE_SIGMAS = 3.0  # the engine's reach in sigmas of the prior (see lost)
MIN_GATE_M = 0.3  # m, floor of the innovation's sigma times GATE_SIGMAS
# the fusion's noise (kalman.FusionParams' defaults), also the smoother's motion noise
FUSION = FusionParams()

# two poses this close are one hypothesis (one basin of a likelihood surface)
SAME_BASIN_M = 0.3
SAME_BASIN_RAD = 0.2
_mirror = FieldModel.mirror_pose  # a pose's image under the field's 180 deg symmetry


def check_conf(conf: dict) -> None:
    """The bank's keys of a method's conf, checked (FieldlocError)."""
    from ..common.errors import FieldlocError

    if not 0.0 <= float(conf["min_confidence"]) <= 1.0:
        raise FieldlocError(f"min_confidence must lie in [0, 1], not {conf['min_confidence']}")
    if not isinstance(conf["smooth"], bool):
        raise FieldlocError(f"smooth must be true or false, not {str(conf['smooth'])[:40]!r}")
    if not isinstance(conf.get("recalibrate", False), bool):
        raise FieldlocError(f"recalibrate must be true or false, not"
                            f" {str(conf['recalibrate'])[:40]!r}")
    if conf["smooth"] and conf["independent"]:
        raise FieldlocError("smooth decides every frame with the whole recording; it does not"
                            " localise frames independently")
    if int(conf["hypotheses"]) < 1:
        raise FieldlocError(f"hypotheses must be >= 1, not {conf['hypotheses']}")


@dataclass
class Track:
    """One hypothesis carried over frames: a Kalman-fused pose, its weight (log, normalised
    over the tracks) and the share of that weight belonging to the pose's mirror image."""

    fusion: DecentralisedFusion
    log_weight: float
    mirror: float = 0.0
    born: int = 0  # frame index
    ident: int = 0
    misses: int = 0  # frames in a row whose fix did not beat the null
    pose: np.ndarray = field(default_factory=lambda: np.zeros(3))  # last recorded pose
    cov: np.ndarray = field(default_factory=lambda: np.eye(3))


@dataclass(kw_only=True)
class Candidate:
    """A pose proposed this frame: the engine's ``fix`` (anything with ``pose`` (3,) and
    ``mode``), its vision covariance R (3, 3), its (log) prior, the frame's tempered
    negative log-likelihood ``nll`` (nats), the track it belongs to (None: a new track), the
    share of its mirror image; set by the bank: ``log_post``."""

    fix: object
    R: np.ndarray
    log_prior: float
    nll: float = 0.0
    track: Track | None = None
    mirror: float = 0.0
    beats_null: bool = True  # tracked: the fix is fused into its track only if it does
    log_post: float = 0.0
    own_mass: float = 1.0  # global candidates: likelihood of the folded fixes relative to
    mirror_mass: float = 0.0  # the candidate's, in its basin and in its mirror image

    @property
    def pose(self) -> np.ndarray:
        return self.fix.pose


class TrackBank:
    """The tracks and the mass of elsewhere between frames (see the module doc).

    ``area``: m^2 of the world a global search covers (the uniform prior over where the robot
    could have been put); ``reach``: m, half the side of the square around a prior the engine
    searches when tracking; ``reach_cells``: how many distinct positions that square holds
    (the uniform floor of a wrong prior); ``symmetric``: the field is point-symmetric (every
    pose has a mirror that explains a frame as well)."""

    def __init__(self, conf: dict, *, area: float, reach: float, reach_cells: int,
                 symmetric: bool):
        self.conf = conf
        self.fusion_params = FUSION
        self.use_fusion = bool(conf["fusion"]["enabled"])
        self.reach = float(reach)
        self.log_basins = math.log(max(area / AMBIGUITY_DISTANCE_M ** 2, 1.0))
        # the Mahalanobis term of a prior that is wrong with PRIOR_OUTLIER_PROBABILITY: a
        # Gaussian over a uniform floor on the reach's cells, -log of the floor
        self.prior_cap = -math.log(max(PRIOR_OUTLIER_PROBABILITY, 1e-300)
                                   / max(int(reach_cells), 1))
        self.symmetric = bool(symmetric)
        self.tracks: list[Track] = []
        self.other = 1.0  # probability that the robot is at none of the tracks
        self.has_odometry = True  # whether the dataset measures the robot's motion
        self.failures_in_row = 0
        self.max_predicted_frames = MAX_PREDICTED_FRAMES
        self._next_ident = 0

    # ------------------------------------------------------------------ before the frame
    def reset(self):
        """Forget every track (a frame localised on its own)."""
        self.tracks, self.other = [], 1.0

    def other_prior(self) -> float:
        """Log mass of elsewhere before this frame's evidence: where no track is (all of it
        before the first fix), plus the kidnap probability of the tracks."""
        if not self.tracks:
            return 0.0
        eps = float(KIDNAP_PROBABILITY)
        return math.log(max(self.other + eps * (1 - self.other), eps))

    def global_log_prior(self, other_prior: float) -> float:
        """Log prior of one new candidate of a global search: elsewhere's mass over the
        world's basins."""
        return other_prior - self.log_basins

    def prior(self, t: Track, dt: float, odo, col: bool):
        """(prior pose, its position covariance (2, 2)) of a track: the previous pose moved by
        the odometry (by the last fused motion on collision frames; a random walk of up to the
        fusion's max_speed when the dataset has no odometry), the covariance from the fusion's
        prediction (without fusion: ``MIN_GATE_M`` / ``GATE_SIGMAS`` growing with the
        misses)."""
        f = t.fusion
        if self.use_fusion and f.state is not None:
            if not self.has_odometry:  # no motion measured at all: a random walk (repeating
                # the last fused motion would feed each correction back as a velocity)
                f.motion_known = False
                f.last_motion = np.zeros(3)
            pose, cov = f.predicted(dt, odo, col)
            return pose, cov[:2, :2]
        pose = compose(t.pose, odo) if odo is not None and not col else t.pose
        s = MIN_GATE_M / GATE_SIGMAS * math.sqrt(1 + t.misses)
        return np.asarray(pose, float).copy(), np.eye(2) * s * s

    def lost(self, prior_cov) -> bool:
        """Whether the engine's reach no longer covers where the robot may be
        (``GATE_SIGMAS`` of the prior's largest sigma exceed it)."""
        (largest, _), _u = eig2(float(prior_cov[0, 0]), float(prior_cov[0, 1]),
                                float(prior_cov[1, 1]))
        return math.sqrt(max(largest, 0.0)) * GATE_SIGMAS > self.reach

    def innovation_information(self, prior_cov, R=None) -> np.ndarray:
        """Inverse of the innovation covariance (2, 2): the prior's, the fix's (if given) and a
        floor of (``MIN_GATE_M`` / ``GATE_SIGMAS``)^2 against overconfidence."""
        floor = (MIN_GATE_M / GATE_SIGMAS) ** 2
        a, b, d = float(prior_cov[0, 0]) + floor, float(prior_cov[0, 1]), \
            float(prior_cov[1, 1]) + floor
        if R is not None:
            a, b, d = a + float(R[0, 0]), b + float(R[0, 1]), d + float(R[1, 1])
        det = a * d - b * b
        return np.array([[d / det, -b / det], [-b / det, a / det]])

    def prior_term(self, d: np.ndarray, info: np.ndarray) -> float:
        """The prior's share of a tracked fix's score: Mahalanobis^2 / 2 of the fix's offset
        ``d`` from the prior under ``info``, capped by the uniform floor."""
        return min(0.5 * float(d @ info @ d), self.prior_cap)

    def tracked_log_prior(self, t: Track, d: np.ndarray, prior_cov, R) -> float:
        """Log prior of a track's fix offset ``d`` (2,) from the track's prior: the track's
        weight, 1 - kidnap, and the odometry's agreement (the innovation against prior and
        fix covariance, capped by the uniform floor)."""
        m2 = min(float(d @ self.innovation_information(prior_cov, R) @ d), 2 * self.prior_cap)
        return t.log_weight + math.log1p(-KIDNAP_PROBABILITY) - 0.5 * m2

    # ------------------------------------------------------------------ global candidates
    def near_track(self, pose) -> bool:
        """Whether a pose lies in the basin of a track (or of its mirror image)."""
        return any(near_pose(t.pose, pose, SAME_BASIN_M, SAME_BASIN_RAD)
                   or (t.mirror > 0 and near_pose(t.pose, mirror_scalar(*pose), SAME_BASIN_M,
                                                  SAME_BASIN_RAD))
                   for t in self.tracks)

    def fold(self, out: list[Candidate], pose, nll: float) -> bool:
        """Fold a fix (pose, nll) into a better candidate of ``out`` it duplicates (the same
        basin) or mirrors (on a point-symmetric field): its likelihood relative to the
        candidate's adds to that candidate's own or mirror mass. False if it is new."""
        mirror = mirror_scalar(*pose)
        for c in out:
            rel = math.exp(-(nll - c.nll))
            if near_pose(c.pose, pose, SAME_BASIN_M, SAME_BASIN_RAD):
                c.own_mass += rel
                return True
            if self.symmetric and near_pose(c.pose, mirror, SAME_BASIN_M, SAME_BASIN_RAD):
                c.mirror_mass += rel
                return True
        return False

    def finish_global(self, out: list[Candidate], heading_known: bool):
        """The folded masses into the global candidates' priors and mirror shares; with no
        field-aligned heading known (``heading_known``: one that tells a heading from its
        opposite, as a field-aligned IMU) on a point-symmetric field the mirror explains
        the frame exactly as well, searched or not (the search's refinements differ a
        little), so it carries the candidate's own mass."""
        for c in out:
            if not heading_known and self.symmetric:
                c.mirror_mass = c.own_mass
            total = c.own_mass + c.mirror_mass
            c.log_prior += math.log(total)
            c.mirror = c.mirror_mass / total

    def start_half(self, c: Candidate, start_half: str, error: float, mirrored) -> bool:
        """The start_half prior (own: x < 0, opponent: x > 0) on a first-fix candidate: the
        share of its weight on the other half (its own or its mirror's) is multiplied by
        ``error`` (the chance that the user is wrong). When the mirror carries more,
        ``mirrored(c, pose)`` moves the candidate to the mirror pose (the engine refits it
        there) and True is returned."""
        want_negative = start_half == "own"
        own_ok = (c.pose[0] < 0) == want_negative
        p_own = (1 - c.mirror) * (1.0 if own_ok else error)
        p_mir = c.mirror * (error if own_ok else 1.0)
        if not self.symmetric:
            c.log_prior += math.log(max(p_own, 1e-300))
            return False
        total = p_own + p_mir
        c.log_prior += math.log(max(total, 1e-300))
        moved = p_mir > p_own
        if moved:  # the mirror image is where the robot starts
            mirrored(c, _mirror(c.pose))
            p_own, p_mir = p_mir, p_own
        c.mirror = p_mir / total if total > 0 else 0.0
        return moved

    # ------------------------------------------------------------------ the belief
    def posterior(self, tracked: list[Candidate], new: list[Candidate], other_prior: float,
                  null_nll: float | None) -> float:
        """Normalise the candidates' log_prior - nll with elsewhere's: in a global frame
        (``null_nll`` given) elsewhere explains what the null explains, as one basin of the
        world's; otherwise it keeps its share, scaled by how well the tracks explain the
        frame. Sets every candidate's ``log_post``; returns elsewhere's."""
        cands = tracked + new
        for c in cands:
            c.log_post = c.log_prior - c.nll
        if null_nll is not None:
            other_post = other_prior - self.log_basins - null_nll
        elif len(tracked) == 1:  # the common frame: the sums below of one term each
            c = tracked[0]
            w = c.track.log_weight
            other_post = other_prior + float((c.log_post - c.log_prior + w) - w)
        else:
            like = np.array([c.log_post - c.log_prior + c.track.log_weight for c in tracked])
            wsum = np.array([c.track.log_weight for c in tracked])
            other_post = other_prior + float(np.logaddexp.reduce(like)
                                             - np.logaddexp.reduce(wsum))
        logs = np.array([c.log_post for c in cands] + [other_post])
        logs -= logs.max() + math.log(np.exp(logs - logs.max()).sum())
        for c, lp in zip(cands, logs[:-1]):
            c.log_post = float(lp)
        return float(logs[-1])

    def update(self, i: int, cands: list[Candidate], other: float, dt: float, odo,
               col: bool) -> Candidate:
        """The tracks after this frame from the candidates' normalised log weights (and the
        log weight ``other`` of elsewhere): pruned below ``PRUNE_PROBABILITY`` (their mass
        goes elsewhere), merged when in one basin, at most ``MAX_TRACKS``; each track's
        fusion corrected with its fix when the fix beats the null (else predicted only).
        Returns the candidate of the strongest track."""
        conf = self.conf
        order = sorted(range(len(cands)), key=lambda k: -cands[k].log_post)
        kept: list[Track] = []
        lead = cands[order[0]]
        cap = MAX_TRACKS
        if conf["independent"]:
            cap = max(cap, int(conf["hypotheses"]))
        for k in order:
            c = cands[k]
            if c.log_post < math.log(PRUNE_PROBABILITY) and kept:
                continue
            same = [t for t in kept if near_pose(t.pose, c.pose, SAME_BASIN_M,
                                                 SAME_BASIN_RAD)]
            if same:
                same[0].log_weight = float(np.logaddexp(same[0].log_weight, c.log_post))
                continue
            if len(kept) >= cap:
                continue
            if c.track is None:
                t = self._new_track(c, i)
            else:
                t = c.track
                t.log_weight = c.log_post
                t.mirror = c.mirror
                vision = (c.pose, c.R) if c.beats_null else None
                if self.use_fusion:
                    fused = t.fusion.step(dt, odo, col, vision)  # a copy of its state
                    t.pose, t.cov = fused.mean, fused.cov
                elif vision is not None:
                    t.pose, t.cov = c.pose.copy(), c.R.copy()
                t.misses = 0 if vision is not None else t.misses + 1
            kept.append(t)
        kept_mass = float(np.exp([t.log_weight for t in kept]).sum())
        self.other = float(min(max(1.0 - kept_mass, math.exp(other)), 1.0 - 1e-12))
        self.tracks = kept
        self.failures_in_row = 0
        return lead

    def _new_track(self, c: Candidate, i: int) -> Track:
        f = DecentralisedFusion(self.fusion_params)
        f.reset(c.pose, c.R)
        self._next_ident += 1
        return Track(fusion=f, log_weight=c.log_post, mirror=c.mirror, born=i,
                     ident=self._next_ident, pose=c.pose.copy(), cov=c.R.copy())

    def failed(self, dt: float, odo, col: bool):
        """A failed frame: the tracks only predict; after ``MAX_PREDICTED_FRAMES`` failed
        frames in a row they are dropped (lost: global search only)."""
        self.failures_in_row += 1
        if self.failures_in_row > self.max_predicted_frames or self.conf["independent"]:
            self.reset()
            return
        for t in self.tracks:
            if self.use_fusion and t.fusion.state is not None:
                fused = t.fusion.step(dt, odo, col, None)  # a copy of its state
                t.pose, t.cov = fused.mean, fused.cov
            elif odo is not None and not col:
                t.pose = compose(t.pose, odo)
            t.misses += 1

    def hypotheses(self) -> np.ndarray:
        """(k, 4) ranked (x, y, theta, probability) of the tracks and, on a point-symmetric
        field, their mirror images, at most ``hypotheses``."""
        rows = []
        for t in self.tracks:
            w = math.exp(t.log_weight)
            x, y, th = t.pose.tolist()
            rows.append((x, y, th, w * (1 - t.mirror)))
            if self.symmetric:
                rows.append((*mirror_scalar(x, y, th), w * t.mirror))
        rows.sort(key=lambda r: -r[3])  # stable: a track before its mirror on a tie
        k = int(self.conf["hypotheses"])
        out = rows[:k]
        if self.symmetric and k > 1:  # the top's mirror image is always listed
            m = mirror_scalar(*out[0][:3])
            if not any(near_pose(r, m, 1e-6, 1e-6) for r in out[1:]):
                out[-1 if len(out) == k else len(out):] = [
                    next(r for r in rows if near_pose(r, m, 1e-6, 1e-6))]
        return np.array(out, float)

    def confident(self) -> bool:
        """Whether the belief is confident up to the field's symmetry: a track (a pose and,
        on a point-symmetric field, its mirror image, whose shares no observation can move
        without a field-aligned heading) holds at least ``min_confidence``. Without a mirror
        share this is the top hypothesis's acceptance; with one it is what a search could
        still change (a global search cannot tell a pose from its mirror either)."""
        return bool(self.tracks) and max(t.log_weight for t in self.tracks) >= math.log(
            max(float(self.conf["min_confidence"]), 1e-300))

    def conclude(self, hyps: np.ndarray, top: Candidate, tracked: bool, flags: list):
        """(pose, covariance, confidence, accepted) of the frame from its hypotheses, and the
        flags every method records: relocalised (the top is a track born this frame while an
        older track existed), mirror-ambiguous (the mirror has at least half the top's
        probability), low-confidence."""
        pose = hyps[0, :3]
        cov = self.tracks[0].cov
        if top.track is None and tracked:
            flags.append("relocalised")
        if len(hyps) > 1 and self.symmetric and near_pose(hyps[1], mirror_scalar(*pose), 0.3,
                                                          0.2) \
                and hyps[1, 3] >= 0.5 * hyps[0, 3]:
            flags.append("mirror-ambiguous")
        confidence = float(hyps[0, 3])
        accepted = confidence >= self.conf["min_confidence"]
        if not accepted:
            flags.append("low-confidence")
        return pose, cov, confidence, accepted


def eig2(a: float, b: float, d: float):
    """Eigenvalues (l1, l2) and the unit eigenvector (ux, uy) of l1 of the symmetric 2 x 2
    matrix [[a, b], [b, d]] (the other eigenvector is (-uy, ux))."""
    mean, half = 0.5 * (a + d), 0.5 * (a - d)
    r = math.hypot(half, b)
    l1, l2 = mean + r, mean - r
    if r < 1e-300:
        return (l1, l2), (1.0, 0.0)
    ang = 0.5 * math.atan2(b, half)
    return (l1, l2), (math.cos(ang), math.sin(ang))


def near_pose(candidate, pose, distance: float = 0.5, angle: float = 0.2) -> bool:
    """Whether a candidate (x, y, theta, ...) lies within ``distance`` m and ``angle`` rad of
    a pose."""
    if math.hypot(candidate[0] - pose[0], candidate[1] - pose[1]) >= distance:
        return False
    return abs(wrap_scalar(float(candidate[2] - pose[2]))) < angle


def mirror_scalar(x, y, theta) -> tuple[float, float, float]:
    """FieldModel.mirror_pose in scalar arithmetic (the same floating-point result, without
    a numpy array per call)."""
    x, y, theta = float(x), float(y), float(theta)
    return -x, -y, wrap_scalar(theta + math.pi)


# ---------------------------------------------------------------------------- the frame loop


class FrameFailed(Exception):
    """A frame that cannot be localised; the message is the reason recorded in its flags."""


@dataclass
class FrameSensors:
    """What a dataset says of each frame besides its features: the odometry increment since
    the previous frame (``has_odometry`` where there is one), the IMU yaw and collisions, and
    the truth's heading (``heading: truth`` only)."""

    increments: np.ndarray
    has_odometry: np.ndarray
    yaw: np.ndarray
    collision: np.ndarray
    truth_heading: np.ndarray | None


def frame_sensors(conf: dict, dataset, stamps) -> FrameSensors:
    """The FrameSensors of frames at ``stamps`` from ``dataset`` (Dataset or None), matched
    within ``conf['stamp_tolerance']`` s."""
    from . import heading as heading_mod
    from .motion_model import accumulate_odometry

    stamps = np.asarray(stamps, dtype=float)
    n = len(stamps)
    tol = float(conf["stamp_tolerance"])
    odometry = dataset.optional("odometry") if dataset is not None else None
    increments, has_odo = accumulate_odometry(odometry, stamps)
    imu = dataset.optional("imu") if dataset is not None else None
    if imu is not None:
        yaw, collision = heading_mod.imu_per_frame(imu, stamps, tol)
    else:
        yaw, collision = np.full(n, np.nan), np.zeros(n, dtype=bool)
    truth_th = (heading_mod.truth_heading(dataset.optional("truth"), stamps, tol)
                if conf["heading"] == "truth" else None)
    return FrameSensors(increments, has_odo, yaw, collision, truth_th)


def localise_frames(loc, features, sensors: FrameSensors, *, desc: str,
                    progress: bool = False) -> PoseTrack:
    """Every frame of ``features`` (names, stamps, frame(name)) through a localiser ``loc``
    of the bank (``frame(i, features, dt, odometry, flags)`` -> (hypotheses, top candidate,
    pose, covariance, accepted), or FrameFailed; ``failed(dt, odometry, collision)``; and
    ``radial``, a RadialCorrection or None), recorded as a PoseTrack. A frame's runtime is
    the method's, without reading its features."""
    from tqdm import tqdm

    names = list(features.names)
    stamps = np.asarray(features.stamps, dtype=float)
    track = PoseTrack()
    prev_stamp = None
    for i in tqdm(range(len(names)), desc=desc, unit="frame", disable=not progress):
        name, stamp = names[i], float(stamps[i])
        dt = 0.0 if prev_stamp is None else max(stamp - prev_stamp, 0.0)
        prev_stamp = stamp
        odo = sensors.increments[i] if sensors.has_odometry[i] else None
        col = bool(sensors.collision[i])
        flags = ["collision"] if col else []
        try:
            fr = features.frame(name)
        except (KeyError, OSError) as e:
            fr, reason = None, f"unreadable-features ({e})"
        t0 = time.perf_counter()
        try:
            if fr is None:
                raise FrameFailed(reason)
            hyps, top, pose, cov, accepted = loc.frame(i, fr, dt, odo, flags)
        except FrameFailed as e:
            loc.failed(dt, odo, col)
            log.debug("frame %s failed: %s", name, e)
            track.add(name, stamp, None, error=math.nan, confidence=0.0, mode="failed",
                      runtime=time.perf_counter() - t0, flags=",".join(flags + [str(e)]))
            continue
        track.add(name, stamp, pose, error=top.fix.error_norm, confidence=float(hyps[0, 3]),
                  mode=top.fix.mode, runtime=time.perf_counter() - t0, covariance=cov,
                  flags=",".join(flags), hypotheses=hyps, accepted=accepted)
    if loc.radial is not None:
        track.meta["radial_correction"] = loc.radial.summary()
    return track
