"""Odometry and IMU readings made from the true motion, with the faults of real robots.

Odometry (``odometry.csv``: stamp, dx, dy, dtheta in the robot frame since the previous frame;
zero on the first frame):
- a scale error per run (wheel radius, gear play): translation and rotation each scaled by
  1 + N(0, scale_sigma);
- slip per frame: the translation multiplied by 1 + N(0, slip_sigma) per axis, and a rotation
  error N(0, slip_rotation) per metre moved;
- drift: a systematic rotation of ``drift`` rad per metre travelled, its sign drawn per run;
- white noise on every component;
- collisions: on collision frames the wheels lose contact or are blocked, so the reading is
  off by N(0, collision_xy) m and N(0, collision_theta) rad.

IMU (``imu.csv``: stamp, yaw, collision): the true heading plus a bias (an offset per run and a
random walk), white noise, and a jolt on collision frames; collision is 1 on frames of a
collision. Collisions are events at ``collision_rate_hz`` lasting ``collision_frames`` frames,
plus every frame on which another robot comes within ``contact_distance`` (its centre).

All noise levels are conf values (defaults below are for a wheeled MSL robot; a walking humanoid
wants a larger slip and scale error).
"""

from __future__ import annotations

import numpy as np

from ..common.conf import PAIR
from ..common.geometry import between, wrap_angle

ODOMETRY_DEFAULTS = {
    "scale_sigma": 0.03,  # relative, per run, translation
    "rotation_scale_sigma": 0.03,  # relative, per run, rotation
    "slip_sigma": 0.04,  # relative, per frame, per axis
    "slip_rotation": 0.02,  # rad per metre moved, per frame
    "drift": 0.01,  # rad per metre travelled, systematic
    "noise_xy": 0.002,  # m per frame
    "noise_theta": 0.002,  # rad per frame
    "collision_xy": 0.08,  # m per collision frame
    "collision_theta": 0.15,  # rad per collision frame
}

IMU_DEFAULTS = {
    "yaw_noise": 0.004,  # rad, white
    "bias_sigma": 0.008,  # rad, offset per run
    "bias_walk": 0.001,  # rad per sqrt(s), random walk
    "collision_yaw": 0.03,  # rad, extra noise on collision frames
    "collision_rate_hz": 0.1,  # collision events per second
    "collision_frames": [2, 5],  # frames per event (inclusive range)
    "contact_distance": 0.55,  # m: another robot's centre this close is a collision
}

# the ranges of the list-valued keys (common.conf.check_bounds): a collision lasts a whole
# number of frames, at least one, drawn from [low, high]
IMU_BOUNDS = {"collision_frames": (1, None, PAIR)}


def true_motion(poses) -> np.ndarray:
    """(N, 3) robot-frame motion since the previous frame (zero for the first)."""
    poses = np.asarray(poses, dtype=float)
    out = np.zeros_like(poses)
    for i in range(1, len(poses)):
        out[i] = between(poses[i - 1], poses[i])
    return out


def collision_flags(n_frames: int, rate_hz: float, conf: dict, rng: np.random.Generator,
                    contacts=None) -> np.ndarray:
    """(N,) bool: frames on which the robot is in a collision."""
    c = {**IMU_DEFAULTS, **conf}
    flags = np.zeros(n_frames, dtype=bool)
    p = min(1.0, float(c["collision_rate_hz"]) / rate_hz)
    starts = np.flatnonzero(rng.random(n_frames) < p)
    lo, hi = (int(v) for v in c["collision_frames"])
    lengths = rng.integers(lo, hi + 1, size=len(starts))
    for s, n in zip(starts, lengths):
        flags[max(s, 1): s + n] = True
    if contacts is not None:
        flags |= np.asarray(contacts, dtype=bool)
    flags[0] = False
    return flags


def odometry(poses, conf: dict, rng: np.random.Generator, collisions=None) -> np.ndarray:
    """(N, 3) odometry readings dx, dy, dtheta for true poses (N, 3)."""
    c = {**ODOMETRY_DEFAULTS, **conf}
    motion = true_motion(poses)
    n = len(motion)
    dist = np.hypot(motion[:, 0], motion[:, 1])
    scale_t = 1.0 + rng.normal(0.0, c["scale_sigma"])
    scale_r = 1.0 + rng.normal(0.0, c["rotation_scale_sigma"])
    drift = float(c["drift"]) * rng.choice([-1.0, 1.0])
    out = motion.copy()
    out[:, :2] *= scale_t * (1.0 + rng.normal(0.0, c["slip_sigma"], size=(n, 2)))
    out[:, 2] *= scale_r
    out[:, 2] += dist * (drift + rng.normal(0.0, c["slip_rotation"], size=n))
    out[:, :2] += rng.normal(0.0, c["noise_xy"], size=(n, 2))
    out[:, 2] += rng.normal(0.0, c["noise_theta"], size=n)
    if collisions is not None:
        hit = np.asarray(collisions, dtype=bool)
        k = int(hit.sum())
        out[hit, :2] += rng.normal(0.0, c["collision_xy"], size=(k, 2))
        out[hit, 2] += rng.normal(0.0, c["collision_theta"], size=k)
    out[0] = 0.0
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def imu_yaw(poses, stamps, conf: dict, rng: np.random.Generator, collisions=None) -> np.ndarray:
    """(N,) IMU yaw (rad, field frame) for true poses (N, 3) at ``stamps``."""
    c = {**IMU_DEFAULTS, **conf}
    poses = np.asarray(poses, dtype=float)
    n = len(poses)
    dt = np.diff(np.asarray(stamps, dtype=float), prepend=stamps[0])
    walk = np.cumsum(rng.normal(0.0, 1.0, size=n) * c["bias_walk"] * np.sqrt(np.maximum(dt, 0)))
    bias = rng.normal(0.0, c["bias_sigma"]) + walk
    yaw = poses[:, 2] + bias + rng.normal(0.0, c["yaw_noise"], size=n)
    if collisions is not None:
        hit = np.asarray(collisions, dtype=bool)
        yaw[hit] += rng.normal(0.0, c["collision_yaw"], size=int(hit.sum()))
    return wrap_angle(yaw)
