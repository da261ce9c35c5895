"""The particle filter's clusters (mcl.py): a belief's heaviest cluster is found in a
weighted 1 m x 1 m x 45 deg histogram of the particles (the heaviest 2 x 2 x 2 window, heading
wrapping around) and refined by three mean-shift steps; a cluster's members are the particles
within ``radius`` metres and ``heading`` radians of its centre.

The search is one compiled pass (``_heaviest``), as a frame's few hundred particles make
array passes spend their time on temporaries (docs/results.md, images to poses).
tests/oracles/mcl_clusters.py writes it out as array passes, and tests/test_mcl_clusters.py
holds the kernel against it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..common.jit import njit

HEADING_BINS = 8  # the histogram's 45 deg heading bins
MEAN_SHIFT_STEPS = 3


class Particles(NamedTuple):
    """N particles as the cluster kernels read them: weights, positions, heading and the
    heading's cosine and sine, (N,) float64 each."""

    w: np.ndarray
    x: np.ndarray
    y: np.ndarray
    th: np.ndarray
    cos_t: np.ndarray
    sin_t: np.ndarray


class Clustering:
    """Clusters of particles in the world (x0, x1, y0, y1) ``bounds`` with the cluster radius
    (m) and heading window (rad)."""

    def __init__(self, bounds: tuple, radius: float, heading: float):
        self.radius = radius
        self.heading = heading
        x0, x1, y0, y1 = bounds
        # the histogram: its origin and 1 m cells (at least one along each axis)
        self._grid = (float(x0), float(y0), max(int(math.ceil(x1 - x0)), 1),
                      max(int(math.ceil(y1 - y0)), 1))
        self._window = (float(radius) ** 2, math.cos(heading))

    def heaviest(self, w, x, y, th, cos_t, sin_t) -> np.ndarray:
        """The centre of the belief's heaviest cluster under weights ``w``: the heaviest
        2 x 2 x 2 window of a 1 m x 1 m x 45 deg histogram (heading wraps around), then three
        mean-shift steps with the cluster radius."""
        parts = Particles(*(np.ascontiguousarray(a, dtype=np.float64)
                            for a in (w, x, y, th, cos_t, sin_t)))
        out = np.empty(3)
        _heaviest(parts, self._grid, self._window, out)
        return out

    def members(self, centre, x, y, cos_t, sin_t) -> np.ndarray:
        """Particles within the cluster radius and heading of ``centre``."""
        dx, dy = x - centre[0], y - centre[1]
        near = dx * dx + dy * dy <= self.radius ** 2
        cos_d = cos_t * math.cos(centre[2]) + sin_t * math.sin(centre[2])
        return near & (cos_d >= math.cos(self.heading))


@njit(cache=True, nogil=True)
def _mean_of(p, keep, out):
    """The weighted mean pose of the particles ``p`` (Particles) with weights w * keep (keep:
    (N,) bool, or an empty array: all) into ``out``: the heading by its mean direction,
    uniform weights where they sum to 0."""
    n = len(p.w)
    every = len(keep) == 0
    s = sx = sy = ss = sc = 0.0
    for i in range(n):
        if every or keep[i]:
            wi = p.w[i]
            s += wi
            sx += wi * p.x[i]
            sy += wi * p.y[i]
            ss += wi * p.sin_t[i]
            sc += wi * p.cos_t[i]
    if not s > 0:
        s, sx, sy, ss, sc = float(n), 0.0, 0.0, 0.0, 0.0
        for i in range(n):
            sx += p.x[i]
            sy += p.y[i]
            ss += p.sin_t[i]
            sc += p.cos_t[i]
    out[0], out[1], out[2] = sx / s, sy / s, math.atan2(ss, sc)


@njit(cache=True, nogil=True)
def _heaviest(p, grid, window, out):
    """Clustering.heaviest into ``out`` (x, y, theta): ``grid`` (x0, y0, nbx, nby) the
    histogram's origin and cells, ``window`` (radius^2, cos of the heading window)."""
    x0, y0, nbx, nby = grid
    r2, cos_h = window
    nbt = HEADING_BINS
    n = len(p.w)
    bx = np.empty(n, np.int64)
    by = np.empty(n, np.int64)
    bt = np.empty(n, np.int64)
    h = np.zeros((nbx + 1, nby + 1, nbt))  # one empty row and column past the field
    for i in range(n):
        bx[i] = min(max(int(p.x[i] - x0), 0), nbx - 1)
        by[i] = min(max(int(p.y[i] - y0), 0), nby - 1)
        bt[i] = int((p.th[i] + math.pi) * (nbt / (2 * math.pi))) % nbt
        h[bx[i], by[i], bt[i]] += p.w[i]
    # the heaviest 2 x 2 x 2 window (heading wraps around); the first in C order on a tie
    best, bi, bj, bk = -1.0, 0, 0, 0
    for i in range(nbx):
        for j in range(nby):
            for k in range(nbt):
                k1 = (k + 1) % nbt
                win = (h[i, j, k] + h[i + 1, j, k] + h[i, j + 1, k] + h[i + 1, j + 1, k]
                       + (h[i, j, k1] + h[i + 1, j, k1] + h[i, j + 1, k1] + h[i + 1, j + 1, k1]))
                if win > best:
                    best, bi, bj, bk = win, i, j, k
    keep = np.empty(n, np.bool_)
    for i in range(n):
        keep[i] = (bi <= bx[i] <= bi + 1 and bj <= by[i] <= bj + 1
                   and (bt[i] - bk) % nbt <= 1)
    _mean_of(p, keep, out)
    for _ in range(MEAN_SHIFT_STEPS):
        c, s_ = math.cos(out[2]), math.sin(out[2])
        total = 0.0
        for i in range(n):
            dx, dy = p.x[i] - out[0], p.y[i] - out[1]
            keep[i] = dx * dx + dy * dy <= r2 and p.cos_t[i] * c + p.sin_t[i] * s_ >= cos_h
            if keep[i]:
                total += p.w[i]
        if total <= 0:
            break
        _mean_of(p, keep, out)
