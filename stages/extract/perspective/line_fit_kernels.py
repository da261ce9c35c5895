"""The numba kernels of the field lines (``line_fit``): the orthogonal least-squares fit of a
line (``_fit_points``) and the extent of points along it, the split step of split-and-merge
over every component and the merge step's test of similar parts, the perpendicular feet of
floor lines, the lens's distortion of ideal pixels (``distort_point``), and the refinement of
a segment on the full-resolution white mask (``refine_kernel``: profiles across it, their
white runs, a robust fit, and ``grow_kernel`` along it at each end); ``median`` is np.median
compiled. They take plain arrays and numbers (a lens as ``line_fit.lens_parameters``' nine
values) and write into output arrays; ``line_fit`` holds the Python API that builds their
inputs and reads their results, and the crossings' kernels use the fit, the distortion and
the refinement too. Kept apart so that the API reads without the kernels' loops in the way;
nothing here imports ``line_fit``.
"""

from __future__ import annotations

import math

import numpy as np

from ...common.jit import njit


@njit(cache=True, nogil=True)
def _fit_points(p):
    """fit_line on points (n, 2): centroid, direction, normal and rms."""
    n = p.shape[0]
    cx, cy = 0.0, 0.0
    for i in range(n):
        cx += p[i, 0]
        cy += p[i, 1]
    cx /= n
    cy /= n
    sxx, syy, sxy = 0.0, 0.0, 0.0
    for i in range(n):
        dx, dy = p[i, 0] - cx, p[i, 1] - cy
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # major axis of the 2 x 2 scatter
    ux, uy = math.cos(theta), math.sin(theta)
    minor = 0.5 * (sxx + syy) - math.hypot(0.5 * (sxx - syy), sxy)
    return cx, cy, ux, uy, -uy, ux, math.sqrt(max(minor, 0.0) / n)


@njit(cache=True, nogil=True)
def _extent(points, idx, cx, cy, ux, uy, out):
    lo, hi = np.inf, -np.inf
    for i in idx:
        t = (points[i, 0] - cx) * ux + (points[i, 1] - cy) * uy
        lo = min(lo, t)
        hi = max(hi, t)
    out[0, 0], out[0, 1] = cx + lo * ux, cy + lo * uy
    out[1, 0], out[1, 1] = cx + hi * ux, cy + hi * uy


@njit(cache=True, nogil=True)
def _split_ranges(p, max_distance, min_nodes, out):
    """split_component on the ordered points p (n, 2): the parts as runs [a, b) of them into
    ``out`` (n, 2), in order; returns their number."""
    n = p.shape[0]
    stack = np.empty((2 * n + 4, 2), np.int64)
    stack[0, 0], stack[0, 1] = 0, n
    top, m = 1, 0
    while top > 0:
        top -= 1
        a, b = stack[top, 0], stack[top, 1]
        if b - a < min_nodes:
            continue
        cx, cy, ux, uy, nx, ny, rms = _fit_points(p[a:b])
        k, dmax = 0, -1.0
        for i in range(b - a):
            d = abs((p[a + i, 0] - cx) * nx + (p[a + i, 1] - cy) * ny)
            if d > dmax:
                k, dmax = i, d
        if dmax <= max_distance:
            out[m, 0], out[m, 1] = a, b
            m += 1
            continue
        last = b - a - 1
        if k == 0 or k == last:
            # the worst node is an end node: the chord between the ends is the better test
            c0, c1 = p[b - 1, 0] - p[a, 0], p[b - 1, 1] - p[a, 1]
            length = math.hypot(c0, c1)
            if length > 0:
                if b - a > 2:
                    k, dmax = 1, -1.0
                    for i in range(1, last):
                        d = abs(((p[a + i, 0] - p[a, 0]) * -c1 + (p[a + i, 1] - p[a, 1]) * c0)
                                / length)
                        if d > dmax:
                            k, dmax = i, d
                else:
                    k = 0
            if k == 0 or k == last:
                stack[top, 0], stack[top, 1] = (a + 1, b) if k == 0 else (a, b - 1)
                top += 1
                continue
        # the right half below the left one: the left is split first
        stack[top, 0], stack[top, 1] = a + k, b
        stack[top + 1, 0], stack[top + 1, 1] = a, a + k + 1
        top += 2
    return m


@njit(cache=True, nogil=True)
def _split_all(points, flat, start, max_distance, min_nodes, out, out_start):
    """split_components, compiled: per component (``flat[start[c]:start[c + 1]]``) its nodes
    with finite points, split by _split_ranges; the parts' node indices one after another
    into ``out``, part k at ``out[out_start[k]:out_start[k + 1]]``. Returns their number."""
    m, k = 0, 0
    for c in range(len(start) - 1):
        a, b = start[c], start[c + 1]
        idx = np.empty(b - a, np.int64)
        n = 0
        for i in range(a, b):
            j = flat[i]
            if np.isfinite(points[j, 0]) and np.isfinite(points[j, 1]):
                idx[n] = j
                n += 1
        if n < min_nodes:
            continue
        p = np.empty((n, 2))
        for i in range(n):
            p[i, 0], p[i, 1] = points[idx[i], 0], points[idx[i], 1]
        ranges = np.empty((n, 2), np.int64)
        parts = _split_ranges(p, max_distance, min_nodes, ranges)
        for r in range(parts):
            for q in range(ranges[r, 0], ranges[r, 1]):
                out[k] = idx[q]
                k += 1
            m += 1
            out_start[m] = k
    return m


@njit(cache=True, nogil=True)
def _fit_parts(points, flat, start, fits, ends):
    """part_fits, compiled: per part (``flat[start[k]:start[k + 1]]``) _fit_points of its
    points and _extent along the fit."""
    for k in range(len(start) - 1):
        idx = flat[start[k]:start[k + 1]]
        p = np.empty((len(idx), 2))
        for i in range(len(idx)):
            p[i, 0], p[i, 1] = points[idx[i], 0], points[idx[i], 1]
        cx, cy, ux, uy, nx, ny, rms = _fit_points(p)
        fits[k, 0], fits[k, 1], fits[k, 2], fits[k, 3] = cx, cy, ux, uy
        fits[k, 4], fits[k, 5], fits[k, 6] = nx, ny, rms
        _extent(points, idx, cx, cy, ux, uy, ends[k])


@njit(cache=True, nogil=True)
def _similar_kernel(cosine, cen, nor, ends, rows, cos_max, max_offset, upper):
    """_similar_pairs after the directions' cosines: per row part i = rows[a] and part j in
    row-major order, the larger of the ends' distances (max over the two ends of |e . n -
    c . n|, the sums of two products as numpy's einsum and sum form them) and the pairs
    within cos_max and max_offset (not i itself; j > i if ``upper``)."""
    n_rows, n = cosine.shape
    off = np.empty(n_rows * n)
    pi = np.empty(n_rows * n, np.int64)
    pj = np.empty(n_rows * n, np.int64)
    m = 0
    for a in range(n_rows):
        i = rows[a]
        ci = cen[i, 0] * nor[i, 0] + cen[i, 1] * nor[i, 1]
        for j in range(n):
            cj = cen[j, 0] * nor[j, 0] + cen[j, 1] * nor[j, 1]
            to_i = max(abs((ends[j, 0, 0] * nor[i, 0] + ends[j, 0, 1] * nor[i, 1]) - ci),
                       abs((ends[j, 1, 0] * nor[i, 0] + ends[j, 1, 1] * nor[i, 1]) - ci))
            to_j = max(abs((ends[i, 0, 0] * nor[j, 0] + ends[i, 0, 1] * nor[j, 1]) - cj),
                       abs((ends[i, 1, 0] * nor[j, 0] + ends[i, 1, 1] * nor[j, 1]) - cj))
            o = max(to_i, to_j)
            if cosine[a, j] >= cos_max and o <= max_offset and j != i and (i < j or not upper):
                off[m], pi[m], pj[m] = o, i, j
                m += 1
    return off[:m], pi[:m], pj[:m]


@njit(cache=True, nogil=True, error_model="numpy")
def _perpendicular_feet(p0, p1, dist, length, at, along):
    """floor_lines_parameters before the arctan2: per line its length, the distance to the
    foot of the perpendicular from the origin (``t = -(p0 . d) / length^2``) and in ``at``
    the (y, x) whose angle is the line's: the foot's, the line's direction where the line
    runs through the origin (``along``: a quarter turn is added), p0's for a line of no
    length."""
    for k in range(p0.shape[0]):
        dx, dy = p1[k, 0] - p0[k, 0], p1[k, 1] - p0[k, 1]
        length[k] = np.hypot(dx, dy)
        along[k] = False
        if length[k] == 0:
            dist[k] = np.hypot(p0[k, 0], p0[k, 1])
            at[k, 0], at[k, 1] = p0[k, 1], p0[k, 0]
            continue
        t = -(p0[k, 0] * dx + p0[k, 1] * dy) / (length[k] * length[k])
        fx, fy = p0[k, 0] + t * dx, p0[k, 1] + t * dy
        dist[k] = np.hypot(fx, fy)
        if dist[k] < 1e-9:
            at[k, 0], at[k, 1] = dy, dx
            along[k] = True
        else:
            at[k, 0], at[k, 1] = fy, fx


@njit(cache=True, nogil=True, inline="always")
def distort_point(lens, x, y):
    """An ideal pixel (x, y) -> the distorted image pixel (the lens of ``lens_parameters``);
    the compiled one-point form of ``distort_ideal``."""
    return _distort(x, y, lens[0], lens[1], lens[2], lens[3], lens[4], lens[5], lens[6],
                    lens[7], lens[8])


@njit(cache=True, nogil=True, inline="always")
def _distort(x, y, fx, fy, cx, cy, k1, k2, p1, p2, k3):
    """distort_point with the lens's values given one by one (a loop that reads them once
    before it runs on vectors: read from the array inside it, they might change with its
    stores)."""
    nx = (x - cx) / fx
    ny = (y - cy) / fy
    r2 = nx * nx + ny * ny
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = nx * radial + 2 * p1 * nx * ny + p2 * (r2 + 2 * nx * nx)
    yd = ny * radial + p1 * (r2 + 2 * ny * ny) + 2 * p2 * nx * ny
    return xd * fx + cx, yd * fy + cy


@njit(cache=True, nogil=True)
def _distort_all(lens, p, out):
    for i in range(p.shape[0]):
        out[i, 0], out[i, 1] = distort_point(lens, p[i, 0], p[i, 1])


@njit(cache=True, nogil=True, inline="always")
def _bilinear_at(image, x, y):
    """The image bilinearly at (x, y), pixels outside it 0: each of the four pixels read at
    its index clamped to the image and taken where it lies inside (no branch, so that a loop
    of these runs on vectors; adding +0.0 for a pixel outside leaves the sum as skipping it
    would)."""
    h, w = image.shape
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx, fy = x - x0, y - y0
    ix, iy = np.int64(x0), np.int64(y0)
    out = 0.0
    for dy in range(2):
        wy = (1.0 - fy) if dy == 0 else fy
        yi = iy + dy
        in_y = (yi >= 0) and (yi < h)
        yc = min(max(yi, 0), h - 1)
        for dx in range(2):
            wx = (1.0 - fx) if dx == 0 else fx
            xi = ix + dx
            xc = min(max(xi, 0), w - 1)
            v = np.float64(image[yc, xc]) if (in_y and (xi >= 0) and (xi < w)) else 0.0
            out += v * (wx * wy)
    return out


@njit(cache=True, nogil=True)
def _profile_runs(image, lens, ox, oy, ux, uy, along, reach, centre, width, ok):
    """white_profiles + run_centres for one origin/direction: per position along, the centre
    and width of the white run nearest the middle and whether there is one (not touching the
    profile's ends)."""
    nx, ny = -uy, ux
    t = int(round(2 * reach)) + 1  # offsets -reach .. reach, 1 px apart
    mid = t // 2
    prof = np.empty(t)
    xs = np.empty(t)  # the samples' image positions
    ys = np.empty(t)
    fx, fy, cx, cy = lens[0], lens[1], lens[2], lens[3]
    k1, k2, p1, p2, k3 = lens[4], lens[5], lens[6], lens[7], lens[8]
    for s in range(len(along)):
        bx, by = ox + along[s] * ux, oy + along[s] * uy
        # the whole profile, in two passes that run on vectors: the samples' image
        # positions through the lens, then their bilinear values (cheaper than taking only
        # the samples the run search below reads, one by one)
        for k in range(t):
            a = -reach + k
            xs[k], ys[k] = _distort(bx + a * nx, by + a * ny, fx, fy, cx, cy, k1, k2, p1, p2,
                                    k3)
        for k in range(t):
            prof[k] = _bilinear_at(image, xs[k], ys[k])
        best = -1
        for d in range(mid + 1):
            k = mid - d
            if k >= 0 and prof[k] >= 0.5:
                best = k
                break
            k = mid + d
            if k < t and prof[k] >= 0.5:
                best = k
                break
        if best < 0:
            ok[s] = False
            centre[s] = 0.0
            width[s] = 0.0
            continue
        lo, hi = best, best
        while lo > 0 and prof[lo - 1] >= 0.5:
            lo -= 1
        while hi < t - 1 and prof[hi + 1] >= 0.5:
            hi += 1
        mass, wsum = 0.0, 0.0
        for k in range(lo, hi + 1):
            mass += prof[k]
            wsum += prof[k] * (-reach + k)
        centre[s] = wsum / mass if mass > 0 else 0.0
        width[s] = mass
        ok[s] = not (lo == 0 or hi == t - 1)


@njit(cache=True, nogil=True)
def _fit(px, py, keep):
    """fit_line on the kept points: centroid, direction, normal and rms."""
    n = 0
    cx, cy = 0.0, 0.0
    for i in range(len(px)):
        if keep[i]:
            cx += px[i]
            cy += py[i]
            n += 1
    cx /= n
    cy /= n
    sxx, syy, sxy = 0.0, 0.0, 0.0
    for i in range(len(px)):
        if keep[i]:
            dx, dy = px[i] - cx, py[i] - cy
            sxx += dx * dx
            syy += dy * dy
            sxy += dx * dy
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    ux, uy = math.cos(theta), math.sin(theta)
    minor = 0.5 * (sxx + syy) - math.hypot(0.5 * (sxx - syy), sxy)
    rms = math.sqrt(max(minor, 0.0) / n)
    return cx, cy, ux, uy, -uy, ux, rms


@njit(cache=True, nogil=True)
def _robust(px, py, min_residual, max_gap, iterations):
    n = len(px)
    keep = np.zeros(n, np.bool_)
    for i in range(n // 4, n - n // 4):
        keep[i] = True
    if keep.sum() < 2:
        keep[:] = True
    cx, cy, ux, uy, nx, ny, rms = _fit(px, py, keep)
    mid = n // 2
    r = np.empty(n)
    for _ in range(iterations):
        for i in range(n):
            r[i] = (px[i] - cx) * nx + (py[i] - cy) * ny
        core = r[keep]
        med = np.median(core)
        sigma = 1.4826 * np.median(np.abs(core - med))
        tol = max(min_residual, 3.0 * sigma)
        ok = np.abs(r) <= tol
        lo, hi = 0, n
        i = 0
        while i < n:
            if ok[i]:
                i += 1
                continue
            j = i
            while j < n and not ok[j]:
                j += 1
            if j - i > max_gap:
                if j <= mid:
                    lo = max(lo, j)
                elif i > mid:
                    hi = min(hi, i)
            i = j
        new = ok.copy()
        new[:lo] = False
        new[hi:] = False
        if new.sum() < 2:
            break
        same = True
        for i in range(n):
            if new[i] != keep[i]:
                same = False
                break
        if same:
            break
        keep = new
        cx, cy, ux, uy, nx, ny, rms = _fit(px, py, keep)
    return keep, cx, cy, ux, uy, nx, ny, rms


@njit(cache=True, nogil=True)
def grow_kernel(image, lens, ex, ey, dx, dy, step, reach, grow, tol):
    """``grow_along`` compiled: the end (ideal px) reached from (ex, ey) along (dx, dy)."""
    n = 0
    v = step
    while v <= grow + 1e-9:
        n += 1
        v = step * (n + 1)
    if n == 0:
        return ex, ey
    # one profile at a time, so that the walk ends with its second miss in a row
    along = np.empty(1)
    centre = np.empty(1)
    width = np.empty(1)
    ok = np.empty(1, np.bool_)
    last, miss = -1, 0
    for k in range(n):
        along[0] = step * (k + 1)
        _profile_runs(image, lens, ex, ey, dx, dy, along, reach, centre, width, ok)
        if ok[0] and abs(centre[0]) <= tol:
            last, miss = k, 0
        else:
            miss += 1
            if miss >= 2:
                break
    if last < 0:
        return ex, ey
    return ex + step * (last + 1) * dx, ey + step * (last + 1) * dy


@njit(cache=True, nogil=True)
def refine_kernel(ends, image, lens, step, reach, extend, min_points, grow, res):
    """``refine_segment`` compiled: the refined ends and their line fit into ``res`` (res[0] =
    0 when it fails); returns the profiles' white points and widths."""
    res[0] = 0.0
    dx, dy = ends[1, 0] - ends[0, 0], ends[1, 1] - ends[0, 1]
    length = math.hypot(dx, dy)
    empty = np.zeros((0, 2))
    if length < 1e-6:
        return empty, np.zeros(0)
    ux, uy = dx / length, dy / length
    n = 0
    while -extend + n * step < length + extend + 1e-9:
        n += 1
    along = np.empty(n)
    for k in range(n):
        along[k] = -extend + k * step
    centre = np.empty(n)
    width = np.empty(n)
    ok = np.empty(n, np.bool_)
    _profile_runs(image, lens, ends[0, 0], ends[0, 1], ux, uy, along, reach, centre, width, ok)
    m = int(ok.sum())
    if m < min_points:
        return empty, np.zeros(0)
    nx, ny = -uy, ux
    px = np.empty(m)
    py = np.empty(m)
    wd = np.empty(m)
    j = 0
    for k in range(n):
        if ok[k]:
            px[j] = ends[0, 0] + along[k] * ux + centre[k] * nx
            py[j] = ends[0, 1] + along[k] * uy + centre[k] * ny
            wd[j] = width[k]
            j += 1
    keep, cx, cy, fux, fuy, fnx, fny, rms = _robust(px, py, 1.5, 12, 3)
    kk = int(keep.sum())
    if kk < min_points:
        return empty, np.zeros(0)
    pts = np.empty((kk, 2))
    widths = np.empty(kk)
    tmin, tmax = np.inf, -np.inf
    j = 0
    for i in range(m):
        if keep[i]:
            pts[j, 0], pts[j, 1] = px[i], py[i]
            widths[j] = wd[i]
            t = (px[i] - cx) * fux + (py[i] - cy) * fuy
            tmin, tmax = min(tmin, t), max(tmax, t)
            j += 1
    lox, loy = cx + tmin * fux, cy + tmin * fuy
    hix, hiy = cx + tmax * fux, cy + tmax * fuy
    if (hix - lox) * ux + (hiy - loy) * uy < 0:
        lox, loy, hix, hiy = hix, hiy, lox, loy
    if grow > 0:
        r = np.empty(kk)
        for i in range(kk):
            r[i] = (pts[i, 0] - cx) * fnx + (pts[i, 1] - cy) * fny
        med = np.median(r)
        tol = max(1.5, 3.0 * 1.4826 * np.median(np.abs(r - med)))
        sx, sy = hix - lox, hiy - loy
        sl = max(math.hypot(sx, sy), 1e-9)
        sx, sy = sx / sl, sy / sl
        lox, loy = grow_kernel(image, lens, lox, loy, -sx, -sy, step, reach, grow, tol)
        hix, hiy = grow_kernel(image, lens, hix, hiy, sx, sy, step, reach, grow, tol)
    res[0] = 1.0
    res[1], res[2], res[3], res[4] = lox, loy, hix, hiy
    res[5], res[6], res[7], res[8], res[9], res[10] = cx, cy, fux, fuy, fnx, fny
    res[11] = rms
    return pts, widths


@njit(cache=True, nogil=True)
def _refine_all(ends, image, lens, rule, res, pts, widths, start):
    """refine_segments, compiled: refine_kernel of each segment into ``res[k]``, its points
    and widths into ``pts`` and ``widths`` from ``start[k]`` on. ``rule``: refine_kernel's
    (step, reach, extend, min_points, grow), one tuple of scalars as refine_segments makes
    it."""
    step, reach, extend, min_points, grow = rule
    for k in range(ends.shape[0]):
        p, w = refine_kernel(ends[k], image, lens, step, reach, extend, min_points, grow,
                             res[k])
        a = start[k]
        if a + p.shape[0] > pts.shape[0]:
            raise ValueError("refine_segments: more points than profiles")
        for i in range(p.shape[0]):
            pts[a + i, 0], pts[a + i, 1] = p[i, 0], p[i, 1]
            widths[a + i] = w[i]
        start[k + 1] = a + p.shape[0]
