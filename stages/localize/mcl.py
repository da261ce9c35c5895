"""Monte-Carlo localisation (seed 000, section 5): a sampling-importance-resampling particle
filter over (x, y, theta) on lines, crossings and goal posts from a perspective camera.

Per frame: (1) predict, every particle moved by the odometry increment with noise
(stages.localize.motion_model); (2) weight, each particle's weight multiplied by the
likelihood of the frame's observations (stages.localize.observation_model: eq. 3 for crossings
and posts, eqs. 4-5 for lines, association by the crossing tables for L and T and per particle
for X, posts and lines, uniform floor by confidence, product over observations); a frame with
no usable observation keeps the predicted belief (no weighting, no resampling); (3) estimate;
(4) resample (low-variance) when the effective sample size falls below ``resample_threshold``
of the particles, when particles are to be injected, or when the particle count changes.

New particles at resampling:
- augmented MCL (Thrun et al.): the mean per-observation likelihood of the predicted belief is
  followed by a slow and a fast exponential average (``alpha_slow``, ``alpha_fast``); a share
  ``max(0, 1 - w_fast / w_slow)`` (at most ``max_inject``) of the particles is replaced, half
  of them (``inject_from_observations``) by poses that explain a crossing or goal post seen in
  this frame by a field landmark of its kind, the rest uniformly; the frame's mode is then
  "recovering" and its flags hold "injected=N";
- sensor resetting: a constant share ``sensor_reset_fraction`` per frame placed by the
  frame's landmarks, so that a filter sure of a wrong place still meets the right one; to
  save the candidates' cost on most frames, the share of ``sensor_reset_every`` frames is
  placed at once on every that many-th frame with landmarks. Poses placed by landmarks are
  drawn from ``reset_pool`` candidates (an observed crossing or post explained by a random
  field landmark of its kind) in proportion to their likelihood under all of the frame's
  observations; on a resetting frame the candidates are weighted in the same call as the
  particles, otherwise (augmented MCL injecting) in a call of their own;
- ``random_fraction``: a constant share of uniform particles (0 by default).
Unless the prior was symmetric (below), each new pose is taken as whichever of itself and its
mirror image lies nearer to the last estimate: no observation can tell the two apart, and the
other would only let the track flip to the mirrored side.

Particle count (250-1000, ``particles_min`` / ``particles_max``): at resampling the number
follows the belief's spread s = sqrt(var x + var y): ``particles_min`` when s <= ``spread_low``,
``particles_max`` when s >= ``spread_high``, linear between, and the maximum whenever augmented
MCL injects. A simple stand-in for KLD sampling: a tight belief needs few particles, a wide or
multi-modal one many. The initial belief has ``init_particles`` (4000 for a uniform start),
kept while the spread stays at or above ``spread_high`` (global localisation).

Estimate: a weighted histogram of the particles (1 m x 1 m x 45 deg bins, summed over 2 x 2 x 2
neighbouring bins) gives the heaviest region; three mean-shift steps with radius
``cluster_radius`` and heading window ``cluster_heading`` give the best cluster; its weighted
mean is the pose, its weighted covariance the covariance, its weight share the confidence; the
poses file's ``error`` is sqrt(var x + var y) of that cluster (m).

Symmetry: the field looks the same after a 180 deg turn about the centre spot (both goals
white), so a pose and its mirror (FieldModel.mirror_pose) explain every image equally. With
the default ``init: placement`` (own half, x < 0, at either touch line, facing into the field,
as robots enter in a game) the prior breaks the symmetry and the filter keeps its side; a frame
is flagged "mirror-ambiguous" when the particles around the mirrored pose weigh at least
``mirror_ratio`` of the best cluster. With ``init: uniform`` on a point-symmetric field the
posterior stays exactly symmetric; the filter then holds one particle per mirrored pair
(``symmetric_pairs``), reports the member of the pair that continues the previous estimate (own
half at the start), with confidence at most 0.5, and flags every frame "mirror-ambiguous".
``init: pose`` starts around ``init_pose`` with ``init_spread``.

Every random draw comes from one ``np.random.default_rng(seed)``: the same inputs and seed give
the same poses.
"""

from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from stages.common.errors import FieldlocError
from stages.common.geometry import wrap_angle
from stages.common.observations import Observations
from stages.common.poses_file import PoseTrack

from . import motion_model
from .observation_model import DEFAULTS as OBSERVATION_DEFAULTS
from .observation_model import ObservationModel

log = logging.getLogger(__name__)

_DEFAULT = {
    "seed": 0,
    "init": "placement",  # placement | uniform | pose
    "init_pose": None,  # [x, y, theta] for init = pose
    "init_spread": [0.3, 0.3, 0.2],  # m, m, rad: sigma around init_pose; placement uses the
    # first as the spread across the touch line and the last for the heading
    "particles_min": 250,
    "particles_max": 1000,
    # particles of the initial belief, kept until its spread falls below spread_high
    "init_particles": {"placement": 1000, "uniform": 4000, "pose": 1000},
    "spread_low": 0.15,  # m: belief spread at or below which particles_min are used
    "spread_high": 0.8,  # m: spread at or above which particles_max are used
    "resample_threshold": 0.5,  # resample when the effective sample size < this * N
    "alpha_slow": 0.01,  # augmented MCL: slow average of the observation likelihood
    "alpha_fast": 0.1,  # ... and the fast one
    "max_inject": 0.25,  # at most this share of particles injected per frame
    "random_fraction": 0.0,  # constant share of uniform random particles per resampling
    "sensor_reset_fraction": 0.02,  # constant share placed by the landmarks (per frame)
    "sensor_reset_every": 3,  # ... placed at every this many frames with landmarks, at once
    "reset_pool": 100,  # candidate poses per frame for the placed shares (by likelihood)
    "inject_from_observations": 0.5,  # share of injected poses placed by observed landmarks
    "world_margin": 0.5,  # m around the field where uniform particles may lie
    "cluster_radius": 0.6,  # m
    "cluster_heading": 0.6,  # rad
    "mirror_ratio": 0.5,  # mirrored cluster weight / best cluster weight to flag ambiguity
    "symmetric_pairs": True,  # a symmetric prior on a symmetric field keeps its symmetry
    "min_confidence": 0.8,  # a frame is accepted when its best cluster holds this share (a
    # belief split evenly between a pose and its mirror holds 0.5 each)
    "hypotheses": 5,  # clusters of the belief listed per frame
    "observation": dict(OBSERVATION_DEFAULTS),
    "motion": dict(motion_model.DEFAULTS),
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
    # the seed's ablation: crossings and goal posts only
    "no-lines": _preset(observation={"use_lines": False}),
    # global localisation from anywhere on the field (up to the field's symmetry)
    "uniform": _preset(init="uniform"),
}


@dataclass
class Estimate:
    """The filter's answer for one frame."""

    pose: np.ndarray  # (3,)
    covariance: np.ndarray  # (3, 3)
    confidence: float  # weight share of the best cluster
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

    def __init__(self, model: ObservationModel, conf: dict | None = None, seed: int | None = None):
        self.conf = copy.deepcopy(_DEFAULT) if conf is None else conf
        self.model = model
        self.field = model.field
        self.rng = np.random.default_rng(self.conf["seed"] if seed is None else seed)
        self.particles = np.zeros((0, 3))
        self.weights = np.zeros(0)
        self.w_slow: float | None = None
        self.w_fast: float | None = None
        self._last_obs: Observations | None = None
        self.paired = False  # particles stand for themselves and their mirrored poses
        self.symmetric = self.field.is_point_symmetric()
        self._last_pose: np.ndarray | None = None
        self._last_estimate: Estimate | None = None
        self._landmarks = None
        self._pool: tuple | None = None
        self._prep = None  # this frame's prepared observations (after correct)
        self._since_reset = 0  # frames with landmarks since the last sensor reset
        self._reset_now: bool | None = None  # correct's decision for this frame
        hx, hy = self.field.length / 2, self.field.width / 2
        m = float(self.conf["world_margin"])
        self._bounds = (-hx - m, hx + m, -hy - m, hy + m)

    @classmethod
    def from_field(cls, field_model, conf: dict | None = None) -> ParticleFilter:
        """A filter on a field with ``conf["observation"]`` (crossing tables computed)."""
        conf = copy.deepcopy(_DEFAULT) if conf is None else conf
        return cls(ObservationModel.from_field(field_model, conf["observation"]), conf)

    # ------------------------------------------------------------------ initial belief
    def initialise(self, mode: str | None = None, pose=None):
        c = self.conf
        mode = mode or c["init"]
        self.paired = (mode == "uniform" and bool(c["symmetric_pairs"])
                       and self.field.is_point_symmetric())
        n = self._base_count(int(c["init_particles"].get(mode, c["particles_max"])))
        self._last_pose = None
        self._last_estimate = None
        self._since_reset = 0
        if mode == "uniform":
            p = self._uniform(n)
        elif mode == "placement":
            p = self._placement(n)
        elif mode == "pose":
            pose = c["init_pose"] if pose is None else pose
            if pose is None or len(pose) != 3:
                raise FieldlocError("init=pose needs init_pose=[x, y, theta]")
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

    def _uniform(self, n: int) -> np.ndarray:
        x0, x1, y0, y1 = self._bounds
        u = self.rng.random((n, 3))
        return np.stack([x0 + (x1 - x0) * u[:, 0], y0 + (y1 - y0) * u[:, 1],
                         -math.pi + 2 * math.pi * u[:, 2]], axis=1)

    def _placement(self, n: int) -> np.ndarray:
        """Own half (x < 0), at either touch line, facing into the field."""
        fm = self.field
        s_across, s_heading = float(self.conf["init_spread"][0]), float(self.conf["init_spread"][2])
        side = np.where(self.rng.random(n) < 0.5, 1.0, -1.0)
        x = self.rng.uniform(-fm.length / 2, 0.0, n)
        across = self.rng.standard_normal(n) * s_across  # beyond the line is outwards
        turn = self.rng.standard_normal(n) * s_heading
        p = fm.touchline_pose(x, side, inset=-across)
        p[:, 2] = wrap_angle(p[:, 2] + turn)
        return p

    # ------------------------------------------------------------------ the update
    def predict(self, odometry, dt: float, has_odometry: bool = True, collision: bool = False,
                imu_yaw: bool = False):
        self.particles = motion_model.sample_motion(
            self.particles, odometry, dt, self.rng, self.conf["motion"], has_odometry=has_odometry,
            collision=collision, imu_yaw=imu_yaw)

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
        p = self.particles
        # on a resetting frame, candidate poses placed by this frame's landmarks are weighted
        # in the same call; the placed poses of ``resample`` draw from them by their likelihood
        self._prep = prep
        self._pool = None
        self._reset_now = self._resetting(prep.obs)
        pool = np.zeros((0, 3))
        if self._reset_now:
            pool = self._poses_from_landmarks(int(self.conf["reset_pool"]), prep.obs)
        if len(pool):
            p = np.concatenate([p, pool])
        ll = self.model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], prep)
        n = len(self.particles)
        if len(pool):
            self._pool = (pool, ll[n:])
        ll = ll[:n]
        # augmented MCL: the mean per-observation likelihood under the predicted belief
        w_avg = float(np.dot(self.weights, np.exp(ll / k)))
        if self.w_slow is None:
            self.w_slow = self.w_fast = w_avg
        else:
            self.w_slow += self.conf["alpha_slow"] * (w_avg - self.w_slow)
            self.w_fast += self.conf["alpha_fast"] * (w_avg - self.w_fast)
        lw = np.log(np.maximum(self.weights, 1e-300)) + ll
        lw -= lw.max()
        w = np.exp(lw)
        self.weights = w / w.sum()
        self._last_obs = prep.obs
        return k

    def inject_share(self) -> float:
        """Augmented MCL: the share of random particles, max(0, 1 - w_fast / w_slow)."""
        c = self.conf
        share = float(c["random_fraction"])
        if self.w_slow and self.w_fast is not None and self.w_slow > 0:
            share += max(0.0, 1.0 - self.w_fast / self.w_slow)
        return min(share, float(c["max_inject"]))

    def resample(self, obs: Observations | None = None, spread: float | None = None):
        """Low-variance resampling when needed, with new particles; returns how many were
        injected by augmented MCL (certainty dropped) and how many placed by this frame's
        landmarks (the constant ``sensor_reset_fraction``)."""
        c = self.conf
        n = len(self.weights)
        ess = 1.0 / float(np.dot(self.weights, self.weights))
        share = self.inject_share()
        n_target = self._particle_count(spread, share)
        n_aug = int(self.rng.binomial(n_target, share)) if share > 0 else 0
        landmarks = obs is not None and (len(obs.crossings) or len(obs.posts))
        reset = 0.0
        if landmarks:
            now = self._resetting(obs) if self._reset_now is None else self._reset_now
            if now:  # the share of the frames since the last reset
                reset = min(float(c["sensor_reset_fraction"]) * (self._since_reset + 1), 1.0)
                self._since_reset = 0
            else:
                self._since_reset += 1
        n_reset = int(self.rng.binomial(n_target, reset)) if reset > 0 else 0
        aug = self._mirror_guard(self._injected_poses(n_aug, obs)) if n_aug else np.zeros((0, 3))
        placed = (self._mirror_guard(self._landmark_poses(n_reset, obs)) if n_reset
                  else np.zeros((0, 3)))
        new = np.concatenate([aug, placed])[: n_target - 1]
        needed = ess < c["resample_threshold"] * n or len(new) > 0 or abs(n_target - n) > 0.25 * n
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

    def _resetting(self, obs: Observations) -> bool:
        """Whether this frame places the sensor-reset share: it has landmarks, and either the
        belief is wide (the last spread at or above ``spread_high``: every frame) or
        ``sensor_reset_every`` - 1 frames with landmarks have passed since the last."""
        if not (len(obs.crossings) or len(obs.posts)):
            return False
        last = self._last_estimate
        if last is None or not last.spread < self.conf["spread_high"]:
            return True
        return self._since_reset + 1 >= max(int(self.conf["sensor_reset_every"]), 1)

    def _mirror_guard(self, poses: np.ndarray) -> np.ndarray:
        """Without the pairing of a symmetric prior the track has chosen a side of the field: a
        new pose and its mirror image explain the observations equally, so each new pose is
        taken as whichever of the two lies nearer to the last estimate (the new poses can then
        find a lost robot, but not flip the track to the mirrored side)."""
        last = self._last_estimate
        if self.paired or last is None or not len(poses):
            return poses
        cx, cy = float(last.pose[0]), float(last.pose[1])
        flip = (poses[:, 0] + cx) ** 2 + (poses[:, 1] + cy) ** 2 < (poses[:, 0] - cx) ** 2 + (
            poses[:, 1] - cy) ** 2
        out = poses.copy()
        out[flip, 0:2] *= -1.0
        out[flip, 2] = wrap_angle(out[flip, 2] + math.pi)
        return out

    def _particle_count(self, spread: float | None, share: float) -> int:
        """Particles (held) after resampling: by the belief's spread between particles_min and
        particles_max; a larger initial set (init_particles) is kept until the belief has
        narrowed below spread_high."""
        c = self.conf
        lo, hi = int(c["particles_min"]), int(c["particles_max"])
        if spread is not None and spread >= c["spread_high"]:
            return max(self._base_count(hi), len(self.weights))
        if share > 0 or spread is None:
            return self._base_count(hi)
        f = (spread - c["spread_low"]) / max(c["spread_high"] - c["spread_low"], 1e-9)
        return self._base_count(int(round(lo + (hi - lo) * min(max(f, 0.0), 1.0))))

    def _injected_poses(self, n: int, obs: Observations | None) -> np.ndarray:
        """New poses: a share explained by this frame's crossings and posts, the rest uniform."""
        n_obs_based = 0
        out = []
        if obs is not None and (len(obs.crossings) or len(obs.posts)):
            n_obs_based = int(round(n * float(self.conf["inject_from_observations"])))
        if n_obs_based:
            out.append(self._landmark_poses(n_obs_based, obs))
        out.append(self._uniform(n - sum(len(q) for q in out)))
        return np.concatenate(out)

    def _landmark_poses(self, n: int, obs: Observations) -> np.ndarray:
        """``n`` poses explained by this frame's landmarks: drawn from the candidate pool of
        ``correct`` in proportion to their likelihood under all of the frame's observations
        (likelihood-filtered sensor resetting), else placed directly."""
        if n <= 0:
            return np.zeros((0, 3))
        if self._pool is None and self._prep is not None:  # not weighted with the particles
            pool = self._poses_from_landmarks(int(self.conf["reset_pool"]), self._prep.obs)
            ll = (self.model.log_likelihood(pool[:, 0], pool[:, 1], pool[:, 2], self._prep)
                  if len(pool) else None)
            self._pool = (pool, ll)
        pool, ll = self._pool if self._pool is not None else (np.zeros((0, 3)), None)
        if not len(pool):
            return self._poses_from_landmarks(n, obs)
        w = np.exp(ll - ll.max())
        cum = np.cumsum(w / w.sum())
        cum[-1] = 1.0
        idx = np.searchsorted(cum, (self.rng.random() + np.arange(n)) / n, side="left")
        return pool[idx]

    def _landmark_table(self):
        """Field landmarks by observation kind (0 L, 1 T, 2 X, 3 goal post): positions (M, 2),
        orientations (M,), and where each kind starts."""
        if self._landmarks is None:
            fm = self.field
            types = np.asarray(fm.crossing_types)
            pos, orient, start, count = [], [], [], []
            n = 0
            for kind in ("L", "T", "X"):
                sel = np.flatnonzero(types == kind)
                pos.append(np.asarray(fm.crossings, float).reshape(-1, 2)[sel])
                orient.append(np.asarray(fm.crossing_orientation, float)[sel])
                start.append(n)
                count.append(len(sel))
                n += len(sel)
            posts = np.asarray(fm.goal_posts, float).reshape(-1, 2)
            pos.append(posts)
            orient.append(np.zeros(len(posts)))
            start.append(n)
            count.append(len(posts))
            self._landmarks = (np.concatenate(pos), np.concatenate(orient), np.array(start),
                               np.array(count))
        return self._landmarks

    def _poses_from_landmarks(self, n: int, obs: Observations) -> np.ndarray:
        """Poses at which one observed crossing or goal post is explained by a random field
        landmark of its kind (sensor resetting); poses off the world are dropped."""
        rng = self.rng
        pos, orient, start, count = self._landmark_table()
        cr, po = obs.crossings, obs.posts
        kind = np.concatenate([cr[:, 0].astype(np.int64), np.full(len(po), 3)])
        d = np.concatenate([cr[:, 1], po[:, 0]])
        b = np.concatenate([cr[:, 2], po[:, 1]])
        o = np.concatenate([cr[:, 3], np.zeros(len(po))])
        ok = (kind >= 0) & (kind <= 3)
        ok[ok] &= count[kind[ok]] > 0
        if not ok.any() or n <= 0:
            return np.zeros((0, 3))
        kind, d, b, o = kind[ok], d[ok], b[ok], o[ok]
        u = rng.random((4, n))  # observation, landmark, quarter turn (X), post circle
        noise = rng.standard_normal((3, n))
        r = (u[0] * len(kind)).astype(np.int64)
        r_kind = kind[r]
        k = start[r_kind] + (u[1] * count[r_kind]).astype(np.int64)
        mc = self.model.conf
        dd = d[r] * (1.0 + noise[0] * (mc["sigma_range"] + mc["range_growth"]))
        bb = b[r] + noise[1] * mc["sigma_bearing"]
        post = r_kind == 3
        # a crossing fixes the heading by its orientation (X: up to quarter turns); a post
        # leaves it free, on a circle around the post
        turns = np.floor(u[2] * 4.0) * (r_kind == 2) * (math.pi / 2)
        th = orient[k] + turns - o[r] + noise[2] * 0.1
        psi = np.where(post, (2.0 * u[3] - 1.0) * math.pi, th + bb)
        th = np.where(post, psi - bb, th)
        p = np.stack([pos[k, 0] - dd * np.cos(psi), pos[k, 1] - dd * np.sin(psi), wrap_angle(th)],
                     axis=1)
        x0, x1, y0, y1 = self._bounds
        ok = (p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1)
        return p[ok]

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
        centre = self._cluster(w, x, y, th, cos_t, sin_t)
        wm = w * self._members(centre, x, y, cos_t, sin_t)
        conf_share = float(wm.sum())
        mirror = self.field.mirror_pose(centre)
        in_mirror = self._members(mirror, x, y, cos_t, sin_t)
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
        if conf_share > 0 and mirror_share >= c["mirror_ratio"] * conf_share:
            flags.append("mirror-ambiguous")
        rows = [(*centre, conf_share)]
        if self.symmetric:
            rows.append((*mirror, mirror_share))
        rest = w * ~(self._members(centre, x, y, cos_t, sin_t) | in_mirror)
        scale = 0.5 if self.paired else 1.0  # a held particle stands for two poses
        while len(rows) < int(c["hypotheses"]) and rest.sum() > 1e-3:
            other = self._cluster(rest, x, y, th, cos_t, sin_t)
            members = self._members(other, x, y, cos_t, sin_t)
            share = float(rest @ members)
            if share <= 0:
                break
            rows.append((*other, share * scale))
            if self.paired:
                rows.append((*self.field.mirror_pose(other), share * scale))
            rest = rest * ~members
        rows.sort(key=lambda r: -r[3])  # stable: the best cluster before its mirror on a tie
        return Estimate(pose=centre, covariance=cov, confidence=conf_share,
                        mirror_weight=mirror_share, spread=spread, flags=flags,
                        n_particles=n_particles,
                        hypotheses=np.array(rows[:int(c["hypotheses"])], float))

    def _cluster(self, w, x, y, th, cos_t, sin_t) -> np.ndarray:
        """The centre of the belief's heaviest cluster under weights ``w``: the heaviest
        2 x 2 x 2 window of a 1 m x 1 m x 45 deg histogram (heading wraps around), then three
        mean-shift steps with the cluster radius."""
        x0, x1, y0, y1 = self._bounds
        nbx, nby, nbt = max(int(math.ceil(x1 - x0)), 1), max(int(math.ceil(y1 - y0)), 1), 8
        bx = np.minimum(np.maximum((x - x0).astype(np.int64), 0), nbx - 1)
        by = np.minimum(np.maximum((y - y0).astype(np.int64), 0), nby - 1)
        bt = ((th + math.pi) * (nbt / (2 * math.pi))).astype(np.int64) % nbt
        h = np.bincount((bx * nby + by) * nbt + bt, weights=w,
                        minlength=nbx * nby * nbt).reshape(nbx, nby, nbt)
        hp = np.zeros((nbx + 1, nby + 1, nbt))
        hp[:nbx, :nby] = h
        win = hp[:-1, :-1] + hp[1:, :-1] + hp[:-1, 1:] + hp[1:, 1:]
        win += np.roll(win, -1, axis=2)
        i, j, k = np.unravel_index(int(np.argmax(win)), win.shape)
        inwin = (((bx - i) & ~1) == 0) & (((by - j) & ~1) == 0) & (
            ((bt - k) % nbt) <= 1)
        centre = self._weighted_mean(w * inwin, x, y, cos_t, sin_t)
        for _ in range(3):
            wm = w * self._members(centre, x, y, cos_t, sin_t)
            if wm.sum() <= 0:
                break
            centre = self._weighted_mean(wm, x, y, cos_t, sin_t)
        return centre

    def _members(self, centre, x, y, cos_t, sin_t) -> np.ndarray:
        """Particles within the cluster radius and heading of ``centre``."""
        c = self.conf
        dx, dy = x - centre[0], y - centre[1]
        near = dx * dx + dy * dy <= c["cluster_radius"] ** 2
        cos_d = cos_t * math.cos(centre[2]) + sin_t * math.sin(centre[2])
        return near & (cos_d >= math.cos(c["cluster_heading"]))

    @staticmethod
    def _weighted_mean(w, x, y, cos_t, sin_t) -> np.ndarray:
        s = float(w.sum())
        if s <= 0:
            w, s = np.ones(len(x)), float(len(x))
        return np.array([float(w @ x) / s, float(w @ y) / s,
                         math.atan2(float(w @ sin_t), float(w @ cos_t))])

    # ------------------------------------------------------------------ one frame
    def step(self, odometry, dt: float, obs: Observations, *, has_odometry: bool = True,
             first: bool = False, collision: bool = False, imu_yaw: bool = False) -> Estimate:
        """Predict (unless ``first``), weight, estimate, resample. Returns the estimate.
        ``collision``: the IMU flags a collision since the last frame (``imu_yaw``: the
        odometry's dtheta was replaced by the IMU's yaw change)."""
        if not first:
            self.predict(odometry, dt, has_odometry, collision, imu_yaw)
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


def run(conf: dict, dataset, features, map_file, progress=None) -> PoseTrack:
    """Localise every frame of ``features`` (stages.common.features_file.FeaturesFile, with
    perspective features) on ``map_file`` (stages.common.map_file.MapFile) with the odometry of
    ``dataset`` (stages.common.dataset.Dataset, or None: no odometry). ``conf``: a resolved
    preset of ``confs``. ``progress``: None/False, True (tqdm), or a callable wrapping an
    iterable."""
    if features is None or map_file is None:
        raise FieldlocError("mcl needs a features file and a map")
    kind = features.camera_kind
    if kind and kind != "perspective":
        raise FieldlocError(
            f"{features.path}: features of a '{kind}' camera; --method mcl needs perspective"
            " features (lines, crossings, goal posts)")
    model = ObservationModel.from_map(map_file, conf["observation"])
    pf = ParticleFilter(model, conf)
    pf.initialise()
    odometry = dataset.optional("odometry") if dataset is not None else None
    stamps = np.asarray(features.stamps, float)
    increments, _has = motion_model.accumulate_odometry(odometry, stamps)
    imu = dataset.optional("imu") if dataset is not None else None
    collision, dyaw = motion_model.imu_per_frame(imu, stamps)
    imu_yaw = collision & np.isfinite(dyaw)
    increments[imu_yaw, 2] = dyaw[imu_yaw]  # a pushed robot's odometry does not know its turn
    track = PoseTrack()
    prev_stamp = None
    for i in _iterate(range(len(features.names)), progress):
        name = features.names[i]
        stamp = float(stamps[i])
        t0 = time.perf_counter()
        try:
            obs = Observations.from_features(features.frame(name))
        except (KeyError, ValueError) as e:
            log.warning("frame %s: unreadable features (%s); prediction only", name, e)
            obs = Observations.empty()
        dt = 0.0 if prev_stamp is None else max(stamp - prev_stamp, 0.0)
        est = pf.step(increments[i], dt, obs, has_odometry=odometry is not None,
                      first=prev_stamp is None, collision=bool(collision[i]),
                      imu_yaw=bool(imu_yaw[i]))
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
    return track
