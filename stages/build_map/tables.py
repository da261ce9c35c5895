"""The lookup tables of Ribeiro et al. (2015), computed analytically over the world grid.

- radial: where each radial scan line crosses line centre lines (ray-segment and ray-circle
  intersections, closed form, all cells at once per scan line);
- spiral: the first centre-line crossing radius of each spiral scan line. Field lines are
  axis-aligned, so the crossings of one spiral with the line y = c seen from a cell depend only on
  the offset c - y_cell: they are computed once per distinct offset on the spiral polyline and
  shared by every cell of that grid row. Circles and arcs are solved in the cell's polar frame:
  the spiral point at turn phi lies on the circle where cos(a + s phi - gamma) = h(phi), with
  h(phi) = (r(phi)^2 + rho^2 - R^2) / (2 r(phi) rho) independent of the start angle a; crossings
  are bracketed on a 5 deg phi lattice (a cosine lookup per start angle) and refined by Newton
  steps on the exact equation;
- distance: distance from each cell centre to the nearest centre line (the Tribots table), and
  its gradient.
"""

from __future__ import annotations

import math

import numpy as np

from ..common.errors import FieldlocError
from ..common.field import FieldModel, nearest_line_point
from ..common.map_file import Grid
from ..common.scanlines import NO_HIT_MM, ScanLines


def _to_mm(metres: np.ndarray) -> np.ndarray:
    out = np.full(metres.shape, NO_HIT_MM, dtype=np.uint16)
    ok = np.isfinite(metres)
    out[ok] = np.clip(np.rint(metres[ok] * 1000.0), 0, NO_HIT_MM - 1).astype(np.uint16)
    return out


# ---------------------------------------------------------------------------- radial


def _swept_box(grid: Grid, xlo, xhi, ylo, yhi, dx, dy, t_min, t_max):
    """Index ranges (i0, i1, j0, j1) of the cells from which a ray (direction dx, dy) can meet
    something inside the box [xlo, xhi] x [ylo, yhi] at a distance in [t_min, t_max]."""
    ox0 = xlo - max(t_min * dx, t_max * dx)
    ox1 = xhi - min(t_min * dx, t_max * dx)
    oy0 = ylo - max(t_min * dy, t_max * dy)
    oy1 = yhi - min(t_min * dy, t_max * dy)
    res = grid.resolution
    j0 = max(int(math.floor((ox0 - grid.origin[0]) / res)), 0)
    j1 = min(int(math.ceil((ox1 - grid.origin[0]) / res)) + 1, grid.shape[1])
    i0 = max(int(math.floor((oy0 - grid.origin[1]) / res)), 0)
    i1 = min(int(math.ceil((oy1 - grid.origin[1]) / res)) + 1, grid.shape[0])
    return i0, i1, j0, j1


def _ray_hits(fm: FieldModel, grid: Grid, angle: float, t_min: float, t_max: float):
    """All centre-line crossing distances of the ray from every cell (ny, nx, K) float32,
    inf = none. Each line is intersected only from the cells whose ray can reach it."""
    # snapped so that a scan line along a field line is exactly parallel to it whichever way
    # its angle was computed (k * step + heading or (k + m) * step)
    dx, dy = round(math.cos(angle), 12), round(math.sin(angle), 12)
    eps = 1e-9
    xs, ys = grid.xs, grid.ys
    n_cand = len(fm.segments) + 2 * len(fm.arcs)
    hits = np.full(tuple(grid.shape) + (n_cand,), np.inf, dtype=np.float32)
    col = 0
    for (ax, ay), (bx, by) in fm.segments:
        ex, ey = bx - ax, by - ay
        den = dx * ey - dy * ex
        if abs(den) < 1e-12:  # parallel: a ray along a line sees no crossing
            col += 1
            continue
        i0, i1, j0, j1 = _swept_box(grid, min(ax, bx), max(ax, bx), min(ay, by), max(ay, by),
                                    dx, dy, t_min, t_max)
        if i0 < i1 and j0 < j1:
            wx, wy = ax - xs[None, j0:j1], ay - ys[i0:i1, None]
            t = (wx * ey - wy * ex) / den
            u = (wx * dy - wy * dx) / den
            ok = (u >= -eps) & (u <= 1 + eps) & (t >= t_min - eps) & (t <= t_max + eps)
            hits[i0:i1, j0:j1, col] = np.where(ok, t, np.inf)
        col += 1
    for cx, cy, r, a0, sweep in fm.arcs:
        i0, i1, j0, j1 = _swept_box(grid, cx - r, cx + r, cy - r, cy + r, dx, dy, t_min, t_max)
        if i0 < i1 and j0 < j1:
            fx, fy = xs[None, j0:j1] - cx, ys[i0:i1, None] - cy
            b = fx * dx + fy * dy
            c = fx * fx + fy * fy - r * r
            disc = b * b - c
            sq = np.sqrt(np.maximum(disc, 0.0))
            for n, t in enumerate((-b - sq, -b + sq)):
                ok = (disc >= 0) & (t >= t_min - eps) & (t <= t_max + eps)
                if sweep < 2 * math.pi - 1e-12:
                    phi = np.arctan2(fy + t * dy, fx + t * dx)
                    ok &= np.mod(phi - a0 + eps, 2 * math.pi) <= sweep + 2 * eps
                hits[i0:i1, j0:j1, col + n] = np.where(ok, t, np.inf)
        col += 2
    return hits


def merge_crossings(sorted_hits: np.ndarray, merge_distance: float, keep: int) -> np.ndarray:
    """Merge crossings closer than ``merge_distance`` along a scan line into one (the middle of
    the group, as a camera sees one white run), keep the first ``keep``. Input (..., K) sorted
    ascending with inf padding; output (..., keep) with inf padding."""
    shape = sorted_hits.shape[:-1]
    out = np.full(shape + (keep,), np.inf)
    count = np.zeros(shape, dtype=np.int64)
    g_start = np.full(shape, np.inf)
    g_end = np.full(shape, -np.inf)

    def flush(mask):
        m = mask & np.isfinite(g_start) & (count < keep)
        idx = np.nonzero(m)
        out[idx + (count[idx],)] = 0.5 * (g_start[idx] + g_end[idx])
        count[idx] += 1

    for k in range(sorted_hits.shape[-1]):
        h = sorted_hits[..., k]
        with np.errstate(invalid="ignore"):
            new_group = np.isfinite(h) & ~(h - g_end <= merge_distance)
        flush(new_group)
        g_start = np.where(new_group, h, g_start)
        g_end = np.where(np.isfinite(h), h, g_end)
    flush(np.ones(shape, dtype=bool))
    return out


def radial_table(fm: FieldModel, grid: Grid, sl: ScanLines, heading: float = 0.0) -> np.ndarray:
    """(n_angles, max_crossings, ny, nx) uint16 mm for a robot with ``heading`` (the map stores
    heading 0; other headings are index rotations of it)."""
    ny, nx = grid.shape
    out = np.empty((sl.n_angles, sl.max_crossings, ny, nx), dtype=np.uint16)
    for k, angle in enumerate(sl.radial_angles):
        hits = _ray_hits(fm, grid, float(angle) + heading, sl.robot_radius, sl.max_range)
        hits = np.sort(hits, axis=-1)
        count = np.isfinite(hits).sum(axis=-1)
        merged = np.full((ny, nx, sl.max_crossings), np.inf)
        merged[..., 0] = hits[..., 0]
        several = count >= 2  # only these can hold crossings to merge
        if several.any():
            k_eff = int(count.max())
            merged[several] = merge_crossings(hits[several][:, :k_eff], fm.line_width,
                                              sl.max_crossings)
        out[k] = _to_mm(np.moveaxis(merged, -1, 0))
    return out


# ---------------------------------------------------------------------------- spiral


def _polyline_crossings(coord: np.ndarray, along: np.ndarray, radius: np.ndarray,
                        offsets: np.ndarray):
    """Crossings of a polyline with the lines coord == offset, for many offsets.
    Returns (along, radius) arrays (n_offsets, K) with inf padding."""
    s = coord[None, :] - offsets[:, None]
    # a spiral that starts exactly on a line shows no green -> white transition there
    s[:, 0] = np.where(np.abs(s[:, 0]) < 1e-9, s[:, 1], s[:, 0])
    neg = s < 0
    change = neg[:, :-1] != neg[:, 1:]
    oi, m = np.nonzero(change)
    f = s[oi, m] / (s[oi, m] - s[oi, m + 1])
    a = along[m] + f * (along[m + 1] - along[m])
    r = radius[m] + f * (radius[m + 1] - radius[m])
    counts = np.bincount(oi, minlength=len(offsets))
    K = max(int(counts.max()) if len(counts) else 0, 1)
    rank = np.arange(len(oi)) - np.repeat(np.cumsum(counts) - counts, counts)
    A = np.full((len(offsets), K), np.inf)
    R = np.full((len(offsets), K), np.inf)
    A[oi, rank] = a
    R[oi, rank] = r
    return A, R


def _spiral_line_crossings(fm: FieldModel, grid: Grid, sl: ScanLines, table: np.ndarray,
                           heading: float):
    """Minimum first-crossing radius (m) of every spiral with the straight lines, in place into
    ``table`` (2, n, ny, nx) float."""
    xs, ys = grid.xs, grid.ys
    reach = sl.spiral_end_radius + 1e-9
    horizontal, vertical = [], []
    for (ax, ay), (bx, by) in fm.segments:
        if abs(ay - by) < 1e-12:
            horizontal.append((ay, min(ax, bx), max(ax, bx)))
        elif abs(ax - bx) < 1e-12:
            vertical.append((ax, min(ay, by), max(ay, by)))
        else:
            raise FieldlocError(
                "the spiral table supports axis-aligned field lines only; this field has a"
                f" slanted segment from ({ax}, {ay}) to ({bx}, {by})"
            )
    phi = sl.spiral_phi()
    radius = sl.spiral_radius(phi)
    # (axis of the line's constant coordinate, lines, cell coords across, cell coords along)
    families = [(1, horizontal, ys, xs), (0, vertical, xs, ys)]
    for direction in (0, 1):
        for k in range(sl.n_angles):
            pts = sl.spiral_points(direction, k, heading)
            for axis, lines, across, along_cells in families:
                if not lines:
                    continue
                res, first = grid.resolution, along_cells[0]
                # offsets (line coordinate - cell coordinate) that the spiral can reach
                rows, offs = [], []
                for c, _lo, _hi in lines:
                    d = c - across
                    sel = np.nonzero(np.abs(d) <= reach)[0]
                    rows.append(sel)
                    offs.append(d[sel])
                uniq, inverse = np.unique(np.round(np.concatenate(offs), 9), return_inverse=True)
                A, R = _polyline_crossings(pts[:, axis], pts[:, 1 - axis], radius, uniq)
                start = 0
                for (_c, lo, hi), sel in zip(lines, rows):
                    inv = inverse[start : start + len(sel)]
                    start += len(sel)
                    # only cells within the spiral's reach of the segment along it
                    c0 = max(int(math.floor((lo - reach - first) / res)), 0)
                    c1 = min(int(math.ceil((hi + reach - first) / res)) + 1, len(along_cells))
                    a = A[inv][:, None, :] + along_cells[None, c0:c1, None]  # (rows, cells, K)
                    ok = (a >= lo - 1e-9) & (a <= hi + 1e-9)
                    best = np.where(ok, R[inv][:, None, :], np.inf).min(axis=-1)
                    view = table[direction, k]
                    if axis == 1:  # horizontal line: rows of the grid are y
                        view[sel, c0:c1] = np.minimum(view[sel, c0:c1], best)
                    else:
                        view[c0:c1, sel] = np.minimum(view[c0:c1, sel], best.T)


def _spiral_arc_crossings(fm: FieldModel, grid: Grid, sl: ScanLines, table: np.ndarray,
                          heading: float, chunk: int = 256):
    """Minimum first-crossing radius of every spiral with the circles and arcs, in place."""
    n = sl.n_angles
    sub = 2  # phi lattice at half the scan-line angle step
    step = sl.angle_step / sub
    r0, r1 = sl.robot_radius, sl.spiral_end_radius
    kturn = (r1 - r0) / (2 * math.pi)
    m_phi = np.arange(n * sub + 1)
    rphi = r0 + kturn * m_phi * step
    X, Y = np.meshgrid(grid.xs, grid.ys)
    for cx, cy, R, a0, sweep in fm.arcs:
        full = sweep >= 2 * math.pi - 1e-12
        rho_all = np.hypot(X - cx, Y - cy)
        cells_all = np.nonzero((np.abs(rho_all - R) <= r1 + 1e-9) & (rho_all > 1e-9))
        for c0 in range(0, len(cells_all[0]), chunk):
            cells = (cells_all[0][c0 : c0 + chunk], cells_all[1][c0 : c0 + chunk])
            cx_cells, cy_cells = X[cells], Y[cells]
            rho = rho_all[cells]
            # direction cell -> centre, in the frame rotated by the heading
            gamma = np.arctan2(cy - cy_cells, cx - cx_cells) - heading
            h = (rphi[None, :] ** 2 + rho[:, None] ** 2 - R * R) / (
                2 * rphi[None, :] * rho[:, None]
            )
            cg = np.cos(gamma).astype(np.float32)[:, None, None]
            sg = np.sin(gamma).astype(np.float32)[:, None, None]
            h32 = h.astype(np.float32)[:, None, :]
            for direction, s in ((0, 1), (1, -1)):
                # lattice angles a_k + s phi_m; cos(theta - gamma) without a gather
                theta = sl.angle_step * np.arange(n)[:, None] + s * step * m_phi[None, :]
                ct, st = np.cos(theta).astype(np.float32), np.sin(theta).astype(np.float32)
                g = ct[None] * cg + st[None] * sg - h32  # (cells, k, m)
                neg = g < 0
                ci, k, m = np.nonzero(neg[:, :, :-1] != neg[:, :, 1:])
                if len(ci) == 0:
                    continue
                if full:  # the first crossing of each spiral is the one the table keeps
                    _, first = np.unique(ci * n + k, return_index=True)
                    ci, k, m = ci[first], k[first], m[first]
                g0, g1 = g[ci, k, m].astype(float), g[ci, k, m + 1].astype(float)
                f = g0 / (g0 - g1)
                ph = (m + f) * step
                a = k * sl.angle_step
                rh, gm = rho[ci], gamma[ci]
                for _ in range(3):  # Newton on cos(a + s ph - gm) - h(ph), exact spiral
                    rr = r0 + kturn * ph
                    hh = (rr * rr + rh * rh - R * R) / (2 * rr * rh)
                    dh = kturn * (1 / (2 * rh) - (rh * rh - R * R) / (2 * rr * rr * rh))
                    val = np.cos(a + s * ph - gm) - hh
                    der = -s * np.sin(a + s * ph - gm) - dh
                    ok = np.abs(der) > 1e-9
                    upd = np.where(ok, val / np.where(ok, der, 1.0), 0.0)
                    ph = np.clip(ph - upd, m * step, (m + 1) * step)
                rr = r0 + kturn * ph
                if not full:
                    px = cx_cells[ci] + rr * np.cos(heading + a + s * ph)
                    py = cy_cells[ci] + rr * np.sin(heading + a + s * ph)
                    rel = np.mod(np.arctan2(py - cy, px - cx) - a0, 2 * math.pi)
                    on_arc = rel <= sweep + 1e-9
                    ci, k, rr = ci[on_arc], k[on_arc], rr[on_arc]
                    # crossings come in order of phi per spiral: keep the first on the arc
                    _, first = np.unique(ci * n + k, return_index=True)
                    ci, k, rr = ci[first], k[first], rr[first]
                flat = table[direction].reshape(n, -1)
                lin = np.ravel_multi_index((cells[0][ci], cells[1][ci]), grid.shape)
                flat[k, lin] = np.minimum(flat[k, lin], rr)


def spiral_table(fm: FieldModel, grid: Grid, sl: ScanLines, heading: float = 0.0) -> np.ndarray:
    """(2, n_angles, ny, nx) uint16 mm: first centre-line crossing radius per spiral, for a robot
    with ``heading`` (the map stores heading 0)."""
    table = np.full((2, sl.n_angles) + tuple(grid.shape), np.inf)
    _spiral_line_crossings(fm, grid, sl, table, heading)
    _spiral_arc_crossings(fm, grid, sl, table, heading)
    return _to_mm(table)


# ---------------------------------------------------------------------------- distance


def distance_table(fm: FieldModel, grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) from each cell centre to the nearest centre line, (ny, nx) float32, and its
    gradient d/dx, d/dy (2, ny, nx) float32 (zero on a line)."""
    X, Y = np.meshgrid(grid.xs, grid.ys)
    p = np.stack([X, Y], axis=-1)
    near = nearest_line_point(p, fm.segments, fm.arcs)
    v = p - near
    d = np.hypot(v[..., 0], v[..., 1])
    safe = np.where(d > 1e-12, d, 1.0)
    grad = np.where(d[..., None] > 1e-12, v / safe[..., None], 0.0)
    return d.astype(np.float32), np.moveaxis(grad, -1, 0).astype(np.float32)
