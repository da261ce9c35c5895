"""Monte-Carlo localisation (Schulz et al. (2011), section 5): a sampling-importance-resampling
particle filter over (x, y, theta) on lines, crossings and goal posts from a perspective camera.

Per frame (``ParticleFilter.step``): (1) predict: each particle moved by the odometry with
noise (motion_model); (2) weight: by the likelihood of the frame's observations
(observation_model) and, with ``imu_heading_sigma``, of the IMU's yaw as a field heading
(heading.heading_log_likelihood); a frame with no usable observation keeps the predicted
belief; (3) estimate; (4) resample, with new particles placed by the frame's observations or
drawn uniformly. The filter holds the particle set and orchestrates; its parts are modules of
their own:

- mcl_start: the initial belief (``init``: placement, uniform or pose) and a uniform start's
  places found by its first frame with observations;
- mcl_resampling: the particle count, low-variance resampling, augmented MCL (Thrun, Burgard
  and Fox 2005) and sensor resetting (Lenser and Veloso 2000), the mirror guard on new poses;
- mcl_rivals: the odds that the robot is elsewhere (the kidnap share) and the rival places kept
  over frames after a uniform start;
- mcl_placement (poses a frame's observations place), mcl_clusters (the estimate's clusters),
  mcl_smoothing (the smoother's candidates with ``smooth: true``, smooth.py).

What one frame's weighting finds (its prepared observations, the poses its observations
placed, the kidnap share) is a value (mcl_resampling.Frame) handed to its resampling and to the
smoother's inputs; the filter keeps over frames only the particles, augmented MCL's averages,
the rivals, the frames since the last sensor reset and the last estimate.

Estimate: a weighted histogram (1 m x 1 m x 45 deg bins, summed over 2 x 2 x 2 neighbours)
and three mean-shift steps (``CLUSTER_RADIUS``, ``CLUSTER_HEADING``) find the best cluster: its
weighted mean is the pose, its covariance the covariance, its weight share the confidence,
sqrt(var x + var y) the ``error``. The rivals outside the clusters are hypotheses too, at the
odds their sums give (mcl_rivals.Rivals.with_rivals).

Symmetry: with both goals white a pose and its mirror (FieldModel.mirror_pose) explain every
image equally. The default ``init: placement`` (own half at either touch line facing into the
field, as robots enter a game; the opponent's with ``start_half: opponent``) breaks it; a frame
is "mirror-ambiguous" when the mirrored pose weighs ``MIRROR_RATIO`` of the best cluster.
``init: uniform`` on a point-symmetric field keeps one particle per mirrored pair
(mcl_start.SYMMETRIC_PAIRS), reports the member continuing the last estimate at confidence
<= 0.5, flags every frame and decides ``confidence_up_to_mirror``, unless ``start_half`` names
the first pose's half (``start_half_error``): that half, carried to later frames by the
odometry (start_half.StartHalf), then decides which of a pose and its mirror image each pose
the filter adds stands for (the first frame's places, sensor resets, augmented MCL, the
rivals). ``init: pose``: around ``init_pose``, ``init_spread``.

All draws come from one ``np.random.default_rng(seed)``: same inputs and seed, same poses. The
figures behind the tuned constants: docs/results.md, "Why the defaults are what they are".
Lower-case names in double backquotes are conf keys (what a user chooses), upper-case ones
tuned constants.
"""

from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from stages.common.conf import SCALAR, check_bounds
from stages.common.errors import FieldlocError
from stages.common.geometry import wrap_angle
from stages.common.observations import Observations
from stages.common.poses_file import PoseTrack

from . import mcl_start, motion_model, smooth
from .heading import check_start_half, frame_headings, heading_log_likelihood
from .mcl_clusters import Clustering
from .mcl_placement import PosePlacer
from .mcl_resampling import (
    RESAMPLE_THRESHOLD,
    RESET_POOL,
    SPREAD_HIGH,
    Belief,
    Frame,
    LikelihoodAverages,
    NewPoses,
    low_variance,
    mirror_guard,
    particle_count,
    places,
    reset_share,
    resetting,
)
from .mcl_rivals import Rivals
from .mcl_smoothing import (
    SMOOTH_KIDNAP_PROBABILITY,
    SMOOTH_TEMPERATURE,
    MclScorer,
    SmoothingInputs,
    motion_of,
    start_prior,
)
from .observation_model import BOUNDS as OBSERVATION_BOUNDS
from .observation_model import DEFAULTS as OBSERVATION_DEFAULTS
from .observation_model import ObservationModel
from .start_half import StartHalf

log = logging.getLogger(__name__)

# the most particles a belief may hold (a million: 24 MB a pose array, seconds a frame); more
# would only make a run of a few hundred frames take hours
MAX_PARTICLES = 1_000_000

# ---------------------------------------------------------------------------- tuned constants
# (the figures behind them: docs/results.md, "Why the defaults are what they are"; the
# start's, resampling's, rivals' and smoother's are in their modules)
WORLD_MARGIN = 0.5  # m around the field where uniform particles may lie
CLUSTER_RADIUS = 0.6  # m
CLUSTER_HEADING = 0.6  # rad
MIRROR_RATIO = 0.5  # mirrored cluster weight / best cluster weight to flag ambiguity

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
    # the touch line a placement stands on (left: y > 0, on the left looking from the own
    # goal to the opponent's; right: y < 0; any): at a touch line, the penalty area's side
    # line and the centre line seen from one side look alike from the other side's mirror
    # place, so a team that knows the side its robot enters from says so
    "start_side": "any",
    "init_spread": [0.3, 0.3, 0.2],  # m, m, rad: sigma around init_pose; placement uses the
    # first as the scale of how far inside the touch line the robot stands (half-normal: on
    # the line or inside it, never beyond) and the last for the heading
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
    # every frame localised on its own, from a uniform start (init uniform; start_half still
    # puts every frame on that half), with no odometry and nothing of the other frames
    # (snapshots at unknown poses: real stills)
    "independent": False,
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
    # every frame on its own (snapshots)
    "independent": _preset(init="uniform", independent=True),
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
    """The particle set and its update; ``step`` runs one frame. Kept over frames: the
    particles and their weights, augmented MCL's likelihood averages (``averages``), the
    rivals (``rivals``), the frames with landmarks since the last sensor reset and the last
    estimate (``last``)."""

    def __init__(self, model: ObservationModel, conf: dict | None = None, seed: int | None = None,
                 *, imu_heading: bool = False):
        self.conf = copy.deepcopy(_DEFAULT) if conf is None else conf
        self.model = model
        self.field = model.field
        self.rng = np.random.default_rng(self.conf["seed"] if seed is None else seed)
        self.particles = np.zeros((0, 3))
        self.weights = np.zeros(0)
        # the frames bring the IMU's field heading (``imu_heading_sigma`` and an imu.csv):
        # it tells a pose from its mirror (headings pi apart), so particles are never paired
        self.imu_heading = bool(imu_heading)
        self.paired = False  # particles stand for themselves and their mirrored poses
        self.symmetric = self.field.is_point_symmetric()
        self.last: Estimate | None = None  # the last frame's estimate
        self.averages = LikelihoodAverages()
        self._since_reset = 0  # frames with landmarks since the last sensor reset
        self._start_search = False  # a uniform start: the first observations place the belief
        self._start_keep = 0  # a dense start: the particles its first observations keep
        self._known_start = False  # a placement or pose start whose belief is still wide
        self.start_half: StartHalf | None = None  # a uniform start's given half
        self.bounds = world_bounds(self.field)
        if self.conf["init_pose"] is not None:  # refused off the world, whatever the init
            mcl_start.check_init_pose(self.conf["init_pose"], self.bounds)
        self.clusters = Clustering(self.bounds, float(CLUSTER_RADIUS), float(CLUSTER_HEADING))
        self.rivals = Rivals(model, self.clusters, self.bounds)
        self.new_poses = NewPoses(model, PosePlacer(model, self.bounds), self.bounds,
                                  self.clusters, self.rng)

    @classmethod
    def from_field(cls, field_model, conf: dict | None = None) -> ParticleFilter:
        """A filter on a field with ``conf["observation"]`` (crossing tables computed)."""
        conf = copy.deepcopy(_DEFAULT) if conf is None else conf
        return cls(ObservationModel.from_field(field_model, conf["observation"]), conf)

    def initialise(self, mode: str | None = None, pose=None, n: int | None = None):
        """The initial belief of ``mode`` (the conf's ``init`` by default; mcl_start): ``n``
        particles (by default INIT_PARTICLES of the mode, drawn START_DENSITY times over until
        the first frame with observations; half while each stands for a mirrored pair)."""
        c = self.conf
        mode = mode or c["init"]
        self.paired = mcl_start.is_paired(mode, c, self.symmetric, self.imu_heading)
        dense = mcl_start.density(mode) if n is None else 1  # a count given is held as given
        n = mcl_start.held_count(mcl_start.initial_count(mode, c) if n is None else int(n),
                                 self.paired)
        self.last = None
        self._since_reset = 0
        self.rivals.start(mode)
        self._start_search = mcl_start.searches_places(mode)
        self._known_start = mcl_start.is_known(mode)
        self.start_half = (StartHalf(c["start_half"], c["start_half_error"])
                           if mode == "uniform" and self.symmetric and c["start_half"] != "any"
                           else None)
        self._start_keep = n if dense > 1 else 0
        self.particles = mcl_start.initial_poses(mode, n * dense, self.rng, self.field,
                                                 self.bounds, c, pose)
        self.weights = np.full(len(self.particles), 1.0 / len(self.particles))
        self.averages = LikelihoodAverages()

    # ------------------------------------------------------------------ the update
    def predict(self, odometry, dt: float, has_odometry: bool = True, collision: bool = False,
                imu_yaw: bool = False):
        self.particles = motion_model.sample_motion(
            self.particles, odometry, dt, self.rng, has_odometry=has_odometry,
            collision=collision, imu_yaw=imu_yaw)
        self.rivals.move(odometry)
        if self.start_half is not None:
            self.start_half.move(odometry, dt, has_odometry=has_odometry, collision=collision,
                                 imu_yaw=imu_yaw)

    def fold(self):
        """Paired mode: hold each particle as whichever of itself and its mirrored pose lies
        nearer to the last estimate (own half, x <= 0, before the first). The belief is the
        same; folding keeps the held set in one piece so that clusters can be found."""
        if not self.paired or not len(self.particles):
            return
        p = self.particles
        if self.last is None:
            flip = p[:, 0] > 0
        else:
            cx, cy = self.last.pose[0], self.last.pose[1]
            flip = (p[:, 0] + cx) ** 2 + (p[:, 1] + cy) ** 2 < (p[:, 0] - cx) ** 2 + (
                p[:, 1] - cy) ** 2
        p[flip, 0:2] *= -1.0
        p[flip, 2] = wrap_angle(p[flip, 2] + math.pi)

    def correct(self, obs: Observations, heading=None) -> Frame:
        """Weight the particles by the observations ``obs`` and the IMU's field heading
        ``heading`` ((yaw, sigma) rad, or None). Returns what the frame's weighting found, for
        its resampling (mcl_resampling.Frame; its ``prep`` None without usable observations).
        On a resetting frame, poses placed by the frame's observations are weighted in the
        same call: ``resample`` draws the placed poses from them by their likelihood, and
        while tracking their best (or a rival, mcl_rivals) says how likely "elsewhere" is."""
        prep = self.model.prepare(obs)
        frame = Frame(heading=heading)
        k = len(prep)
        if k == 0:
            return frame
        if self._start_search:
            self._start_search = False
            p = mcl_start.placed_start(self.model, prep, len(self.particles), self.rng,
                                       self.bounds, self.conf, symmetric=self.symmetric,
                                       paired=self.paired, start_half=self.start_half)
            if p is not None:
                self.particles, self.weights = p, np.full(len(p), 1.0 / len(p))
        frame.prep = prep
        wide = self._wide()
        frame.reset = resetting(prep.obs, wide, self.averages.share(), self._since_reset)
        if wide:
            self.rivals.clear()
        pool = (self.new_poses.observed(int(RESET_POOL), frame) if frame.reset
                else np.zeros((0, 3)))
        if self.start_half is not None:  # rivals on the side the start half favours
            pool = self.start_half.sided(pool)
        p, rivals = self.particles, self.rivals.poses
        if len(pool) or len(rivals):
            p = np.concatenate([p, pool, rivals])
        ll = self.model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], prep)
        if heading is not None:
            ll = ll + heading_log_likelihood(p[:, 2], heading)
        n, n_pool = len(self.particles), len(pool)
        ll_pool, ll_rivals = ll[n:n + n_pool], ll[n + n_pool:]
        if n_pool:
            frame.pool = (pool, ll_pool)
        ll = ll[:n]
        if not wide:
            lw = np.log(np.maximum(self.weights, 1e-300)) + ll
            top = float(lw.max())
            log_tracked = top + math.log(float(np.exp(lw - top).sum()))
            # the belief's own place, a pose as a rival is: its heaviest particle
            ll_belief = float(ll[int(np.argmax(lw))])
            self.rivals.update(pool, ll_pool, ll_rivals, log_tracked, ll_belief,
                               self.last.pose)
            self.rivals.remember(prep, ll_belief, log_tracked)
            if n_pool:
                frame.kidnap, frame.rival = self.rivals.kidnap_share(
                    self.averages.share(), log_tracked, ll_pool)
        # augmented MCL: the mean per-observation likelihood under the predicted belief
        self.averages.update(float(np.dot(self.weights, np.exp(ll / k))))
        lw = np.log(np.maximum(self.weights, 1e-300)) + ll
        lw -= lw.max()
        w = np.exp(lw)
        self.weights = w / w.sum()
        if self._start_keep:  # a dense start's first observations: keep the tracking count
            idx = low_variance(self.weights, self._start_keep, self.rng)
            self.particles = self.particles[idx]
            self.weights = np.full(len(idx), 1.0 / len(idx))
            self._start_keep = 0
        return frame

    def resample(self, frame: Frame | None = None, spread: float | None = None):
        """Low-variance resampling when needed (mcl_resampling), with new particles; returns
        how many were injected by augmented MCL and how many placed by the observations of
        ``frame`` (what ``correct`` found). While the belief is wide (global localisation)
        augmented MCL injects its share and the observations place SENSOR_RESET_FRACTION per
        frame (together weighted as mcl_start.START_ERROR while a placement or pose start's
        belief has not yet narrowed); while tracking, the placed poses are the posterior share
        of "elsewhere"."""
        n = len(self.weights)
        ess = 1.0 / float(np.dot(self.weights, self.weights))
        wide = self._wide()
        self._known_start = self._known_start and wide  # until the belief first narrows
        share = self.averages.share() if wide else 0.0
        n_target = particle_count(spread, share, self.conf, n, self.paired)
        n_aug = int(self.rng.binomial(n_target, share)) if share > 0 else 0
        reset = 0.0
        if frame is not None and frame.prep is not None and places(frame.prep.obs):
            reset = reset_share(frame.reset, wide, self._since_reset, frame.kidnap)
            self._since_reset = 0 if frame.reset else self._since_reset + 1
        n_reset = int(self.rng.binomial(n_target, reset)) if reset > 0 else 0
        aug = self._guard(self.new_poses.injected(n_aug, frame)) if n_aug else np.zeros((0, 3))
        placed = (self._guard(self.new_poses.placed(n_reset, frame)) if n_reset
                  else np.zeros((0, 3)))
        new = np.concatenate([aug, placed])[: n_target - 1]
        needed = ess < RESAMPLE_THRESHOLD * n or len(new) > 0 or abs(n_target - n) > 0.25 * n
        if not needed:
            return 0, 0
        idx = low_variance(self.weights, n_target - len(new), self.rng)
        self.particles = np.concatenate([self.particles[idx], new])
        self.weights = np.full(n_target, 1.0 / n_target)
        if self._known_start and len(new):
            # while a known start's belief is wide, the new poses stand for "the start was
            # wrong" (mcl_start.START_ERROR), not for their share of the particles
            share = min(float(mcl_start.START_ERROR), len(new) / n_target)
            self.weights[:len(idx)] = (1.0 - share) / len(idx)
            self.weights[len(idx):] = share / len(new)
        n_aug = min(len(aug), len(new))
        return n_aug, len(new) - n_aug

    def _wide(self) -> bool:
        """Whether the belief was wide at the last estimate (spread at or above SPREAD_HIGH:
        global localisation)."""
        return self.last is None or not self.last.spread < SPREAD_HIGH

    def _guard(self, poses: np.ndarray) -> np.ndarray:
        """New ``poses`` on the side of the field the belief supports
        (mcl_resampling.mirror_guard), unless particles stand for mirrored pairs."""
        if self.paired:
            return poses
        return mirror_guard(poses, Belief(self.particles, self.weights), self.clusters,
                            None if self.last is None else self.last.pose,
                            None if self.start_half is None else self.start_half.log_odds)

    # ------------------------------------------------------------------ the estimate
    def estimate(self) -> Estimate:
        """The pose (weighted mean of the best cluster), its covariance and confidence (the
        cluster's weight share), the weight around the mirrored pose, and the belief's
        hypotheses: its clusters, heaviest first (at most ``hypotheses``), each a pose with its
        weight share, beside the rivals (mcl_rivals); on a point-symmetric field the best
        cluster's mirror image is always among them."""
        c = self.conf
        p, w = self.particles, self.weights
        x, y, th = (np.ascontiguousarray(p[:, k]) for k in range(3))
        cos_t, sin_t = np.cos(th), np.sin(th)
        centre = self.clusters.heaviest(w, x, y, th, cos_t, sin_t)
        in_centre = self.clusters.members(centre, x, y, cos_t, sin_t)
        wm = w * in_centre
        conf_share = float(wm.sum())
        mirror = self.field.mirror_pose(centre)
        in_mirror = self.clusters.members(mirror, x, y, cos_t, sin_t)
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
        rest = w * ~(in_centre | in_mirror)
        scale = 0.5 if self.paired else 1.0  # a held particle stands for two poses
        while len(rows) < int(c["hypotheses"]) and rest.sum() > 1e-3:
            other = self.clusters.heaviest(rest, x, y, th, cos_t, sin_t)
            members = self.clusters.members(other, x, y, cos_t, sin_t)
            share = float(rest @ members)
            if share <= 0:
                break
            rows.append((*other, share * scale))
            if self.paired:
                rows.append((*self.field.mirror_pose(other), share * scale))
            rest = rest * ~members
        rows.sort(key=lambda r: -r[3])  # stable: the best cluster before its mirror on a tie
        rows, belief = self.rivals.with_rivals(rows, symmetric=self.symmetric,
                                               paired=self.paired)
        conf_share, mirror_share = conf_share * belief, mirror_share * belief
        return Estimate(pose=centre, covariance=cov, confidence=conf_share,
                        mirror_weight=mirror_share, spread=spread, flags=flags,
                        n_particles=n_particles,
                        hypotheses=np.array(rows[:int(c["hypotheses"])], float))

    # ------------------------------------------------------------------ one frame
    def step(self, odometry, dt: float, obs: Observations, *, has_odometry: bool = True,
             first: bool = False, collision: bool = False, imu_yaw: bool = False,
             heading=None) -> tuple[Estimate, Frame]:
        """Predict (unless ``first``), weight, estimate, resample. Returns the estimate and
        what the frame's weighting found (mcl_resampling.Frame, the smoother's input).
        ``collision``: the IMU flags a collision since the last frame (``imu_yaw``: the
        odometry's dtheta was replaced by the IMU's yaw change); ``heading``: the IMU's field
        heading this frame, (yaw, sigma) rad, or None."""
        if not first:
            self.predict(odometry, dt, has_odometry, collision, imu_yaw)
        self.fold()
        frame = self.correct(obs, heading)
        est = self.estimate()
        self.last = est
        k = est.n_observations = frame.n_observations
        # a frame without observations brings no information: keep the predicted belief
        injected, _placed = self.resample(frame, est.spread) if k else (0, 0)
        est.injected = injected
        if k == 0:
            est.flags.append("no-observations")
            est.mode = "predicted"
        elif injected:
            est.flags.append(f"injected={injected}")
            est.mode = "recovering"
        if first:
            est.mode = "initial"
        return est, frame


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


def world_bounds(field) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1): the field and WORLD_MARGIN around it, where particles may lie."""
    hx, hy = field.length / 2 + float(WORLD_MARGIN), field.width / 2 + float(WORLD_MARGIN)
    return (-hx, hx, -hy, hy)


def observation_model(conf: dict, dataset, map_file) -> ObservationModel:
    """The observation model of ``conf`` (a resolved preset) on ``map_file``, with the camera's
    height from the dataset's calibration where the conf leaves it open."""
    obs_conf = dict(conf["observation"])
    if obs_conf["camera_height"] is None:
        obs_conf["camera_height"] = _camera_height(dataset)
    return ObservationModel.from_map(map_file, obs_conf)


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
    check_conf(conf)
    model = observation_model(conf, dataset, map_file)
    odometry = dataset.optional("odometry") if dataset is not None else None
    stamps = np.asarray(features.stamps, float)
    increments, _has = motion_model.accumulate_odometry(odometry, stamps)
    imu = dataset.optional("imu") if dataset is not None else None
    collision, dyaw = motion_model.imu_per_frame(imu, stamps)
    imu_yaw = collision & np.isfinite(dyaw)
    increments[imu_yaw, 2] = dyaw[imu_yaw]  # a pushed robot's odometry does not know its turn
    headings = frame_headings(imu, stamps, collision, conf["imu_heading_sigma"])
    imu_heading = any(h is not None for h in headings)
    if conf["independent"]:
        return _independent(conf, model, features, headings, imu_heading, progress)
    pf = ParticleFilter(model, conf, imu_heading=imu_heading)
    pf.initialise()
    keep = SmoothingInputs() if conf["smooth"] else None
    track = PoseTrack()
    prev_stamp = None
    for i in _iterate(range(len(features.names)), progress):
        name = features.names[i]
        stamp = float(stamps[i])
        t0 = time.perf_counter()
        obs, reason = _frame_observations(features, name)
        dt = 0.0 if prev_stamp is None else max(stamp - prev_stamp, 0.0)
        est, frame = pf.step(increments[i], dt, obs, has_odometry=odometry is not None,
                      first=prev_stamp is None, collision=bool(collision[i]),
                      imu_yaw=bool(imu_yaw[i]), heading=headings[i])
        if keep is not None:
            keep.add(frame, est, reason)
        if collision[i]:
            est.flags.append("collision")
        prev_stamp = stamp
        _add(track, conf, name, stamp, est, time.perf_counter() - t0)
    if keep is None:
        return track
    scorer = MclScorer(model, keep, mirrored=pf.symmetric,
                       temperature=float(SMOOTH_TEMPERATURE))
    motion = motion_of(increments, stamps, odometry is not None, collision, imu_yaw)
    x0, x1, y0, y1 = pf.bounds
    return smooth.smooth_track(scorer, track, motion, conf,
                               kidnap_probability=SMOOTH_KIDNAP_PROBABILITY,
                               area=(x1 - x0) * (y1 - y0),
                               log_prior0=start_prior(conf, model.field))


def _frame_observations(features, name: str) -> tuple[Observations, str | None]:
    """A frame's observations, and why there are none where its features are unreadable
    (the frame is then a prediction only)."""
    try:
        return Observations.from_features(features.frame(name)), None
    except (KeyError, ValueError) as e:
        log.warning("frame %s: unreadable features (%s); prediction only", name, e)
        return Observations.empty(), "unreadable-features"


def _add(track: PoseTrack, conf: dict, name: str, stamp: float, est: Estimate,
         runtime: float) -> None:
    """One frame's estimate onto ``track``, accepted at the conf's ``min_confidence``."""
    accepted = est.confidence >= conf["min_confidence"]
    if not accepted:
        est.flags.append("low-confidence")
    track.add(name, stamp, est.pose, hypotheses=est.hypotheses, accepted=accepted,
              error=float(np.sqrt(max(np.trace(est.covariance[:2, :2]), 0.0)))
              if np.all(np.isfinite(est.covariance)) else math.nan,
              confidence=est.confidence, mode=est.mode, runtime=runtime,
              covariance=est.covariance, flags=",".join(est.flags))


def _independent(conf: dict, model: ObservationModel, features, headings, imu_heading: bool,
                 progress) -> PoseTrack:
    """Every frame localised on its own (conf ``independent``): a filter of its own from a
    uniform start (its first-frame place search) and one update with the frame's observations
    and IMU heading, no odometry; what the frame alone says, its pose and its mirror image
    sharing the belief on a symmetric field (the pair's share: symmetry.py). The same seed
    for each frame, so a frame's result does not depend on the others."""
    track = PoseTrack()
    stamps = np.asarray(features.stamps, float)
    for i in _iterate(range(len(features.names)), progress):
        name = features.names[i]
        t0 = time.perf_counter()
        obs, _ = _frame_observations(features, name)
        pf = ParticleFilter(model, conf, imu_heading=imu_heading)
        pf.initialise("uniform")
        est, _ = pf.step(np.zeros(3), 0.0, obs, has_odometry=False, first=True,
                         collision=False, imu_yaw=False, heading=headings[i])
        _add(track, conf, name, float(stamps[i]), est, time.perf_counter() - t0)
    return track


# the ranges mcl's numeric keys must lie in to run at all (common.conf.check_bounds; the
# particle counts and start_half_error in check_conf, init_pose on the field where the field is
# known, mcl_start.initial_poses): every number a user may give, so that none reaches the
# filter's kernels unchecked. An init_spread beyond MAX_INIT_SPREAD (m, rad) puts the particles
# off any field (the largest is 22 m long) and spreads the heading uniformly many times over
MAX_INIT_SPREAD = 100.0
# imu_heading_sigma (rad): below a milliradian no IMU's yaw is that sure (and a heading's
# log-likelihood, (difference / sigma)^2, overflows as sigma nears 0); above pi the yaw says
# nothing (a difference of headings lies within +-pi)
MIN_IMU_HEADING_SIGMA = 1e-3
MAX_IMU_HEADING_SIGMA = math.pi
BOUNDS = {"seed": (0, None), "hypotheses": (1, 1000), "min_confidence": (0, 1),
          "init_spread": (0, MAX_INIT_SPREAD, 3),
          "init_pose": (None, None, 3),
          "imu_heading_sigma": (MIN_IMU_HEADING_SIGMA, MAX_IMU_HEADING_SIGMA, SCALAR),
          **{f"observation.{k}": b for k, b in OBSERVATION_BOUNDS.items()}}


def check_conf(conf: dict) -> None:
    """The method's keys checked (FieldlocError): at run time, and where a batch SPEC names the
    method, before anything runs."""
    check_bounds(conf, BOUNDS)
    counts = {"particles_min": conf["particles_min"], "particles_max": conf["particles_max"]}
    for key, v in counts.items():
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_PARTICLES:
            raise FieldlocError(f"{key} must be a whole number in 1..{MAX_PARTICLES}, not"
                                f" {str(v)[:40]}")
    if conf["particles_min"] > conf["particles_max"]:
        raise FieldlocError(f"particles_min ({conf['particles_min']}) must not exceed"
                            f" particles_max ({conf['particles_max']})")
    for key in ("smooth", "independent"):
        if not isinstance(conf[key], bool):
            raise FieldlocError(f"{key} must be true or false, not {str(conf[key])[:40]!r}")
    if conf["independent"] and (conf["init"] != "uniform" or conf["start_side"] != "any"):
        # each frame starts from a uniform belief: a placement (or its touch line) is a
        # start's, and would go unused (start_half holds: every frame on that half)
        what = (f"init {str(conf['init'])[:40]!r}" if conf["init"] != "uniform"
                else f"start_side {str(conf['start_side'])[:40]!r}")
        raise FieldlocError(f"independent starts every frame from a uniform belief (init"
                            f" uniform, start_side any), not {what}: give init=uniform with"
                            " it (mcl's default init is placement), or use --independent or"
                            " the preset 'independent', which do")
    if conf["smooth"] and conf["independent"]:
        raise FieldlocError("smooth decides every frame with the whole recording; it does not"
                            " localise frames independently")
    check_start_half(conf)
    if conf["start_side"] not in mcl_start.START_SIDES:
        raise FieldlocError(f"start_side must be one of {', '.join(mcl_start.START_SIDES)}, not"
                            f" {str(conf['start_side'])[:40]!r}")

