"""Readable oracles of the perspective chain's geometry (numpy and np.linalg, float64): the
floor projection of ideal pixels and back, a floor line's egocentric parameters, the angle
between two vectors, where two lines meet, the least-squares line of points, and the lines'
width ratios. The compiled kernels are compared with these within stated tolerances.
"""

from __future__ import annotations

import numpy as np


def to_floor(rotation, k, height, position, ideal) -> np.ndarray:
    """Ideal pixels (N, 2) -> floor points (N, 2): the ray R K^-1 (u, v, 1) (np.linalg)
    scaled to reach the floor ``height`` below the lens, plus the lens's ``position``; NaN
    unless the ray points down."""
    p = np.asarray(ideal, float).reshape(-1, 2)
    rays = np.einsum("ij,nj->ni", rotation @ np.linalg.inv(k),
                     np.concatenate([p, np.ones((len(p), 1))], axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(rays[:, 2] < -1e-9, height / -rays[:, 2], np.nan)
    return rays[:, :2] * t[:, None] + np.asarray(position, float)


def to_ideal(rotation, k, height, position, floor) -> np.ndarray:
    """Floor points (N, 2) -> ideal pixels (N, 2): the point seen from the lens, in camera
    coordinates (np.linalg.solve of the rotation), through K; NaN behind the camera."""
    f = np.asarray(floor, float).reshape(-1, 2) - np.asarray(position, float)
    world = np.concatenate([f, np.full((len(f), 1), -float(height))], axis=1)
    cam = np.linalg.solve(rotation, world.T).T
    h = cam @ np.asarray(k, float).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(h[:, 2:] > 1e-9, h[:, :2] / h[:, 2:], np.nan)


def floor_line_parameters(p0, p1) -> tuple[float, float, float]:
    """(distance, angle, length) of the floor line through p0, p1: the perpendicular from the
    origin onto it (its foot by projection), the foot's bearing (the line's direction plus a
    quarter turn when the line runs through the origin, p0's bearing for a line of no length),
    and the segment's length."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length == 0:
        return float(np.linalg.norm(p0)), float(np.arctan2(p0[1], p0[0])), 0.0
    foot = p0 - np.dot(p0, d) / np.dot(d, d) * d
    dist = float(np.linalg.norm(foot))
    if dist < 1e-9:
        return dist, float(np.arctan2(d[1], d[0]) + np.pi / 2), length
    return dist, float(np.arctan2(foot[1], foot[0])), length


def angle_between(a, b) -> float:
    """The angle (radians, [0, pi]) between two 2-vectors by atan2 of their cross and dot
    products (accurate near 0 and pi); 0 when one is zero."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if not a.any() or not b.any():
        return 0.0
    return float(np.arctan2(abs(a[0] * b[1] - a[1] * b[0]), np.dot(a, b)))


def line_cut(c1, u1, c2, u2):
    """(t, s, |sin|) of the lines c1 + t u1 and c2 + s u2 meeting (np.linalg.solve);
    None when they are parallel."""
    a = np.array([u1, -np.asarray(u2)], float).T
    det = np.linalg.det(a)
    if det == 0:
        return None
    t, s = np.linalg.solve(a, np.asarray(c2, float) - np.asarray(c1, float))
    return float(t), float(s), abs(det)


def fit_line(points):
    """(centroid, unit direction, rms orthogonal residual) of the least-squares line through
    points (n, 2): the major axis of their scatter (np.linalg.eigh)."""
    p = np.asarray(points, float)
    c = p.mean(axis=0)
    w, v = np.linalg.eigh(np.cov((p - c).T, bias=True))
    u = v[:, 1]
    n = np.array([-u[1], u[0]])
    return c, u, float(np.sqrt(np.mean(((p - c) @ n) ** 2)))


def width_ratios(refs, rotation, k, height, position, line_width: float) -> list[float]:
    """Per refined line: the median over its white runs of the run's width over the width a
    painted line of ``line_width`` m has in the image there (across the image line, ideal
    px, from the floor points half a width to each side of the run's floor point, across the
    floor line); NaN where no run lies on the floor."""
    out = []
    for r in refs:
        floor = to_floor(rotation, k, height, position, r.centres)
        e = to_floor(rotation, k, height, position, r.ends)
        d = e[1] - e[0]
        nf = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        a = to_ideal(rotation, k, height, position, floor - 0.5 * line_width * nf)
        b = to_ideal(rotation, k, height, position, floor + 0.5 * line_width * nf)
        expected = np.abs((b - a) @ r.fit.normal)
        ratio = r.widths / np.maximum(expected, 1e-6)
        ok = np.isfinite(floor).all(axis=1) & np.isfinite(ratio)
        out.append(float(np.median(ratio[ok])) if ok.any() else float("nan"))
    return out
