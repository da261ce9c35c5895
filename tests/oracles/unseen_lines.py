"""Reference of the unseen term's visible length (stages.localize.mcl_kernels.line_in_view):
every piece's middle tested at once as array passes, no circle cut, no stepping."""

from __future__ import annotations

import numpy as np


def line_in_view(pose, points: np.ndarray, mask: np.ndarray, r: float, cell: float,
                 *, edge: float = 0.0) -> float:
    """Length (m) of the pieces (``points`` (M, 3): middle x, y and length) whose middle lies
    within ``r`` of ``pose`` (x, y, theta) and in a cell of ``mask`` (cells of ``cell`` m
    over [-r, r]^2 about the robot, row y, column x) that is set. With ``edge`` > 0, the
    length of the pieces whose middle lies within ``edge`` of a cell's side or of the circle
    instead (where a last bit of rounding decides)."""
    x, y, th = pose
    dx, dy = points[:, 0] - x, points[:, 1] - y
    c, s = np.cos(th), np.sin(th)
    u, v = c * dx + s * dy, c * dy - s * dx
    ix = np.floor((u + r) / cell).astype(int)
    iy = np.floor((v + r) / cell).astype(int)
    n = mask.shape[0]
    if edge > 0:
        fu, fv = (u + r) / cell, (v + r) / cell
        near = (np.abs(fu - np.round(fu)) * cell < edge) | (np.abs(fv - np.round(fv)) * cell
                                                            < edge)
        near |= np.abs(np.hypot(u, v) - r) < edge
        return float(points[near, 2].sum())
    ok = (u * u + v * v <= r * r) & (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n)
    ok[ok] = mask[iy[ok], ix[ok]] > 0
    return float(points[ok, 2].sum())
