"""A readable oracle of where two fitted field lines cross (crossing_kernels._pair_crossings):
whether they meet at about a right angle on the floor, where, and as which shape, with the
margin of every threshold the decision passed, so that a test compares decisions only where
they are clear.
"""

from __future__ import annotations

import math

import numpy as np

from .perspective_geometry import line_cut


def _arms(t: float, length: float, u, end_gap: float, tol: float):
    """The arms a line (ends at 0 and ``length`` along ``u``) gives where another line cuts
    it at ``t``: two when the cut is inside it by more than ``tol``, one (towards its far
    end) when its nearer end lies within ``tol`` of the other line, else None; and the
    margins of these tests."""
    margins = [abs(t - tol), abs(t - (length - tol))]
    if tol < t < length - tol:
        return [np.asarray(u), -np.asarray(u)], margins
    margins += [abs(end_gap - tol), abs(t - 0.5 * length)]
    if end_gap > tol:
        return None, margins
    return ([np.asarray(u)] if t <= 0.5 * length else [-np.asarray(u)]), margins


def pair_crossing(ends_i, ends_j, width_i: float, width_j: float, fang_i: float,
                  fang_j: float, tol: float, max_misfit: float):
    """(kind, point, margin) of lines i and j (ends (2, 2) ideal px, white widths, floor
    angles): kind 2 (L), 3 (T) or None (no field crossing: not about square on the floor,
    parallel, not meeting, or an X), the intersection, and the smallest margin of the
    thresholds decided (radians, |sin| or px)."""
    ei, ej = np.asarray(ends_i, float), np.asarray(ends_j, float)
    li, lj = np.linalg.norm(ei[1] - ei[0]), np.linalg.norm(ej[1] - ej[0])
    ui, uj = (ei[1] - ei[0]) / max(li, 1e-9), (ej[1] - ej[0]) / max(lj, 1e-9)
    diff = (fang_i - fang_j) % math.pi
    off_square = abs(min(diff, math.pi - diff) - math.pi / 2)
    margins = [abs(off_square - max_misfit)]
    if not off_square <= max_misfit:
        return None, None, min(margins)
    cut = line_cut(ei[0], ui, ej[0], uj)
    margins.append(abs((cut[2] if cut else 0.0) - 1e-3))
    if cut is None or cut[2] < 1e-3:
        return None, None, min(margins)
    t_i, t_j, _ = cut
    point = ei[0] + t_i * ui
    near_i = ei[0] if t_i <= 0.5 * li else ei[1]
    near_j = ej[0] if t_j <= 0.5 * lj else ej[1]
    gap_i = abs(np.dot(near_i - ej[0], [-uj[1], uj[0]]))
    gap_j = abs(np.dot(near_j - ei[0], [-ui[1], ui[0]]))
    arms_i, m_i = _arms(t_i, li, ui, gap_i, tol + width_j)
    arms_j, m_j = _arms(t_j, lj, uj, gap_j, tol + width_i)
    margins += m_i + (m_j if arms_i is not None else [])
    if arms_i is None or arms_j is None:
        return None, point, min(margins)
    kind = len(arms_i) + len(arms_j)
    return (kind if kind < 4 else None), point, min(margins)
