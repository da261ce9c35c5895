"""The table search over the whole field (Ribeiro et al. (2015), section IV-B): a known
heading's best poses anywhere (``global_search``), the whole error surface (``surface``, the
grid belief's), and the search with no heading known (``unknown_heading_search``). Functions
of the map's tables (lut_tables.LutTables); a frame's data passes through their arguments
only.

A global search computes the fine surface only where the min-pooled lookup's bound does not
rule a cell out (branch and bound, ``lut_kernels.separated_minima``): the coarse cells opened
in the order of their bound, a computed cell passed to the greedy non-maximum suppression
once it lies below every bound not opened: a small part of the field, and the same cells as
the greedy on the whole surface (``full_surface``, computed cell by cell) would pick. The
candidates are then refined exactly (lut_local.refine).

``unknown_heading_search`` evaluates all 72 headings on every ``coarse_step``-th cell in x
and y (the min-pooled lookup), keeps the best few (heading, cell) candidates and refines each
in full resolution with a local search, the exact refinement, and heading refinement.
"""

from __future__ import annotations

import math

import numpy as np

from ..common.geometry import wrap_angle
from . import lut_kernels
from .lut_kernels import tiled_sum, weighted_cells
from .lut_local import SearchResult, local_search, local_surface, refine, refine_heading
from .lut_matching import Observation
from .lut_tables import LutTables


def global_search(tables: LutTables, obs: Observation, theta: float, *, candidates: int = 3,
                  separation: float = 0.5) -> SearchResult | None:
    """Best pose over all cells for a known heading, refined to sub-cell."""
    if len(obs) == 0:
        return None
    m = tables.scanlines.heading_index(theta)
    starts = separated_minima(tables, obs, m, candidates, separation / tables.grid.resolution)
    # exact error (nearest table heading) on each candidate's 3 x 3 neighbourhood
    ci, cj = np.divmod(starts, tables.nx)
    off = np.arange(-1, 2)
    ni = np.clip(ci[:, None, None] + off[None, :, None], 0, tables.ny - 1)
    nj = np.clip(cj[:, None, None] + off[None, None, :], 0, tables.nx - 1)
    nb = (ni * tables.nx + nj).reshape(len(starts), 9)
    exact = tables.exact_error(obs, nb, m)
    low = exact.argmin(axis=1)
    order = np.argsort(exact[np.arange(len(starts)), low], kind="stable")
    first = nb[order[0], low[order[0]]]
    best = refine(tables, obs, divmod(int(first), tables.nx), theta)
    best.mode = "global"
    W = max(obs.total_weight, 1e-12)
    best.candidate_error_norm = float(exact[order[0], low[order[0]]] / W)
    for c in order[1:]:
        x, y = tables.grid.centre_of(*divmod(int(nb[c, low[c]]), tables.nx))
        best.candidates.append((float(x), float(y), float(theta),
                                float(exact[c, low[c]] / W)))
    return best


def surface(tables: LutTables, obs: Observation, theta: float) -> np.ndarray:
    """The error term of every cell (ny, nx), in full-weight observations, at the table
    heading nearest ``theta``, from the error lookup (quantised), each observation
    weighed by ``obs.weight`` (its evidence weight where ``with_evidence`` set one: a
    white structure near the robot, a cable, counts as one correlated measurement)."""
    m = tables.scanlines.heading_index(theta)
    lw = obs.weight if obs.lookup_weight is None else obs.lookup_weight
    scale = np.where(lw > 0, obs.weight / np.where(lw > 0, lw, 1.0), 0.0)
    out = np.empty(tables.ncell, dtype=np.float32)
    weighted_cells(tables.quantised, tables.observed(obs), m,
                   np.ascontiguousarray(scale, dtype=np.float32), out)
    return out.reshape(tables.ny, tables.nx).astype(np.float64) / float(tables.q_levels)


def full_surface(tables: LutTables, obs: Observation, m: int) -> np.ndarray:
    """The quantised error surface of every cell (flat, uint16) at table heading m."""
    return local_surface(tables, obs, m, 0, tables.ny, 0, tables.nx).reshape(-1)


def separated_minima(tables: LutTables, obs: Observation, m: int, k: int, min_cells: float
                     ) -> np.ndarray:
    """Flat indices of up to k lowest cells of the quantised error surface at table
    heading m (lowest value, then lowest index), each outside the square of half-width
    ``min_cells`` around the ones before (non-maximum suppression, greedy), by branch and
    bound on the min-pooled lookup (lut_kernels.separated_minima): the same cells as the
    greedy on the whole surface (``full_surface``), which is computed only where the bound
    does not rule a cell out (a small part of the field: docs/results.md)."""
    out = np.empty(max(k, 0), dtype=np.int64)
    n = lut_kernels.separated_minima(tables.quantised, tables.min_pooled, tables.observed(obs),
                                     int(m), tables.kernel_grid, int(k),
                                     max(1, int(math.ceil(min_cells))), out)
    return out[:n]


def unknown_heading_search(tables: LutTables, obs: Observation, *, candidates: int = 8,
                           separation: float = 1.0, half_width: float = 0.3
                           ) -> SearchResult | None:
    """Pose and heading with no heading known: the error lookup on every
    ``coarse_step``-th cell for all 72 table headings, the best ``candidates``
    (heading, cell) pairs (distinct: more than ``separation`` apart or more than one
    table step in heading) refined in full resolution: a local search around each, the
    heading refined between table steps, the pose refined exactly."""
    if len(obs) == 0:
        return None
    n = tables.n_angles
    cs = max(1, tables.params.coarse_step)
    cy, cx = tables.coarse_shape
    ncoarse = cy * cx
    surfaces = np.empty((n, ncoarse), dtype=np.uint16)
    kern = tables.observed(obs)
    for m in range(n):
        tiled_sum(tables.min_pooled, kern, m, (0, cy, 0, cx), surfaces[m].reshape(cy, cx))
    flat = surfaces.ravel()
    pool = min(flat.size, 64 * candidates)
    cand = np.argpartition(flat, pool - 1)[:pool]
    cand = cand[np.argsort(flat[cand], kind="stable")]
    cm, cc = np.divmod(cand, ncoarse)
    ci, cj = np.divmod(cc, tables.coarse_shape[1])
    px, py = tables.grid.centre_of(ci * cs, cj * cs)
    chosen: list[int] = []
    for q in range(len(cand)):
        ok = True
        for c in chosen:
            dm = abs((int(cm[q]) - int(cm[c]) + n // 2) % n - n // 2)
            if dm <= 1 and (px[q] - px[c]) ** 2 + (py[q] - py[c]) ** 2 <= separation**2:
                ok = False
                break
        if ok:
            chosen.append(q)
            if len(chosen) == candidates:
                break
    results = []
    for q in chosen:
        theta = float(wrap_angle(int(cm[q]) * tables.step))
        r = local_search(tables, obs, theta, (float(px[q]), float(py[q])),
                         half_width=half_width, refine=False)
        r, _ = refine_heading(tables, obs, r.cell, theta, fine=False)
        results.append(r)
    results.sort(key=lambda r: r.error)
    for n in range(min(2, len(results))):  # the fine heading fit for the two best
        results[n], _ = refine_heading(tables, obs, results[n].cell, results[n].theta)
    best = min(results, key=lambda r: r.error)
    best.mode = "global-heading"
    best.candidates = [(r.x, r.y, r.theta, r.error_norm) for r in results if r is not best]
    best.candidate_error_norm = best.error_norm
    return best

