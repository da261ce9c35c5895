"""Method mcl's candidates for the smoother (smooth.py) after a causal run of the particle filter
(mcl.py): what the run keeps per frame, the candidates' local fits and covariances, the
odometry's motion and the initial belief's prior.

A frame's global candidates are the poses its particle set held (the belief's clusters, the
best places of the sensor-resetting pool where the frame reset) and, on a point-symmetric
field, their mirror images; its local candidates the starts the smoother's beams give it. Each
is fitted to the frame's observations (``local_fit``: damped Newton steps, Levenberg (1944),
Marquardt (1963), on the observation model's log-likelihood less a Gaussian anchor at the
start, the derivatives from a quadratic fitted on a 3 x 3 x 3 stencil: the likelihood is a
minimum over associations, rough at the scale of a centimetre). A candidate's cost is the
negative log-likelihood over ``SMOOTH_TEMPERATURE`` (consecutive frames repeat their errors,
so a frame counts as less than independent evidence), its covariance the inverse of the
tempered curvature with a weak prior and a floor (``fix_covariance``). The causal run is
unchanged by smoothing and draws no extra random number. docs/smoothing.md has the whole
method.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..common.geometry import wrap_angle
from . import motion_model, place_search, smooth
from .heading import heading_log_likelihood
from .mcl_start import placement_log_density
from .observation_model import ObservationModel
from .smooth import FrameCandidates
from .tracking import KIDNAP_PROBABILITY

SMOOTH_TEMPERATURE = 2.0  # the smoother's frame likelihood is the model's to the power
# 1 / this (consecutive frames' errors are not independent; docs/smoothing.md)
# per frame, that the robot is not where the path says: the smoother's outlier floor
# (smooth.Transition), the value lut, fit and templates smooth with (tracking.
# KIDNAP_PROBABILITY). Not the filter's 1e-3 (mcl_rivals.KIDNAP_PROBABILITY), the share its
# resampling gives "elsewhere" so that a live filter recovers: over a whole recording that
# made a jump about as cheap as 13 nats, and on NAO tuning walk 463 (placement start, either
# touch line) the start's reflection onto the other touch line, ruled out once the robot
# turned, passed its mass to the mirror image, held at confidence 0.93 for 300 frames
# (docs/smoothing.md, "mcl")
SMOOTH_KIDNAP_PROBABILITY = KIDNAP_PROBABILITY

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


class SmoothingInputs:
    """What the causal run keeps per frame for the smoother: the frame's prepared
    observations (None without usable ones) and why, and the poses the particle set held (its
    clusters, the best places of the sensor-resetting pool)."""

    def __init__(self):
        self.prepared: list = []
        self.reasons: list = []
        self.modes: list = []
        self.headings: list = []  # the IMU's field heading (yaw, sigma) per frame, or None

    def add(self, frame, est, reason: str | None = None):
        """One frame: what its weighting found (``frame``, mcl_resampling.Frame) and its
        estimate ``est`` (mcl.Estimate); ``reason``: why it has no observations, if known."""
        prep = frame.prep
        if prep is None and reason is None:
            reason = "no-observations"
        self.prepared.append(prep)
        self.reasons.append(reason)
        self.headings.append(frame.heading)
        modes = [np.asarray(est.hypotheses, float).reshape(-1, 4)[:, :3]]
        if frame.pool is not None and len(frame.pool[0]):
            pool, ll = frame.pool
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
        fixes = self._fixes(i, starts)  # one per start, in order
        return dataclasses.replace(fixes, start=np.arange(len(fixes)))


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


def start_prior(conf: dict, field_model):
    """The log prior over the smoother's first candidates that the causal run's initial
    belief states (mcl_start.initial_poses), or None: ``placement``, the placement's density
    (mcl_start.placement_log_density); ``pose``, a Gaussian of ``init_spread`` around
    ``init_pose``; ``uniform``, the half ``start_half`` names (none for any)."""
    init = conf["init"]
    spread = np.asarray(conf["init_spread"], float)
    if init == "placement":
        return lambda cands: placement_log_density(cands.poses, field_model, conf)
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
