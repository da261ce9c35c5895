"""Monte-Carlo localisation (Schulz et al. (2011), section 5): a sampling-importance-resampling
particle filter over (x, y, theta) on lines, crossings and goal posts from a perspective camera.

Per frame: (1) predict: each particle moved by the odometry with noise (motion_model); (2)
weight: by the likelihood of the frame's observations (observation_model) and, with
``imu_heading_sigma``, of the IMU's yaw as a field heading; a frame with no usable observation
keeps the predicted belief; (3) estimate; (4) resample (low-variance) when the effective sample
size falls below ``RESAMPLE_THRESHOLD``, on injection, or when the particle count changes.

New particles at resampling:
- augmented MCL (Thrun, Burgard and Fox 2005): from slow and fast averages of the mean
  per-observation likelihood (``ALPHA_SLOW``, ``ALPHA_FAST``), a share max(0, 1 - w_fast /
  w_slow) (<= ``MAX_INJECT``) is replaced while the belief is wide, half by poses the frame's
  observations place (``INJECT_FROM_OBSERVATIONS``), half uniformly (mode "recovering", flag
  "injected=N"); while tracking, the share raises the kidnap prior;
- sensor resetting (Lenser and Veloso 2000): ``RESET_POOL`` poses at which one observation is
  explained by a field feature of its kind, drawn by their likelihood under the whole frame. A
  wide belief (spread >= ``SPREAD_HIGH``) places ``SENSOR_RESET_FRACTION`` every frame; a
  tracking one, every ``SENSOR_RESET_EVERY``-th frame (every frame while the likelihood drops),
  places the posterior share of "elsewhere": prior max(``KIDNAP_PROBABILITY``, augmented MCL's
  share) over the hypothesis regions, the best candidate against the belief's predictive
  likelihood sum(w_i L_i). A tracked robot places (almost) nothing, a kidnapped one most;
- ``RIVALS`` (a uniform start's: one frame rarely beats the kidnap prior, and a start settled
  metres off along a touch line would stay there): the pool's best poses, moved by the
  odometry, each summing its log-likelihood ratio against the belief's predictive likelihood,
  forgetting over ``RIVAL_MEMORY`` frames (a sequential test); the best stands for "elsewhere"
  once its sum beats the frame's best candidate. A new rival's sum starts from the frames
  before it (``_retro_odds``, up to ``RIVAL_LOOKBACK``), not from its first ratio counted once
  per earlier frame. Rivals in the best cluster or its mirror, or ``RIVAL_FLOOR`` below the
  belief, are dropped;
- ``RANDOM_FRACTION``: a constant share of uniform particles (0 by default).
Unless the prior was symmetric, each new pose is taken as whichever of itself and its mirror
the belief supports more (kernel density on 256 particles drawn by weight), else the one nearer
the last estimate: no observation tells them apart, and the other only lets the track flip.

Uniform start (``init: uniform``): the first frame with observations is scored on a coarse
grid (``START_GRID``, each pose as anywhere in its cell: place_search.cell_model), and the
``START_PLACES`` best distinct places (1 m or 30 deg apart, up to the mirror), refined on two
local grids (place_search.search), each get an *equal* share of the particles, drawn from the
frame's posterior around it; the grid's likelihood outside them is drawn uniformly (or
``START_UNIFORM_SHARE``). Drawn uniformly, the particles of a sharp peak are few and off it;
drawn by the first frame's likelihood, a broad plateau outweighs a sharp peak: either way
chance picks among places the first frames explain alike. Equal shares keep each place alive
until the frames decide.

Particle count (a stand-in for KLD sampling, Fox 2003): ``INIT_PARTICLES`` at the start,
then ``particles_min`` at spread s = sqrt(var x + var y) <= ``SPREAD_LOW``, ``particles_max``
at s >= ``SPREAD_HIGH`` or while augmented MCL injects, linear between.

Estimate: a weighted histogram (1 m x 1 m x 45 deg bins, summed over 2 x 2 x 2 neighbours)
and three mean-shift steps (``CLUSTER_RADIUS``, ``CLUSTER_HEADING``) find the best cluster: its
weighted mean is the pose, its covariance the covariance, its weight share the confidence,
sqrt(var x + var y) the ``error``. Rivals outside the clusters are hypotheses too, at the odds
their sums give (``_with_rivals``): a particle set alone cannot hold two places that explain a
still robot's frames alike, and would overstate the one it kept.

Symmetry: with both goals white a pose and its mirror (FieldModel.mirror_pose) explain every
image equally. The default ``init: placement`` (own half at either touch line facing into the
field, as robots enter a game; the opponent's with ``start_half: opponent``) breaks it; a frame
is "mirror-ambiguous" when the mirrored pose weighs ``MIRROR_RATIO`` of the best cluster.
``init: uniform`` on a point-symmetric field keeps one particle per mirrored pair
(``SYMMETRIC_PAIRS``), reports the member continuing the last estimate at confidence <= 0.5,
flags every frame and decides ``confidence_up_to_mirror``, unless ``start_half`` names the
first pose's half (``start_half_error``). ``init: pose``: around ``init_pose``, ``init_spread``.

Smoothing (``smooth: true``, offline; smooth.py): ``MclScorer`` scores the particles' poses,
their mirrors and local fits (``local_fit``) by the negative log-likelihood over
``SMOOTH_TEMPERATURE`` (consecutive frames repeat their errors), with the tempered curvature's
inverse as covariance; the causal run is unchanged.

All draws come from one ``np.random.default_rng(seed)``: same inputs and seed, same poses. The
figures behind these choices: docs/results.md, "Why the defaults are what they are".
Lower-case names in double backquotes are conf keys (what a user chooses), upper-case ones
the module's tuned constants.
"""

from __future__ import annotations

import collections
import copy
import logging
import math
import time
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from stages.common.conf import check_bounds
from stages.common.errors import FieldlocError
from stages.common.geometry import compose, inverse, wrap_angle
from stages.common.observations import Observations
from stages.common.poses_file import PoseTrack

from . import heading as heading_mod
from . import motion_model, place_search, smooth
from .heading import check_start_half
from .mcl_clusters import Clustering
from .mcl_placement import PosePlacer
from .observation_model import DEFAULTS as OBSERVATION_DEFAULTS
from .observation_model import ObservationModel
from .smooth import FrameCandidates

log = logging.getLogger(__name__)

# a new rival's odds are summed over the frames of this many of the rivals' memory
# (``RIVAL_MEMORY``) back: a frame that far back weighs exp(-3) ~ 5 % of this one
RIVAL_LOOKBACK = 3.0
_NO_SUPPORT = -30.0  # log belief density below which a pose counts as unsupported
# the most particles a belief may hold (a million: 24 MB a pose array, seconds a frame); more
# would only make a run of a few hundred frames take hours
MAX_PARTICLES = 1_000_000
IMU_STAMP_TOLERANCE = 0.05  # s: an imu.csv row this near a frame gives the frame's heading

# ---------------------------------------------------------------------------- tuned constants
# (the figures behind them: docs/results.md, "Why the defaults are what they are")

# particles of the initial belief by the start (``init``), kept until its spread falls below
# SPREAD_HIGH
INIT_PARTICLES = MappingProxyType({"placement": 1000, "uniform": 4000, "pose": 1000})
SPREAD_LOW = 0.15  # m: belief spread at or below which particles_min are used
SPREAD_HIGH = 0.8  # m: spread at or above which particles_max are used
RESAMPLE_THRESHOLD = 0.5  # resample when the effective sample size < this * N
ALPHA_SLOW = 0.01  # augmented MCL: slow average of the observation likelihood
ALPHA_FAST = 0.1  # ... and the fast one
MAX_INJECT = 0.25  # at most this share of particles injected per frame
RANDOM_FRACTION = 0.0  # constant share of uniform random particles per resampling
SENSOR_RESET_FRACTION = 0.02  # share placed by the landmarks per frame while the belief is
# wide (global localisation)
KIDNAP_PROBABILITY = 1e-3  # per frame, that the robot is not where the belief says: while
# tracking, the landmarks place the posterior share of "elsewhere" (module doc); also the
# smoother's outlier floor (smooth.Transition)
SENSOR_RESET_EVERY = 3  # ... placed at every this many frames with landmarks, at once
RESET_POOL = 100  # candidate poses per frame for the placed shares (by likelihood)
# while tracking, the pool's best poses kept over frames as rivals of the belief, each
# accumulating its evidence against it (a sequential test of "elsewhere"), by the initial
# belief: a uniform start's first frames settle on one of several places that explain
# them alike, and the rivals find the right one later; from the placement (or a given
# pose) the prior has chosen, and rivals there take rendered NAO walks off the truth
# where people's legs and other robots pass for posts
RIVALS = MappingProxyType({"placement": 0, "uniform": 8, "pose": 0})
# a uniform start's first frame with observations places the particles at the places
# where that frame fits best (place_search: the observation model on a coarse grid over
# the world, the best poses that are other places, each refined), an equal share each,
# the grid's likelihood share outside them uniform: every place that explains the frame
# holds particles at its best pose, and the frames that follow decide between them,
# where particles drawn uniformly or placed by one observation reached one of them first
# and held it (module doc)
START_PLACES = 16  # places searched for (0: a uniform belief)
START_GRID = (0.2, 6.0)  # m, deg: the coarse grid's step and turn
START_UNIFORM_SHARE = None  # share of the first particles drawn uniformly; None: the
# grid's share of the likelihood outside the places found
RIVAL_FLOOR = 10.0  # nats: a rival whose evidence falls this far below the belief's is
# dropped
RIVAL_MEMORY = 20.0  # frames: a rival's evidence forgets with this time constant, so that
# one as good as the belief (a random walk) seldom drifts past the kidnap prior
INJECT_FROM_OBSERVATIONS = 0.5  # share of injected poses placed by observed landmarks
WORLD_MARGIN = 0.5  # m around the field where uniform particles may lie
CLUSTER_RADIUS = 0.6  # m
CLUSTER_HEADING = 0.6  # rad
MIRROR_RATIO = 0.5  # mirrored cluster weight / best cluster weight to flag ambiguity
SYMMETRIC_PAIRS = True  # a symmetric prior on a symmetric field keeps its symmetry
SMOOTH_TEMPERATURE = 2.0  # the smoother's frame likelihood is the model's to the power
# 1 / this (consecutive frames' errors are not independent; docs/smoothing.md)

# ---------------------------------------------------------------------------- the presets
# what a user chooses: the start they know, the particle count (speed against accuracy), the
# acceptance threshold, the seed, the IMU's heading, smoothing and the observations used
_DEFAULT = {
    "seed": 0,
    "init": "placement",  # placement | uniform | pose
    "init_pose": None,  # [x, y, theta] for init = pose
    # where the robot's first pose lies (own: x < 0, opponent: x > 0, any): a uniform start
    # then draws its belief on that half, which breaks the field's 180 deg symmetry where no
    # observation can; a placement is on that half's touch lines (the own half for any)
    "start_half": "any",
    "start_half_error": 1e-3,  # probability that start_half is wrong (that share of a
    # uniform start's particles lies on the other half)
    "init_spread": [0.3, 0.3, 0.2],  # m, m, rad: sigma around init_pose; placement uses the
    # first as the spread across the touch line and the last for the heading
    "particles_min": 250,
    "particles_max": 1000,
    "min_confidence": 0.8,  # a frame is accepted when its best cluster holds this share (a
    # belief split evenly between a pose and its mirror holds 0.5 each)
    "hypotheses": 5,  # clusters of the belief listed per frame
    # the IMU's yaw (imu.csv) taken as the field heading plus a small bias, as lut's
    # ``imu_alignment: field``, with this sigma (rad): each frame's particles are weighted by
    # it besides the observations (not on collision frames, where the yaw jolts), which also
    # tells a pose from its mirror; None: the yaw's changes are used on collisions only
    "imu_heading_sigma": None,
    "smooth": False,  # decide every frame with the whole recording (smooth.py, MclScorer):
    # offline; the causal run's poses are then replaced by the smoothed ones
    "observation": dict(OBSERVATION_DEFAULTS),  # camera height, kinds of observation used
}


def _preset(**changes) -> dict:
    c = copy.deepcopy(_DEFAULT)
    for k, v in changes.items():
        if isinstance(v, dict):
            c[k].update(v)
        else:
            c[k] = v
    return c


camera_kinds = ("perspective",)  # the features it reads
confs = {
    "default": _preset(),
    # the paper's ablation: crossings and goal posts only
    "no-lines": _preset(observation={"use_lines": False}),
    # global localisation from anywhere on the field (up to the field's symmetry)
    "uniform": _preset(init="uniform"),
}


@dataclass
class Estimate:
    """The filter's answer for one frame."""

    pose: np.ndarray  # (3,)
    covariance: np.ndarray  # (3, 3)
    confidence: float  # weight share of the best cluster (less the rivals' share)
    mirror_weight: float  # weight share around the mirrored pose
    spread: float  # m, position spread of the whole particle set
    flags: list = field(default_factory=list)
    mode: str = "tracking"
    n_observations: int = 0
    n_particles: int = 0
    injected: int = 0  # augmented MCL's random particles this frame
    hypotheses: np.ndarray | None = None  # (k, 4) x, y, theta, weight share, heaviest first


class ParticleFilter:
    """The particle set and its update; ``step`` runs one frame."""

    def __init__(self, model: ObservationModel, conf: dict | None = None, seed: int | None = None,
                 *, imu_heading: bool = False):
        self.conf = copy.deepcopy(_DEFAULT) if conf is None else conf
        self.model = model
        self.field = model.field
        self.rng = np.random.default_rng(self.conf["seed"] if seed is None else seed)
        self.particles = np.zeros((0, 3))
        self.weights = np.zeros(0)
        self.w_slow: float | None = None
        self.w_fast: float | None = None
        self._last_obs: Observations | None = None
        # the frames bring the IMU's field heading (``imu_heading_sigma`` and an imu.csv):
        # it tells a pose from its mirror (headings pi apart), so particles are never paired
        self.imu_heading = bool(imu_heading)
        self._heading = None  # this frame's IMU field heading (yaw, sigma), or None
        self.paired = False  # particles stand for themselves and their mirrored poses
        self.symmetric = self.field.is_point_symmetric()
        self._last_pose: np.ndarray | None = None
        self._last_estimate: Estimate | None = None
        self._pool: tuple | None = None
        self._prep = None  # this frame's prepared observations (after correct)
        self._since_reset = 0  # frames with landmarks since the last sensor reset
        self._reset_now: bool | None = None  # correct's decision for this frame
        self._kidnap: float | None = None  # this frame's posterior share of "elsewhere"
        # while tracking: rival poses (R, 3) kept over frames, and the log-likelihood ratio
        # of each against the belief's predictive likelihood, summed since it was found
        self._rivals = np.zeros((0, 3))
        self._rival_evidence = np.zeros(0)
        # ... and its log odds against the belief: the same sum with the frame that found it
        self._rival_odds = np.zeros(0)
        # while tracking, the frames a new rival's odds are summed over (_retro_odds): per
        # frame with observations its prepared observations, the belief's reference
        # log-likelihood and the odometry since the frame before; and the odometry since the
        # last of them
        self._recent: collections.deque = collections.deque(maxlen=1)
        self._since_recent = np.zeros(3)
        self._rival_placed: np.ndarray | None = None  # the rival this frame places, if any
        self._n_rivals = 0  # rivals kept, by the initial belief (RIVALS)
        self._start_search = False  # a uniform start: the first observations place the belief
        hx, hy = self.field.length / 2, self.field.width / 2
        m = float(WORLD_MARGIN)
        self._bounds = (-hx - m, hx + m, -hy - m, hy + m)
        self._placer = PosePlacer(model, self._bounds)  # poses placed by observations
        self._clusters = Clustering(self._bounds, float(CLUSTER_RADIUS),
                                    float(CLUSTER_HEADING))

    @classmethod
    def from_field(cls, field_model, conf: dict | None = None) -> ParticleFilter:
        """A filter on a field with ``conf["observation"]`` (crossing tables computed)."""
        conf = copy.deepcopy(_DEFAULT) if conf is None else conf
        return cls(ObservationModel.from_field(field_model, conf["observation"]), conf)

    # ------------------------------------------------------------------ initial belief
    def initialise(self, mode: str | None = None, pose=None, n: int | None = None):
        """The initial belief of ``mode`` (the conf's ``init`` by default): ``n`` particles
        (by default INIT_PARTICLES of the mode; half while each stands for a mirrored pair)."""
        c = self.conf
        mode = mode or c["init"]
        self.paired = (mode == "uniform" and bool(SYMMETRIC_PAIRS)
                       and self.field.is_point_symmetric() and c["start_half"] == "any"
                       and not self.imu_heading)
        n = self._base_count(int(INIT_PARTICLES.get(mode, c["particles_max"]) if n is None
                                 else n))
        self._last_pose = None
        self._last_estimate = None
        self._since_reset = 0
        self._clear_rivals()
        self._n_rivals = int(RIVALS.get(mode, 0))
        self._start_search = mode == "uniform" and int(START_PLACES) > 0
        if mode == "uniform":
            p = self._uniform(n, start=True)
        elif mode == "placement":
            p = self._placement(n)
        elif mode == "pose":
            pose = c["init_pose"] if pose is None else pose
            if pose is None or len(pose) != 3:
                raise FieldlocError("init=pose needs init_pose=[x, y, theta]")
            x0, x1, y0, y1 = self._bounds
            if not (x0 <= float(pose[0]) <= x1 and y0 <= float(pose[1]) <= y1):
                raise FieldlocError(
                    f"init_pose ({float(pose[0]):.4g}, {float(pose[1]):.4g}) m lies off the"
                    f" field and its margin (x within {x0:g}..{x1:g}, y within {y0:g}..{y1:g})")
            s = np.asarray(c["init_spread"], float)
            p = np.asarray(pose, float) + self.rng.standard_normal((n, 3)) * s
            p[:, 2] = wrap_angle(p[:, 2])
        else:
            raise FieldlocError(f"unknown init '{mode}' (placement, uniform or pose)")
        self.particles = p
        self.weights = np.full(n, 1.0 / n)
        self.w_slow = self.w_fast = None

    def _base_count(self, n: int) -> int:
        """Particles held for a belief of ``n``: half when each stands for a mirrored pair."""
        return max(n // 2, 1) if self.paired else n

    def _uniform(self, n: int, *, start: bool = False) -> np.ndarray:
        """``n`` poses drawn uniformly over the world; with ``start``, over the start's
        half where ``start_half`` names one (``start_half_error`` of them on the other)."""
        x0, x1, y0, y1 = self._bounds
        u = self.rng.random((n, 3))
        p = np.stack([x0 + (x1 - x0) * u[:, 0], y0 + (y1 - y0) * u[:, 1],
                      -math.pi + 2 * math.pi * u[:, 2]], axis=1)
        if start and self.conf["start_half"] != "any":
            sign = -1.0 if self.conf["start_half"] == "own" else 1.0
            wrong = self.rng.random(n) < float(self.conf["start_half_error"])
            # folded onto the half (the world is symmetric about x = 0), or off it
            p[:, 0] = np.where(wrong, -sign, sign) * np.abs(p[:, 0])
        return p

    def _start_bounds(self) -> tuple:
        """Where a uniform start's places are searched: the half ``start_half`` names, the
        half x <= 0 while particles stand for mirrored pairs, else the world."""
        x0, x1, y0, y1 = self._bounds
        half = self.conf["start_half"]
        if half == "own" or self.paired:
            return (x0, 0.0, y0, y1)
        if half == "opponent":
            return (0.0, x1, y0, y1)
        return self._bounds

    def _placement(self, n: int) -> np.ndarray:
        """The start's half (``start_half``; own, x < 0, for any), at either touch line,
        facing into the field."""
        fm = self.field
        s_across, s_heading = float(self.conf["init_spread"][0]), float(self.conf["init_spread"][2])
        side = np.where(self.rng.random(n) < 0.5, 1.0, -1.0)
        x = -_placement_sign(self.conf) * self.rng.uniform(-fm.length / 2, 0.0, n)
        across = self.rng.standard_normal(n) * s_across  # beyond the line is outwards
        turn = self.rng.standard_normal(n) * s_heading
        p = fm.touchline_pose(x, side, inset=-across)
        p[:, 2] = wrap_angle(p[:, 2] + turn)
        return p

    # ------------------------------------------------------------------ the update
    def predict(self, odometry, dt: float, has_odometry: bool = True, collision: bool = False,
                imu_yaw: bool = False):
        self.particles = motion_model.sample_motion(
            self.particles, odometry, dt, self.rng, has_odometry=has_odometry,
            collision=collision, imu_yaw=imu_yaw)
        if len(self._rivals):  # the rivals move by the odometry, without noise (each is one
            # pose: a random walk would carry it off the place whose evidence it sums)
            self._rivals = motion_model.moved(self._rivals, *(float(v) for v in odometry))
        if self._n_rivals > 0:
            self._since_recent = compose(self._since_recent, np.asarray(odometry, float))

    def fold(self):
        """Paired mode: hold each particle as whichever of itself and its mirrored pose lies
        nearer to the last estimate (own half, x <= 0, before the first). The belief is the
        same; folding keeps the held set in one piece so that clusters can be found."""
        if not self.paired or not len(self.particles):
            return
        p = self.particles
        if self._last_pose is None:
            flip = p[:, 0] > 0
        else:
            cx, cy = self._last_pose[0], self._last_pose[1]
            flip = (p[:, 0] + cx) ** 2 + (p[:, 1] + cy) ** 2 < (p[:, 0] - cx) ** 2 + (
                p[:, 1] - cy) ** 2
        p[flip, 0:2] *= -1.0
        p[flip, 2] = wrap_angle(p[flip, 2] + math.pi)

    def correct(self, obs: Observations) -> int:
        """Weight the particles by the observations; returns how many were used."""
        prep = self.model.prepare(obs)
        k = len(prep)
        if k == 0:
            return 0
        if self._start_search:
            self._start_search = False
            self._place_start(prep)
        p = self.particles
        # on a resetting frame, candidate poses placed by this frame's observations are
        # weighted in the same call; ``resample`` draws the placed poses from them by their
        # likelihood, and while tracking their best says how likely "elsewhere" is
        self._prep = prep
        self._pool = None
        self._kidnap = None
        self._rival_placed = None
        self._reset_now = self._resetting(prep.obs)
        wide = self._wide()
        if wide:
            self._clear_rivals()
        pool = np.zeros((0, 3))
        if self._reset_now:
            pool = self._poses_from_observations(int(RESET_POOL), prep.obs)
        rivals = self._rivals
        if len(pool) or len(rivals):
            p = np.concatenate([p, pool, rivals])
        ll = self.model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], prep)
        if self._heading is not None:
            ll = ll + heading_log_likelihood(p[:, 2], self._heading)
        n, n_pool = len(self.particles), len(pool)
        ll_pool, ll_rivals = ll[n:n + n_pool], ll[n + n_pool:]
        if n_pool:
            self._pool = (pool, ll_pool)
        ll = ll[:n]
        if not wide:
            lw = np.log(np.maximum(self.weights, 1e-300)) + ll
            top = float(lw.max())
            log_tracked = top + math.log(float(np.exp(lw - top).sum()))
            # the belief's own place, a pose as a rival is: its heaviest particle
            ll_belief = float(ll[int(np.argmax(lw))])
            self._update_rivals(pool, ll_pool, ll_rivals, log_tracked, ll_belief)
            if self._n_rivals > 0:
                self._recent.append((prep, ll_belief, log_tracked, self._since_recent))
                self._since_recent = np.zeros(3)
            if n_pool:
                self._kidnap = self._kidnap_share(log_tracked, ll_pool)
        # augmented MCL: the mean per-observation likelihood under the predicted belief
        w_avg = float(np.dot(self.weights, np.exp(ll / k)))
        if self.w_slow is None:
            self.w_slow = self.w_fast = w_avg
        else:
            self.w_slow += ALPHA_SLOW * (w_avg - self.w_slow)
            self.w_fast += ALPHA_FAST * (w_avg - self.w_fast)
        lw = np.log(np.maximum(self.weights, 1e-300)) + ll
        lw -= lw.max()
        w = np.exp(lw)
        self.weights = w / w.sum()
        self._last_obs = prep.obs
        return k

    def _place_start(self, prep):
        """A uniform start's first frame with observations: the belief placed at the places
        where the frame fits best (place_search.search: ``START_PLACES`` of them on the coarse
        grid ``START_GRID`` over the world, or its half x <= 0 while particles stand for
        mirrored pairs, each refined), an equal share of the particles around each (a
        Gaussian of the frame's posterior near it, place_search.local_posterior), and the
        grid's share of the likelihood outside them uniform over the world (or
        ``START_UNIFORM_SHARE`` when given)."""
        c = self.conf
        n = len(self.particles)
        bounds = self._start_bounds()
        step, turn = (float(v) for v in START_GRID)
        places, elsewhere = place_search.search(
            self.model, prep, bounds, step, turn, int(START_PLACES),
            mirror=self.symmetric, cells=True)
        if not places:
            return
        if START_UNIFORM_SHARE is not None:
            elsewhere = float(START_UNIFORM_SHARE)
        n_uni = int(round(n * min(max(elsewhere, 0.0), 1.0)))
        counts = np.full(len(places), (n - n_uni) // len(places))
        counts[:(n - n_uni) - int(counts.sum())] += 1
        drawn = [self._uniform(n_uni, start=True)]
        for (pose, _ll), m in zip(places, counts):
            mean, cov = place_search.local_posterior(self.model, prep, pose)
            q = mean + self.rng.standard_normal((int(m), 3)) @ np.linalg.cholesky(cov).T
            if self.symmetric and not self.paired and c["start_half"] == "any":
                # the place or its mirror image, alike
                flip = self.rng.random(len(q)) < 0.5
                q[flip] = self.field.mirror_pose(q[flip])
            drawn.append(q)
        p = np.concatenate(drawn)
        p[:, 2] = wrap_angle(p[:, 2])
        self.particles = p
        self.weights = np.full(len(p), 1.0 / len(p))

    def _kidnap_share(self, log_tracked: float, ll_pool: np.ndarray) -> float:
        """The posterior share of "the robot is elsewhere": its prior (the larger of
        ``KIDNAP_PROBABILITY`` and augmented MCL's share, ``inject_share``) spread over the
        world's hypothesis regions (a cluster's radius and heading window), against the
        predicted belief's likelihood sum(w_i L_i) (``log_tracked``, its log). The place it
        would be is the best of this frame's placed poses (its likelihood in this frame) or
        the best rival (its likelihood ratio summed over the frames since it was found), as
        far as either explains more; a rival that does is the one ``resample`` places."""
        log_prior = math.log(self._elsewhere() / self._regions())
        ratio = float(ll_pool.max()) - log_tracked
        if len(self._rival_evidence):
            best = int(np.argmax(self._rival_evidence))
            if self._rival_evidence[best] > ratio:
                ratio = float(self._rival_evidence[best])
                self._rival_placed = self._rivals[best].copy()
        return 1.0 / (1.0 + math.exp(min(-(log_prior + ratio), 700.0)))

    def _clear_rivals(self):
        self._rivals = np.zeros((0, 3))
        self._rival_evidence = np.zeros(0)
        self._rival_odds = np.zeros(0)
        memory = max(float(RIVAL_MEMORY), 1.0)
        self._recent = collections.deque(maxlen=int(math.ceil(RIVAL_LOOKBACK * memory)))
        self._since_recent = np.zeros(3)

    def _update_rivals(self, pool, ll_pool, ll_rivals, log_tracked: float,
                       ll_belief: float | None = None):
        """The sequential test of "elsewhere" while tracking: each rival's evidence grows by its
        log-likelihood ratio against the belief's predictive likelihood in this frame, so a
        place that explains every frame a little better than the belief wins over a few frames
        (one frame's ratio must beat the kidnap prior on its own). The pool's best poses join
        as new rivals, or move a rival they lie within a cluster of to the better of the two
        poses; rivals inside the belief's best cluster (or its mirror), or below the belief by
        ``RIVAL_FLOOR``, are dropped; the ``RIVALS`` strongest are kept."""
        k_max = self._n_rivals
        if k_max <= 0:
            return
        poses = self._rivals.copy()
        keep_share = 1.0 - 1.0 / max(float(RIVAL_MEMORY), 1.0)
        evidence = self._rival_evidence * keep_share + (ll_rivals - log_tracked)
        # the odds compare poses with poses: each rival with the belief's heaviest particle
        # (against the belief's predictive likelihood, a spread belief would lose to any
        # rival as good as its best pose)
        ll_b = log_tracked if ll_belief is None else ll_belief
        odds = self._rival_odds * keep_share + (ll_rivals - ll_b)
        if len(pool):
            top = (np.argpartition(-ll_pool, k_max - 1)[:k_max] if len(pool) > k_max
                   else np.arange(len(pool)))
            q, ll_q = pool[top], ll_pool[top]
            new = np.ones(len(q), bool)
            if len(poses):  # a candidate within a cluster of a rival moves it
                near = (((q[:, None, 0] - poses[None, :, 0]) ** 2
                         + (q[:, None, 1] - poses[None, :, 1]) ** 2
                         <= float(CLUSTER_RADIUS) ** 2)
                        & (np.cos(q[:, None, 2] - poses[None, :, 2])
                           >= math.cos(float(CLUSTER_HEADING))))
                new = ~near.any(axis=1)
                held = np.array(ll_rivals, float)
                for j in np.flatnonzero(~new):
                    i = int(np.argmax(near[j]))
                    if ll_q[j] > held[i]:
                        poses[i], held[i] = q[j], ll_q[j]
            # a new rival's sums start with the frames before this one (_retro_odds); this
            # frame chose it (the best of the pool) and counts in the single frame's test,
            # so its evidence leaves this frame out
            e_q, o_q = self._retro_odds(q[new], keep_share)
            poses = np.concatenate([poses, q[new]])
            evidence = np.concatenate([evidence, e_q])
            odds = np.concatenate([odds, o_q + (ll_q[new] - ll_b)])
        keep = evidence > -float(RIVAL_FLOOR)
        last = self._last_estimate
        if last is not None and len(poses):
            x, y, th = poses[:, 0], poses[:, 1], poses[:, 2]
            cos_t, sin_t = np.cos(th), np.sin(th)
            for centre in (last.pose, self.field.mirror_pose(last.pose)):
                keep &= ~self._clusters.members(centre, x, y, cos_t, sin_t)
        poses, evidence, odds = poses[keep], evidence[keep], odds[keep]
        order = np.argsort(-evidence, kind="stable")[:k_max]
        self._rivals, self._rival_evidence = poses[order], evidence[order]
        self._rival_odds = odds[order]

    def _retro_odds(self, q: np.ndarray, keep_share: float) -> tuple[np.ndarray, np.ndarray]:
        """The sums new rivals ``q`` (R, 3) would hold had each been followed through the
        frames the belief has weighed while tracking (``_recent``), before this one: each
        rival moved back there by the odometry, its log-likelihood there against the
        belief's predictive likelihood then (the evidence) and against the belief's heaviest
        particle then (the odds), forgetting as the rivals' sums do. A place found now is
        scored on what the frames before said of it, not on this frame alone: one frame that
        happens to fit it is not the many frames a rival must win, and a place that fitted
        every frame so far has won them already."""
        evidence, odds = np.zeros(len(q)), np.zeros(len(q))
        if not len(q) or not self._recent:
            return evidence, odds
        p = np.asarray(q, float)
        inc, weight = self._since_recent, 1.0
        for prep, ll_ref, log_tracked, inc_before in reversed(self._recent):
            p = motion_model.moved(p, *inverse(inc))
            weight *= keep_share
            ll = self.model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], prep)
            evidence += weight * (ll - float(log_tracked))
            odds += weight * (ll - float(ll_ref))
            inc = inc_before
        return evidence, odds

    def _elsewhere(self) -> float:
        """The prior probability that the robot is not where the belief says: the larger of
        ``KIDNAP_PROBABILITY`` and augmented MCL's share (``inject_share``)."""
        return max(float(KIDNAP_PROBABILITY), self.inject_share(), 1e-300)

    def _regions(self) -> float:
        """How many hypothesis regions (a cluster's radius and heading window) the world holds:
        a uniform belief's density in the units of ``_log_support`` is about 1 / this."""
        x0, x1, y0, y1 = self._bounds
        return max((x1 - x0) * (y1 - y0) / (math.pi * CLUSTER_RADIUS ** 2)
                   * math.pi / max(CLUSTER_HEADING, 1e-6), 1.0)

    def inject_share(self) -> float:
        """Augmented MCL: the share of random particles, max(0, 1 - w_fast / w_slow)."""
        share = float(RANDOM_FRACTION)
        if self.w_slow and self.w_fast is not None and self.w_slow > 0:
            share += max(0.0, 1.0 - self.w_fast / self.w_slow)
        return min(share, float(MAX_INJECT))

    def resample(self, obs: Observations | None = None, spread: float | None = None):
        """Low-variance resampling when needed, with new particles; returns how many were
        injected by augmented MCL and how many placed by this frame's observations. While the
        belief is wide (global localisation) augmented MCL injects its share and the
        observations place ``SENSOR_RESET_FRACTION`` per frame; while tracking, the placed
        poses are the posterior share of "elsewhere" (``_kidnap_share``)."""
        n = len(self.weights)
        ess = 1.0 / float(np.dot(self.weights, self.weights))
        wide = self._wide()
        share = self.inject_share() if wide else 0.0
        n_target = self._particle_count(spread, share)
        n_aug = int(self.rng.binomial(n_target, share)) if share > 0 else 0
        reset = 0.0
        if obs is not None and self._places(obs):
            now = self._resetting(obs) if self._reset_now is None else self._reset_now
            if now and wide:  # the share of the frames since the last reset
                reset = min(float(SENSOR_RESET_FRACTION) * (self._since_reset + 1), 1.0)
            elif now:
                reset = self._kidnap or 0.0
            self._since_reset = 0 if now else self._since_reset + 1
        n_reset = int(self.rng.binomial(n_target, reset)) if reset > 0 else 0
        aug = self._mirror_guard(self._injected_poses(n_aug, obs)) if n_aug else np.zeros((0, 3))
        placed = (self._mirror_guard(self._placed_poses(n_reset, obs)) if n_reset
                  else np.zeros((0, 3)))
        new = np.concatenate([aug, placed])[: n_target - 1]
        needed = ess < RESAMPLE_THRESHOLD * n or len(new) > 0 or abs(n_target - n) > 0.25 * n
        if not needed:
            return 0, 0
        keep = n_target - len(new)
        cum = np.cumsum(self.weights)
        cum[-1] = 1.0
        u = (self.rng.random() + np.arange(keep)) / keep
        idx = np.searchsorted(cum, u, side="left")
        self.particles = np.concatenate([self.particles[idx], new])
        self.weights = np.full(n_target, 1.0 / n_target)
        n_aug = min(len(aug), len(new))
        return n_aug, len(new) - n_aug

    def _wide(self) -> bool:
        """Whether the belief was wide at the last estimate (spread at or above SPREAD_HIGH:
        global localisation)."""
        last = self._last_estimate
        return last is None or not last.spread < SPREAD_HIGH

    def _resetting(self, obs: Observations) -> bool:
        """Whether this frame places poses by its observations (sensor resetting): it has
        observations that place one (``_places``), and the belief is wide (the last spread at
        or above ``SPREAD_HIGH``: every frame), augmented MCL's averages say the likelihood
        dropped (every frame), or ``SENSOR_RESET_EVERY`` - 1 such frames have passed since the
        last."""
        if not self._places(obs):
            return False
        if self._wide() or self.inject_share() > 0:
            return True
        return self._since_reset + 1 >= max(int(SENSOR_RESET_EVERY), 1)

    @staticmethod
    def _places(obs: Observations) -> bool:
        """Whether ``obs`` holds an observation that places a pose (a crossing, a goal post or
        a line)."""
        return bool(len(obs.crossings) or len(obs.posts) or len(obs.lines))

    def _mirror_guard(self, poses: np.ndarray) -> np.ndarray:
        """Without the pairing of a symmetric prior the track has chosen a side of the field: a
        new pose and its mirror image explain the observations equally, so each new pose is
        taken as whichever of the two the current belief supports more (the new poses can then
        find a lost robot, but not flip the track to the mirrored side). The support is the
        belief's density at the pose (``_log_support``); where the belief holds neither (a far
        kidnap), the one nearer the last estimate."""
        if self.paired or not len(poses):
            return poses
        mirror = poses.copy()
        mirror[:, 0:2] *= -1.0
        mirror[:, 2] = wrap_angle(mirror[:, 2] + math.pi)
        own, other = self._log_support(poses), self._log_support(mirror)
        flip = other > own
        last = self._last_estimate
        if last is not None:
            cx, cy = float(last.pose[0]), float(last.pose[1])
            nearer = (poses[:, 0] + cx) ** 2 + (poses[:, 1] + cy) ** 2 < (
                poses[:, 0] - cx) ** 2 + (poses[:, 1] - cy) ** 2
            none = np.maximum(own, other) < _NO_SUPPORT
            flip = np.where(none, nearer, flip)
        out = poses.copy()
        out[flip] = mirror[flip]
        return out

    def _log_support(self, poses: np.ndarray, held: int = 256) -> np.ndarray:
        """log of the belief's density at ``poses`` (M, 3), up to a constant: the weighted sum
        of Gaussian kernels (``CLUSTER_RADIUS``, ``CLUSTER_HEADING``) on ``held`` particles
        drawn from the belief by their weight (evenly spaced on the weights' cumulative sum,
        no random draw)."""
        w = self.weights
        cum = np.cumsum(w)
        k = min(held, len(w))
        idx = np.minimum(np.searchsorted(cum, (np.arange(k) + 0.5) / k * cum[-1]), len(w) - 1)
        q = self.particles[idx]
        dx = poses[:, 0:1] - q[None, :, 0]
        dy = poses[:, 1:2] - q[None, :, 1]
        e = (dx * dx + dy * dy) / (2.0 * CLUSTER_RADIUS ** 2)
        e += (1.0 - np.cos(poses[:, 2:3] - q[None, :, 2])) / max(CLUSTER_HEADING, 1e-6) ** 2
        top = (-e).max(axis=1)
        return top + np.log(np.exp(-e - top[:, None]).sum(axis=1)) - math.log(len(q))

    def _particle_count(self, spread: float | None, share: float) -> int:
        """Particles (held) after resampling: by the belief's spread between particles_min and
        particles_max; a larger initial set (INIT_PARTICLES) is kept until the belief has
        narrowed below SPREAD_HIGH."""
        c = self.conf
        lo, hi = int(c["particles_min"]), int(c["particles_max"])
        if spread is not None and spread >= SPREAD_HIGH:
            return max(self._base_count(hi), len(self.weights))
        if share > 0 or spread is None:
            return self._base_count(hi)
        f = (spread - SPREAD_LOW) / max(SPREAD_HIGH - SPREAD_LOW, 1e-9)
        return self._base_count(int(round(lo + (hi - lo) * min(max(f, 0.0), 1.0))))

    def _injected_poses(self, n: int, obs: Observations | None) -> np.ndarray:
        """New poses: a share placed by this frame's observations, the rest uniform."""
        n_placed = 0
        out = []
        if obs is not None and self._places(obs):
            n_placed = int(round(n * float(INJECT_FROM_OBSERVATIONS)))
        if n_placed:
            out.append(self._placed_poses(n_placed, obs))
        out.append(self._uniform(n - sum(len(q) for q in out)))
        return np.concatenate(out)

    def _placed_poses(self, n: int, obs: Observations) -> np.ndarray:
        """``n`` poses explained by this frame's observations: drawn from the candidate pool of
        ``correct`` in proportion to their likelihood under all of the frame's observations
        (likelihood-filtered sensor resetting), else placed directly."""
        if n <= 0:
            return np.zeros((0, 3))
        if self._rival_placed is not None:  # a rival won the sequential test: around it
            spread = np.array([CLUSTER_RADIUS, CLUSTER_RADIUS, CLUSTER_HEADING])
            p = self._rival_placed + self.rng.standard_normal((n, 3)) * (spread / 6.0)
            p[:, 2] = wrap_angle(p[:, 2])
            return p
        if self._pool is None and self._prep is not None:  # not weighted with the particles
            pool = self._poses_from_observations(int(RESET_POOL), self._prep.obs)
            ll = (self.model.log_likelihood(pool[:, 0], pool[:, 1], pool[:, 2], self._prep)
                  if len(pool) else None)
            self._pool = (pool, ll)
        pool, ll = self._pool if self._pool is not None else (np.zeros((0, 3)), None)
        if not len(pool):
            return self._poses_from_observations(n, obs)
        w = np.exp(ll - ll.max())
        cum = np.cumsum(w / w.sum())
        cum[-1] = 1.0
        idx = np.searchsorted(cum, (self.rng.random() + np.arange(n)) / n, side="left")
        return pool[idx]

    def _poses_from_observations(self, n: int, obs: Observations) -> np.ndarray:
        """Poses at which one observation of the frame is explained by a random field feature
        of its kind (sensor resetting, mcl_placement.PosePlacer)."""
        usable = obs if self._prep is not None and obs is self._prep.obs else self.model.usable(obs)
        return self._placer.poses(n, usable, self.rng)

    # ------------------------------------------------------------------ the estimate
    def estimate(self) -> Estimate:
        """The pose (weighted mean of the best cluster), its covariance and confidence (the
        cluster's weight share), the weight around the mirrored pose, and the belief's
        hypotheses: its clusters, heaviest first (at most ``hypotheses``), each a pose with its
        weight share; on a point-symmetric field the best cluster's mirror image is always
        among them."""
        c = self.conf
        p, w = self.particles, self.weights
        x, y, th = (np.ascontiguousarray(p[:, k]) for k in range(3))
        cos_t, sin_t = np.cos(th), np.sin(th)
        centre = self._clusters.heaviest(w, x, y, th, cos_t, sin_t)
        wm = w * self._clusters.members(centre, x, y, cos_t, sin_t)
        conf_share = float(wm.sum())
        mirror = self.field.mirror_pose(centre)
        in_mirror = self._clusters.members(mirror, x, y, cos_t, sin_t)
        mirror_share = float(w @ in_mirror)
        cov = np.full((3, 3), np.nan)
        if conf_share > 0:
            d = np.stack([x - centre[0], y - centre[1], wrap_angle(th - centre[2])])
            dw = d * (wm / conf_share)
            cov = dw @ d.T
        mx, my = float(w @ x), float(w @ y)
        spread = math.sqrt(max(float(w @ ((x - mx) ** 2 + (y - my) ** 2)), 0.0))
        flags = []
        n_particles = len(p)
        if self.paired:  # the belief is half the held set, half its mirror image
            conf_share = mirror_share = 0.5 * (conf_share + mirror_share)
            n_particles *= 2
        if conf_share > 0 and mirror_share >= MIRROR_RATIO * conf_share:
            flags.append("mirror-ambiguous")
        rows = [(*centre, conf_share)]
        if self.symmetric:
            rows.append((*mirror, mirror_share))
        rest = w * ~(self._clusters.members(centre, x, y, cos_t, sin_t) | in_mirror)
        scale = 0.5 if self.paired else 1.0  # a held particle stands for two poses
        while len(rows) < int(c["hypotheses"]) and rest.sum() > 1e-3:
            other = self._clusters.heaviest(rest, x, y, th, cos_t, sin_t)
            members = self._clusters.members(other, x, y, cos_t, sin_t)
            share = float(rest @ members)
            if share <= 0:
                break
            rows.append((*other, share * scale))
            if self.paired:
                rows.append((*self.field.mirror_pose(other), share * scale))
            rest = rest * ~members
        rows.sort(key=lambda r: -r[3])  # stable: the best cluster before its mirror on a tie
        rows, belief = self._with_rivals(rows)
        conf_share, mirror_share = conf_share * belief, mirror_share * belief
        return Estimate(pose=centre, covariance=cov, confidence=conf_share,
                        mirror_weight=mirror_share, spread=spread, flags=flags,
                        n_particles=n_particles,
                        hypotheses=np.array(rows[:int(c["hypotheses"])], float))

    def _with_rivals(self, rows: list) -> tuple[list, float]:
        """The belief's hypotheses ``rows`` (heaviest first) beside its rivals (a uniform
        start's places kept over frames, ``_update_rivals``), and the share of the belief in
        the whole. Each rival not inside a listed cluster (or its mirror image) holds, against
        the belief, the odds its log-likelihood ratio against the belief's heaviest particle,
        summed over the frames, gives (with the rivals' forgetting; a rival found now is
        scored on the frames before it, ``_retro_odds``; a place and the belief have the same
        prior after a uniform start):
        the belief's rows are scaled by 1 / (1 + sum of the odds), a rival's row holds its
        odds over the same sum (half of it, and half its mirror image, while particles stand
        for mirrored pairs). The belief's best cluster stays first (it is the frame's pose),
        and its mirror image second on a point-symmetric field, as the belief lists them.
        A particle set cannot hold two places that explain a still robot's frames alike:
        which keeps the mass is the luck of the first frames (the poses placed by the
        observations land at one of them first), while the rivals find the other."""
        if not len(self._rivals) or not rows:
            return rows, 1.0
        def near(a, b) -> bool:  # b a member of a's cluster (the clusters' own rule)
            return bool(self._clusters.members(a, b[0], b[1], math.cos(b[2]), math.sin(b[2])))

        held = [np.asarray(r[:3], float) for r in rows]
        found = []
        for i in np.argsort(-self._rival_odds, kind="stable"):
            pose = self._rivals[i]
            images = (pose, self.field.mirror_pose(pose)) if self.symmetric else (pose,)
            if any(near(h, q) for h in held for q in images):
                continue
            found.append((pose, math.exp(min(float(self._rival_odds[i]), 50.0))))
            held.append(pose)
        if not found:
            return rows, 1.0
        total = 1.0 + sum(o for _, o in found)
        out = [(*r[:3], r[3] / total) for r in rows]
        for pose, o in found:
            if self.paired:
                half = 0.5 * o / total
                out += [(*pose, half), (*self.field.mirror_pose(pose), half)]
            else:
                out.append((*pose, o / total))
        pinned = 2 if self.symmetric and len(rows) > 1 else 1  # the pose and its mirror
        return out[:pinned] + sorted(out[pinned:], key=lambda r: -r[3]), 1.0 / total

    # ------------------------------------------------------------------ one frame
    def step(self, odometry, dt: float, obs: Observations, *, has_odometry: bool = True,
             first: bool = False, collision: bool = False, imu_yaw: bool = False,
             heading=None) -> Estimate:
        """Predict (unless ``first``), weight, estimate, resample. Returns the estimate.
        ``collision``: the IMU flags a collision since the last frame (``imu_yaw``: the
        odometry's dtheta was replaced by the IMU's yaw change); ``heading``: the IMU's field
        heading this frame, (yaw, sigma) rad, or None."""
        if not first:
            self.predict(odometry, dt, has_odometry, collision, imu_yaw)
        self._heading = heading
        self.fold()
        self._last_obs = None
        self._pool = None
        self._prep = None
        self._reset_now = None
        k = self.correct(obs)
        est = self.estimate()
        self._last_pose = est.pose
        self._last_estimate = est
        est.n_observations = k
        # a frame without observations brings no information: keep the predicted belief
        injected, _placed = self.resample(self._last_obs, est.spread) if k else (0, 0)
        est.injected = injected
        if k == 0:
            est.flags.append("no-observations")
            est.mode = "predicted"
        elif injected:
            est.flags.append(f"injected={injected}")
            est.mode = "recovering"
        if first:
            est.mode = "initial"
        return est


# ---------------------------------------------------------------------------- the stage


def _iterate(items, progress):
    if callable(progress):
        return progress(items)
    if progress:
        from tqdm import tqdm

        return tqdm(items, desc="mcl", unit="frame")
    return items


def _camera_height(dataset) -> float | None:
    """The camera's height above the floor from the dataset's perspective calibration (None
    without one: the observation model's default)."""
    if dataset is None:
        return None
    try:
        camera = dataset.camera()
    except FieldlocError:
        return None
    h = getattr(camera, "height", None)
    return float(h) if h is not None and math.isfinite(h) and h > 0 else None


def run(conf: dict, dataset, features, map_file, progress=None) -> PoseTrack:
    """Localise every frame of ``features`` (stages.common.features_file.FeaturesFile, with
    perspective features) on ``map_file`` (stages.common.map_file.MapFile) with the odometry of
    ``dataset`` (stages.common.dataset.Dataset, or None: no odometry). ``conf``: a resolved
    preset of ``confs``. ``progress``: None/False, True (tqdm), or a callable wrapping an
    iterable. With ``smooth`` the causal run's track is then smoothed with the whole
    recording (``MclScorer``, smooth.py)."""
    if features is None or map_file is None:
        raise FieldlocError("mcl needs a features file and a map")
    kind = features.camera_kind
    if kind and kind not in camera_kinds:
        raise FieldlocError(
            f"{features.path}: features of a '{kind}' camera; --method mcl needs perspective"
            " features (lines, crossings, goal posts)")
    _check_conf(conf)
    obs_conf = dict(conf["observation"])
    if obs_conf["camera_height"] is None:
        obs_conf["camera_height"] = _camera_height(dataset)
    model = ObservationModel.from_map(map_file, obs_conf)
    odometry = dataset.optional("odometry") if dataset is not None else None
    stamps = np.asarray(features.stamps, float)
    increments, _has = motion_model.accumulate_odometry(odometry, stamps)
    imu = dataset.optional("imu") if dataset is not None else None
    collision, dyaw = motion_model.imu_per_frame(imu, stamps)
    imu_yaw = collision & np.isfinite(dyaw)
    increments[imu_yaw, 2] = dyaw[imu_yaw]  # a pushed robot's odometry does not know its turn
    headings = frame_headings(imu, stamps, collision, conf["imu_heading_sigma"])
    pf = ParticleFilter(model, conf, imu_heading=any(h is not None for h in headings))
    pf.initialise()
    keep = SmoothingInputs() if conf["smooth"] else None
    track = PoseTrack()
    prev_stamp = None
    for i in _iterate(range(len(features.names)), progress):
        name = features.names[i]
        stamp = float(stamps[i])
        t0 = time.perf_counter()
        reason = None
        try:
            obs = Observations.from_features(features.frame(name))
        except (KeyError, ValueError) as e:
            log.warning("frame %s: unreadable features (%s); prediction only", name, e)
            obs = Observations.empty()
            reason = "unreadable-features"
        dt = 0.0 if prev_stamp is None else max(stamp - prev_stamp, 0.0)
        est = pf.step(increments[i], dt, obs, has_odometry=odometry is not None,
                      first=prev_stamp is None, collision=bool(collision[i]),
                      imu_yaw=bool(imu_yaw[i]), heading=headings[i])
        if keep is not None:
            keep.add(pf, est, reason)
        if collision[i]:
            est.flags.append("collision")
        prev_stamp = stamp
        runtime = time.perf_counter() - t0
        accepted = est.confidence >= conf["min_confidence"]
        if not accepted:
            est.flags.append("low-confidence")
        track.add(name, stamp, est.pose, hypotheses=est.hypotheses, accepted=accepted,
                  error=float(np.sqrt(max(np.trace(est.covariance[:2, :2]), 0.0)))
                  if np.all(np.isfinite(est.covariance)) else math.nan,
                  confidence=est.confidence, mode=est.mode, runtime=runtime,
                  covariance=est.covariance, flags=",".join(est.flags))
    if keep is None:
        return track
    scorer = MclScorer(model, keep, mirrored=pf.symmetric,
                       temperature=float(SMOOTH_TEMPERATURE))
    motion = motion_of(increments, stamps, odometry is not None, collision, imu_yaw)
    x0, x1, y0, y1 = pf._bounds
    # the smoother's outlier floor: the filter's kidnap prior
    return smooth.smooth_track(scorer, track, motion, conf,
                               kidnap_probability=KIDNAP_PROBABILITY,
                               area=(x1 - x0) * (y1 - y0),
                               log_prior0=start_prior(conf, model.field))


# the ranges mcl's numeric keys must lie in to run at all (common.conf.check_bounds; the
# particle counts below); an init_spread beyond MAX_INIT_SPREAD (m, rad) puts the particles
# off any field (the largest is 22 m long) and spreads the heading uniformly many times over
MAX_INIT_SPREAD = 100.0
BOUNDS = {"seed": (0, None), "hypotheses": (1, 1000), "init_spread": (0, MAX_INIT_SPREAD, 3),
          "init_pose": (None, None, 3), "observation.camera_height": ((0,), 10.0)}


def _check_conf(conf: dict):
    check_bounds(conf, BOUNDS)
    counts = {"particles_min": conf["particles_min"], "particles_max": conf["particles_max"]}
    for key, v in counts.items():
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_PARTICLES:
            raise FieldlocError(f"{key} must be a whole number in 1..{MAX_PARTICLES}, not"
                                f" {str(v)[:40]}")
    if conf["particles_min"] > conf["particles_max"]:
        raise FieldlocError(f"particles_min ({conf['particles_min']}) must not exceed"
                            f" particles_max ({conf['particles_max']})")
    if not isinstance(conf["smooth"], bool):
        raise FieldlocError(f"smooth must be true or false, not {str(conf['smooth'])[:40]!r}")
    s = conf["imu_heading_sigma"]
    if s is not None and (isinstance(s, bool) or not isinstance(s, (int, float))
                          or not 0 < s < math.inf):
        raise FieldlocError(f"imu_heading_sigma must be a number > 0 (rad) or null, not"
                            f" {str(s)[:40]}")
    check_start_half(conf)


# ---------------------------------------------------------------------------- the smoother

# places the sensor-resetting pool of a frame adds to the smoother's candidates (its best
# poses that are other places, place_search.separate)
POOL_PLACES = 4
# the local fit (``local_fit``): the stencil's step in x, y (m) and theta (rad), and its
# schedule (scale of the step, iterations)
FIT_STEP = (0.04, 0.04, math.radians(2.0))
FIT_SCHEDULE = ((1.0, 1), (0.5, 1), (0.25, 1))
# ... and its anchor at the start (m, m, rad): of the order of the smoother's state sigmas
# (smooth.STATE_SIGMA_M, STATE_SIGMA_RAD)
FIT_ANCHOR = (0.1, 0.1, 0.05)
# a fix's covariance: a weak prior (sigma 3 m, 3 m, 1 rad) where the frame says nothing (so
# that such fixes, which only follow the odometry, do not pull the pose graph), and a floor
# (1 cm, 0.5 deg: the fit's resolution) where it says much
COV_PRIOR = (3.0, 3.0, 1.0)
COV_FLOOR = (0.01, 0.01, math.radians(0.5))
# m: the soft edge of a placement's own half in the smoother's start prior (the causal
# placement draws x <= 0 only; a candidate fitted a few centimetres past the centre line is
# still one of its poses)
PLACEMENT_EDGE = 0.1


def _stencil():
    """The 27 offsets of a 3 x 3 x 3 stencil (in steps) and the pseudo-inverse of their
    full quadratic's design matrix (1, x, y, t, x^2, y^2, t^2, xy, xt, yt)."""
    o = np.stack(np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0],
                             indexing="ij"), axis=-1).reshape(-1, 3)
    a = np.column_stack([np.ones(len(o)), o, o ** 2, o[:, 0] * o[:, 1], o[:, 0] * o[:, 2],
                         o[:, 1] * o[:, 2]])
    return o, np.linalg.pinv(a)


_STENCIL = _stencil()
_CENTRE = 13  # the stencil's offset (0, 0, 0)


def _quadratic(ll: np.ndarray):
    """Gradient (M, 3) and Hessian (M, 3, 3) of the quadratics fitted to the stencil values
    ``ll`` (M, 27), in stencil steps."""
    coef = ll @ _STENCIL[1].T
    g = coef[:, 1:4]
    h = np.empty((len(ll), 3, 3))
    h[:, 0, 0], h[:, 1, 1], h[:, 2, 2] = 2 * coef[:, 4], 2 * coef[:, 5], 2 * coef[:, 6]
    h[:, 0, 1] = h[:, 1, 0] = coef[:, 7]
    h[:, 0, 2] = h[:, 2, 0] = coef[:, 8]
    h[:, 1, 2] = h[:, 2, 1] = coef[:, 9]
    return g, h


def local_fit(model: ObservationModel, prep, starts: np.ndarray, step=FIT_STEP,
              schedule=FIT_SCHEDULE, anchor=FIT_ANCHOR):
    """The frame's best poses near ``starts`` (M, 3): damped Newton steps (Levenberg 1944,
    Marquardt 1963) on the observation model's log-likelihood less a Gaussian anchor at the
    start (``anchor``: its sigmas in x, y, theta), the gradient and Hessian from a full
    quadratic fitted on a 3 x 3 x 3 stencil around the pose (the likelihood is a minimum over
    associations, so its derivatives exist piecewise only, and it is rough at the scale of a
    centimetre: a quadratic over the stencil is a smoothed one). ``schedule``: (scale of
    ``step``, iterations) from coarse to fine. A Newton step is taken only where it finds a
    higher objective than the stencil's best pose, which is taken otherwise, so the objective
    never falls. The anchor keeps a fix where the frame says nothing (along the only line it
    sees) at the start, where the odometry put it, instead of wherever the plateau's noise
    leads. Returns the poses (M, 3), their log-likelihoods (M,, without the anchor) and the
    log-likelihood's Hessian (M, 3, 3, field units) on the stencil of ``step`` at each."""
    offsets = _STENCIL[0]
    start = np.array(starts, float, copy=True).reshape(-1, 3)
    m = len(start)
    if not m:
        return start, np.zeros(0), np.zeros((0, 3, 3))
    sig = np.asarray(anchor, float)
    rows = np.arange(m)

    def penalty(q):  # poses (M, K, 3) -> the anchor's -log density (M, K)
        d = q - start[:, None, :]
        d[..., 2] = wrap_angle(d[..., 2])
        return 0.5 * np.sum((d / sig) ** 2, axis=-1)

    def stencil(p, h):  # the objective and log-likelihood on the stencil (M, 27)
        q = p[:, None, :] + offsets[None, :, :] * h
        ll = model.log_likelihood(q[..., 0].ravel(), q[..., 1].ravel(), q[..., 2].ravel(),
                                  prep).reshape(m, -1)
        return q, ll - penalty(q), ll

    p = start.copy()
    top_ll = model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], prep)
    top = top_ll.copy()
    for scale, iterations in schedule:
        h = np.asarray(step, float) * scale
        for _ in range(int(iterations)):
            q, obj, ll = stencil(p, h)
            g, hs = _quadratic(obj)
            best = np.argmax(obj, axis=1)
            top, top_ll, p = obj[rows, best], ll[rows, best], q[rows, best]
            # Newton on the objective where its quadratic is concave, at most 1.5 steps in
            # each axis (from the stencil's centre)
            concave = np.linalg.eigvalsh(hs).max(axis=1) < 0
            if not concave.any():
                continue
            s = np.zeros((m, 3))
            s[concave] = -np.linalg.solve(hs[concave], g[concave][:, :, None])[:, :, 0]
            newton = q[:, _CENTRE] + np.clip(s, -1.5, 1.5) * h
            ll_n = model.log_likelihood(newton[:, 0], newton[:, 1], newton[:, 2], prep)
            obj_n = np.where(concave, ll_n - penalty(newton[:, None, :])[:, 0], -np.inf)
            better = obj_n > top
            top = np.where(better, obj_n, top)
            top_ll = np.where(better, ll_n, top_ll)
            p = np.where(better[:, None], newton, p)
    p[:, 2] = wrap_angle(p[:, 2])
    h = np.asarray(step, float)
    _, _, ll = stencil(p, h)
    _, hs = _quadratic(ll)
    return p, top_ll, hs / (h[:, None] * h[None, :])


def fix_covariance(hessian: np.ndarray, temperature: float) -> np.ndarray:
    """Covariances (M, 3, 3) of fixes from the log-likelihood's Hessian (M, 3, 3) at each:
    the inverse of the tempered information (the negative Hessian over the temperature, its
    negative eigenvalues taken as 0: no information) with a weak prior (``COV_PRIOR``), plus
    the fit's resolution (``COV_FLOOR``)."""
    info = -0.5 * (hessian + np.swapaxes(hessian, 1, 2)) / float(temperature)
    w, v = np.linalg.eigh(info)
    info = np.einsum("mij,mj,mkj->mik", v, np.maximum(w, 0.0), v)
    info = info + np.diag(1.0 / np.square(COV_PRIOR))
    return np.linalg.inv(info) + np.diag(np.square(COV_FLOOR))


def frame_headings(imu: dict | None, stamps: np.ndarray, collision: np.ndarray,
                   sigma: float | None) -> list:
    """Per frame the IMU's field heading (yaw, ``sigma``) rad, or None: without
    ``imu_heading_sigma``, without an imu.csv row within IMU_STAMP_TOLERANCE of the frame,
    and on collision frames (the yaw jolts)."""
    if sigma is None or imu is None:
        return [None] * len(stamps)
    yaw, _col = heading_mod.imu_per_frame(imu, stamps, IMU_STAMP_TOLERANCE)
    return [(float(y), float(sigma)) if np.isfinite(y) and not c else None
            for y, c in zip(yaw, collision)]


def heading_log_likelihood(theta: np.ndarray, heading: tuple[float, float]) -> np.ndarray:
    """log N(theta; yaw, sigma^2) of poses' headings under the IMU's field heading (yaw, sigma),
    up to a constant: the term a frame's IMU heading adds to its particles' weights."""
    yaw, sigma = heading
    return -0.5 * (wrap_angle(np.asarray(theta, float) - yaw) / sigma) ** 2


class SmoothingInputs:
    """What the causal run keeps per frame for the smoother: the frame's prepared
    observations (None without usable ones) and why, and the poses the particle set held (its
    clusters, the best places of the sensor-resetting pool)."""

    def __init__(self):
        self.prepared: list = []
        self.reasons: list = []
        self.modes: list = []
        self.headings: list = []  # the IMU's field heading (yaw, sigma) per frame, or None

    def add(self, pf: ParticleFilter, est: Estimate, reason: str | None = None):
        prep = pf._prep
        if prep is None and reason is None:
            reason = "no-observations"
        self.prepared.append(prep)
        self.reasons.append(reason)
        self.headings.append(pf._heading)
        modes = [np.asarray(est.hypotheses, float).reshape(-1, 4)[:, :3]]
        if pf._pool is not None and len(pf._pool[0]):
            pool, ll = pf._pool
            modes.append(pool[place_search.separate(pool, ll, POOL_PLACES, mirror=False)])
        self.modes.append(np.concatenate(modes))


class MclScorer:
    """Method mcl's candidates for the smoother (smooth.Scorer) after a causal run: a frame's
    global candidates are the poses its particle set held (the clusters of the belief, the
    best places of the observations' pool where the frame reset) and, on a point-symmetric
    field, their mirror images; its local candidates the given starts; each fitted to the
    frame's observations (``local_fit``). The nll is the observation model's negative
    log-likelihood there over ``temperature``; the covariance the inverse of the tempered
    curvature (``fix_covariance``), its error term the covariance's position spread (m, as
    the causal run's)."""

    def __init__(self, model: ObservationModel, inputs: SmoothingInputs, *, mirrored: bool,
                 temperature: float = 1.0):
        self.model = model
        self.inputs = inputs
        self.frames = len(inputs.prepared)
        self.mirrored = bool(mirrored)
        self.temperature = float(temperature)

    def failed(self, i: int) -> str | None:
        return self.inputs.reasons[i]

    def _fixes(self, i: int, starts: np.ndarray) -> FrameCandidates:
        starts = np.asarray(starts, float).reshape(-1, 3)
        prep = self.inputs.prepared[i]
        if prep is None or not len(starts):
            return FrameCandidates.empty()
        poses, ll, hess = local_fit(self.model, prep, starts)
        if self.inputs.headings[i] is not None:  # the IMU's heading, as the causal run's
            ll = ll + heading_log_likelihood(poses[:, 2], self.inputs.headings[i])
        cov = fix_covariance(hess, self.temperature)
        error = np.sqrt(np.maximum(cov[:, 0, 0] + cov[:, 1, 1], 0.0))
        return FrameCandidates(poses, -ll / self.temperature, cov, error)

    def global_candidates(self, i: int) -> FrameCandidates:
        starts = self.inputs.modes[i]
        if self.mirrored:
            starts = np.concatenate([starts, self.model.field.mirror_pose(starts)])
        return self._fixes(i, starts)

    def local_candidates(self, i: int, starts: np.ndarray) -> FrameCandidates:
        return self._fixes(i, starts)


def motion_of(increments: np.ndarray, stamps: np.ndarray, has_odometry: bool,
              collision: np.ndarray, imu_yaw: np.ndarray) -> smooth.Motion:
    """The run's smooth.Motion: per frame the odometry increment and the motion model's
    noise of that update (motion_model.motion_sigmas) as its covariance."""
    n = len(increments)
    cov = np.zeros((n, 3, 3))
    for i in range(n):
        dt = float(stamps[i] - stamps[i - 1]) if i else 0.0
        s_t, s_r = motion_model.motion_sigmas(increments[i], max(dt, 0.0),
                                              has_odometry=has_odometry,
                                              collision=bool(collision[i]),
                                              imu_yaw=bool(imu_yaw[i]))
        cov[i] = np.diag([s_t * s_t, s_t * s_t, s_r * s_r])
    return smooth.Motion(np.asarray(increments, float), cov)


def _placement_sign(conf: dict) -> float:
    """The sign of x on the half a placement stands on: the opponent half when
    ``start_half`` says so, else the own half."""
    return 1.0 if conf["start_half"] == "opponent" else -1.0


def start_prior(conf: dict, field_model):
    """The log prior over the smoother's first candidates that the causal run's initial
    belief states (``ParticleFilter.initialise``), or None: ``placement``, on its half's
    stretch of the touch lines (the own half, from the centre line to the goal line at x =
    -length / 2, or the opponent half for ``start_half`` opponent; beyond it by d, -d^2 / (2
    ``PLACEMENT_EDGE``^2)), at either touch line facing into the field, with the
    placement's spread across the line and in heading (``init_spread``); ``pose``, a Gaussian
    of ``init_spread`` around ``init_pose``; ``uniform``, the half ``start_half`` names (none
    for any)."""
    init = conf["init"]
    spread = np.asarray(conf["init_spread"], float)
    if init == "placement":
        def prior(cands: FrameCandidates) -> np.ndarray:
            p = cands.poses
            best = np.full(len(p), -np.inf)
            for side in (1.0, -1.0):
                at = field_model.touchline_pose(p[:, 0], side)
                across = (p[:, 1] - at[:, 1]) / spread[0]
                turn = wrap_angle(p[:, 2] - at[:, 2]) / spread[2]
                best = np.maximum(best, -0.5 * (across ** 2 + turn ** 2))
            # the placement's stretch of the touch line: the centre line to the goal line
            along = _placement_sign(conf) * p[:, 0]
            beyond = np.maximum(-along, 0.0) + np.maximum(along - 0.5 * field_model.length, 0.0)
            return best - 0.5 * (beyond / PLACEMENT_EDGE) ** 2
        return prior
    if init == "pose" and conf["init_pose"] is not None:
        centre = np.asarray(conf["init_pose"], float)

        def prior(cands: FrameCandidates) -> np.ndarray:
            d = cands.poses - centre
            d[:, 2] = wrap_angle(d[:, 2])
            return -0.5 * np.sum((d / spread) ** 2, axis=1)
        return prior
    if init == "uniform":
        return smooth.start_half_prior(conf, True)
    return None
