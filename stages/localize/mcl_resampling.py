"""The particle filter's resampling and new particles (mcl.py): how many particles the belief
holds, when it resamples, and the poses it injects.

Resampling is low-variance (systematic), when the effective sample size falls below
``RESAMPLE_THRESHOLD`` of the particles, on injection, or when the particle count changes by
more than a quarter. The count is a stand-in for KLD sampling (Fox 2003): ``particles_min`` at
a spread s = sqrt(var x + var y) <= ``SPREAD_LOW``, ``particles_max`` at s >= ``SPREAD_HIGH``
or while augmented MCL injects, linear between; a larger initial belief
(mcl_start.INIT_PARTICLES) is kept until it has narrowed below ``SPREAD_HIGH``.

New particles at resampling:

- augmented MCL (Thrun, Burgard and Fox 2005): from slow and fast averages of the mean
  per-observation likelihood (``ALPHA_SLOW``, ``ALPHA_FAST``), a share max(0, 1 - w_fast /
  w_slow) (<= ``MAX_INJECT``) is replaced while the belief is wide, ``INJECT_FROM_OBSERVATIONS``
  of it by poses the frame's observations place, the rest uniformly; while tracking, the
  share raises the kidnap prior (mcl_rivals.py);
- sensor resetting (Lenser and Veloso 2000): ``RESET_POOL`` poses at which one observation is
  explained by a field feature of its kind (mcl_placement.PosePlacer), drawn by their
  likelihood under the whole frame. A wide belief (spread >= ``SPREAD_HIGH``) places
  ``SENSOR_RESET_FRACTION`` every frame; a tracking one, every ``SENSOR_RESET_EVERY``-th frame
  (every frame while the likelihood drops), places the posterior share of "elsewhere"
  (mcl_rivals.Rivals.kidnap_share), around the rival that won where one did;
- ``RANDOM_FRACTION``: a constant share of uniform particles.

Unless the prior was symmetric, each new pose is taken as whichever of itself and its mirror
the belief supports more (``mirror_guard``: a kernel density on 256 particles drawn by
weight), else the one nearer the last estimate: no observation tells them apart, and the other
only lets the track flip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..common.geometry import wrap_angle
from ..common.jit import njit
from ..common.observations import Observations
from .mcl_start import held_count, uniform_poses
from .start_half import HALF_DECIDES

SPREAD_LOW = 0.15  # m: belief spread at or below which particles_min are used
SPREAD_HIGH = 0.8  # m: spread at or above which particles_max are used
RESAMPLE_THRESHOLD = 0.5  # resample when the effective sample size < this * N
ALPHA_SLOW = 0.01  # augmented MCL: slow average of the observation likelihood
ALPHA_FAST = 0.1  # ... and the fast one
MAX_INJECT = 0.25  # at most this share of particles injected per frame
RANDOM_FRACTION = 0.0  # constant share of uniform random particles per resampling
SENSOR_RESET_FRACTION = 0.02  # share placed by the landmarks per frame while the belief is
# wide (global localisation)
SENSOR_RESET_EVERY = 3  # ... placed at every this many frames with landmarks, at once
RESET_POOL = 100  # candidate poses per frame for the placed shares (by likelihood)
INJECT_FROM_OBSERVATIONS = 0.5  # share of injected poses placed by observed landmarks
NO_SUPPORT = -30.0  # log belief density below which a pose counts as unsupported
SUPPORT_PARTICLES = 256  # particles the belief's density at a new pose is summed over


@dataclass
class Frame:
    """What weighting one frame found, for its resampling and the smoother's inputs: the
    prepared observations (observation_model; None without usable ones), the IMU's field
    heading (yaw, sigma) or None, whether the frame places poses by its observations
    (``reset``), the poses they placed with their log-likelihoods (``pool``; filled by
    ``NewPoses.placed`` where weighting placed none), the posterior share of "elsewhere"
    (``kidnap``, while tracking) and the rival to place around (``rival``)."""

    prep: object = None
    heading: tuple | None = None
    reset: bool = False
    pool: tuple | None = None
    kidnap: float | None = None
    rival: np.ndarray | None = None

    @property
    def n_observations(self) -> int:
        return 0 if self.prep is None else len(self.prep)


class Belief(NamedTuple):
    """A particle set: poses (N, 3) and their weights (N,)."""

    particles: np.ndarray
    weights: np.ndarray


class LikelihoodAverages:
    """Augmented MCL's slow and fast averages of the mean per-observation likelihood (None
    before the first frame with observations)."""

    def __init__(self):
        self.slow: float | None = None
        self.fast: float | None = None

    def update(self, w_avg: float):
        if self.slow is None:
            self.slow = self.fast = w_avg
        else:
            self.slow += ALPHA_SLOW * (w_avg - self.slow)
            self.fast += ALPHA_FAST * (w_avg - self.fast)

    def share(self) -> float:
        """The share of random particles, max(0, 1 - w_fast / w_slow) (with
        ``RANDOM_FRACTION``, at most ``MAX_INJECT``)."""
        share = float(RANDOM_FRACTION)
        if self.slow and self.fast is not None and self.slow > 0:
            share += max(0.0, 1.0 - self.fast / self.slow)
        return min(share, float(MAX_INJECT))


def places(obs: Observations) -> bool:
    """Whether ``obs`` holds an observation that places a pose (a crossing, a goal post or
    a line)."""
    return bool(len(obs.crossings) or len(obs.posts) or len(obs.lines))


def resetting(obs: Observations, wide: bool, share: float, since_reset: int) -> bool:
    """Whether a frame places poses by its observations ``obs`` (sensor resetting): it has
    observations that place one, and the belief is ``wide`` (every frame), augmented MCL's
    ``share`` says the likelihood dropped (every frame), or ``SENSOR_RESET_EVERY`` - 1 frames
    with landmarks have passed since the last (``since_reset``)."""
    if not places(obs):
        return False
    if wide or share > 0:
        return True
    return since_reset + 1 >= max(int(SENSOR_RESET_EVERY), 1)


def reset_share(now: bool, wide: bool, since_reset: int, kidnap: float | None) -> float:
    """The share of the particles a frame places by its observations: none unless it resets
    (``now``); while the belief is ``wide``, ``SENSOR_RESET_FRACTION`` for each frame since
    the last reset; while tracking, the posterior share of "elsewhere" (``kidnap``)."""
    if now and wide:
        return min(float(SENSOR_RESET_FRACTION) * (since_reset + 1), 1.0)
    if now:
        return kidnap or 0.0
    return 0.0


def particle_count(spread: float | None, share: float, conf: dict, held: int,
                   paired: bool) -> int:
    """Particles (held) after resampling: by the belief's ``spread`` between
    ``particles_min`` and ``particles_max``, the most while augmented MCL injects
    (``share``); a larger set (``held`` now) is kept until the belief has narrowed below
    ``SPREAD_HIGH``."""
    lo, hi = int(conf["particles_min"]), int(conf["particles_max"])
    if spread is not None and spread >= SPREAD_HIGH:
        return max(held_count(hi, paired), held)
    if share > 0 or spread is None:
        return held_count(hi, paired)
    f = (spread - SPREAD_LOW) / max(SPREAD_HIGH - SPREAD_LOW, 1e-9)
    return held_count(int(round(lo + (hi - lo) * min(max(f, 0.0), 1.0))), paired)


def low_variance(weights: np.ndarray, keep: int, rng) -> np.ndarray:
    """Indices of ``keep`` particles drawn by ``weights`` with one random offset (low-variance
    resampling)."""
    cum = np.cumsum(weights)
    cum[-1] = 1.0
    u = (rng.random() + np.arange(keep)) / keep
    return np.searchsorted(cum, u, side="left")


def log_support(belief: Belief, poses: np.ndarray, clusters,
                held: int = SUPPORT_PARTICLES) -> np.ndarray:
    """log of the ``belief``'s density at ``poses`` (M, 3), up to a constant: the weighted sum
    of Gaussian kernels (the ``clusters``' radius and heading window) on ``held`` particles
    drawn from the belief by their weight (evenly spaced on the weights' cumulative sum, no
    random draw)."""
    w = belief.weights
    cum = np.cumsum(w)
    k = min(held, len(w))
    idx = np.minimum(np.searchsorted(cum, (np.arange(k) + 0.5) / k * cum[-1]), len(w) - 1)
    q = belief.particles[idx]
    out = np.empty(len(poses))
    _log_kernel_density(np.ascontiguousarray(poses, float), np.ascontiguousarray(q, float),
                        (1.0 / (2.0 * clusters.radius ** 2),
                         1.0 / max(clusters.heading, 1e-6) ** 2), out)
    return out


# a kernel this far (in log) below the pose's nearest adds less than e^-40 of it: not summed
_KERNEL_REACH = 40.0


@njit(cache=True, nogil=True)
def _log_kernel_density(poses, support, scales, out):
    """``out`` (M,) = log mean_k exp(-e_mk) with e = |d xy|^2 w_xy + (1 - cos d theta) w_th
    between pose m and support particle k (``scales``: w_xy, w_th): log_support's sum, one
    pass per pose, the terms below the nearest's by ``_KERNEL_REACH`` left out."""
    w_xy, w_th = scales
    n = support.shape[0]
    cs, sn = np.cos(support[:, 2]), np.sin(support[:, 2])
    e = np.empty(n)
    for m in range(poses.shape[0]):
        x, y = poses[m, 0], poses[m, 1]
        c, s = math.cos(poses[m, 2]), math.sin(poses[m, 2])
        low = np.inf
        for k in range(n):
            dx, dy = x - support[k, 0], y - support[k, 1]
            e[k] = (dx * dx + dy * dy) * w_xy + (1.0 - (c * cs[k] + s * sn[k])) * w_th
            low = min(low, e[k])
        total = 0.0
        for k in range(n):
            if e[k] - low < _KERNEL_REACH:
                total += math.exp(low - e[k])
        out[m] = -low + math.log(total) - math.log(n)


def mirror_guard(poses: np.ndarray, belief: Belief, clusters, last_pose,
                 log_odds=None) -> np.ndarray:
    """Without the pairing of a symmetric prior the track has chosen a side of the field: a
    new pose and its mirror image explain the observations equally, so each new pose is
    taken as whichever of the two the ``belief`` supports more (the new poses can then find a
    lost robot, but not flip the track to the mirrored side). The support is the belief's
    density at the pose (``log_support``); where the belief holds neither (a far kidnap), the
    one nearer the last estimate's pose ``last_pose`` (None before the first).

    ``log_odds`` (poses -> log prior odds of each pose over its mirror image; a start half
    carried by the odometry, StartHalf) weighs in: the side is the one of the
    larger support times prior, and where the belief holds neither, the prior's side where
    its odds reach start_half.HALF_DECIDES."""
    if not len(poses):
        return poses
    mirror = poses.copy()
    mirror[:, 0:2] *= -1.0
    mirror[:, 2] = wrap_angle(mirror[:, 2] + math.pi)
    own, other = log_support(belief, poses, clusters), log_support(belief, mirror, clusters)
    odds = np.zeros(len(poses)) if log_odds is None else log_odds(poses)
    flip = other > own + odds
    if last_pose is not None:
        cx, cy = float(last_pose[0]), float(last_pose[1])
        nearer = (poses[:, 0] + cx) ** 2 + (poses[:, 1] + cy) ** 2 < (
            poses[:, 0] - cx) ** 2 + (poses[:, 1] - cy) ** 2
        if log_odds is not None:
            nearer = np.where(np.abs(odds) >= HALF_DECIDES, odds < 0.0, nearer)
        none = np.maximum(own, other) < NO_SUPPORT
        flip = np.where(none, nearer, flip)
    out = poses.copy()
    out[flip] = mirror[flip]
    return out


class NewPoses:
    """The poses resampling injects: placed by a frame's observations (``placer``,
    mcl_placement.PosePlacer, weighted by the observation ``model``) or uniform over the
    world ``bounds``; ``clusters``: the belief's clustering (a rival's poses lie within its
    cluster); ``rng``: the filter's generator."""

    def __init__(self, model, placer, bounds: tuple, clusters, rng):
        self.model = model
        self.placer = placer
        self.bounds = bounds
        self.clusters = clusters
        self.rng = rng

    def observed(self, n: int, frame: Frame) -> np.ndarray:
        """Poses at which one observation of the frame is explained by a random field
        feature of its kind (sensor resetting)."""
        return self.placer.poses(n, frame.prep.obs, self.rng)

    def injected(self, n: int, frame: Frame | None) -> np.ndarray:
        """``n`` new poses of augmented MCL: a share placed by this frame's observations, the
        rest uniform."""
        n_placed = 0
        out = []
        if frame is not None and frame.prep is not None and places(frame.prep.obs):
            n_placed = int(round(n * float(INJECT_FROM_OBSERVATIONS)))
        if n_placed:
            out.append(self.placed(n_placed, frame))
        out.append(uniform_poses(n - sum(len(q) for q in out), self.rng, self.bounds))
        return np.concatenate(out)

    def placed(self, n: int, frame: Frame) -> np.ndarray:
        """``n`` poses explained by this frame's observations: around the rival that won the
        sequential test where one did, else drawn from the frame's pool in proportion to their
        likelihood under all of the frame's observations (likelihood-filtered sensor
        resetting; the pool placed now where weighting placed none), else placed directly."""
        if n <= 0:
            return np.zeros((0, 3))
        if frame.rival is not None:  # a rival won the sequential test: around it
            r, h = self.clusters.radius, self.clusters.heading
            spread = np.array([r, r, h])
            p = frame.rival + self.rng.standard_normal((n, 3)) * (spread / 6.0)
            p[:, 2] = wrap_angle(p[:, 2])
            return p
        if frame.pool is None:  # not weighted with the particles
            pool = self.observed(RESET_POOL, frame)
            ll = (self.model.log_likelihood(pool[:, 0], pool[:, 1], pool[:, 2], frame.prep)
                  if len(pool) else None)
            frame.pool = (pool, ll)
        pool, ll = frame.pool
        if not len(pool):
            return self.observed(n, frame)
        w = np.exp(ll - ll.max())
        cum = np.cumsum(w / w.sum())
        cum[-1] = 1.0
        idx = np.searchsorted(cum, (self.rng.random() + np.arange(n)) / n, side="left")
        return pool[idx]
