"""Local minima of a sampled error surface (figures 3 and 4 of the SURF template paper: "many local
minima" against "one minimum", counted rather than drawn).

A local minimum is a sample strictly below every neighbour it has on the sampled grid: the 8
neighbours in 2D (the 2 in 1D, the 26 in 3D), and not on the grid's border (a border sample's
missing neighbours may be lower); with ``level`` only the minima below it count.
"""

from __future__ import annotations

import itertools

import numpy as np

from .errors import FieldlocError


def local_minima(surface: np.ndarray, level: float = np.inf) -> np.ndarray:
    """Indices (M, ndim) of the strict interior local minima of a 1D, 2D or 3D ``surface``
    below ``level`` (module doc), lowest first."""
    s = np.asarray(surface, float)
    if s.ndim not in (1, 2, 3):
        raise FieldlocError(f"a surface is 1D, 2D or 3D, not {s.ndim}D")
    if min(s.shape) < 3:
        return np.zeros((0, s.ndim), np.int64)
    inner = tuple(slice(1, -1) for _ in range(s.ndim))
    centre = s[inner]
    ok = np.isfinite(centre) & (centre < level)
    offsets = [o for o in itertools.product((-1, 0, 1), repeat=s.ndim) if any(o)]
    for off in offsets:
        view = tuple(slice(1 + o, s.shape[a] - 1 + o) for a, o in enumerate(off))
        ok &= centre < s[view]
    idx = np.argwhere(ok) + 1
    return idx[np.argsort(s[tuple(idx.T)], kind="stable")]


def count_minima(surface: np.ndarray, level: float = np.inf) -> int:
    """How many strict interior local minima ``surface`` has below ``level``."""
    return int(len(local_minima(surface, level)))
