"""Kalman filtering of Ribeiro et al. (2015), section IV-C: a filter for vision, one for odometry,
and their decentralised fusion in information form (the paper's equations 6-9).

State: the pose (x, y, theta) in the field frame. All three filters share one process model:
the robot keeps the motion (robot frame) it made over the previous frame (the paper predicts
from the commands sent to the motors; a recorded dataset has no commands, so the last fused
motion stands in for them), with process noise Q that grows with the frame interval and the
speed. Each node is a standard Kalman filter started from that common prediction:

- the vision node corrects it with the pose from the table search (R from the search's error
  surface, see stages.localize.lut);
- the odometry node corrects the predicted motion with the odometry increment (slip noise
  proportional to the motion) and moves the previous fused pose by the corrected motion.

Fusion (decentralised Kalman filter, information form). With the common prediction
x(k|k-1), P(k|k-1) and each node's posterior x_i(k), P_i(k):

    e_i = P_i(k)^-1 x_i(k) - P(k|k-1)^-1 x(k|k-1)            (6)
    E_i = P_i(k)^-1 - P(k|k-1)^-1                             (7)
    P(k) = (P(k|k-1)^-1 + sum_i E_i)^-1                       (8)
    x(k) = P(k) (P(k|k-1)^-1 x(k|k-1) + sum_i e_i)            (9)

Headings are handled in a frame local to the prediction (each node's state as an offset from
x(k|k-1) with the angle wrapped), which keeps equations 6-9 linear across +-pi. A node that has
nothing this frame (no vision fix, or odometry on an IMU collision frame) sends no information
(e_i = 0, E_i = 0): on collision frames the fusion uses vision alone, as the paper prescribes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..common.geometry import compose, wrap_angle
from ..common.jit import njit


@dataclass
class Gaussian:
    """A pose estimate: mean (3,) and covariance (3, 3)."""

    mean: np.ndarray
    cov: np.ndarray

    def copy(self) -> Gaussian:
        return Gaussian(self.mean.copy(), self.cov.copy())


def _delta(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a - b with the heading difference wrapped."""
    d = np.asarray(a, float) - np.asarray(b, float)
    d[2] = float(wrap_angle(d[2]))
    return d


def motion_jacobians(pose: np.ndarray, motion: np.ndarray):
    """Jacobians of pose (+) motion with respect to the pose and to the motion."""
    th = float(pose[2])
    c, s = np.cos(th), np.sin(th)
    dx, dy = float(motion[0]), float(motion[1])
    jp = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    jm = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return jp, jm


def move(est: Gaussian, motion: np.ndarray, motion_cov: np.ndarray) -> Gaussian:
    """The estimate moved by a robot-frame motion (dx, dy, dtheta) with covariance."""
    jp, jm = motion_jacobians(est.mean, motion)
    mean = compose(est.mean, motion)
    cov = jp @ est.cov @ jp.T + jm @ motion_cov @ jm.T
    return Gaussian(mean, 0.5 * (cov + cov.T))


class LocalFilter:
    """One node: a Kalman filter that corrects the common prediction with its own sensor and
    reports the information it gained (equations 6 and 7)."""

    def __init__(self, name: str):
        self.name = name
        self.prior: Gaussian | None = None
        self.posterior: Gaussian | None = None

    def predict(self, prior: Gaussian):
        self.prior = prior.copy()
        self.posterior = None

    def correct(self, z: np.ndarray, R: np.ndarray) -> Gaussian:
        """Standard Kalman update with a direct pose measurement z (H = I)."""
        p = self.prior
        S = p.cov + R
        K = p.cov @ np.linalg.inv(S)
        mean = p.mean + K @ _delta(z, p.mean)
        mean[2] = float(wrap_angle(mean[2]))
        ikh = np.eye(3) - K
        cov = ikh @ p.cov @ ikh.T + K @ R @ K.T  # Joseph form
        self.posterior = Gaussian(mean, 0.5 * (cov + cov.T))
        return self.posterior

    def information(self) -> tuple[np.ndarray, np.ndarray]:
        """(e_i, E_i) of equations 6 and 7, in the frame local to the prior's mean; zeros if
        the node had no measurement this frame."""
        if self.posterior is None:
            return np.zeros(3), np.zeros((3, 3))
        inv_post = np.linalg.inv(self.posterior.cov)
        inv_prior = np.linalg.inv(self.prior.cov)
        e = inv_post @ _delta(self.posterior.mean, self.prior.mean)  # prior mean is 0 locally
        return e, inv_post - inv_prior


def fuse(prior: Gaussian, nodes: list[LocalFilter]) -> Gaussian:
    """Equations 8 and 9: the fused estimate from the common prediction and the nodes'
    information."""
    inv_prior = np.linalg.inv(prior.cov)
    e_sum = np.zeros(3)
    E_sum = np.zeros((3, 3))
    for node in nodes:
        e, E = node.information()
        e_sum += e
        E_sum += E
    cov = np.linalg.inv(inv_prior + E_sum)
    delta = cov @ e_sum  # P(k) (P(k|k-1)^-1 * 0 + sum e_i), local frame
    mean = np.asarray(prior.mean, float) + delta
    mean[2] = float(wrap_angle(mean[2]))
    return Gaussian(mean, 0.5 * (cov + cov.T))


@dataclass
class FusionParams:
    """Noise parameters of the fusion (standard deviations)."""

    model_xy: float = 0.3  # m per s: how far the robot may deviate from its last motion
    model_theta: float = 0.5  # rad per s
    model_min_xy: float = 0.01  # m: never-zero process noise ("near zero, but never zero")
    model_min_theta: float = 0.005  # rad
    max_speed: float = 3.0  # m/s, model noise while the motion is unknown (after a reset)
    max_turn_rate: float = 3.0  # rad/s
    odometry_xy: float = 0.05  # fraction of the travelled distance (slip)
    odometry_theta: float = 0.05  # rad per rad turned, plus
    odometry_min_xy: float = 0.005  # m per frame
    odometry_min_theta: float = 0.005  # rad per frame

    @classmethod
    def from_conf(cls, conf: dict) -> FusionParams:
        return cls(**{k: float(conf[k]) for k in cls.__dataclass_fields__})


def model_sigma_xy(model_xy, model_min_xy, dt, speed):
    """The model's position noise (m, sigma) over ``dt`` s at ``speed`` m/s: how far the robot
    may deviate from the motion it last made, ``model_xy`` per second growing with the speed,
    never below ``model_min_xy``. Scalars or arrays (the smoother's collision frames,
    smooth.motion_of)."""
    return np.maximum(model_min_xy, model_xy * dt * (1.0 + speed))


class DecentralisedFusion:
    """Vision node + odometry node + fusion over a sequence of frames.

    ``step`` and ``predicted`` run one compiled kernel (``_frame_kernel``) per frame; the
    node classes above (LocalFilter, fuse, move) are the same equations in numpy, and a test
    holds the kernel to them."""

    def __init__(self, params: FusionParams | None = None):
        self.params = params or FusionParams()
        self.state: Gaussian | None = None
        self.last_motion = np.zeros(3)  # robot frame, previous frame's fused motion
        self.motion_known = False
        self.vision = LocalFilter("vision")
        self.odometry = LocalFilter("odometry")

    def reset(self, pose: np.ndarray, cov: np.ndarray):
        self.state = Gaussian(np.asarray(pose, float).copy(), np.asarray(cov, float).copy())
        self.last_motion = np.zeros(3)
        self.motion_known = False  # no motion yet: the model knows nothing of the speed

    def model_noise(self, dt: float) -> np.ndarray:
        """Process noise Q (robot frame) of the model's motion over ``dt`` (right after a
        reset, when no motion is known, noise for any speed up to max_speed)."""
        p = self.params
        if self.motion_known:
            speed = np.hypot(*self.last_motion[:2]) / max(dt, 1e-3)
            sxy = float(model_sigma_xy(p.model_xy, p.model_min_xy, dt, speed))
            sth = max(p.model_min_theta, p.model_theta * dt)
        else:
            sxy = max(p.model_min_xy, p.max_speed * dt)
            sth = max(p.model_min_theta, p.max_turn_rate * dt)
        return np.diag([sxy**2, sxy**2, sth**2])

    def model_prediction(self, dt: float) -> Gaussian:
        """The common prediction: the last fused motion repeated, with process noise."""
        return move(self.state, self.last_motion, self.model_noise(dt))

    def odometry_noise(self, increment: np.ndarray) -> np.ndarray:
        """Covariance S (robot frame) of an odometry increment: slip proportional to the
        motion, never zero."""
        p = self.params
        dist = float(np.hypot(increment[0], increment[1]))
        sxy = max(p.odometry_min_xy, p.odometry_xy * dist)
        sth = max(p.odometry_min_theta, p.odometry_theta * abs(float(increment[2])))
        return np.diag([sxy**2, sxy**2, sth**2])

    def odometry_posterior(self, increment: np.ndarray, dt: float) -> Gaussian:
        """The odometry node's Kalman correction. Both the model and the odometry predict the
        motion since the previous fused pose, so the node corrects the *motion*: the model's
        motion m (noise Q) with the measured increment u (noise S), gain K = Q (Q + S)^-1,
        then moves the previous pose by the corrected motion. (Correcting the predicted pose
        with "previous pose + u" instead would count the previous pose's covariance twice.)"""
        Q = self.model_noise(dt)
        S = self.odometry_noise(increment)
        K = Q @ np.linalg.inv(Q + S)
        motion = self.last_motion + K @ _delta(increment, self.last_motion)
        motion[2] = float(wrap_angle(motion[2]))
        Cu = (np.eye(3) - K) @ Q
        return move(self.state, motion, 0.5 * (Cu + Cu.T))

    def odometry_prior(self, increment: np.ndarray | None) -> np.ndarray | None:
        """The previous fused pose moved by the odometry (the table search's prior)."""
        if self.state is None:
            return None
        if increment is None:
            return self.state.mean.copy()
        return compose(self.state.mean, increment)

    def step(self, dt: float, odometry: np.ndarray | None, collision: bool,
             vision: tuple[np.ndarray, np.ndarray] | None) -> Gaussian | None:
        """One frame: common prediction, the two nodes' corrections, fusion. ``odometry``:
        robot-frame increment since the previous frame (None: none recorded); on a collision
        frame it is not fused. ``vision``: (pose, covariance) from the search, or None.
        Returns the fused estimate (None before the first vision fix)."""
        if self.state is None:
            if vision is None:
                return None
            self.reset(*vision)
            return self.state.copy()
        use_odo = odometry is not None and not collision
        mean, cov, motion = _frame_kernel(
            (self.state.mean, self.state.cov, self.last_motion, self.motion_known), float(dt),
            (_vec3(odometry if use_odo else None), use_odo),
            (_vec3(None if vision is None else vision[0]),
             _mat3(None if vision is None else vision[1]), vision is not None),
            self._params(), False)
        self.last_motion = motion
        self.motion_known = True
        self.state = Gaussian(mean, cov)
        return self.state.copy()

    def predicted(self, dt: float, odometry: np.ndarray | None, collision: bool):
        """(pose, covariance (3, 3)) where the robot is expected this frame: the previous
        fused pose moved by the odometry with the odometry node's covariance, or (collision
        frames, no odometry) by the last fused motion with the model's."""
        use_odo = odometry is not None and not collision
        mean, cov, _m = _frame_kernel(
            (self.state.mean, self.state.cov, self.last_motion, self.motion_known), float(dt),
            (_vec3(odometry if use_odo else None), use_odo), (_ZERO3, _ZERO33, False),
            self._params(), True)
        return mean, cov

    def _params(self) -> np.ndarray:
        if getattr(self, "_param_array", None) is None:
            p = self.params
            self._param_array = np.array([
                p.model_xy, p.model_theta, p.model_min_xy, p.model_min_theta, p.max_speed,
                p.max_turn_rate, p.odometry_xy, p.odometry_theta, p.odometry_min_xy,
                p.odometry_min_theta], dtype=np.float64)
        return self._param_array


_ZERO3 = np.zeros(3)
_ZERO33 = np.zeros((3, 3))


def _vec3(v) -> np.ndarray:
    return _ZERO3 if v is None else np.ascontiguousarray(v, dtype=np.float64).reshape(3)


def _mat3(m) -> np.ndarray:
    return _ZERO33 if m is None else np.ascontiguousarray(m, dtype=np.float64).reshape(3, 3)


# ---------------------------------------------------------------------------- the kernel
# The same equations as the classes above (move, LocalFilter.correct and .information, fuse,
# DecentralisedFusion.model_noise, odometry_noise and odometry_posterior), compiled.


@njit(cache=True, nogil=True)
def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


@njit(cache=True, nogil=True)
def _inv3(a):
    out = np.empty((3, 3))
    out[0, 0] = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    out[0, 1] = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
    out[0, 2] = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    out[1, 0] = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    out[1, 1] = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
    out[1, 2] = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
    out[2, 0] = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    out[2, 1] = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
    out[2, 2] = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    det = a[0, 0] * out[0, 0] + a[0, 1] * out[1, 0] + a[0, 2] * out[2, 0]
    return out / det


@njit(cache=True, nogil=True)
def _sym(a):
    return 0.5 * (a + a.T)


@njit(cache=True, nogil=True)
def _mm(a, b):
    """a @ b of 3 x 3 matrices in plain loops (numba's matmul calls BLAS, whose call costs
    more than the product of two 3 x 3 matrices)."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@njit(cache=True, nogil=True)
def _mv(a, v):
    """a @ v of a 3 x 3 matrix and a 3-vector in plain loops (as _mm)."""
    out = np.empty(3)
    for i in range(3):
        out[i] = a[i, 0] * v[0] + a[i, 1] * v[1] + a[i, 2] * v[2]
    return out


@njit(cache=True, nogil=True)
def _move(mean, cov, motion, motion_cov):
    th = mean[2]
    c, s = math.cos(th), math.sin(th)
    dx, dy = motion[0], motion[1]
    jp = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    jm = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = np.array([mean[0] + c * dx - s * dy, mean[1] + s * dx + c * dy,
                    _wrap(mean[2] + motion[2])])
    return out, _sym(_mm(_mm(jp, cov), jp.T) + _mm(_mm(jm, motion_cov), jm.T))


@njit(cache=True, nogil=True)
def _frame_kernel(state, dt, odometry, vision, p, prior_only):
    """One frame of DecentralisedFusion.step (prior_only False: returns the fused mean,
    covariance and motion) or the search prior of ``predicted`` (prior_only True: the odometry
    node's posterior, or the model prediction without odometry; motion unused). ``state``:
    (mean, cov, last motion, whether it is known); ``odometry``: (increment, whether it is
    used); ``vision``: (pose, covariance, whether there is one); ``p``: the FusionParams as
    an array in their field order."""
    mean, cov, last_motion, motion_known = state
    odo, use_odo = odometry
    z, R, use_vision = vision
    # model noise Q (robot frame) over dt
    if motion_known:
        speed = math.hypot(last_motion[0], last_motion[1]) / max(dt, 1e-3)
        sxy = max(p[2], p[0] * dt * (1.0 + speed))
        sth = max(p[3], p[1] * dt)
    else:
        sxy = max(p[2], p[4] * dt)
        sth = max(p[3], p[5] * dt)
    Q = np.zeros((3, 3))
    Q[0, 0] = Q[1, 1] = sxy * sxy
    Q[2, 2] = sth * sth
    prior_mean, prior_cov = _move(mean, cov, last_motion, Q)
    odo_mean = prior_mean
    odo_cov = prior_cov
    if use_odo:
        dist = math.hypot(odo[0], odo[1])
        oxy = max(p[8], p[6] * dist)
        oth = max(p[9], p[7] * abs(odo[2]))
        S = np.zeros((3, 3))
        S[0, 0] = S[1, 1] = oxy * oxy
        S[2, 2] = oth * oth
        K = _mm(Q, _inv3(Q + S))
        d = odo - last_motion
        d[2] = _wrap(d[2])
        motion = last_motion + _mv(K, d)
        motion[2] = _wrap(motion[2])
        Cu = _mm(np.eye(3) - K, Q)
        odo_mean, odo_cov = _move(mean, cov, motion, _sym(Cu))
    if prior_only:
        if use_odo:
            pose = np.array([mean[0] + math.cos(mean[2]) * odo[0] - math.sin(mean[2]) * odo[1],
                             mean[1] + math.sin(mean[2]) * odo[0] + math.cos(mean[2]) * odo[1],
                             _wrap(mean[2] + odo[2])])
            return pose, odo_cov, last_motion
        return prior_mean, prior_cov, last_motion
    inv_prior = _inv3(prior_cov)
    e_sum = np.zeros(3)
    E_sum = np.zeros((3, 3))
    if use_odo:  # the odometry node's information (equations 6 and 7)
        inv_post = _inv3(odo_cov)
        d = odo_mean - prior_mean
        d[2] = _wrap(d[2])
        e_sum += _mv(inv_post, d)
        E_sum += inv_post - inv_prior
    if use_vision:  # the vision node: a Kalman correction with H = I (Joseph form)
        Kv = _mm(prior_cov, _inv3(prior_cov + R))
        d = z - prior_mean
        d[2] = _wrap(d[2])
        v_mean = prior_mean + _mv(Kv, d)
        v_mean[2] = _wrap(v_mean[2])
        ikh = np.eye(3) - Kv
        v_cov = _sym(_mm(_mm(ikh, prior_cov), ikh.T) + _mm(_mm(Kv, R), Kv.T))
        inv_post = _inv3(v_cov)
        d = v_mean - prior_mean
        d[2] = _wrap(d[2])
        e_sum += _mv(inv_post, d)
        E_sum += inv_post - inv_prior
    f_cov = _inv3(inv_prior + E_sum)  # equations 8 and 9
    f_mean = prior_mean + _mv(f_cov, e_sum)
    f_mean[2] = _wrap(f_mean[2])
    # the fused motion since the previous pose (geometry.between)
    c, s = math.cos(mean[2]), math.sin(mean[2])
    dx, dy = f_mean[0] - mean[0], f_mean[1] - mean[1]
    motion = np.array([c * dx + s * dy, -s * dx + c * dy, _wrap(f_mean[2] - mean[2])])
    return f_mean, _sym(f_cov), motion
