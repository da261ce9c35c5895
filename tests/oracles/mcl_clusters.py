"""Reference for stages.localize.mcl_clusters' compiled search: the heaviest cluster written
out as array passes (numpy), as mcl_clusters' module doc describes it."""

from __future__ import annotations

import math

import numpy as np


def weighted_mean(w, x, y, cos_t, sin_t) -> np.ndarray:
    """The weighted mean pose (the heading by its mean direction; uniform weights where
    they sum to 0)."""
    s = float(w.sum())
    if s <= 0:
        w, s = np.ones(len(x)), float(len(x))
    return np.array([float(w @ x) / s, float(w @ y) / s,
                     math.atan2(float(w @ sin_t), float(w @ cos_t))])


def heaviest(bounds, radius, heading, w, x, y, th):
    """The centre (x, y, theta) of the heaviest cluster of the particles under ``w``: the
    heaviest 2 x 2 x 2 window of a 1 m x 1 m x 45 deg histogram over ``bounds`` (x0, x1, y0,
    y1; heading wraps around), then three mean-shift steps within ``radius`` m and
    ``heading`` rad."""
    cos_t, sin_t = np.cos(th), np.sin(th)
    x0, x1, y0, y1 = bounds
    nbx, nby, nbt = max(int(math.ceil(x1 - x0)), 1), max(int(math.ceil(y1 - y0)), 1), 8
    bx = np.clip((x - x0).astype(np.int64), 0, nbx - 1)
    by = np.clip((y - y0).astype(np.int64), 0, nby - 1)
    bt = ((th + math.pi) * (nbt / (2 * math.pi))).astype(np.int64) % nbt
    h = np.bincount((bx * nby + by) * nbt + bt, weights=w,
                    minlength=nbx * nby * nbt).reshape(nbx, nby, nbt)
    hp = np.zeros((nbx + 1, nby + 1, nbt))
    hp[:nbx, :nby] = h
    win = hp[:-1, :-1] + hp[1:, :-1] + hp[:-1, 1:] + hp[1:, 1:]
    win += np.roll(win, -1, axis=2)
    i, j, k = np.unravel_index(int(np.argmax(win)), win.shape)
    inwin = (((bx - i) & ~1) == 0) & (((by - j) & ~1) == 0) & (((bt - k) % nbt) <= 1)
    centre = weighted_mean(w * inwin, x, y, cos_t, sin_t)
    for _ in range(3):
        near = (x - centre[0]) ** 2 + (y - centre[1]) ** 2 <= radius ** 2
        near &= cos_t * math.cos(centre[2]) + sin_t * math.sin(centre[2]) >= math.cos(heading)
        wm = w * near
        if wm.sum() <= 0:
            break
        centre = weighted_mean(wm, x, y, cos_t, sin_t)
    return centre
