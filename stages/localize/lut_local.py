"""The table search near a known place (Ribeiro et al. (2015), section IV-B): the best cell of
a window around a prior, and the refinement every search ends with. Functions of the map's
tables (lut_tables.LutTables); a frame's data passes through their arguments only.

A window's best cell is found by branch and bound (``lut_kernels.tracked_window``): the cells
of the least bound on the min-pooled lookup first, then every cell whose bound is not above
the best score they found: the same cell as the window's whole quantised surface
(``local_surface``, computed cell by cell) would give. The quantised surface only picks
cells; the pose is then refined with the exact error (lut_tables' module doc):

- sub-cell position (``refine``): exact error on the 3 x 3 cells around the best cell (moving
  to a lower neighbour until the centre is the minimum), then a least-squares quadratic fit of
  the 9 values; the fitted minimum (clipped to one cell) is the position, its Hessian the
  shape of the fix;
- heading between the 5 deg table headings: the error at heading theta is interpolated
  linearly between the error surfaces of the two neighbouring table headings (m and m + 1,
  weights by the fraction of the step); ``refine_heading`` fits a parabola through the error
  at theta - 5 deg, theta, theta + 5 deg for a vision estimate of the heading.

The global searches (lut_global.py) and a track's fix (lut_tracked.py) end in these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..common.geometry import wrap_angle
from .lut_kernels import Posterior, refine_cell, tracked_window, window_sum
from .lut_matching import Observation
from .lut_tables import LutTables

# a tracked window ranked by its quantised surface alone (local_search: no prior)
_LEAST_SURFACE = tuple(Posterior(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))


@dataclass
class SearchResult:
    """A pose found by the search. ``error`` is the weighted error term (sum over
    observations), ``error_norm`` = error / total weight in [0, 1)."""

    x: float
    y: float
    theta: float
    error: float
    error_norm: float
    cell: tuple[int, int]
    n_observations: int
    hessian: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))  # m^-2, of e_norm
    at_window_edge: bool = False
    mode: str = ""
    candidates: list = field(default_factory=list)  # (x, y, theta, error_norm) of runners-up
    # the fix's own error_norm computed as its candidates' are (global search: exact error on
    # the best cell at the nearest table heading, before the sub-cell and heading refinement),
    # so a fix and its runners-up compare like with like
    candidate_error_norm: float = math.nan

    @property
    def pose(self) -> np.ndarray:
        return np.array([self.x, self.y, self.theta])


def local_window(tables: LutTables, x: float, y: float, half_width: float):
    """Cell bounds [i0, i1) x [j0, j1) of the window around (x, y), clipped to the grid."""
    x, y = float(x), float(y)
    res = tables.resolution
    if math.isfinite(x) and math.isfinite(y):  # Grid.cell_of in scalar arithmetic
        ci, cj = tables.grid.cell_of_point(x, y)
    else:
        ci, cj = tables.grid.cell_of(x, y)
    h = int(round(half_width / res))
    return (max(0, int(ci) - h), min(tables.ny, int(ci) + h + 1),
            max(0, int(cj) - h), min(tables.nx, int(cj) + h + 1))


def local_surface(tables: LutTables, obs: Observation, m: int, i0: int, i1: int, j0: int,
                  j1: int):
    """The quantised error surface (uint16) at table heading m on the window
    [i0, i1) x [j0, j1)."""
    out = np.empty((i1 - i0, j1 - j0), dtype=np.uint16)
    window_sum(tables.quantised, tables.observed(obs), int(m), i0, i1, j0, j1, tables.nx, out)
    return out


def refine(tables: LutTables, obs: Observation, cell, theta: float, *, max_moves: int = 4
           ) -> SearchResult:
    """Exact sub-cell refinement around ``cell``: the exact error at the continuous heading
    theta on the 3 x 3 cells around it (moving to the lowest while it is not the centre,
    at most ``max_moves`` times), then a least-squares quadratic fit of those 9 values (the
    compiled ``refine_cell``, which tracked_fix runs too)."""
    out = np.empty(9)
    refine_cell(tables.quantised, tables.observed(obs), tables.at_heading(theta),
                tables.kernel_grid, int(cell[0]), int(cell[1]), int(max_moves),
                max(obs.total_weight, 1e-12), out)
    x, y, e, e_norm, ci, cj, hxx, hxy, hyy = out.tolist()
    return SearchResult(
        x=x, y=y, theta=float(theta), error=e, error_norm=e_norm, cell=(int(ci), int(cj)),
        n_observations=len(obs), hessian=np.array([[hxx, hxy], [hxy, hyy]]))


_refine = refine  # for local_search, whose flag ``refine`` hides the function


def refine_heading(tables: LutTables, obs: Observation, cell, theta: float, *,
                   max_shifts: int = 2, fine: bool = True) -> tuple[SearchResult, float]:
    """Vision estimate of the heading near ``theta``: the position is refined (exactly) at
    the three table headings m - 1, m, m + 1 around theta, and a parabola through their
    error terms gives the heading between table steps (shifting m while the lowest is at
    an end); with ``fine`` a second parabola through theta +- a quarter step (errors with
    the angle-interpolated predictions) sharpens it. The pose is then refined at that
    heading. Returns the result and the curvature of e_norm over the heading (rad^-2, 0 if
    flat)."""
    m = int(round(float(theta) / tables.step))
    W = max(obs.total_weight, 1e-12)
    res: dict[int, SearchResult] = {}
    for _ in range(max_shifts + 1):
        for mm in (m - 1, m, m + 1):
            if mm not in res:
                start = res[m].cell if m in res else cell
                res[mm] = refine(tables, obs, start, mm * tables.step)
        e = np.array([res[mm].error / W for mm in (m - 1, m, m + 1)])
        lowest = int(np.argmin(e))
        if lowest == 1:
            break
        cell = res[m - 1 + lowest].cell
        m = m - 1 + lowest
    off, den = _parabola_vertex(e, 0.5)
    curvature = den / tables.step**2
    th = (m + off) * tables.step
    cell = res[m].cell
    if fine:  # the same fit at a quarter step with the angle-interpolated predictions
        h = 0.25 * tables.step
        fine_res = [refine(tables, obs, cell, th + dh) for dh in (-h, 0.0, h)]
        off2, den2 = _parabola_vertex(np.array([r.error for r in fine_res]) / W, 1.0)
        th += off2 * h
        cell = fine_res[1].cell
        if den2 > 1e-12:
            curvature = den2 / h**2
    out = refine(tables, obs, cell, float(wrap_angle(th)))
    return out, float(max(curvature, 0.0))


def local_search(tables: LutTables, obs: Observation, theta: float, prior_xy, *,
                 half_width: float = 1.0, refine: bool = True) -> SearchResult | None:
    """Best pose in a window (2 half_width square) around the prior for a known heading.
    ``at_window_edge`` is set when the best cell lies on a window side that is not the
    world's edge (the true minimum may lie outside)."""
    if len(obs) == 0:
        return None
    m = tables.scanlines.heading_index(theta)
    i0, i1, j0, j1 = local_window(tables, prior_xy[0], prior_xy[1], half_width)
    best, value = tracked_window(tables.quantised, tables.min_pooled, tables.observed(obs), m,
                                 (i0, i1, j0, j1), tables.kernel_grid,
                                 _LEAST_SURFACE)  # no prior
    i, j = divmod(int(best), tables.nx)
    edge = ((i == i0 and i0 > 0) or (i == i1 - 1 and i1 < tables.ny)
            or (j == j0 and j0 > 0) or (j == j1 - 1 and j1 < tables.nx))
    if refine:
        r = _refine(tables, obs, (i, j), theta)
    else:  # the best cell only, with its quantised error
        x, y = tables.grid.centre_of(i, j)
        e = float(value) / tables.q_levels
        r = SearchResult(x=float(x), y=float(y), theta=float(theta), error=e,
                         error_norm=e / max(obs.total_weight, 1e-12), cell=(i, j),
                         n_observations=len(obs))
    r.at_window_edge = bool(edge)
    r.mode = "local"
    return r


def _parabola_vertex(e: np.ndarray, limit: float) -> tuple[float, float]:
    """Vertex offset (in sample steps, clipped to +-limit) of the parabola through three
    equally spaced values, and its second difference (0 offset if not a bowl)."""
    den = float(e[0] - 2 * e[1] + e[2])
    if den <= 1e-12:
        return 0.0, 0.0
    return float(np.clip(0.5 * (e[0] - e[2]) / den, -limit, limit)), den
