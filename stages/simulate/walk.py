"""A walking humanoid (the KidSize robot of Schulz et al. 2011): where it enters the field and
how its head moves while it walks.

- ``touchline_start``: robots enter the field at a touch line of their own half (x < 0),
  facing into the field; the entry point along the touch line and the side are seeded.
- ``head_motion``: the camera's pitch and roll over a walk. The torso sways sideways once per
  two steps (roll) and bobs once per step (pitch), with amplitudes that grow with the walking
  speed (or the turn rate when turning on the spot); the head tilts slowly around its nominal
  pitch as the robot looks near and far; servo backlash adds jitter. The angles written to
  ``head.csv`` are what the robot measures (IMU and joint encoders): the truth plus
  ``measurement_noise``.
"""

from __future__ import annotations

import numpy as np

from ..common.conf import PAIR
from ..common.errors import FieldlocError

HEAD_DEFAULTS = {
    "step_hz": 1.8,  # steps per second at full walking speed
    "sway_roll": 0.035,  # rad: amplitude of the sideways sway (one period per two steps)
    "bob_pitch": 0.02,  # rad: amplitude of the pitch bob (one period per step)
    "tilt": 0.06,  # rad: slow head tilt around the nominal pitch
    "tilt_periods": [4.0, 12.0],  # s: range of the tilt's periods
    "jitter": 0.004,  # rad: servo backlash, white per frame
    "walk_speed": 0.2,  # m/s at which the gait reaches its full amplitude
    "turn_speed": 0.4,  # rad/s turning on the spot that counts as full walking
    "measurement_noise": 0.005,  # rad: error of the angles the robot records (head.csv)
}
# the ranges of the list-valued keys (common.conf.check_bounds)
HEAD_BOUNDS = {"tilt_periods": ((0,), None, PAIR)}  # s, a range drawn from


def touchline_start(field, margin: float, rng: np.random.Generator) -> list[float]:
    """[x, y, theta]: a point on a touch line of the own half (``margin`` inside the line so the
    trajectory generator accepts it), facing into the field."""
    hx = field.length / 2
    lo, hi = -hx + max(1.0, margin), -max(0.5, margin)
    if lo >= hi:
        raise FieldlocError(f"field {field.name} is too short for a touch-line start")
    x = float(rng.uniform(lo, hi))
    side = float(rng.choice([-1.0, 1.0]))
    return [float(v) for v in field.touchline_pose(x, side, margin)]


def head_motion(stamps, poses, pitch: float, roll: float, conf: dict,
                rng: np.random.Generator) -> dict[str, np.ndarray]:
    """True head angles over a walk at ``stamps`` along ``poses`` (N, 3), around the nominal
    ``pitch`` and ``roll``. Returns arrays (N,): pitch, roll (rad), pitch_rate, roll_rate,
    yaw_rate (rad/s, for motion blur) and measured_pitch, measured_roll (what head.csv says)."""
    c = {**HEAD_DEFAULTS, **(conf or {})}
    t = np.asarray(stamps, dtype=float)
    p = np.asarray(poses, dtype=float)
    n = len(t)
    if n == 0:
        empty = np.zeros(0)
        return {k: empty for k in ("pitch", "roll", "pitch_rate", "roll_rate", "yaw_rate",
                                   "measured_pitch", "measured_roll")}
    if n > 1:
        dt = np.diff(t)
        speed = np.hypot(*np.diff(p[:, :2], axis=0).T) / dt
        turn = np.abs(np.diff(np.unwrap(p[:, 2]))) / dt
        speed = np.concatenate([[speed[0]], speed])
        turn = np.concatenate([[turn[0]], turn])
        yaw_rate = np.gradient(np.unwrap(p[:, 2]), t)
    else:
        speed = turn = yaw_rate = np.zeros(1)
    active = np.clip(np.maximum(speed / float(c["walk_speed"]),
                                turn / float(c["turn_speed"])), 0.0, 1.0)
    # gait phase: one cycle per step, advancing only while walking
    step_dt = np.diff(t, prepend=t[0])
    phase = 2 * np.pi * np.cumsum(float(c["step_hz"]) * step_dt * np.sqrt(active))
    phase += rng.uniform(0, 2 * np.pi)
    amp = np.sqrt(active)
    lo, hi = c["tilt_periods"]
    periods = rng.uniform(float(lo), float(hi), 2)
    phases = rng.uniform(0, 2 * np.pi, 2)
    tilt = float(c["tilt"]) * (0.7 * np.sin(2 * np.pi * t / periods[0] + phases[0])
                               + 0.3 * np.sin(2 * np.pi * t / periods[1] + phases[1]))
    smooth_pitch = pitch + tilt + float(c["bob_pitch"]) * amp * np.sin(phase)
    smooth_roll = roll + float(c["sway_roll"]) * amp * np.sin(phase / 2)
    jit = float(c["jitter"])
    true_pitch = smooth_pitch + rng.normal(0.0, jit, n)
    true_roll = smooth_roll + rng.normal(0.0, jit, n)
    if n > 1:
        pitch_rate = np.gradient(smooth_pitch, t)
        roll_rate = np.gradient(smooth_roll, t)
    else:
        pitch_rate = roll_rate = np.zeros(1)
    noise = float(c["measurement_noise"])
    return {
        "pitch": true_pitch,
        "roll": true_roll,
        "pitch_rate": pitch_rate,
        "roll_rate": roll_rate,
        "yaw_rate": yaw_rate,
        "measured_pitch": true_pitch + rng.normal(0.0, noise, n),
        "measured_roll": true_roll + rng.normal(0.0, noise, n),
    }
