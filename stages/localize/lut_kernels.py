"""The numba kernels of the table search (lut_search.py): compiled once, cached on disk.

They follow lut_matching.py's and lut_tables.py's definitions exactly: the same float32 arithmetic
per observation, sums over observations accumulated in float64. The tables are the map's
(uint16 millimetres; ``metres`` gives an entry in metres as the float32 tables had it). The
kernels take a few named bundles: ``Quantised`` (the tables, the quantised errors and the
exact error's constants), ``MinPooled`` (the min-pooled lookup), ``Observed`` (a frame's
observations), ``At`` (the table headings a frame is scored at), ``Grid`` (the search grid),
``Posterior`` (a tracked search's ranking), ``FixRule`` and ``LineFit`` (what a tracked fix
is judged and moved by); a window of cells is (i0, i1, j0, j1). The bundles of scalars (At,
Grid, Posterior, FixRule, a window) are passed as plain tuples in their classes' order and
unpacked by the kernels: numba types a tuple of scalars on its compiled fast path, a
NamedTuple in Python (about 0.7 us a call, a few per tracked frame).

- ``cells_sum``, ``window_sum``, ``weighted_cells``: the quantised error surface of a frame
  on a list of cells, a window, or every cell weighted per observation, computed from the
  tables (``Quantised``; ``prepare`` the observations' offsets); ``tiled_sum`` the min-pooled
  lookup's surface; ``separated_minima`` the separated minima of the whole
  field's surface, computed only where the min-pooled lookup's lower bound does not rule a
  cell out (branch and bound);
- ``tracked_window``: the surface on a tracked search's window ranked by the posterior (error
  term over the temperature plus the prior's capped Mahalanobis term), its best cell, by
  branch and bound;
  ``tracked_window_bound`` a lower bound of its best score from the min-pooled lookup;
  ``tracked_fix`` a track's whole fix in one call (window, sub-cell refinement in the chosen
  basin and in the prior's, support);
- ``observation_prediction``: one observation's predicted crossing at one cell (nearest table
  crossing at a table heading, the angle-interpolated prediction between two), the base of
  ``exact_error_cells`` (the weighted error term on a few cells), ``observation_errors_cell``
  (every observation's error at one cell) and ``refine_moves`` (the cell moves of the sub-cell
  refinement);
- ``quadratic_fit``: the sub-cell minimum of a 3 x 3 patch;
- ``structure_sizes``: the white structures of a frame's line points (``evidence_weights``:
  the evidence weights from them).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..common.jit import njit
from .point_fit import fit_refine

MAX_CROSSINGS = 4
TILE = 8  # cells per side of a block of the tiled min-pooled lookup (64 cells: a cache line)
NONE_M = 1.0e3  # a "none" table entry in metres: far from any observation -> saturated error
TOP = 65535  # a quantised surface's "no value" (above any sum: 432 observations x 151 levels)
# unsigned offsets of a cell's crossings (unsigned + signed would be a float in numba)
U1, U2, U3, U4 = np.uint64(1), np.uint64(2), np.uint64(3), np.uint64(MAX_CROSSINGS)


class Quantised(NamedTuple):
    """The error lookup of lut_tables.py's module doc, computed on the fly: the map's tables
    (uint16 mm, scan-line-major: ``radial`` flat (line, cell, crossing), ``spiral`` flat
    (line, cell)) and per distance bin the quantised error of every table value
    (``values``, uint8, rows of ``width`` = NO_HIT_MM + 1: the radial bins, then the spiral
    bins; column mm for a table value mm, column NO_HIT_MM for "none": indexed by the table
    values as they are; ``width`` fixed, ``nb_radial`` and ``nb_spiral`` the rows of the
    two families). The lookup's entry of (line, bin, cell) is the least of its
    crossings' values (``cells_sum``): the value is monotone in the error, so the least
    value is the nearest crossing's. The exact error reads the same tables with the
    search's pair tolerance (m) and Cauchy scale squared (m^2), ``pair_tol`` and ``c2``,
    both float32 (the exact error's arithmetic)."""

    radial: np.ndarray
    spiral: np.ndarray
    ncell: int
    n_angles: int
    values: np.ndarray
    width: int
    nb_radial: int
    nb_spiral: int
    pair_tol: np.float32
    c2: np.float32


class MinPooled(NamedTuple):
    """The min-pooled error lookup (uint8, tiled: ``tiled_sum``): every ``step``-th cell of
    the error lookup (cy x cx of them, ``ntx`` blocks wide), each the least entry of the
    fine cells within step // 2 of it and of ``bin_pool`` consecutive distance bins, with the
    layout of its rows (``lookup_row``: ``rows_radial`` and ``rows_spiral`` per scan line;
    ``nb_radial`` and ``nb_spiral`` the fine bins, where an observed bin is clipped)."""

    lookup: np.ndarray
    step: int
    cy: int
    cx: int
    ntx: int
    n_angles: int
    nb_radial: int
    nb_spiral: int
    spiral_row0: int
    bin_pool: int
    rows_radial: int
    rows_spiral: int


class Observed(NamedTuple):
    """A frame's observations as the kernels read them: family (0 radial, 1, 2 spiral), scan
    line and distance bin (rounded; the quantised surfaces' rows), int64 each; the distance
    (m) and weight as float32 (the exact error's arithmetic) and the weight as float64 (the
    support's sums)."""

    family: np.ndarray
    angle_index: np.ndarray
    bins: np.ndarray
    dist: np.ndarray
    weight: np.ndarray
    weight64: np.ndarray


class At(NamedTuple):
    """Where on the table headings a frame is scored: ``m`` the nearest table heading (the
    quantised surfaces'), and for the exact error the table heading ``m0`` below the
    heading with the fraction ``a`` of the step to it, the predictions interpolated
    between m0 and m0 + 1 when ``interpolate`` (LutTables ``exact_error_at_heading``)."""

    m: int
    m0: int
    a: float
    interpolate: bool


class Grid(NamedTuple):
    """The search grid: ny x nx cells, cell (i, j)'s centre at (x0 + j res, y0 + i res)."""

    ny: int
    nx: int
    x0: float
    y0: float
    res: float


class Posterior(NamedTuple):
    """How a tracked search ranks a cell: its quantised error surface times ``scale`` plus
    min(0.5 d^T [[ia, ib], [ib, ic]] d, ``cap``), d = the cell's centre - (px, py) (the
    prior's position and information, capped: a prior that may be wrong)."""

    scale: float
    px: float
    py: float
    ia: float
    ib: float
    ic: float
    cap: float


class FixRule(NamedTuple):
    """What a tracked fix is judged by besides the window: the observations' total weight
    (the error's norm), the temperature of the exact error when the prior's basin competes
    with the window's, and the support's inlier error (m) and Cauchy scale squared."""

    total_weight: float
    temperature: float
    inlier_error: float
    c2: float


class LineFit(NamedTuple):
    """The line points' fit a tracked fix may be moved by (``point_fit.fit_refine``):
    ``enabled``, the distance raster ``table`` with its origin (x0, y0) and resolution, the
    frame's ``points`` (robot frame), the fit's Cauchy scale squared ``c2``, the heading
    ``theta`` it keeps and the largest shift (m, per axis) and turn (rad) it may make."""

    enabled: bool
    table: np.ndarray
    x0: float
    y0: float
    res: float
    points: np.ndarray
    c2: float
    theta: float
    max_shift: float
    max_turn: float


# every table distance (uint16 mm, below MAX_MM) in metres as float32, "none" (any larger
# entry: NO_HIT_MM) as NONE_M: the float32 product mm * 0.001 the search has always used,
# read where the exact error needs it (one load where converting would cost a few operations
# per crossing; 64 kB, frozen into the compiled kernels)
MAX_MM = 16383  # tables of scan lines reaching farther are refused (LutTables)
METRES = np.arange(MAX_MM + 1).astype(np.float32) * np.float32(1e-3)
METRES[MAX_MM] = NONE_M

# the least-squares quadratic f = a + b x + c y + d x^2 + e x y + f y^2 on the 3 x 3 offsets
# (-1, 0, 1)^2: the pseudo-inverse (6, 9) of its design matrix (``quadratic_fit``)
_QY, _QX = np.mgrid[-1:2, -1:2]
QPINV = np.ascontiguousarray(np.linalg.pinv(np.stack(
    [np.ones(9), _QX.ravel(), _QY.ravel(), _QX.ravel() ** 2, (_QX * _QY).ravel(),
     _QY.ravel() ** 2], axis=1)))


@njit(cache=True, nogil=True, inline="always")
def metres(mm):
    """A table entry (uint16 mm) in metres (``METRES``)."""
    return METRES[min(mm, MAX_MM)]


@njit(cache=True, nogil=True, inline="always")
def line_offsets(fam, ai, m0, n_angles, ncell):
    """Where observation (family ``fam``, scan line ``ai``) reads its predictions at table
    heading m0 and m0 + 1: the offsets of its table lines in the flat radial table
    ((line, cell, crossing): a cell's MAX_CROSSINGS crossings side by side) or the flat spiral
    table (``fam`` > 0)."""
    k0 = (ai + m0) % n_angles
    k1 = (k0 + 1) % n_angles
    if fam == 0:
        return k0 * MAX_CROSSINGS * ncell, k1 * MAX_CROSSINGS * ncell
    base = (fam - 1) * n_angles
    return (base + k0) * ncell, (base + k1) * ncell


@njit(cache=True, nogil=True, inline="always")
def bracket(at):
    """(a32, b32 = 1 - a32, upper, interpolate) of ``at``: the interpolation's weights in the
    exact error's float32 arithmetic, and which table heading is the nearer."""
    _m, _m0, a, interpolate = at
    a32 = np.float32(a)
    return a32, np.float32(1.0) - a32, a > 0.5, interpolate


@njit(cache=True, nogil=True, inline="always")
def line_prediction(q, fam, r0, r1, d, c, br):
    """The crossing distance (m) predicted for an observation at distance ``d`` whose table
    lines start at r0, r1 (``line_offsets``) at flat cell ``c``: at table heading m0 the
    nearest crossing of its scan line (not interpolating); between m0 and m0 + 1 (``br``:
    ``bracket``, fraction a32 = 1 - b32) the angle-interpolated prediction
    (``LutTables.exact_error_at_heading``)."""
    a32, b32, upper, interpolate = br
    tol = q.pair_tol
    if fam == 0:
        radial_flat = q.radial
        c0 = r0 + c * MAX_CROSSINGS
        n0 = metres(radial_flat[c0])
        e0 = abs(n0 - d)
        for h in range(1, MAX_CROSSINGS):
            t = metres(radial_flat[c0 + h])
            if abs(t - d) < e0:
                n0 = t
                e0 = abs(t - d)
        if not interpolate:
            return n0
        c1 = r1 + c * MAX_CROSSINGS
        n1 = metres(radial_flat[c1])
        e1 = abs(n1 - d)
        for h in range(1, MAX_CROSSINGS):
            t = metres(radial_flat[c1 + h])
            if abs(t - d) < e1:
                n1 = t
                e1 = abs(t - d)
        if abs(n0 - n1) < tol:
            return b32 * n0 + a32 * n1
        return n1 if upper else n0
    t0 = metres(q.spiral[r0 + c])
    if not interpolate:
        return t0
    t1 = metres(q.spiral[r1 + c])
    if abs(t0 - t1) < tol:
        return b32 * t0 + a32 * t1
    return t1 if upper else t0


@njit(cache=True, nogil=True, inline="always")
def observation_prediction(q, obs, o, c, m0, br):
    """The crossing distance (m) predicted for observation ``o`` of ``obs`` at flat cell
    ``c`` and table heading m0 (``line_offsets``, ``line_prediction``)."""
    fam = obs.family[o]
    r0, r1 = line_offsets(fam, obs.angle_index[o], m0, q.n_angles, q.ncell)
    return line_prediction(q, fam, r0, r1, obs.dist[o], c, br)


@njit(cache=True, nogil=True)
def exact_error_cells(q, obs, at, cells, out):
    """out[c] = sum_i weight[i] * rho(e_i) at flat cell cells[c] (e_i = |d_i - the
    prediction|, ``line_prediction``; an observation's table lines found once for all the
    cells)."""
    br = bracket(at)
    c2 = q.c2
    out[:] = 0.0
    for o in range(obs.dist.shape[0]):
        w, d, fam = obs.weight[o], obs.dist[o], obs.family[o]
        r0, r1 = line_offsets(fam, obs.angle_index[o], at[1], q.n_angles, q.ncell)
        for ci in range(cells.shape[0]):
            e = abs(line_prediction(q, fam, r0, r1, d, cells[ci], br) - d)
            e2 = e * e
            out[ci] += w * (e2 / (c2 + e2))


@njit(cache=True, nogil=True)
def observation_errors_cell(q, obs, at, cell, out):
    """out[i] = error (m) of observation i at flat cell ``cell``: |d_i - the prediction|."""
    br = bracket(at)
    for o in range(obs.dist.shape[0]):
        out[o] = abs(observation_prediction(q, obs, o, cell, at[1], br) - obs.dist[o])


@njit(cache=True, nogil=True)
def observation_predictions_cell(q, obs, at, cell, out):
    """out[i] = predicted crossing distance (m) of observation i at flat cell ``cell``."""
    br = bracket(at)
    for o in range(obs.dist.shape[0]):
        out[o] = observation_prediction(q, obs, o, cell, at[1], br)


@njit(cache=True, nogil=True)
def refine_moves(q, obs, at, grid, i, j, max_moves, out):
    """The cell search of ``lut_local.refine``: the exact error (``exact_error_cells``) on
    the 3 x 3 cells around (i, j) (clipped to the grid, row-major, into ``out`` (9,)), moving
    to the lowest while it is not the centre, at most ``max_moves`` times; after a move only
    the cells new to the patch are evaluated. Returns the final cell as the flat index
    i * nx + j; ``out`` holds the last patch."""
    ny, nx = grid[0], grid[1]
    cells = np.empty(9, dtype=np.int64)
    for di in range(3):
        ii = min(max(i - 1 + di, 0), ny - 1)
        for dj in range(3):
            jj = min(max(j - 1 + dj, 0), nx - 1)
            cells[3 * di + dj] = ii * nx + jj
    exact_error_cells(q, obs, at, cells, out)
    new_cells = np.empty(9, dtype=np.int64)
    new_out = np.empty(9)
    todo = np.empty(9, dtype=np.int64)
    vals = np.empty(9)
    for _ in range(max_moves):
        b = np.argmin(out)
        if b == 4:
            break
        mi, mj = b // 3 - 1, b % 3 - 1
        ni = min(max(i + mi, 0), ny - 1)
        nj = min(max(j + mj, 0), nx - 1)
        if ni == i and nj == j:  # the lowest is a clipped copy of the centre: at the edge
            break
        n_todo = 0
        for di in range(3):
            ii = min(max(ni - 1 + di, 0), ny - 1)
            for dj in range(3):
                jj = min(max(nj - 1 + dj, 0), nx - 1)
                c = ii * nx + jj
                new_cells[3 * di + dj] = c
                found = -1
                for k in range(9):
                    if cells[k] == c:
                        found = k
                        break
                if found >= 0:
                    new_out[3 * di + dj] = out[found]
                else:
                    todo[n_todo] = 3 * di + dj
                    n_todo += 1
        if n_todo:
            sub = np.empty(n_todo, dtype=np.int64)
            for k in range(n_todo):
                sub[k] = new_cells[todo[k]]
            exact_error_cells(q, obs, at, sub, vals[:n_todo])
            for k in range(n_todo):
                new_out[todo[k]] = vals[k]
        cells[:] = new_cells
        out[:] = new_out
        i, j = ni, nj
    return i * nx + j


@njit(cache=True, nogil=True, inline="always")
def lookup_row(p, fam, ai, b, m):
    """The min-pooled lookup's row of an observation (family ``fam``, scan line ``ai``,
    distance bin ``b``) at table heading m in the layout of ``p`` (MinPooled):
    LutTables.lookup_rows(..., coarse=True) for one observation."""
    k = (ai + m) % p.n_angles
    if fam == 0:
        return k * p.rows_radial + min(b, p.nb_radial - 1) // p.bin_pool
    return (p.spiral_row0 + ((fam - 1) * p.n_angles + k) * p.rows_spiral
            + min(b, p.nb_spiral - 1) // p.bin_pool)


@njit(cache=True, nogil=True)
def tiled_sum(p, rows, m, win, out):
    """out[i - i0, j - j0] = sum over the observations (``rows``: their family, scan line and
    distance bin) of their min-pooled lookup rows' cell (i, j) (uint16), the min-pooled
    surface at table heading m on the coarse window ``win`` [i0, i1) x [j0, j1). The lookup
    (``p``: MinPooled) is tiled: each row holds the cells in TILE x TILE blocks, ``p.ntx``
    blocks per block row, block-row-major, a block's cells row-major. The blocks that cover
    the window are summed whole, one contiguous stretch per block row and observation (a few
    cache lines, where rows of cells cost one per row of the window), and the window is
    taken from them once."""
    i0, i1, j0, j1 = win
    lookup, ntx = p.lookup, p.ntx
    t = TILE
    tt = TILE * TILE
    ti0, ti1 = i0 // t, (i1 - 1) // t + 1
    tj0, tj1 = j0 // t, (j1 - 1) // t + 1
    span = (tj1 - tj0) * tt
    acc = np.zeros((ti1 - ti0) * span, dtype=np.uint16)
    for o in range(rows.family.shape[0]):
        row = lookup[lookup_row(p, rows.family[o], rows.angle_index[o], rows.bins[o], m)]
        for a in range(ti1 - ti0):
            src = row[((ti0 + a) * ntx + tj0) * tt:((ti0 + a) * ntx + tj0) * tt + span]
            dst = acc[a * span:(a + 1) * span]
            for q in range(span):
                dst[q] += src[q]
    col = np.empty(j1 - j0, dtype=np.int64)  # the window out of the blocks
    for j in range(j0, j1):
        col[j - j0] = (j // t - tj0) * tt + j % t
    for i in range(i0, i1):
        src = acc[(i // t - ti0) * span + (i % t) * t:]
        dst = out[i - i0]
        for j in range(j1 - j0):
            dst[j] = src[col[j]]


@njit(cache=True, nogil=True)
def prepare(q, rows, m):
    """Per observation (``rows``: Observed) at table heading m, (3, n): its family,
    where its table line starts (``line_offsets``) and where its distance bin's quantised
    errors start in ``q.values`` (the last bin for farther distances, as ``lookup_row``)."""
    n = rows.family.shape[0]
    out = np.empty((3, n), np.int64)
    for o in range(n):
        f = rows.family[o]
        out[0, o] = f
        out[1, o] = line_offsets(f, rows.angle_index[o], m, q.n_angles, q.ncell)[0]
        b = rows.bins[o]
        if f == 0:
            out[2, o] = min(b, q.nb_radial - 1) * q.width
        else:
            out[2, o] = (q.nb_radial + min(b, q.nb_spiral - 1)) * q.width
    return out


@njit(cache=True, nogil=True)
def cells_sum(q, prep, cells, n, out):
    """out[t] = the quantised error surface at table heading m at flat cell cells[t], t < n
    (``prep``: ``prepare``): the sum over the observations of their lookup entries, each the
    least quantised error (``Quantised``) of its table line's crossings at the cell.
    Observation by observation: each reads its line's stretch of those cells and its
    bin's errors, where a cell at a time would read as many lines as there are
    observations."""
    values, radial, spiral = q.values, q.radial, q.spiral
    out[:n] = 0
    for o in range(prep.shape[1]):
        # unsigned offsets: an index that cannot be negative is not checked for wrapping
        r0, vbase = np.uint64(prep[1, o]), np.uint64(prep[2, o])
        if prep[0, o] == 0:
            for t in range(n):
                b = r0 + np.uint64(cells[t]) * U4
                out[t] += min(min(values[vbase + radial[b]], values[vbase + radial[b + U1]]),
                              min(values[vbase + radial[b + U2]], values[vbase + radial[b + U3]]))
        else:
            for t in range(n):
                out[t] += values[vbase + spiral[r0 + np.uint64(cells[t])]]


@njit(cache=True, nogil=True)
def window_sum(q, rows, m, i0, i1, j0, j1, nx, out):
    """out[i - i0, j - j0] = the quantised error surface at table heading m on the window
    [i0, i1) x [j0, j1) of a grid nx cells wide (uint16): the sum over the observations
    (``rows``: Observed) of their lookup entries (``cells_sum``)."""
    w = j1 - j0
    cells = np.empty((i1 - i0) * w, dtype=np.int64)
    for i in range(i0, i1):
        for j in range(j0, j1):
            cells[(i - i0) * w + j - j0] = i * nx + j
    sums = np.empty(cells.shape[0], dtype=np.int64)
    cells_sum(q, prepare(q, rows, m), cells, cells.shape[0], sums)
    for t in range(cells.shape[0]):
        out[t // w, t % w] = sums[t]


@njit(cache=True, nogil=True)
def weighted_cells(q, rows, m, scale, out):
    """out[c] = the sum over the observations of their lookup entry at flat cell c times the
    observation's ``scale`` (float32), for every cell (``out`` (ncell,) float32): the whole
    field's quantised error surface with each observation's lookup weight scaled (to its
    evidence weight: Observation.with_evidence), in the lookup's units."""
    prep = prepare(q, rows, m)
    values, radial, spiral = q.values, q.radial, q.spiral
    out[:] = 0.0
    for o in range(prep.shape[1]):
        f = scale[o]
        if f <= 0.0:
            continue
        r0, vbase = np.uint64(prep[1, o]), np.uint64(prep[2, o])  # unsigned (cells_sum)
        if prep[0, o] == 0:
            for c in range(q.ncell):
                b = r0 + np.uint64(c) * U4
                out[c] += f * min(min(values[vbase + radial[b]], values[vbase + radial[b + U1]]),
                                  min(values[vbase + radial[b + U2]],
                                      values[vbase + radial[b + U3]]))
        else:
            for c in range(q.ncell):
                out[c] += f * values[vbase + spiral[r0 + np.uint64(c)]]


@njit(cache=True, nogil=True, inline="always")
def coarse_cell(p, i, n):
    """The coarse row (column) whose min-pooled entries bound fine row (column) i, or -1 past
    the last one (``n``: the coarse rows p.cy or columns p.cx; those fine cells lie within
    step // 2 of no coarse cell)."""
    a = (i + p.step // 2) // p.step
    return a if a < n else -1


@njit(cache=True, nogil=True)
def counting_order(keys, top):
    """The indices of ``keys`` (integers in [0, top]) by key, equal keys by index."""
    count = np.zeros(top + 2, dtype=np.int64)
    for t in range(keys.shape[0]):
        count[keys[t] + 1] += 1
    for v in range(1, top + 2):
        count[v] += count[v - 1]
    out = np.empty(keys.shape[0], dtype=np.int64)
    for t in range(keys.shape[0]):
        out[count[keys[t]]] = t
        count[keys[t]] += 1
    return out


@njit(cache=True, nogil=True)
def separated_minima(q, p, rows, m, grid, k, r, out):
    """The flat cells of up to ``k`` lowest cells of the whole field's quantised surface at
    table heading m, each more than ``r`` cells (in x or y) from the ones before: the picks
    of the greedy non-maximum suppression (lowest value, then lowest index) on the whole
    surface, into ``out`` (k,); returns how many. Branch and bound: the min-pooled surface
    (``p``) bounds every fine cell it covers from below (the cells past its last row or column
    by 0); coarse cells are opened in the order of their bound, a growing batch at a time
    (their fine cells computed together, ``cells_sum``), and a computed cell is passed to the
    greedy once its value lies below the bound of every coarse cell not opened: no cell left
    out can come before it, so the greedy sees the cells in the order of the whole surface
    and stops at the same k picks."""
    ny, nx = grid[0], grid[1]
    cy, cx, step, half = p.cy, p.cx, p.step, p.step // 2
    coarse = np.empty((cy, cx), dtype=np.uint16)
    tiled_sum(p, rows, m, (0, cy, 0, cx), coarse)
    flat = coarse.ravel()
    ncoarse = cy * cx
    order = counting_order(flat, TOP)
    prep = prepare(q, rows, m)
    ncell = ny * nx
    cells = np.empty(ncell, dtype=np.int64)
    sums = np.empty(ncell, dtype=np.int64)
    pending = np.empty(ncell, dtype=np.int64)  # computed, not yet passed: value * ncell + cell
    taken = np.empty(ncell, dtype=np.int64)
    n = 0
    i_edge, j_edge = cy * step - half, cx * step - half  # first fine row, column not covered
    for i in range(ny):
        for j in range(j_edge if i < i_edge else 0, nx):
            cells[n] = i * nx + j
            n += 1
    opened = 0
    n_pending = 0
    n_picks = 0
    while True:
        cells_sum(q, prep, cells, n, sums)
        for t in range(n):
            pending[n_pending] = sums[t] * ncell + cells[t]
            n_pending += 1
        # the computed cells below every bound not opened, in order, to the greedy
        limit = np.int64(flat[order[opened]]) * ncell if opened < ncoarse else TOP * ncell
        n_taken = 0
        kept = 0
        for t in range(n_pending):
            if pending[t] < limit:
                taken[n_taken] = pending[t]
                n_taken += 1
            else:
                pending[kept] = pending[t]
                kept += 1
        n_pending = kept
        passed = np.sort(taken[:n_taken])
        for t in range(n_taken):
            c = passed[t] % ncell
            ci, cj = c // nx, c % nx
            free = True
            for s in range(n_picks):
                if abs(out[s] // nx - ci) <= r and abs(out[s] % nx - cj) <= r:
                    free = False
                    break
            if free:
                out[n_picks] = c
                n_picks += 1
                if n_picks == k:
                    return n_picks
        if opened == ncoarse:
            return n_picks
        # open the next coarse cells: a third as many as are open, at least 8
        n = 0
        for _ in range(min(ncoarse - opened, max(8, opened // 3))):
            a, b = order[opened] // cx, order[opened] % cx
            opened += 1
            for i in range(max(a * step - half, 0), min(a * step - half + step, ny)):
                for j in range(max(b * step - half, 0), min(b * step - half + step, nx)):
                    cells[n] = i * nx + j
                    n += 1


@njit(cache=True, nogil=True)
def tracked_window(q, p, rows, m, win, grid, post):
    """On the window ``win`` (i0, i1, j0, j1) of ``grid``: the flat index of the cell
    minimising its quantised error surface (``cells_sum``) ranked by ``post`` (Posterior:
    surface * scale + the prior's capped Mahalanobis term; the first in row-major order of
    equal ones), and that cell's score. Branch and bound: a cell's score is bounded below by
    the min-pooled surface's (``p``; 0 past its last row or column) in place of its own. The
    cells of the coarse cell holding the least bound are computed first; then, together,
    every other cell whose bound is not above the best score they found: no cell left out
    can score lower or as low."""
    i0, i1, j0, j1 = win
    _ny, nx, x0, y0, res = grid
    scale, px, py, ia, ib, ic, cap = post
    step, half = p.step, p.step // 2
    h, w = i1 - i0, j1 - j0
    row = np.empty(h, dtype=np.int64)  # coarse row of each window row (-1: past the last)
    col = np.empty(w, dtype=np.int64)
    for i in range(h):
        row[i] = coarse_cell(p, i0 + i, p.cy)
    for j in range(w):
        col[j] = coarse_cell(p, j0 + j, p.cx)
    c0, d0 = (i0 + half) // step, (j0 + half) // step
    c1 = max(min((i1 - 1 + half) // step + 1, p.cy), c0)
    d1 = max(min((j1 - 1 + half) // step + 1, p.cx), d0)
    sums = np.zeros((c1 - c0 + 1, d1 - d0 + 1), dtype=np.uint16)  # last row, column: 0
    if c1 > c0 and d1 > d0:
        tiled_sum(p, rows, m, (c0, c1, d0, d1), sums[:c1 - c0, :d1 - d0])
    for i in range(h):
        row[i] = row[i] - c0 if row[i] >= 0 else c1 - c0
    for j in range(w):
        col[j] = col[j] - d0 if col[j] >= 0 else d1 - d0
    lower = np.empty(h * w)
    prior = np.empty(h * w)
    start = 0
    for i in range(h):
        dy = y0 + (i0 + i) * res - py
        for j in range(w):
            dx = x0 + (j0 + j) * res - px
            q2 = 0.5 * (ia * dx * dx + 2.0 * ib * dx * dy + ic * dy * dy)
            t = i * w + j
            prior[t] = min(q2, cap)
            a = row[i]
            v = int(sums[a, col[j]]) if a < c1 - c0 and col[j] < d1 - d0 else 0
            lower[t] = v * scale + prior[t]
            if lower[t] < lower[start]:
                start = t
    prep = prepare(q, rows, m)
    todo = np.empty(h * w, dtype=np.int64)
    cells = np.empty(h * w, dtype=np.int64)
    values = np.empty(h * w, dtype=np.int64)
    best = 0
    best_score = np.inf
    a, b = row[start // w], col[start % w]
    for second in (False, True):
        n = 0
        for t in range(h * w):
            same = row[t // w] == a and col[t % w] == b
            if (same != second) and lower[t] <= best_score:
                todo[n] = t
                cells[n] = (i0 + t // w) * nx + j0 + t % w
                n += 1
        cells_sum(q, prep, cells, n, values)
        for x in range(n):
            t = todo[x]
            score = values[x] * scale + prior[t]
            if score < best_score or (score == best_score and t < best):
                best_score = score
                best = t
    return (i0 + best // w) * nx + j0 + best % w, best_score


@njit(cache=True, nogil=True)
def refine_cell(q, obs, at, grid, i, j, max_moves, total_weight, out):
    """``lut_local.refine`` from cell (i, j): at most ``max_moves`` cell moves
    (``refine_moves``), then the quadratic fit of the last 3 x 3 patch, into ``out`` (9,): x,
    y, error, error_norm, cell i, cell j, and the Hessian of error_norm hxx, hxy, hyy
    (m^-2)."""
    _ny, nx, x0, y0, res = grid
    e = np.empty(9)
    flat = refine_moves(q, obs, at, grid, i, j, max_moves, e)
    fi, fj = flat // nx, flat % nx
    for k in range(9):
        e[k] /= total_weight
    dx, dy, fmin, hxx, hxy, hyy = quadratic_fit(e)
    e_norm = min(max(fmin, 0.0), e[4])
    r2 = res * res
    out[0] = (x0 + fj * res) + dx * res
    out[1] = (y0 + fi * res) + dy * res
    out[2] = e_norm * total_weight
    out[3] = e_norm
    out[4] = fi
    out[5] = fj
    out[6] = hxx / r2
    out[7] = hxy / r2
    out[8] = hyy / r2


@njit(cache=True, nogil=True)
def tracked_fix(q, p, obs, at, win, grid, post, rule, fit, out):
    """A track's fix in one call (``lut_tracked.tracked_fix``): the window's best cell by
    the posterior score (``tracked_window`` at table heading m), refined to sub-cell in its
    basin (``refine_cell`` at the heading m0 / a); when that lies more than two cells from
    the prior (px, py), the basin the prior lies in refined too and kept when its exact
    score error / ``temperature`` + the prior's capped term is lower;
    then the fix's support (``observation_errors_cell`` at the cell nearest it,
    ``inlier_sums`` with the float64 weights and ``rule``'s inlier error); with
    ``fit.enabled``, the fix at heading ``fit.theta`` moved by the line points' fit
    (``point_fit.fit_refine``, the heading kept, within fit.max_shift / fit.max_turn).
    ``out`` (19,): the refined fix (``refine_cell``'s 9 values), at window edge (0 / 1), the
    window's best posterior score, the prior's basin taken (0 / 1), the support's inliers,
    inlier weight, weighted rho, weighted squared error, then the fitted pose (x, y, theta;
    NaN without the fit)."""
    i0, i1, j0, j1 = win
    ny, nx, x0, y0, res = grid
    _scale, px, py = post[:3]
    total_weight, temperature, inlier_error, c2 = rule
    best, window_fit = tracked_window(q, p, obs, at[0], win, grid, post)
    i, j = best // nx, best % nx
    edge = ((i == i0 and i0 > 0) or (i == i1 - 1 and i1 < ny)
            or (j == j0 and j0 > 0) or (j == j1 - 1 and j1 < nx))
    refine_cell(q, obs, at, grid, i, j, 4, total_weight, out[:9])
    out[9] = 1.0 if edge else 0.0
    out[10] = window_fit
    out[11] = 0.0
    if math.hypot(out[0] - px, out[1] - py) > 2 * res:
        # the window's choice rests on the quantised error term; the prior's basin may fit
        # better by the exact one
        own = np.empty(9)
        ci = min(max(int(np.rint((py - y0) / res)), 0), ny - 1)
        cj = min(max(int(np.rint((px - x0) / res)), 0), nx - 1)
        refine_cell(q, obs, at, grid, ci, cj, 4, total_weight, own)
        if _posterior_score(own, temperature, post) < _posterior_score(out, temperature, post):
            out[:9] = own
            out[9] = 0.0
            out[11] = 1.0
    # the support at the cell nearest the fix (LutTables.support)
    ci = min(max(int(np.rint((out[1] - y0) / res)), 0), ny - 1)
    cj = min(max(int(np.rint((out[0] - x0) / res)), 0), nx - 1)
    errors = np.empty(obs.dist.shape[0])
    observation_errors_cell(q, obs, at, ci * nx + cj, errors)
    n_in, w_in, rho, sq = inlier_sums(errors, obs.weight64, inlier_error, c2)
    out[12] = n_in
    out[13] = w_in
    out[14] = rho
    out[15] = sq
    out[16:19] = np.nan
    if fit.enabled:
        normal = np.empty((3, 3))
        fit_refine(fit.table, (fit.x0, fit.y0, fit.res), fit.points, obs.weight64,
                   (out[0], out[1], fit.theta), fit.c2, (8, True, fit.max_shift, fit.max_turn),
                   out[16:19], normal)


@njit(cache=True, nogil=True, inline="always")
def _posterior_score(fix, temperature, post):
    """error / temperature + min(0.5 d^T info d, cap) of a refined fix (``refine_cell``'s
    layout), d its offset from the prior (TrackBank.prior_term)."""
    _scale, px, py, ia, ib, ic, cap = post
    dx, dy = fix[0] - px, fix[1] - py
    q = (dx * ia + dy * ib) * dx + (dx * ib + dy * ic) * dy
    return fix[2] / temperature + min(0.5 * q, cap)


@njit(cache=True, nogil=True)
def tracked_window_bound(p, rows, m, win, grid, post):
    """A lower bound of ``tracked_window``'s best score on the window ``win`` (i0, i1, j0,
    j1), from the min-pooled error lookup ``p`` (every ``step``-th cell, cy x cx; each the
    minimum over the fine cells within step // 2 of it): fine cell (i, j) lies in coarse
    cell ((i + step // 2) // step, (j + step // 2) // step), whose sum over the observations
    is at most the fine cell's, so surface * scale + the capped Mahalanobis term of each fine
    cell is bounded from below (a fine cell past the last coarse row or column, which no
    coarse cell covers, by 0); the least such bound over the window. About step^2 times
    fewer lookups than the window itself."""
    i0, i1, j0, j1 = win
    _ny, _nx, x0, y0, res = grid
    scale, px, py, ia, ib, ic, cap = post
    step, cy, cx = p.step, p.cy, p.cx
    r = step // 2
    c0, d0 = (i0 + r) // step, (j0 + r) // step
    c1 = max(min((i1 - 1 + r) // step + 1, cy), c0)
    d1 = max(min((j1 - 1 + r) // step + 1, cx), d0)
    sums = np.zeros((c1 - c0 + 1, d1 - d0 + 1), dtype=np.uint16)  # last row, column: 0
    if c1 > c0 and d1 > d0:
        tiled_sum(p, rows, m, (c0, c1, d0, d1), sums[:c1 - c0, :d1 - d0])
    best = np.inf
    for i in range(i0, i1):
        dy = y0 + i * res - py
        a = coarse_cell(p, i, cy)  # past the last coarse row no entry bounds it: 0
        a = a - c0 if a >= 0 else c1 - c0
        for j in range(j0, j1):
            dx = x0 + j * res - px
            q = 0.5 * (ia * dx * dx + 2.0 * ib * dx * dy + ic * dy * dy)
            b = coarse_cell(p, j, cx)
            b = b - d0 if b >= 0 else d1 - d0
            score = int(sums[a, b]) * scale + min(q, cap)
            if score < best:
                best = score
    return best


@njit(cache=True, nogil=True)
def quadratic_fit(e):
    """Sub-cell minimum of a 3 x 3 error patch ``e`` (9,, rows y, columns x) by the
    least-squares quadratic (``QPINV``): (dx, dy, value, hxx, hxy, hyy) in cell units. Falls
    back to per-axis parabolas where the fit is not a bowl; offsets are clipped to one
    cell."""
    coef = np.zeros(6)
    for r in range(6):
        acc = 0.0
        for k in range(9):
            acc += QPINV[r, k] * e[k]
        coef[r] = acc
    a, bx, by, dxx, dxy, dyy = coef[0], coef[1], coef[2], coef[3], coef[4], coef[5]
    hxx, hyy = 2 * dxx, 2 * dyy
    det = hxx * hyy - dxy * dxy
    if det > 1e-12 and hxx > 0:
        ox = -(hyy * bx - dxy * by) / det
        oy = -(hxx * by - dxy * bx) / det
    else:
        den = e[3] - 2 * e[4] + e[5]
        ox = 0.5 * (e[3] - e[5]) / den if den > 1e-12 else 0.0
        den = e[1] - 2 * e[4] + e[7]
        oy = 0.5 * (e[1] - e[7]) / den if den > 1e-12 else 0.0
    ox = min(max(ox, -1.0), 1.0)
    oy = min(max(oy, -1.0), 1.0)
    val = a + bx * ox + by * oy + dxx * ox * ox + dxy * ox * oy + dyy * oy * oy
    return ox, oy, val, hxx, dxy, hyy


@njit(cache=True, nogil=True)
def structure_sizes(points, distance, link, link_per_m):
    """Per point, the number of points in its structure: points chained by gaps shorter than
    link + link_per_m * max(distance of the two) (union-find over the pairs found on a grid
    of cells as wide as the longest link)."""
    n = points.shape[0]
    out = np.ones(n)
    if n == 0:
        return out
    far = 0.0
    for i in range(n):
        far = max(far, distance[i])
    cell = link + link_per_m * far
    x0 = points[0, 0]
    y0 = points[0, 1]
    for i in range(n):
        x0 = min(x0, points[i, 0])
        y0 = min(y0, points[i, 1])
    cx = np.empty(n, np.int64)
    cy = np.empty(n, np.int64)
    for i in range(n):
        cx[i] = int((points[i, 0] - x0) / cell)
        cy[i] = int((points[i, 1] - y0) / cell)
    order = np.argsort(cx * 100003 + cy)
    parent = np.arange(n)
    for a in range(n):
        i = order[a]
        for b in range(a + 1, n):
            j = order[b]
            if cx[j] > cx[i] + 1:
                break
            if abs(cy[j] - cy[i]) > 1:
                continue
            dx = points[i, 0] - points[j, 0]
            dy = points[i, 1] - points[j, 1]
            reach = link + link_per_m * max(distance[i], distance[j])
            if dx * dx + dy * dy < reach * reach:
                ri = i  # the roots, halving the paths on the way (the same structures)
                while parent[ri] != ri:
                    parent[ri] = parent[parent[ri]]
                    ri = parent[ri]
                rj = j
                while parent[rj] != rj:
                    parent[rj] = parent[parent[rj]]
                    rj = parent[rj]
                if ri != rj:
                    parent[ri] = rj
    count = np.zeros(n)
    root = np.empty(n, np.int64)
    for i in range(n):
        r = i
        while parent[r] != r:
            r = parent[r]
        root[i] = r
        count[r] += 1.0
    for i in range(n):
        out[i] = count[root[i]]
    return out




@njit(cache=True, nogil=True)
def evidence_weights(points, distance, base, link, link_per_m, per_structure):
    """The evidence weights of a frame's observations (``Observation.with_evidence``): the
    ``base`` weight times min(1, ``per_structure`` / the size of the point's structure
    (``structure_sizes``))."""
    size = structure_sizes(points, distance, link, link_per_m)
    out = np.empty(base.shape[0])
    for i in range(base.shape[0]):
        out[i] = base[i] * min(1.0, per_structure / size[i])
    return out


@njit(cache=True, nogil=True)
def flatten_scanlines(radial, spiral, use_spiral, robot_radius, max_range, spiral_end_radius,
                      range_scale):
    """(family, angle_index, distance, weight) of a frame's radial (n, 4) and spiral (2, n)
    crossing distances (NaN = none), radial first (line-major), then the spirals, those
    outside the scan lines' reach left out (``Observation.from_scanlines``); the weights
    MatchingParams.weight's, 1 / (1 + (d / ``range_scale``)^2), in the same arithmetic."""
    n = radial.shape[0] * radial.shape[1] + (spiral.size if use_spiral else 0)
    fam = np.empty(n, np.int64)
    idx = np.empty(n, np.int64)
    dist = np.empty(n, np.float64)
    k = 0
    for a in range(radial.shape[0]):
        for slot in range(radial.shape[1]):
            d = radial[a, slot]
            if d == d and d >= robot_radius and d <= max_range:
                fam[k] = 0
                idx[k] = a
                dist[k] = d
                k += 1
    if use_spiral:
        for f in range(spiral.shape[0]):
            for a in range(spiral.shape[1]):
                d = spiral[f, a]
                if d == d and d >= robot_radius and d <= spiral_end_radius:
                    fam[k] = 1 + f
                    idx[k] = a
                    dist[k] = d
                    k += 1
    w = np.empty(k, np.float64)
    for i in range(k):
        q = dist[i] / range_scale
        w[i] = 1.0 / (1.0 + q * q)
    return fam[:k].copy(), idx[:k].copy(), dist[:k].copy(), w


@njit(cache=True, nogil=True)
def observation_points(family, angle_index, distance, angle_step, robot_radius,
                       spiral_end_radius):
    """Observations as points (N, 2) in the robot frame: radial crossings at their line's
    angle, spiral crossings at the spiral's angle at that radius (``Observation.points``)."""
    n = distance.shape[0]
    out = np.empty((n, 2))
    turn = 2 * np.pi / (spiral_end_radius - robot_radius)
    for i in range(n):
        a = angle_index[i] * angle_step
        d = distance[i]
        if family[i] == 1:
            a += (d - robot_radius) * turn
        elif family[i] == 2:
            a -= (d - robot_radius) * turn
        out[i, 0] = d * np.cos(a)
        out[i, 1] = d * np.sin(a)
    return out


@njit(cache=True, nogil=True)
def inlier_sums(errors, weight, inlier_error, c2):
    """(inliers, their weight, their weighted rho, their weighted squared error) of
    observations with ``errors`` (m)."""
    n = 0.0
    w_in = 0.0
    rho = 0.0
    sq = 0.0
    for i in range(errors.shape[0]):
        e = errors[i]
        if e < inlier_error:
            n += 1.0
            w_in += weight[i]
            rho += weight[i] * (e * e / (c2 + e * e))
            sq += weight[i] * e * e
    return n, w_in, rho, sq
