"""Motion model of the particle filter (Schulz et al. 2011, eq. 1: p(x_t | x_t-1, u_t-1)): each
particle moves by the odometry increment (dx, dy, dtheta in the robot frame since the previous
frame) with noise drawn per particle.

Noise (standard deviations, per update of ``dt`` seconds)::

    translation (each of dx, dy): trans_per_trans * |d| + trans_per_sqrt_s * sqrt(dt)
    rotation:                     rot_per_rot * |dtheta| + rot_per_trans * |d|
                                  + rot_per_sqrt_s * sqrt(dt)

with |d| = hypot(dx, dy) (the terms are the fields of ``NOISE``, a ``MotionNoise``). The
proportional terms are the odometry's scale errors; the sqrt(dt) terms are the walking robot's
jitter (a random walk, so the filter behaves the same at any frame rate). Without odometry the
increment is zero and ``no_odometry_speed`` (m/s) and ``no_odometry_turn`` (rad/s) bound how far
the robot may have gone in ``dt``.

Collisions (the IMU's collision flag, DIR/imu.csv): a pushed or stumbling robot's odometry is
unreliable (GUIDE: the flag stops odometry from being fused). For such frames the heading
change comes from the IMU's yaw when it is known, and the noise grows by ``collision_trans``
(m) and ``collision_rot`` (rad, with the IMU's yaw) or ``collision_rot_without_imu``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..common.geometry import compose


class MotionNoise(NamedTuple):
    """The motion model's noise terms (module doc): standard deviations per update."""

    trans_per_trans: float
    trans_per_sqrt_s: float
    rot_per_rot: float
    rot_per_trans: float
    rot_per_sqrt_s: float
    no_odometry_speed: float
    no_odometry_turn: float
    collision_trans: float
    collision_rot: float
    collision_rot_without_imu: float


# the particle filter's motion noise (mcl.py; the smoother's transitions take the same,
# mcl_smoothing.motion_of): the values the filter has run with since it was written (docs/results.md
# records no measurement of their own)
NOISE = MotionNoise(
    trans_per_trans=0.15,  # m of noise per m travelled
    trans_per_sqrt_s=0.03,  # m / sqrt(s)
    rot_per_rot=0.15,  # rad of noise per rad turned
    rot_per_trans=0.3,  # rad of noise per m travelled
    rot_per_sqrt_s=0.05,  # rad / sqrt(s)
    no_odometry_speed=0.3,  # m/s, spread per second when there is no odometry
    no_odometry_turn=0.6,  # rad/s
    collision_trans=0.06,  # m of extra noise per update while the IMU flags a collision
    collision_rot=0.03,  # rad of extra noise then, with the IMU's yaw change
    collision_rot_without_imu=0.3,  # rad, when the IMU's yaw is not known
)


def motion_sigmas(odometry, dt: float, noise: MotionNoise = NOISE, *, has_odometry=True,
                  collision: bool = False, imu_yaw: bool = False):
    """(sigma_translation, sigma_rotation) of one update with the terms of ``noise``."""
    c = noise
    dx, dy, dth = (float(v) for v in odometry)
    d = math.hypot(dx, dy)
    rt = math.sqrt(max(dt, 0.0))
    s_t = c.trans_per_trans * d + c.trans_per_sqrt_s * rt
    s_r = c.rot_per_rot * abs(dth) + c.rot_per_trans * d + c.rot_per_sqrt_s * rt
    if not has_odometry:
        s_t += c.no_odometry_speed * max(dt, 0.0)
        s_r += c.no_odometry_turn * max(dt, 0.0)
    if collision:
        s_t += c.collision_trans
        s_r += c.collision_rot if imu_yaw else c.collision_rot_without_imu
    return s_t, s_r


def sample_motion(particles: np.ndarray, odometry, dt: float, rng: np.random.Generator,
                  noise: MotionNoise = NOISE, *, has_odometry: bool = True,
                  collision: bool = False, imu_yaw: bool = False) -> np.ndarray:
    """Particles (N, 3) moved by ``odometry`` (dx, dy, dtheta) with noise; returns a new
    array (the input is not changed). ``collision``: the IMU flags a collision in this update
    (``imu_yaw``: dtheta is the IMU's yaw change)."""
    p = np.asarray(particles, dtype=float)
    n = len(p)
    s_t, s_r = motion_sigmas(odometry, dt, noise, has_odometry=has_odometry,
                             collision=collision, imu_yaw=imu_yaw)
    dx, dy, dth = (float(v) for v in odometry)
    noise = rng.standard_normal((3, n))
    mx = dx + s_t * noise[0]
    my = dy + s_t * noise[1]
    mth = dth + s_r * noise[2]
    return moved(p, mx, my, mth)


def moved(poses: np.ndarray, dx, dy, dtheta) -> np.ndarray:
    """Poses (N, 3) moved by the increment (dx, dy, dtheta) in each pose's own frame (scalars,
    or (N,) arrays: one increment per pose); a new array."""
    p = np.asarray(poses, dtype=float)
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    out = np.empty_like(p)
    out[:, 0] = p[:, 0] + c * dx - s * dy
    out[:, 1] = p[:, 1] + s * dx + c * dy
    out[:, 2] = (p[:, 2] + dtheta + np.pi) % (2 * np.pi) - np.pi
    return out


def accumulate_odometry(odometry: dict | None, frame_stamps: np.ndarray):
    """Odometry increments (F, 3) between consecutive frames: the rows of ``odometry`` (columns
    stamp, dx, dy, dtheta, each an increment since the previous row) with stamps in
    (previous frame stamp, frame stamp], composed in order. The first frame gets the rows up
    to its stamp. ``odometry=None`` gives zeros. Also returns a (F,) bool: whether any row
    fell into the interval."""
    frame_stamps = np.asarray(frame_stamps, dtype=float)
    f = len(frame_stamps)
    out = np.zeros((f, 3))
    has = np.zeros(f, dtype=bool)
    if odometry is None or len(odometry["stamp"]) == 0:
        return out, has
    st = np.asarray(odometry["stamp"], float)
    order = np.argsort(st, kind="stable")
    st = st[order]
    inc = np.stack([np.asarray(odometry[k], float)[order] for k in ("dx", "dy", "dtheta")], 1)
    # row r belongs to the first frame whose stamp is >= its stamp (small tolerance)
    which = np.searchsorted(frame_stamps, st - 1e-6, side="left")
    for fi in np.unique(which):
        if fi >= f:
            continue
        rows = inc[which == fi]
        x = y = th = 0.0
        for ddx, ddy, ddth in rows:
            c, s = math.cos(th), math.sin(th)
            x, y, th = x + c * ddx - s * ddy, y + s * ddx + c * ddy, th + ddth
        out[fi] = (x, y, math.remainder(th, 2 * math.pi))
        has[fi] = True
    return out, has


def imu_per_frame(imu: dict | None, frame_stamps: np.ndarray):
    """From DIR/imu.csv (stamp, yaw, collision): per frame whether a collision was flagged
    since the previous frame (F,) bool, and the yaw change since the previous frame (F,) rad,
    interpolated at the frame stamps (NaN where the IMU does not cover both stamps; 0 for the
    first frame)."""
    frame_stamps = np.asarray(frame_stamps, dtype=float)
    f = len(frame_stamps)
    collision = np.zeros(f, dtype=bool)
    dyaw = np.full(f, np.nan)
    if imu is None or len(imu["stamp"]) == 0 or f == 0:
        return collision, dyaw
    order = np.argsort(imu["stamp"], kind="stable")
    st = np.asarray(imu["stamp"], float)[order]
    flag = np.asarray(imu["collision"], float)[order] > 0
    which = np.searchsorted(frame_stamps, st - 1e-6, side="left")
    hit = which[flag]
    collision[hit[hit < f]] = True
    yaw = np.unwrap(np.asarray(imu["yaw"], float)[order])
    inside = (frame_stamps >= st[0] - 1e-6) & (frame_stamps <= st[-1] + 1e-6)
    at = np.interp(frame_stamps, st, yaw)
    dyaw[1:] = np.where(inside[1:] & inside[:-1], np.diff(at), np.nan)
    dyaw[0] = 0.0
    return collision, dyaw


@dataclass(frozen=True)
class Motion:
    """The odometry of a run: per frame the increment since the previous frame (robot frame)
    and its covariance (the method's fusion noise; large where no odometry was recorded)."""

    increments: np.ndarray  # (N, 3)
    cov: np.ndarray  # (N, 3, 3) robot frame

    def between(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """The increment from frame i to frame j > i (composed) and its covariance (robot
        frame of frame i; the steps' covariances rotated into it and summed)."""
        pose = np.zeros(3)
        cov = np.zeros((3, 3))
        for k in range(i + 1, j + 1):
            c, s = math.cos(pose[2]), math.sin(pose[2])
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            cov = cov + rot @ self.cov[k] @ rot.T
            pose = compose(pose, self.increments[k])
        return pose, cov
