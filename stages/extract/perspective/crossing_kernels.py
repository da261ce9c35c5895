"""The numba kernels of the crossings step (``crossings``): the inner loops of its candidates'
arms and corner angles, the image and floor checks of a crossing's verification, its placement
on the fitted arms, the crossings of pairs of fitted lines, the stem lines and the merging of
arms. They take plain arrays and numbers (a frame's ``crossings.Sight`` and ``crossings.Floor``,
the tuning's numbers indexed by the P_ names below) and return results in output arrays and
codes; ``crossings`` holds the Python API that prepares their inputs and reads their codes.
Kept apart so that the API reads without the kernels' loops in the way; nothing here imports
``crossings``.
"""

from __future__ import annotations

import math

import numpy as np

from ...common.jit import njit
from .line_fit_kernels import _fit_points, distort_point, grow_kernel, refine_kernel
from .line_structure_kernels import bilinear_at

# the numbers of crossings.VerifyFrame.params: the grid's cell (px), the image's size (px),
# whether the fine checks are on and the field region given, a painted line's width ratio,
# the tuning's numbers (crossings.verify_params fills them)
(P_CELL, P_WIDTH, P_HEIGHT, P_FINE, P_USE_FIELD, P_WIDTH_LO, P_WIDTH_HI, P_ARM_STEP,
 P_MIN_ARM_LENGTH, P_ARM_REACH, P_REFINE_STEP, P_REFINE_REACH, P_ARM_GROW, P_ARM_TOLERANCE,
 P_MAX_CELL_SPAN, P_EDGE_MARGIN, P_OBJECT_RADIUS, P_LINE_WIDTH, P_FINE_PX, P_T_GREEN,
 P_T_WHITE, P_RELATIVE, P_ARM_GAP, P_MAX_RADIUS, P_MAX_OTHER, P_MIN_PATH_SHARE,
 P_COUNT) = range(27)
# _image_checks' codes that are no rejection (crossings.IMAGE_REASONS names the others)
IMAGE_VERIFIED, IMAGE_AS_T, IMAGE_FINE = 0, 1, 2

CIRCLE_SAMPLES = 48  # samples on each circle of _circle
_T = np.linspace(0.0, 2 * math.pi, CIRCLE_SAMPLES, endpoint=False)
_RING = np.ascontiguousarray(np.stack([np.cos(_T), np.sin(_T)], axis=1))


@njit(cache=True, nogil=True)
def _points_along(pos, flat, start, reach, out):
    """points_along, compiled: for chain c (nodes ``flat[start[c]:start[c + 1]]``) the arc
    length at each node summed in order (as np.cumsum), the first node at least ``reach``
    along (np.searchsorted's side "left") and the point between it and the node before."""
    for c in range(len(start) - 1):
        a, b = start[c], start[c + 1]
        s_prev, s, total = 0.0, 0.0, 0.0
        k = -1
        for i in range(a + 1, b):
            total = total + np.hypot(pos[flat[i], 0] - pos[flat[i - 1], 0],
                                     pos[flat[i], 1] - pos[flat[i - 1], 1])
            if k < 0:
                s_prev, s = s, total
                if s >= reach:
                    k = i
        last = flat[b - 1]
        if total <= reach:
            out[c, 0], out[c, 1] = pos[last, 0], pos[last, 1]
            continue
        p0, p1 = flat[k - 1], flat[k]
        seg = np.hypot(pos[p1, 0] - pos[p0, 0], pos[p1, 1] - pos[p0, 1])
        t = (reach - s_prev) / max(seg, 1e-9)
        out[c, 0] = pos[p0, 0] + t * (pos[p1, 0] - pos[p0, 0])
        out[c, 1] = pos[p0, 1] + t * (pos[p1, 1] - pos[p0, 1])


@njit(cache=True, nogil=True)
def _angle_at(ax, ay, bx, by):
    """The angle (radians, [0, pi]) between the vectors (ax, ay) and (bx, by); 0 when one is
    zero."""
    na, nb = np.hypot(ax, ay), np.hypot(bx, by)
    if na == 0 or nb == 0:
        return 0.0
    c = _dot(ax, ay, bx, by) / (na * nb)
    c = c if c < 1.0 else 1.0  # as min(1.0, c), max(-1.0, c) (a NaN becomes 1)
    c = c if c > -1.0 else -1.0
    return math.acos(c)


@njit(cache=True, nogil=True)
def _corner_angles(corners, floor, use_floor, out):
    """The L candidates' corner angles: corner i's centre and arm points ``corners[i]`` (3, 2)
    in the grid, the angle between its arms there, or on the floor (``floor[i]`` (3, 2)) where
    all three points are on it (``use_floor``)."""
    for i in range(corners.shape[0]):
        c = corners[i]
        out[i] = _angle_at(c[1, 0] - c[0, 0], c[1, 1] - c[0, 1], c[2, 0] - c[0, 0],
                           c[2, 1] - c[0, 1])
        if use_floor:
            finite = True
            for j in range(3):
                finite = finite and np.isfinite(floor[i, j, 0]) and np.isfinite(floor[i, j, 1])
            if finite:
                f = floor[i]
                out[i] = _angle_at(f[1, 0] - f[0, 0], f[1, 1] - f[0, 1], f[2, 0] - f[0, 0],
                                   f[2, 1] - f[0, 1])


@njit(cache=True, nogil=True)
def _sample_cell(image, x64, y64):
    """A per-cell image sampled bilinearly at one grid point (x = column, y = row), in
    float32, 0 outside the image."""
    h, w = image.shape
    one = np.float32(1.0)
    x, y = np.float32(x64), np.float32(y64)
    fx, fy = np.floor(x), np.floor(y)
    ix, iy = int(fx), int(fy)
    ax, ay = x - fx, y - fy
    out = np.float32(0.0)
    if 0 <= iy < h:
        if 0 <= ix < w:
            out += image[iy, ix] * ((one - ay) * (one - ax))
        if 0 <= ix + 1 < w:
            out += image[iy, ix + 1] * ((one - ay) * ax)
    if 0 <= iy + 1 < h:
        if 0 <= ix < w:
            out += image[iy + 1, ix] * (ay * (one - ax))
        if 0 <= ix + 1 < w:
            out += image[iy + 1, ix + 1] * (ay * ax)
    return out


@njit(cache=True, nogil=True)
def _circle(white, green, field, use_field, cx, cy, r, ring, t_white, t_green, state):
    """Number of green -> white -> green passages on the circle of radius ``r`` around
    (cx, cy) (grid coordinates; ``ring`` the unit circle's samples): a state machine over the
    circle's samples in order, where white (share >= t_white) and green (share >= t_green)
    change the state and anything else keeps it (the last known state carried over, cyclic).
    A circle showing no green or no white counts 0. Also returns the circle's share of
    samples that are neither (an object standing there); with ``use_field`` only among the
    samples inside the field region ``field`` (>= 0.5): beyond the boundary the view is
    unknown, not an object on the field. ``state``: scratch, one int per sample."""
    n = ring.shape[0]
    n_on, neither, any_known = 0, 0, False
    for k in range(n):
        px, py = cx + r * ring[k, 0], cy + r * ring[k, 1]
        if _sample_cell(white, px, py) >= t_white:
            state[k] = 1
        elif _sample_cell(green, px, py) >= t_green:
            state[k] = 0
        else:
            state[k] = -1
        if state[k] >= 0:
            any_known = True
        if use_field and _sample_cell(field, px, py) >= 0.5:
            n_on += 1
            if state[k] < 0:
                neither += 1
    if use_field:
        other = neither / n_on if n_on > 0 else 1.0
    else:
        known = 0
        for k in range(n):
            known += state[k] >= 0
        other = 1.0 - known / n
    if not any_known:
        return 0, other
    # the last known state carried over unknown samples (cyclic)
    last = -1
    for k in range(n):
        if state[k] >= 0:
            last = state[k]
    count, prev = 0, last
    for k in range(n):
        cur = state[k] if state[k] >= 0 else prev
        if cur == 1 and prev == 0:
            count += 1
        prev = cur
    return count, other


@njit(cache=True, nogil=True)
def _path_share(white, px, py, qx, qy, t, step):
    """Share of the samples (``step`` cells apart) on the straight path (px, py) ->
    (qx, qy) (grid coordinates) that are white (at least ``t``)."""
    n = max(2, int(np.ceil(math.hypot(qx - px, qy - py) / step)) + 1)
    d = 1.0 / (n - 1)
    on = 0
    for k in range(n):
        s = k * d if k < n - 1 else 1.0
        if _sample_cell(white, px * (1 - s) + qx * s, py * (1 - s) + qy * s) >= t:
            on += 1
    return on / n


@njit(cache=True, nogil=True)
def _verify(centre, arms, white, green, field, use_field, radii, rule):
    """Image checks of section 4.1 at a crossing ``centre`` (grid coordinates): the circle's
    transition count equals the number of arms (at any of the ``radii`` tried), and a white
    path leads from the crossing along each arm (to ``arms``, the arms' points in grid
    coordinates). ``white`` is the white share per cell inside the field boundary; white means
    at least ``t_white`` and at least ``relative`` times the median white level at the arm
    points (far lines are thin and faint). Arms at a small image angle need a larger circle to
    be told apart: one on which neighbouring arms are ``arm_gap`` cells apart (up to
    ``max_radius``) is tried too. ``field`` (with ``use_field``): the field region per cell (1
    inside the boundary): only the circle's samples inside it count towards the share of
    neither white nor green (at most ``max_other``). Returns a score in [0, 1] (0 =
    rejected): the smallest white-path share, rejected below ``min_path_share``. ``rule``:
    the tuning's (t_white, relative, t_green, arm_gap, max_radius, max_other,
    min_path_share); the cells are sampled bilinearly in float32."""
    t_white, relative, t_green, arm_gap, max_radius, max_other, min_path_share = rule
    ring = _RING
    n_arms = arms.shape[0]
    cx, cy = centre[0], centre[1]
    levels = np.empty(n_arms, np.float32)
    ang = np.empty(n_arms)
    for a in range(n_arms):
        levels[a] = _sample_cell(white, arms[a, 0], arms[a, 1])
        ang[a] = math.atan2(arms[a, 1] - cy, arms[a, 0] - cx)
    ref = np.median(levels) if n_arms else np.float32(np.nan)
    t = max(t_white, relative * ref)
    ang.sort()
    sep = np.inf
    for a in range(n_arms):
        gap = (ang[a + 1] if a + 1 < n_arms else ang[0] + 2 * math.pi) - ang[a]
        sep = min(sep, gap)
    state = np.empty(ring.shape[0], np.int64)
    found = False
    for k in range(len(radii) + 1):
        if k < len(radii):
            r = radii[k]
        elif sep > 0:
            r = min(max_radius, arm_gap / sep)
        else:
            break
        count, other = _circle(white, green, field, use_field, cx, cy, r, ring, t, t_green,
                               state)
        if count == n_arms and other <= max_other:
            found = True
            break
    if not found or n_arms == 0:
        return 0.0
    score = 1.0
    for a in range(n_arms):
        score = min(score, _path_share(white, cx, cy, arms[a, 0], arms[a, 1], t, 0.5))
    return score if score >= min_path_share else 0.0


@njit(cache=True, nogil=True)
def _remainder(a, b):
    """np.remainder of two floats (numpy's divmod: fmod, moved to the sign of b)."""
    mod = np.fmod(a, b)
    if b == 0:
        return mod
    if mod != 0:
        if (b < 0) != (mod < 0):
            mod += b
    else:
        mod = math.copysign(0.0, b)
    return mod


@njit(cache=True, nogil=True)
def _meeting_arms(t, length, ux, uy, end_gap, tol, arms, lengths, a):
    """_meeting compiled: line arms (ux, uy) at ``t`` along a line of ``length`` into
    arms[a:], their lengths into lengths[a:]; returns the new count, or -1 for none."""
    if tol < t < length - tol:
        arms[a, 0], arms[a, 1], lengths[a] = ux, uy, length - t
        arms[a + 1, 0], arms[a + 1, 1], lengths[a + 1] = -ux, -uy, t
        return a + 2
    if end_gap > tol:
        return -1
    if t <= 0.5 * length:
        arms[a, 0], arms[a, 1], lengths[a] = ux, uy, length - t
    else:
        arms[a, 0], arms[a, 1], lengths[a] = -ux, -uy, t
    return a + 1


@njit(cache=True, nogil=True)
def _pair_crossings(ends, widths, fang, tol, max_misfit, first_stem, kinds, lines, points,
                    arms, lengths):
    """line_pair_crossings after the floor angles ``fang`` (N,), compiled: the crossings of
    the line pairs i < j (row by row, as np.nonzero gives them) into the outputs (kind 2 L,
    3 T, the two lines, the point, the arms and their lengths); returns their number."""
    n = ends.shape[0]
    length = np.empty(n)
    u = np.empty((n, 2))
    for i in range(n):
        dx, dy = ends[i, 1, 0] - ends[i, 0, 0], ends[i, 1, 1] - ends[i, 0, 1]
        length[i] = np.hypot(dx, dy)
        den = length[i] if not length[i] < 1e-9 else 1e-9  # np.maximum (NaN stays)
        u[i, 0], u[i, 1] = dx / den, dy / den
    arm = np.empty((4, 2))
    arm_len = np.empty(4)
    m = 0
    half = math.pi / 2
    for i in range(n):
        for j in range(i + 1, n):
            if i >= first_stem and j >= first_stem:
                continue
            diff = _remainder(fang[i] - fang[j], math.pi)
            other = math.pi - diff
            near = diff if (diff <= other or np.isnan(diff)) else other  # np.minimum
            if not abs(near - half) <= max_misfit:  # NaN (off the floor) is no pair
                continue
            det, t_i, t_j = _line_cut(u[i, 0], u[i, 1], u[j, 0], u[j, 1],
                                      ends[j, 0, 0] - ends[i, 0, 0],
                                      ends[j, 0, 1] - ends[i, 0, 1])
            if not abs(det) >= 1e-3:
                continue
            xx, xy = ends[i, 0, 0] + t_i * u[i, 0], ends[i, 0, 1] + t_i * u[i, 1]
            # each line's end nearer the intersection and its distance from the other line
            k = 0 if t_i <= 0.5 * length[i] else 1
            g_i = abs(_dot(ends[i, k, 0] - ends[j, 0, 0], ends[i, k, 1] - ends[j, 0, 1],
                           -u[j, 1], u[j, 0]))
            k = 0 if t_j <= 0.5 * length[j] else 1
            g_j = abs(_dot(ends[j, k, 0] - ends[i, 0, 0], ends[j, k, 1] - ends[i, 0, 1],
                           -u[i, 1], u[i, 0]))
            c = _meeting_arms(t_i, length[i], u[i, 0], u[i, 1], g_i, tol + widths[j], arm,
                              arm_len, 0)
            if c < 0:
                continue
            c = _meeting_arms(t_j, length[j], u[j, 0], u[j, 1], g_j, tol + widths[i], arm,
                              arm_len, c)
            if c < 0 or c == 4:
                continue  # two straight lines crossing: fields have none (their X is the
                # centre circle on the halfway line), so it is no crossing of field lines
            kinds[m], lines[m, 0], lines[m, 1] = c, i, j
            points[m, 0], points[m, 1] = xx, xy
            for q in range(c):
                arms[m, q, 0], arms[m, q, 1], lengths[m, q] = arm[q, 0], arm[q, 1], arm_len[q]
            m += 1
    return m


@njit(cache=True, nogil=True)
def _stems(lines, floor, white_px, lens, fl, rule, out):
    """stem_lines, compiled: the stems into ``out`` (4 N, 2, 2); returns their number.
    ``floor``: the lines' ends on the floor, ``fl``: Floor, ``rule``: (cell, min_span,
    line_width, refine_step, max_reach, grow, tolerance, min_length, min_points,
    sin_misfit) as stem_lines makes it."""
    (cell, min_span, line_width, refine_step, max_reach, grow, tolerance, min_length,
     min_points, sin_misfit) = rule
    n = 0
    res = np.empty(12)
    seg = np.empty((2, 2))
    back = np.empty((1, 2))
    for i in range(lines.shape[0]):
        ax, ay = floor[i, 1, 0] - floor[i, 0, 0], floor[i, 1, 1] - floor[i, 0, 1]
        la = math.hypot(ax, ay)
        if not np.isfinite(la) or la <= 0:
            continue
        ax, ay = ax / la, ay / la
        for k in range(2):
            ex, ey = lines[i, k, 0], lines[i, k, 1]
            bx, by = lines[i, 1 - k, 0] - ex, lines[i, 1 - k, 1] - ey
            nb = max(math.hypot(bx, by), 1e-9)
            back[0, 0], back[0, 1] = bx / nb, by / nb
            for sign in (1.0, -1.0):
                qx, qy = _ideal_point(fl, floor[i, k, 0] - sign * 0.05 * ay,
                                      floor[i, k, 1] + sign * 0.05 * ax)
                vx, vy = qx - ex, qy - ey
                nv = math.hypot(vx, vy)
                if not np.isfinite(nv) or nv <= 0:
                    continue
                vx, vy = vx / nv, vy / nv
                scale = 0.05 / nv  # m of floor per px along v
                if scale * cell <= min_span:
                    continue
                start, reach = _clear_start_kernel(ex, ey, vx, vy, back, scale, fl, line_width,
                                                   tolerance, max_reach)
                step = min(max(line_width / scale, 1.0), refine_step)
                sx, sy = ex + start * vx, ey + start * vy
                gx, gy = grow_kernel(white_px, lens, sx, sy, vx, vy, step, reach, grow, tolerance)
                t = (gx - ex) * vx + (gy - ey) * vy
                if t * scale < min_length or t <= start:
                    continue
                seg[0, 0], seg[0, 1], seg[1, 0], seg[1, 1] = sx, sy, gx, gy
                refine_kernel(seg, white_px, lens, step, reach, 0.0, min_points, refine_step, res)
                if res[0] == 0:
                    continue
                f0x, f0y = floor_at(fl.m, fl.height, fl.pos, True, res[1], res[2])
                f1x, f1y = floor_at(fl.m, fl.height, fl.pos, True, res[3], res[4])
                dx, dy = f1x - f0x, f1y - f0y
                ls = math.hypot(dx, dy)
                if not np.isfinite(ls) or ls < min_length or abs(dx * ax + dy * ay) / ls \
                        > sin_misfit:
                    continue
                out[n, 0, 0], out[n, 0, 1], out[n, 1, 0], out[n, 1, 1] = \
                    res[1], res[2], res[3], res[4]
                n += 1
    return n


@njit(cache=True, nogil=True)
def _distinct_arms(cmp, lengths, cos_same, arms, kept_lengths):
    """merge_line_crossings' arms of a group, in order: an arm whose direction ``cmp`` lies
    within acos(cos_same) of a kept arm's (the first such; _dot) gives that one the larger
    length (Python's max), else it is kept. The kept arms' indices go into ``arms``, their
    lengths into ``kept_lengths``; returns their number."""
    m = 0
    for k in range(cmp.shape[0]):
        same = -1
        for q in range(m):
            j = arms[q]
            if _dot(cmp[k, 0], cmp[k, 1], cmp[j, 0], cmp[j, 1]) >= cos_same:
                same = q
                break
        if same < 0:
            arms[m], kept_lengths[m] = k, lengths[k]
            m += 1
        elif lengths[k] > kept_lengths[same]:
            kept_lengths[same] = lengths[k]
    return m


@njit(cache=True, nogil=True)
def _dot(ax, ay, bx, by):
    """The dot product of the 2-vectors (ax, ay) and (bx, by)."""
    return ax * bx + ay * by


@njit(cache=True, nogil=True)
def _fit_away(sel, ox, oy):
    """The least-squares line (cx, cy, ux, uy) of the points ``sel``
    (n, 2), its direction pointing away from (ox, oy)."""
    cx, cy, ux, uy, _, _, _ = _fit_points(sel)
    if _dot(cx - ox, cy - oy, ux, uy) < 0:
        ux, uy = -ux, -uy
    return cx, cy, ux, uy


@njit(cache=True, nogil=True)
def _meet(c1x, c1y, u1x, u1y, c2x, c2y, u2x, u2y):
    """Where the lines through c1 along u1 and through c2 along u2 meet: (ok, x, y), not ok
    when they are nearly parallel (|sin| < 1e-3, _line_cut)."""
    det, t, _ = _line_cut(u1x, u1y, u2x, u2y, c2x - c1x, c2y - c1y)
    if abs(det) < 1e-3:  # nearly parallel (|sin| < 1e-3)
        return False, np.nan, np.nan
    return True, c1x + t * u1x, c1y + t * u1y


@njit(cache=True, nogil=True)
def _line_cut(u1x, u1y, u2x, u2y, bx, by):
    """(det, t, s) of the lines p + t u1 and p + b + s u2 meeting: the 2 x 2 system
    [u1, -u2] (t, s) = b solved by Cramer's rule; det = u2 x u1 (the sine of the angle
    between unit directions); t and s NaN when det is 0."""
    det = u2x * u1y - u1x * u2y
    if det == 0:
        return det, np.nan, np.nan
    return det, (u2x * by - u2y * bx) / det, (u1x * by - u1y * bx) / det


@njit(cache=True, nogil=True)
def _place(kind, centre, flat, start, coords, refine, white_px, lens, rule, out):
    """place_crossing compiled: the arms' lines, refined, their meeting point and the arms'
    lengths of one candidate (``kind`` 0 L, 1 T, 2 X; chain c of its arms is ``flat[start[c]:
    start[c + 1]]``; ``rule``: (skip, count, t_skip, cell, step, reach, min_points,
    max_shift, arm_step) as place_crossing makes it). The crossing into out[0, :2], arm a's
    direction and length into out[1 + a]; returns 0, or the index of its reason in
    PLACE_REASONS."""
    skip, count, t_skip, cell, step, reach, min_points, max_shift, arm_step = rule
    n = len(start) - 1
    ox, oy = centre[0], centre[1]
    cs = np.empty((n, 2))
    us = np.empty((n, 2))
    sels = []
    for a in range(n):
        # the arm's finite nodes after the crossing's, from ``skip`` on
        m = 0
        pts = np.empty((max(start[a + 1] - start[a] - 1, 0), 2))
        for i in range(start[a] + 1, start[a + 1]):
            px, py = coords[flat[i], 0], coords[flat[i], 1]
            if np.isfinite(px) and np.isfinite(py):
                pts[m, 0], pts[m, 1] = px, py
                m += 1
        if m == 0:
            return 1
        lo, hi = (skip, min(skip + count, m)) if m >= skip + 2 else (0, min(count, m))
        if hi - lo < 2:
            sel = np.empty((hi - lo + 1, 2))
            sel[0, 0], sel[0, 1] = ox, oy
            sel[1:] = pts[lo:hi]
        else:
            sel = pts[lo:hi].copy()
        cx, cy, ux, uy = _fit_away(sel, ox, oy)
        if refine:
            # refined over the nodes' extent from t_skip px off the crossing on
            t0, t1 = np.inf, -np.inf
            for i in range(sel.shape[0]):
                t = _dot(sel[i, 0] - ox, sel[i, 1] - oy, ux, uy)
                t0, t1 = min(t0, t), max(t1, t)
            t0 = max(t0, t_skip)
            if not t1 - t0 < cell:
                ends = np.empty((2, 2))
                ends[0, 0], ends[0, 1] = ox + t0 * ux, oy + t0 * uy
                ends[1, 0], ends[1, 1] = ox + t1 * ux, oy + t1 * uy
                res = np.empty(12)
                centres, _ = refine_kernel(ends, white_px, lens, step, reach, 0.0, min_points,
                                           0.0, res)
                if res[0] != 0:
                    dx, dy = res[7], res[8]
                    if not _dot(dx, dy, ux, uy) >= 0:
                        dx, dy = -dx, -dy
                    cx, cy, ux, uy = res[5], res[6], dx, dy
                    sel = centres
        cs[a, 0], cs[a, 1], us[a, 0], us[a, 1] = cx, cy, ux, uy
        sels.append(sel)
    # the lines' intersection
    if kind == 0:
        ok, x, y = _meet(cs[0, 0], cs[0, 1], us[0, 0], us[0, 1], cs[1, 0], cs[1, 1],
                         us[1, 0], us[1, 1])
    elif kind == 1:
        # the bar: the pair of most nearly opposite arms (the first smallest cosine)
        bi, bj, bs, best = 0, 1, 2, np.inf
        for i, j, s in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            cos = _dot(us[i, 0], us[i, 1], us[j, 0], us[j, 1])
            if cos < best:
                bi, bj, bs, best = i, j, s, cos
        bx, by, vx, vy = _fit_away(np.concatenate((sels[bi], sels[bj])), cs[bi, 0], cs[bi, 1])
        ok, x, y = _meet(bx, by, vx, vy, cs[bs, 0], cs[bs, 1], us[bs, 0], us[bs, 1])
    elif n != 4:
        ok, x, y = False, np.nan, np.nan
    else:
        # X: arm 0 with its most opposite arm (np.argmin: the first smallest), the others
        j, best = 1, np.inf
        for k in range(1, 4):
            cos = _dot(us[0, 0], us[0, 1], us[k, 0], us[k, 1])
            if cos < best or k == 1:
                j, best = k, cos
        r0, r1 = (2, 3) if j == 1 else ((1, 3) if j == 2 else (1, 2))
        ax, ay, vx, vy = _fit_away(np.concatenate((sels[0], sels[j])), cs[0, 0], cs[0, 1])
        bx, by, wx, wy = _fit_away(np.concatenate((sels[r0], sels[r1])), cs[r0, 0],
                                   cs[r0, 1])
        ok, x, y = _meet(ax, ay, vx, vy, bx, by, wx, wy)
    if not ok or np.hypot(x - ox, y - oy) > max_shift:
        return 2
    out[0, 0], out[0, 1] = x, y
    for a in range(n):
        sel = sels[a]
        far = -np.inf
        for i in range(sel.shape[0]):
            t = _dot(sel[i, 0] - x, sel[i, 1] - y, us[a, 0], us[a, 1])
            if not (t <= far or np.isnan(far)):  # np.max: a NaN wins
                far = t
        out[1 + a, 0], out[1 + a, 1] = us[a, 0], us[a, 1]
        out[1 + a, 2] = arm_step if arm_step > far else far
    return 0


@njit(cache=True, nogil=True)
def floor_at(m, height, pos, shifted, x, y):
    """perspective.FloorProjection at one ideal pixel (x, y): its ray m (x, y, 1) cut with the
    floor ``height`` below the lens (NaN unless the ray points down), plus the lens's
    position ``pos`` over the floor if ``shifted`` (perspective._to_floor per pixel)."""
    rx = x * m[0, 0] + y * m[0, 1] + m[0, 2]
    ry = x * m[1, 0] + y * m[1, 1] + m[1, 2]
    down = x * m[2, 0] + y * m[2, 1] + m[2, 2]
    t = height / -down if down < -1e-9 else np.nan
    fx, fy = rx * t, ry * t
    if shifted:
        fx += pos[0]
        fy += pos[1]
    return fx, fy


@njit(cache=True, nogil=True)
def _to_edge(x0, x1, ux, uy, w, h, margin):
    """The distance (ideal px) from (x0, x1) along (ux, uy) to ``margin`` px inside the
    image's edge, at least 0 (in ideal pixels: the lens's distortion is small at the edges of
    the views this is used for)."""
    t = np.inf
    for d, lo, hi in ((ux, margin - x0, (w - 1 - margin) - x0),
                      (uy, margin - x1, (h - 1 - margin) - x1)):
        if d > 1e-12:
            t = min(t, hi / d)
        elif d < -1e-12:
            t = min(t, lo / d)
    return max(t, 0.0)


@njit(cache=True, nogil=True)
def _floor_checks(x, dirs, reach, lengths, has_lengths, sight, fl, p, angles_at, scalars):
    """_verify_crossing's floor checks, compiled: the crossing, a step along each arm, the
    cell below and the arms' ends on the floor; arms shorter than ``min_arm_length`` m grown
    along the white line on the full-resolution mask (white_arm_lengths; ``lengths`` and
    ``reach`` updated in place); the range. Returns 0 or the index of the reason in
    FLOOR_REASONS; ``angles_at`` (A + 1, 2) gets the crossing's floor point and each arm's
    offset from it (for arctan2), ``scalars`` the distance, the cell's span on the floor and
    whether that is beyond the grid's resolution (``sight``: Sight, ``fl``: Floor, ``p``:
    verify_params)."""
    use_white, white_px, lens = sight.use_white, sight.white_px, sight.lens
    m, height, pos, shifted = fl.m, fl.height, fl.pos, fl.shifted
    n = dirs.shape[0]
    cell = p[P_CELL]
    step = p[P_ARM_STEP] * cell
    x0, x1 = x[0], x[1]
    f0x, f0y = floor_at(m, height, pos, shifted, x0, x1)
    if not (np.isfinite(f0x) and np.isfinite(f0y)):
        return 1
    angles_at[0, 0], angles_at[0, 1] = f0x, f0y
    for k in range(n):
        fx, fy = floor_at(m, height, pos, shifted, x0 + step * dirs[k, 0],
                           x1 + step * dirs[k, 1])
        if not (np.isfinite(fx) and np.isfinite(fy)):
            return 1
        angles_at[1 + k, 0], angles_at[1 + k, 1] = fx - f0x, fy - f0y
    bx, by = floor_at(m, height, pos, shifted, x0 + 0.0, x1 + cell)
    span = np.hypot(bx - f0x, by - f0y)  # the cell below
    if not np.isfinite(span):
        span = np.inf
    if has_lengths:
        min_length = p[P_MIN_ARM_LENGTH]
        arm_m = np.empty(n)
        short = False
        for k in range(n):
            ex, ey = floor_at(m, height, pos, shifted, x0 + lengths[k] * dirs[k, 0],
                               x1 + lengths[k] * dirs[k, 1])
            arm_m[k] = np.hypot(ex - f0x, ey - f0y)  # NaN beyond the horizon: long enough
            short = short or arm_m[k] < min_length
        if short and use_white:
            # the fitted nodes or lines may end early (a far arm's few nodes, a line cut at a
            # junction): the arm is as long as the white line goes on along it in the image
            w, h = p[P_WIDTH], p[P_HEIGHT]
            far = p[P_ARM_REACH] * cell
            for k in range(n):
                ux, uy = dirs[k, 0], dirs[k, 1]
                if arm_m[k] < min_length:
                    gx, gy = grow_kernel(white_px, lens, x0 + lengths[k] * ux,
                                         x1 + lengths[k] * uy, ux, uy, p[P_REFINE_STEP],
                                         p[P_REFINE_REACH] * cell, p[P_ARM_GROW] * cell,
                                         p[P_ARM_TOLERANCE])
                    t = _dot(gx - x0, gy - x1, ux, uy)
                    if t > lengths[k]:
                        lengths[k] = t
                    if lengths[k] >= _to_edge(x0, x1, ux, uy, w, h, p[P_REFINE_STEP]):
                        lengths[k] = np.inf  # white up to the image's edge
                ex, ey = floor_at(m, height, pos, shifted, x0 + lengths[k] * ux,
                                   x1 + lengths[k] * uy)
                arm_m[k] = np.hypot(ex - f0x, ey - f0y)
                r = min(far, lengths[k]) if not np.isnan(lengths[k]) else lengths[k]
                if not reach[k] >= r and not np.isnan(reach[k]):  # np.maximum
                    reach[k] = r
        for k in range(n):
            if arm_m[k] < min_length:
                return 2
    scalars[0], scalars[1] = np.hypot(f0x, f0y), span
    # beyond the grid's resolution the full-resolution white mask decides (_verify_fine), as
    # far as its profiles (refine_step px apart) resolve the floor
    fine = span > p[P_MAX_CELL_SPAN]
    if fine and (not use_white or not p[P_FINE]
                 or span * p[P_REFINE_STEP] / cell > p[P_MAX_CELL_SPAN]):
        return 3
    scalars[2] = fine
    return 0


@njit(cache=True, nogil=True)
def _image_checks(kind, x, dirs, reach, sight, fl, p, radii, out):
    """_verify_crossing's image checks, compiled: each arm's reach clipped to the image
    (``reach`` updated in place), the crossing and the arms' ends in the image and on the
    grid, the field boundary and objects near it; an L (``kind`` 0) whose alternative is not
    in view (``_alternative_in_view``) or whose arms' line goes on through it (arm_state
    white) is to be looked at as a T (IMAGE_AS_T); then the circle and white paths
    (``_verify``). Returns IMAGE_VERIFIED with the score and the crossing's image position in
    ``out`` (3,), IMAGE_FINE where the grid does not verify it and the full-resolution check
    decides, or the index of the reason in IMAGE_REASONS (``sight``: Sight, ``fl``: Floor,
    ``p``: verify_params, ``radii``: the circles')."""
    white, green, other_mean, top, field = (sight.white, sight.green, sight.other_mean,
                                            sight.top, sight.field)
    use_white, lens = sight.use_white, sight.lens
    n = dirs.shape[0]
    cell = p[P_CELL]
    x0, x1 = x[0], x[1]
    w, h = p[P_WIDTH], p[P_HEIGHT]
    # an arm leaving the image is verified on its part in view
    grid = np.empty((n + 1, 2))
    for k in range(n + 1):
        if k == 0:
            qx, qy = x0, x1
        else:
            t = _to_edge(x0, x1, dirs[k - 1, 0], dirs[k - 1, 1], w, h, 0.5 * cell)
            if not reach[k - 1] <= t and not np.isnan(reach[k - 1]):  # np.minimum
                reach[k - 1] = t
            qx, qy = x0 + reach[k - 1] * dirs[k - 1, 0], x1 + reach[k - 1] * dirs[k - 1, 1]
        px, py = distort_point(lens, qx, qy)
        if not (np.isfinite(px) and np.isfinite(py)):
            return 3
        if k == 0:
            out[1], out[2] = px, py
        grid[k, 0], grid[k, 1] = (px + 0.5) / cell - 0.5, (py + 0.5) / cell - 0.5
    n_cols = top.shape[0]
    col = min(max(int(np.rint(grid[0, 0])), 0), n_cols - 1)
    near_top = -np.inf  # the boundary within two columns
    for c in range(max(col - 2, 0), min(col + 3, n_cols)):
        near_top = max(near_top, top[c])
    if grid[0, 1] - near_top < p[P_EDGE_MARGIN]:
        return 4  # a line meeting an object or the end of the view
    rows, cols = other_mean.shape
    row = min(max(int(np.rint(grid[0, 1])), 0), rows - 1)
    r = int(p[P_OBJECT_RADIUS])
    for i in range(max(row - r, 0), min(row + r + 1, rows)):
        for j in range(max(col - r, 0), min(col + r + 1, cols)):
            if other_mean[i, j] > 0.5:
                return 5  # a robot's or a person's white foot on a line
    # the arms that would make an L a T must be in view (a T's stem continued would make an
    # X, which fields hold only where the centre circle crosses the halfway line); a thin
    # line leaves a cell mostly green: where the full-resolution mask shows an arm's line
    # going on through the crossing, the L is no L
    if kind == 0:
        if not _alternative_in_view(x0, x1, dirs, sight, p):
            return IMAGE_AS_T
        if use_white:
            for k in range(n):
                if _arm_state(x0, x1, -dirs[k, 0], -dirs[k, 1], dirs, sight, fl, p) == 1:
                    return IMAGE_AS_T
    score = _verify(grid[0], grid[1:], white, green, field, p[P_USE_FIELD] != 0, radii,
                    (p[P_T_WHITE], p[P_RELATIVE], p[P_T_GREEN], p[P_ARM_GAP], p[P_MAX_RADIUS],
                     p[P_MAX_OTHER], p[P_MIN_PATH_SHARE]))
    if score <= 0:
        return IMAGE_FINE if use_white and p[P_FINE] else 6
    out[0] = score
    return IMAGE_VERIFIED


@njit(cache=True, nogil=True)
def _arm_state(x0, x1, ux, uy, arms, sight, fl, p):
    """arm_state, compiled (``sight``: Sight, ``fl``: Floor, ``p``: verify_params): 0
    unknown, 1 white, 2 green."""
    white_px, green, other_mean, top, lens = (sight.white_px, sight.green, sight.other_mean,
                                              sight.top, sight.lens)
    w, h, cell = p[P_WIDTH], p[P_HEIGHT], p[P_CELL]
    line_width, tolerance = p[P_LINE_WIDTH], p[P_ARM_TOLERANCE]
    max_reach = p[P_REFINE_REACH] * cell
    fine_px, min_length, refine_step = p[P_FINE_PX], p[P_MIN_ARM_LENGTH], p[P_REFINE_STEP]
    ratio_lo, ratio_hi, t_green = p[P_WIDTH_LO], p[P_WIDTH_HI], p[P_T_GREEN]
    f0x, f0y = floor_at(fl.m, fl.height, fl.pos, True, x0, x1)
    f1x, f1y = floor_at(fl.m, fl.height, fl.pos, True, x0 + 4.0 * ux, x1 + 4.0 * uy)
    scale = math.hypot(f1x - f0x, f1y - f0y) / 4.0  # m of floor per px along u
    if not np.isfinite(scale) or scale <= 0:
        return 0
    start, reach = _clear_start_kernel(x0, x1, ux, uy, arms, scale, fl, line_width, tolerance,
                                       max_reach)
    need = start + max(fine_px, (min_length - line_width) / scale)
    step = min(max(line_width / scale, 1.0), refine_step)
    edge = _to_edge(x0, x1, ux, uy, w, h, step)  # to ``step`` px inside the image's edge
    sx, sy = x0 + start * ux, x1 + start * uy
    gx, gy = grow_kernel(white_px, lens, sx, sy, ux, uy, step, reach, need, tolerance)
    t = (gx - x0) * ux + (gy - x1) * uy
    nx, ny = -uy, ux
    if t >= need - 1e-6 or t >= edge - 1e-6:
        # white on: a painted line's, if its runs are centred on the arm and as wide as a
        # line of line_width m there (else something white that is no line: unknown)
        stop = min(t, max(need, start + 3 * step))
        seg = np.empty((2, 2))
        seg[0, 0], seg[0, 1] = sx, sy
        seg[1, 0], seg[1, 1] = x0 + stop * ux, x1 + stop * uy
        res = np.empty(12)
        _, widths = refine_kernel(seg, white_px, lens, step, reach, 0.0, 3, 0.0, res)
        if res[0] == 0:
            return 0
        for k in (1, 3):
            if abs((res[k] - x0) * nx + (res[k + 1] - x1) * ny) > 2 * tolerance:
                return 0
        mid = 0.5 * (start + stop)
        expected = _px_width(fl, x0 + mid * ux, x1 + mid * uy, ux, uy, line_width)
        ratio = np.median(widths) / max(expected, 1e-6)
        return 1 if ratio_lo <= ratio <= ratio_hi else 0
    if need > edge:
        return 0
    # a line thinner in the image than half the judged length (fine_px) may break up in the
    # white mask: no white there is no evidence of no line
    mid = 0.5 * (start + need)
    if not _px_width(fl, x0 + mid * ux, x1 + mid * uy, ux, uy, line_width) >= 0.5 * fine_px:
        return 0
    for k in range(3):
        tk = start + 0.5 * k * (need - start)
        px, py = distort_point(lens, x0 + tk * ux, x1 + tk * uy)
        gx_, gy_ = (px + 0.5) / cell - 0.5, (py + 0.5) / cell - 0.5
        col = min(max(int(round(gx_)), 0), top.shape[0] - 1)
        row = min(max(int(round(gy_)), 0), other_mean.shape[0] - 1)
        if gy_ < top[col] or other_mean[row, col] > 0.5:
            return 0
        if _sample_cell(green, gx_, gy_) < t_green:
            return 0
    return 2


@njit(cache=True, nogil=True)
def _ideal_point(fl, fx, fy):
    """perspective.FloorProjection.to_ideal at one floor point (``fl``: Floor)."""
    m_inv = fl.m_inv
    px, py, pz = fx - fl.pos[0], fy - fl.pos[1], -fl.height
    h0 = m_inv[0, 0] * px + m_inv[0, 1] * py + m_inv[0, 2] * pz
    h1 = m_inv[1, 0] * px + m_inv[1, 1] * py + m_inv[1, 2] * pz
    h2 = m_inv[2, 0] * px + m_inv[2, 1] * py + m_inv[2, 2] * pz
    if h2 <= 1e-9:
        return np.nan, np.nan
    return h0 / h2, h1 / h2


@njit(cache=True, nogil=True)
def _px_width(fl, px, py, ux, uy, line_width):
    """The width (ideal px, across (ux, uy)) of a line ``line_width`` m wide on the floor
    along the direction (ux, uy) takes at ideal pixel (px, py) (``fl``: Floor)."""
    f0x, f0y = floor_at(fl.m, fl.height, fl.pos, True, px, py)
    f1x, f1y = floor_at(fl.m, fl.height, fl.pos, True, px + ux, py + uy)
    ax, ay = f1x - f0x, f1y - f0y
    na = math.hypot(ax, ay)
    if not np.isfinite(na) or na <= 0:
        return np.nan
    nx, ny = -ay / na * (0.5 * line_width), ax / na * (0.5 * line_width)
    a0, a1 = _ideal_point(fl, f0x - nx, f0y - ny)
    b0, b1 = _ideal_point(fl, f0x + nx, f0y + ny)
    return abs((b0 - a0) * -uy + (b1 - a1) * ux)


@njit(cache=True, nogil=True)
def _clear_start_kernel(x0, x1, ux, uy, arms, scale, fl, line_width, tolerance, max_reach):
    """Where the half-line from (x0, x1) along (ux, uy) stands clear of the crossing's lines
    (arm_state's start, ideal px; ``scale``: m of floor per px along it) and the reach of
    its profiles (px)."""
    start = max(1.0, line_width / scale)
    w_u = _px_width(fl, x0, x1, ux, uy, line_width)
    if not np.isfinite(w_u):
        w_u = 1.0
    for k in range(arms.shape[0]):
        vx, vy = arms[k, 0], arms[k, 1]
        sin = abs(ux * vy - uy * vx)
        dot = ux * vx + uy * vy
        if 0.0 < dot < 0.999:  # ahead of the line, and not the line itself
            w_v = _px_width(fl, x0, x1, vx, vy, line_width)
            if np.isfinite(w_v):
                start = max(start, (0.5 * (w_u + w_v) + tolerance) / max(sin, 1e-3))
    reach = min(max(1.5 * w_u + 2 * tolerance, 2 * tolerance), max_reach)
    return start, reach


@njit(cache=True, nogil=True)
def _alternative_in_view(x0, x1, dirs, sight, p):
    """Whether the image shows carpet opposite an L's arms (where the third arm of a T would
    be), ``arm_reach`` cells from the crossing (x0, x1): inside the image and the field
    boundary (``edge_margin`` cells below ``sight.top``), no object there, and green (at least
    ``t_green``, sampled as OpenCV's remap does: ``_remap_sample``). A T seen with one half of
    its bar out of view or hidden looks like an L; so do a far X's arms, flattened by the
    perspective (``p``: verify_params)."""
    lens, top, other_mean, green = sight.lens, sight.top, sight.other_mean, sight.green
    w, h, cell = p[P_WIDTH], p[P_HEIGHT], p[P_CELL]
    reach, edge_margin, t_green = p[P_ARM_REACH] * cell, p[P_EDGE_MARGIN], p[P_T_GREEN]
    for k in range(dirs.shape[0]):
        px, py = distort_point(lens, x0 - reach * dirs[k, 0], x1 - reach * dirs[k, 1])
        if not (np.isfinite(px) and np.isfinite(py) and 0 <= px <= w - 1
                and 0 <= py <= h - 1):
            return False
        gx, gy = (px + 0.5) / cell - 0.5, (py + 0.5) / cell - 0.5
        col = min(max(int(np.rint(gx)), 0), top.shape[0] - 1)
        row = min(max(int(np.rint(gy)), 0), other_mean.shape[0] - 1)
        if gy - top[col] < edge_margin or other_mean[row, col] > 0.5:
            return False
        if _remap_sample(green, gx, gy) < t_green:
            return False
    return True


@njit(cache=True, nogil=True)
def _remap_sample(image, x, y):
    """An image sampled bilinearly at one point (bilinear_at, pixels outside the image 0)."""
    return bilinear_at(image, x, y, 0.0)
