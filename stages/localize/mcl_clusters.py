"""The particle filter's clusters (mcl.py): a belief's heaviest cluster is found in a
weighted 1 m x 1 m x 45 deg histogram of the particles (the heaviest 2 x 2 x 2 window, heading
wrapping around) and refined by three mean-shift steps; a cluster's members are the particles
within ``radius`` metres and ``heading`` radians of its centre.
"""

from __future__ import annotations

import math

import numpy as np


class Clustering:
    """Clusters of particles in the world (x0, x1, y0, y1) ``bounds`` with the cluster radius
    (m) and heading window (rad)."""

    def __init__(self, bounds: tuple, radius: float, heading: float):
        self._bounds = bounds
        self.radius = radius
        self.heading = heading

    def heaviest(self, w, x, y, th, cos_t, sin_t) -> np.ndarray:
        """The centre of the belief's heaviest cluster under weights ``w``: the heaviest
        2 x 2 x 2 window of a 1 m x 1 m x 45 deg histogram (heading wraps around), then three
        mean-shift steps with the cluster radius."""
        x0, x1, y0, y1 = self._bounds
        nbx, nby, nbt = max(int(math.ceil(x1 - x0)), 1), max(int(math.ceil(y1 - y0)), 1), 8
        bx = np.minimum(np.maximum((x - x0).astype(np.int64), 0), nbx - 1)
        by = np.minimum(np.maximum((y - y0).astype(np.int64), 0), nby - 1)
        bt = ((th + math.pi) * (nbt / (2 * math.pi))).astype(np.int64) % nbt
        h = np.bincount((bx * nby + by) * nbt + bt, weights=w,
                        minlength=nbx * nby * nbt).reshape(nbx, nby, nbt)
        hp = np.zeros((nbx + 1, nby + 1, nbt))
        hp[:nbx, :nby] = h
        win = hp[:-1, :-1] + hp[1:, :-1] + hp[:-1, 1:] + hp[1:, 1:]
        win += np.roll(win, -1, axis=2)
        i, j, k = np.unravel_index(int(np.argmax(win)), win.shape)
        inwin = (((bx - i) & ~1) == 0) & (((by - j) & ~1) == 0) & (
            ((bt - k) % nbt) <= 1)
        centre = weighted_mean(w * inwin, x, y, cos_t, sin_t)
        for _ in range(3):
            wm = w * self.members(centre, x, y, cos_t, sin_t)
            if wm.sum() <= 0:
                break
            centre = weighted_mean(wm, x, y, cos_t, sin_t)
        return centre

    def members(self, centre, x, y, cos_t, sin_t) -> np.ndarray:
        """Particles within the cluster radius and heading of ``centre``."""
        dx, dy = x - centre[0], y - centre[1]
        near = dx * dx + dy * dy <= self.radius ** 2
        cos_d = cos_t * math.cos(centre[2]) + sin_t * math.sin(centre[2])
        return near & (cos_d >= math.cos(self.heading))


def weighted_mean(w, x, y, cos_t, sin_t) -> np.ndarray:
    """The weighted mean pose (the heading by its mean direction; uniform weights where
    they sum to 0)."""
    s = float(w.sum())
    if s <= 0:
        w, s = np.ones(len(x)), float(len(x))
    return np.array([float(w @ x) / s, float(w @ y) / s,
                     math.atan2(float(w @ sin_t), float(w @ cos_t))])
