"""SE(2) geometry in the field frame: x along the field, y left, theta counter-clockwise."""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(a):
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def wrap_scalar(a: float) -> float:
    """``wrap_angle`` of one angle in Python's float arithmetic: the same result, without a
    numpy array per call (for the per-frame bookkeeping that calls it many times)."""
    return (float(a) + math.pi) % _TWO_PI - math.pi


_TWO_PI = 2 * math.pi


def polar(points) -> tuple[np.ndarray, np.ndarray]:
    """(distance, bearing) of points (N, 2) in the robot frame (bearing counter-clockwise from
    +x)."""
    p = np.asarray(points, float).reshape(-1, 2)
    return np.hypot(p[:, 0], p[:, 1]), np.arctan2(p[:, 1], p[:, 0])


def rotation(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def robot_to_field(pose, points):
    """Points (N, 2) in the robot frame of ``pose`` (x, y, theta) -> field frame."""
    x, y, th = pose
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    c, s = np.cos(th), np.sin(th)
    return np.stack([x + c * p[:, 0] - s * p[:, 1], y + s * p[:, 0] + c * p[:, 1]], axis=1)


def field_to_robot(pose, points):
    """Points (N, 2) in the field frame -> robot frame of ``pose``."""
    x, y, th = pose
    p = np.asarray(points, dtype=float).reshape(-1, 2) - (x, y)
    c, s = np.cos(th), np.sin(th)
    return np.stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]], axis=1)


def compose(a, b):
    """Pose a (+) b: b expressed in a's frame, returned in a's parent frame."""
    ax, ay, at = a
    bx, by, bt = b
    c, s = np.cos(at), np.sin(at)
    return np.array([ax + c * bx - s * by, ay + s * bx + c * by, float(wrap_angle(at + bt))])


def inverse(inc):
    """The motion (dx, dy, dtheta) that undoes ``inc``: in the frame ``inc`` ends in, back to
    the frame it started in (compose(compose(p, inc), inverse(inc)) == p)."""
    dx, dy, dt = (float(v) for v in inc)
    c, s = math.cos(dt), math.sin(dt)
    return np.array([-(c * dx + s * dy), -(-s * dx + c * dy), -dt])


def between(a, b):
    """The motion (dx, dy, dtheta) in a's frame that takes pose a to pose b."""
    ax, ay, at = a
    bx, by, bt = b
    c, s = np.cos(at), np.sin(at)
    dx, dy = bx - ax, by - ay
    return np.array([c * dx + s * dy, -s * dx + c * dy, float(wrap_angle(bt - at))])
