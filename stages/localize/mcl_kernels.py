"""The numba kernel of mcl's observation model (observation_model.py): one frame's
log-likelihood at N poses in one pass, compiled once, cached on disk.

The equations are observation_model's (its module doc); tests/oracles/observation_model.py
writes them out as array passes, and tests/test_mcl.py holds this kernel against it.
Why a kernel: with ~1000 particles and ~8 observations numpy's time went to some 300 calls on
small temporaries (the pose transform of every observation, the cell and table look-ups, each
alternative of a crossing's type evaluated as its own array pass), not to arithmetic. Here
each particle's rotation is computed once, and every (observation, particle) pair evaluates its
alternatives (an L as itself, as a T's corner, as an X; the candidates of an X or a post; a
line's field lines of its direction and the arcs) in registers, keeping the least cost.

Point observations (crossings and posts) are rows of ``pts`` (K, 12)::

    d, cos b, sin b, cos o, sin o, w_d, a_uni, table, as_t, penalty, cand_start, cand_end

``table``: -1 none, ``TABLE_L`` an L (the quadrant of its global orientation picks one of
the four L tables), else the offset of its table in ``lut`` (the T table's);
``as_t`` >= 0: also an L at the T table at that offset (an arm unseen) with ``penalty``;
``cand_start:cand_end``: candidates (rows of ``cand`` (M, 6): x, y, cos 4o, sin 4o, w_o,
sign), with ``penalty`` when the row is also in a table (the confusion's cost), 0 otherwise.
``part`` (K,) says which sum (1 crossings, 2 posts) an observation adds to.

Lines are rows of ``lines`` (L, 12)::

    r, cos a, sin a, w_d, a_uni, mx, my, hm, ratio, h2, w_e, has_extent

The kernels take the poses (``Poses``), the field as the observations are scored against it
(``FieldPoints``, ``FieldLines``) and the model's weights as a tuple of scalars.

``unseen_log_likelihood`` is the "unseen" term (observation_model's module doc): per pose, the
length of field line inside the frame's view (``View``) within its range, from the field's
line samples, and the binomial log-probability of the line pieces seen among them. A line is
stepped only where it crosses the view's convex hull (``ViewArea.planes``): a camera sees
some sixty degrees around the robot, and the pieces outside cannot be in view.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..common.jit import njit

COST_CAP = 60.0  # exp(-60) ~ 1e-26, far below any uniform floor
BIG = 1e6  # cost of an excluded association
TABLE_L = 0  # the point row's table: an L (the T table's offset is 4 cells > 0)

# columns of the point rows and the line rows
P_D, P_CB, P_SB, P_CO, P_SO, P_WD, P_FLOOR, P_TABLE, P_AS_T, P_PEN, P_C0, P_C1 = range(12)
N_POINT_COLS = 12
L_R, L_CA, L_SA, L_WD, L_FLOOR, L_MX, L_MY, L_HM, L_RATIO, L_H2, L_WE, L_EXT = range(12)
N_LINE_COLS = 12


class Poses(NamedTuple):
    """N poses: positions ``x``, ``y``, the cosine and sine of the heading and the heading
    ``th`` (rad, any turn), (N,) each."""

    x: np.ndarray
    y: np.ndarray
    cth: np.ndarray
    sth: np.ndarray
    th: np.ndarray


class FieldPoints(NamedTuple):
    """The field's point landmarks as the point observations are scored against them:
    ``cand`` (M, 6) the candidates (module doc), ``lut`` the crossing tables (flat, per cell
    the crossing's row in ``cross`` or -1), ``cross`` (C, 4) crossing x, y, cos and sin of
    its orientation, ``grid`` the tables' grid: origin x, y, 1 / resolution, nx, ny."""

    cand: np.ndarray
    lut: np.ndarray
    cross: np.ndarray
    grid: np.ndarray


class FieldLines(NamedTuple):
    """The field's lines as the line observations are scored against them: the straight
    lines by direction, ``normals`` and ``tangents`` (G, 2), ``seg`` (S, 3) offset, first and
    last position along the direction, group g's rows ``group_start[g]:group_start[g + 1]``;
    ``arcs`` (A, 5) cx, cy, r, a0, sweep."""

    normals: np.ndarray
    tangents: np.ndarray
    seg: np.ndarray
    group_start: np.ndarray
    arcs: np.ndarray


class ViewArea(NamedTuple):
    """Where one frame saw the floor, about the robot: ``mask`` (n, n) uint8, 1 where the
    image saw the floor, on square cells of 1 / ``inv_cell`` m covering [-r, r]^2 (row: y,
    column: x); ``planes`` (H, 3) half-planes nx u + ny v <= d (m, robot frame) whose
    intersection holds every set cell (edges of the set cells' convex hull, grown:
    view_planes; H = 0: no bound). The kernel steps a line only where it crosses them: a
    camera sees some sixty degrees of the circle, and stepping the rest found nothing."""

    mask: np.ndarray
    r: float
    inv_cell: float
    planes: np.ndarray


class View(NamedTuple):
    """One frame's view for the unseen term (observation_model's module doc): its ``area``
    (ViewArea); the pieces of line ``seen`` and a piece's length (1 / ``inv_piece``); log(1 -
    q) of the detection probability q; the binomial's ``peak`` log-probability and the term's
    ``floor``; the poses' bins (``bin_xy`` m, ``bin_heading`` rad)."""

    area: ViewArea
    seen: float
    inv_piece: float
    log_miss: float
    peak: float
    floor: float
    bin_xy: float
    bin_heading: float


# columns of LineSamples.groups: bounding box, first piece and count, straight (1) or arc
# (0), a straight line's start and unit direction, the pieces' length
G_X0, G_Y0, G_X1, G_Y1, G_START, G_COUNT, G_STRAIGHT, G_AX, G_AY, G_UX, G_UY, G_PIECE = range(12)
N_SAMPLE_GROUP_COLS = 12


class LineSamples(NamedTuple):
    """The field's lines cut into short pieces for the unseen term: ``points`` (M, 3) each
    piece's middle x, y and its length; ``groups`` (G, 12) per line or arc (G_* columns)."""

    points: np.ndarray
    groups: np.ndarray


@njit(cache=True, nogil=True, inline="always")
def _clip(qx, qy, du, dv, planes, lo, hi):
    """The part [lo, hi] of the line (qx, qy) + t (du, dv) (robot frame) inside ``planes``
    (ViewArea); lo > hi when it misses them."""
    for h in range(planes.shape[0]):
        a = planes[h, 0] * qx + planes[h, 1] * qy - planes[h, 2]
        b = planes[h, 0] * du + planes[h, 1] * dv
        if b > 1e-12:
            hi = min(hi, -a / b)
        elif b < -1e-12:
            lo = max(lo, -a / b)
        elif a > 0.0:
            return 1.0, 0.0
    return lo, hi


@njit(cache=True, nogil=True, inline="always")
def _in_view(u, v, area):
    """Whether the point (u, v) (m, robot frame) lies in a set cell of ``area``'s mask."""
    mask, r, inv_cell, _ = area
    ix, iy = int((u + r) * inv_cell), int((v + r) * inv_cell)
    return 0 <= ix < mask.shape[1] and 0 <= iy < mask.shape[0] and mask[iy, ix] != 0


@njit(cache=True, nogil=True, inline="always")
def _straight_in_view(line, c, s, area):
    """Length (m) of a straight line's pieces whose middle lies in ``area`` (ViewArea)
    within its r of the robot: ``line`` (wx, wy, ux, uy, piece, count) its start from the
    robot and unit direction (field frame), its pieces' length and count; c, s the robot's
    heading. The pieces within r and the area's planes are found by cutting the line with
    the circle and the planes, and stepped."""
    wx, wy, ux, uy, piece, count = line
    r, planes = area.r, area.planes
    wu = wx * ux + wy * uy
    disc = wu * wu - (wx * wx + wy * wy - r * r)
    if disc <= 0.0:
        return 0.0
    root = math.sqrt(disc)
    # the line's start and direction in the robot frame, cut with the planes
    qx, qy = c * wx + s * wy, c * wy - s * wx
    eu, ev = c * ux + s * uy, c * uy - s * ux
    lo, hi = _clip(qx, qy, eu, ev, planes, -wu - root, -wu + root)
    if lo > hi:
        return 0.0
    j0 = max(0, int(math.ceil(lo / piece - 0.5 - 1e-9)))
    j1 = min(count, int(math.floor(hi / piece - 0.5 + 1e-9)) + 1)
    # the first piece's middle and the step between pieces, in the robot frame
    t = (j0 + 0.5) * piece
    u, v = qx + t * eu, qy + t * ev
    du, dv = eu * piece, ev * piece
    length = 0.0
    for _ in range(j0, j1):
        if _in_view(u, v, area):
            length += piece
        u += du
        v += dv
    return length


@njit(cache=True, nogil=True)
def segments_in_view(ends, spacing, area):
    """Length (m) of the segments ``ends`` (L, 4: x0, y0, x1, y1, robot frame) inside the
    view ``area`` (ViewArea) within its r of the robot, each cut into equal pieces at most
    ``spacing`` long (a frame's lines, as line_in_view counts the field's)."""
    length = 0.0
    for k in range(ends.shape[0]):
        dx, dy = ends[k, 2] - ends[k, 0], ends[k, 3] - ends[k, 1]
        size = math.sqrt(dx * dx + dy * dy)
        count = max(1, int(math.ceil(size / spacing)))
        inv = 1.0 / max(size, 1e-12)
        length += _straight_in_view((ends[k, 0], ends[k, 1], dx * inv, dy * inv,
                                     size / count, count), 1.0, 0.0, area)
    return length


@njit(cache=True, nogil=True)
def view_planes(mask, r, cell, grow, most):
    """The half-planes (H, 3) nx u + ny v <= d of ``mask``'s set cells' convex hull (cells
    of ``cell`` m over [-r, r]^2, row y, column x), grown by ``grow`` m: the hull of each
    row's first and last set cell's middle (Andrew's monotone chain; the rows come sorted),
    its ``most`` longest edges' (fewer planes bound the cells too, and cutting a line with
    each costs more than the few pieces more it steps). One plane nothing lies in when no
    cell is set; a point's or a line's box when the hull has no area."""
    n = mask.shape[0]
    pts = np.empty((2 * n, 2))
    m = 0
    for iy in range(n):
        first = -1
        last = -1
        for ix in range(mask.shape[1]):
            if mask[iy, ix]:
                if first < 0:
                    first = ix
                last = ix
        if first >= 0:
            pts[m, 0], pts[m, 1] = (first + 0.5) * cell - r, (iy + 0.5) * cell - r
            m += 1
            if last > first:
                pts[m, 0], pts[m, 1] = (last + 0.5) * cell - r, (iy + 0.5) * cell - r
                m += 1
    if m == 0:
        out = np.zeros((1, 3))
        out[0, 2] = -1e9
        return out
    # the points are sorted by (y, x): the two chains of the hull
    hull = np.empty((2 * m + 1, 2))
    h = 0
    for k in range(m):
        while h >= 2 and _turn(hull[h - 2], hull[h - 1], pts[k]) <= 0.0:
            h -= 1
        hull[h] = pts[k]
        h += 1
    low = h + 1
    for k in range(m - 2, -1, -1):
        while h >= low and _turn(hull[h - 2], hull[h - 1], pts[k]) <= 0.0:
            h -= 1
        hull[h] = pts[k]
        h += 1
    h -= 1  # the last point is the first
    if h < 3:  # no area: the box of the points
        out = np.empty((4, 3))
        x0, x1 = pts[:m, 0].min(), pts[:m, 0].max()
        y0, y1 = pts[:m, 1].min(), pts[:m, 1].max()
        out[0, 0], out[0, 1], out[0, 2] = 1.0, 0.0, x1 + grow
        out[1, 0], out[1, 1], out[1, 2] = -1.0, 0.0, -x0 + grow
        out[2, 0], out[2, 1], out[2, 2] = 0.0, 1.0, y1 + grow
        out[3, 0], out[3, 1], out[3, 2] = 0.0, -1.0, -y0 + grow
        return out
    area = 0.0
    for k in range(h):
        area += hull[k, 0] * hull[k + 1, 1] - hull[k + 1, 0] * hull[k, 1]
    turn = 1.0 if area > 0.0 else -1.0  # counter-clockwise: the edge turned right
    out = np.empty((h, 3))
    sizes = np.empty(h)
    for k in range(h):  # the outward normals
        ex, ey = hull[k + 1, 0] - hull[k, 0], hull[k + 1, 1] - hull[k, 1]
        size = math.sqrt(ex * ex + ey * ey)
        nx, ny = turn * ey / size, -turn * ex / size
        out[k, 0], out[k, 1] = nx, ny
        out[k, 2] = nx * hull[k, 0] + ny * hull[k, 1] + grow
        sizes[k] = size
    return out[np.argsort(-sizes)[:most]]


@njit(cache=True, nogil=True, inline="always")
def _turn(a, b, p):
    """> 0 when a -> b -> p turns left (counter-clockwise)."""
    return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])


@njit(cache=True, nogil=True)
def line_in_view(pose, samples, area):
    """Length (m) of the field's lines (``samples``: LineSamples) inside the view ``area``
    (ViewArea) within its r of the pose (x, y, heading cos c, sin s), from the pieces'
    middles. A line's pieces within r and the area's planes are found by cutting it with the
    circle and the planes, an arc's by testing each (an arc outside a plane is skipped)."""
    px, py, c, s = pose
    pts, groups = samples
    r, planes = area.r, area.planes
    r2 = r * r
    length = 0.0
    for g in range(groups.shape[0]):
        row = groups[g]
        if (row[G_X0] > px + r or row[G_X1] < px - r or row[G_Y0] > py + r
                or row[G_Y1] < py - r):
            continue
        k0 = int(row[G_START])
        k1 = k0 + int(row[G_COUNT])
        piece = row[G_PIECE]
        if row[G_STRAIGHT] > 0.0:
            length += _straight_in_view(
                (row[G_AX] - px, row[G_AY] - py, row[G_UX], row[G_UY], piece, k1 - k0),
                c, s, area)
            continue
        # an arc: (x, y) centre, its radius is half the box's width
        ax, ay = 0.5 * (row[G_X0] + row[G_X1]) - px, 0.5 * (row[G_Y0] + row[G_Y1]) - py
        au, av = c * ax + s * ay, c * ay - s * ax
        rad = 0.5 * (row[G_X1] - row[G_X0])
        outside = False
        for h in range(planes.shape[0]):
            if planes[h, 0] * au + planes[h, 1] * av - planes[h, 2] > rad:
                outside = True
                break
        if outside:
            continue
        for k in range(k0, k1):
            dx, dy = pts[k, 0] - px, pts[k, 1] - py
            u = c * dx + s * dy
            v = c * dy - s * dx
            if u * u + v * v <= r2 and _in_view(u, v, area):
                length += piece
    return length


@njit(cache=True, nogil=True)
def binomial_peak(seen, log_miss, step, count):
    """The largest log C(n, seen) + (n - seen) log(1 - q) (``log_miss``) over n = seen +
    k ``step``, k < ``count``. It is concave in n (the digamma's slope falls), so the first
    k where it stops rising is found by bisection."""
    lo, hi = 0, count - 1
    while lo < hi:
        k = (lo + hi) // 2
        n = seen + k * step
        rise = (math.lgamma(n + step + 1.0) - math.lgamma(n + step - seen + 1.0)
                - math.lgamma(n + 1.0) + math.lgamma(n - seen + 1.0) + step * log_miss)
        if rise > 0.0:
            lo = k + 1
        else:
            hi = k
    n = seen + lo * step
    return math.lgamma(n + 1.0) - math.lgamma(n - seen + 1.0) + (n - seen) * log_miss


@njit(cache=True, nogil=True)
def unseen_log_likelihood(out, poses, samples, view):
    """Add the unseen term at every pose (``poses``: Poses) to ``out`` (4, N) (row 3):
    ``samples``: LineSamples; ``view``: View. The pieces a pose should see, n = max(length
    in view / piece, seen), score the binomial's log C(n, seen) + (n - seen) log(1 - q) (less
    what does not depend on n); the term is log(floor + (1 - floor) exp(that - its peak)).

    The term is evaluated at the centre of each pose's bin (``view.bin_xy``,
    ``view.bin_heading``), once per bin the poses occupy: it changes in steps of a piece
    anyway, and a tracked belief's particles share a few dozen bins. The bins are found in
    a hash table (open addressing, Fibonacci hashing): a sort of the poses' keys cost more
    than the few bins of a tracked belief."""
    x, y, th = poses.x, poses.y, poses.th
    bin_xy, bin_th = view.bin_xy, view.bin_heading
    n_poses = x.shape[0]
    turns = int(math.ceil(2.0 * math.pi / bin_th))
    bits = 4
    while (1 << bits) < 2 * n_poses:
        bits += 1
    slot_key = np.full(1 << bits, -1, np.int64)
    slot_term = np.empty(1 << bits)
    last = np.int64((1 << bits) - 1)
    shift = np.uint64(64 - bits)
    acc = out[3]
    for i in range(n_poses):
        jx = int(math.floor(x[i] / bin_xy)) + (1 << 20)
        jy = int(math.floor(y[i] / bin_xy)) + (1 << 20)
        turn = th[i] - 2.0 * math.pi * math.floor((th[i] + math.pi) / (2.0 * math.pi))
        jt = int(math.floor((turn + math.pi) / bin_th)) % turns
        key = (jx * (1 << 21) + jy) * 1024 + jt
        h = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> shift)
        while slot_key[h] >= 0 and slot_key[h] != key:
            h = (h + np.int64(1)) & last
        if slot_key[h] < 0:
            head = (jt + 0.5) * bin_th - math.pi
            length = line_in_view(((jx - (1 << 20) + 0.5) * bin_xy,
                                   (jy - (1 << 20) + 0.5) * bin_xy,
                                   math.cos(head), math.sin(head)), samples, view.area)
            slot_key[h] = key
            slot_term[h] = _unseen_term(length, view)
        acc[i] += slot_term[h]


@njit(cache=True, nogil=True, inline="always")
def _unseen_term(length, view):
    """The unseen term of ``length`` m of field line in ``view`` (unseen_log_likelihood)."""
    seen = view.seen
    n = max(length * view.inv_piece, seen)
    ll = math.lgamma(n + 1.0) - math.lgamma(n - seen + 1.0) + (n - seen) * view.log_miss
    return math.log(view.floor + (1.0 - view.floor) * math.exp(min(ll - view.peak, 0.0)))


@njit(cache=True, nogil=True, inline="always")
def _mixture(cost, a_uni, log_floor):
    """log(a_uni + (1 - a_uni) exp(-cost)), ``log_floor`` (log(a_uni)) where the cost is
    capped (exp(-cost) then no longer counts)."""
    if cost >= COST_CAP:
        return log_floor
    return math.log(a_uni + (1.0 - a_uni) * math.exp(-cost))


@njit(cache=True, nogil=True, inline="always")
def _point(vx, vy, ux, uy, d_o, w_d, w_b):
    """Eq. 3 with the landmark at (vx, vy) from the particle, the bearing error as
    2 (1 - cos)."""
    d_e = math.sqrt(vx * vx + vy * vy)
    cos_b = (ux * vx + uy * vy) / max(d_e, 1e-9)
    e = d_e - d_o
    return e * e * w_d + (1.0 - cos_b) * w_b


@njit(cache=True, nogil=True)
def _table(fp, idx, at, d_o, w_d, weights, l_at_t):
    """Eq. 3 and the orientation term at the crossing the table holds at ``idx`` (the cap
    when it holds none): ``at`` (x, y, ux, uy, gx, gy) the particle's position, the
    observation's bearing and its orientation in the field frame, ``weights`` (w_b, w_o);
    ``l_at_t``: an L at a T, its bisector 45 deg from the stem."""
    x, y, ux, uy, gx, gy = at
    w_b, w_o = weights
    cross = fp.cross
    k = fp.lut[idx]
    if k < 0:
        return COST_CAP
    cost = _point(cross[k, 0] - x, cross[k, 1] - y, ux, uy, d_o, w_d, w_b)
    if w_o > 0.0:
        ci, si = cross[k, 2], cross[k, 3]
        cos_o = ci * gx + si * gy
        if l_at_t:
            cos_o = (cos_o + abs(ci * gy - si * gx)) * math.sqrt(0.5)
        cost += (1.0 - cos_o) * w_o
    return cost


@njit(cache=True, nogil=True)
def point_log_likelihood(out, poses, pts, part, fp, weights):
    """Add each point observation's log-likelihood at every pose (``poses``: Poses) to
    ``out`` (4, N) (row ``part[k]``), against ``fp`` (FieldPoints); ``weights``: (w_b, w_o),
    1 / sigma_b^2 and 1 / sigma_o^2 (0: no orientation term)."""
    x, y, cth, sth = poses.x, poses.y, poses.cth, poses.sth
    cand, grid = fp.cand, fp.grid
    w_b = weights[0]
    n = x.shape[0]
    ox, oy, inv_res = grid[0], grid[1], grid[2]
    nx, ny = int(grid[3]), int(grid[4])
    cells = nx * ny
    for k in range(pts.shape[0]):  # one observation's constants, then every pose
        row = pts[k]
        d_o, w_d, a_uni, pen = row[P_D], row[P_WD], row[P_FLOOR], row[P_PEN]
        log_floor = math.log(a_uni + (1.0 - a_uni) * math.exp(-COST_CAP))
        cb, sb, co, so = row[P_CB], row[P_SB], row[P_CO], row[P_SO]
        table, as_t = int(row[P_TABLE]), int(row[P_AS_T])
        c0, c1 = int(row[P_C0]), int(row[P_C1])
        cand_pen = pen if table >= 0 else 0.0
        x_term = c1 > c0 and cand[c0, 4] > 0.0
        acc = out[part[k]]
        for i in range(n):
            px, py, c, s = x[i], y[i], cth[i], sth[i]
            ux = cb * c - sb * s
            uy = cb * s + sb * c
            gx = co * c - so * s
            gy = co * s + so * c
            cost = BIG
            if table >= 0 or as_t >= 0:  # the cell where the particle places the point
                j = min(max(int((px + d_o * ux - ox) * inv_res + 0.5), 0), nx - 1)
                ii = min(max(int((py + d_o * uy - oy) * inv_res + 0.5), 0), ny - 1)
                cell = ii * nx + j
                if table >= 0:
                    off = table
                    if table == TABLE_L:  # L: the quadrant of its global orientation picks the set
                        below = gy < 0.0
                        off = (2 * int(below) + int(below != (gx < 0.0))) * cells
                    cost = _table(fp, off + cell, (px, py, ux, uy, gx, gy), d_o, w_d,
                                  weights, False)
                # an alternative costs at least its penalty: none can do better than a type
                # that costs less
                if as_t >= 0 and cost > pen:
                    alt = _table(fp, as_t + cell, (px, py, ux, uy, gx, gy), d_o, w_d,
                                 weights, True) + pen
                    cost = min(cost, alt)
            if c1 > c0 and cost > cand_pen:
                c4 = s4 = 0.0
                if x_term:  # X orientation modulo 90 deg
                    c2, s2 = gx * gx - gy * gy, 2.0 * gx * gy
                    c4, s4 = c2 * c2 - s2 * s2, 2.0 * c2 * s2
                best = BIG
                for m in range(c0, c1):
                    vx, vy = cand[m, 0] - px, cand[m, 1] - py
                    d_e = math.sqrt(vx * vx + vy * vy)
                    e = (d_e - d_o) * (d_e - d_o) * w_d
                    if e >= best:  # its range term alone costs more than the best so far
                        continue
                    e += (1.0 - (ux * vx + uy * vy) / max(d_e, 1e-9)) * w_b
                    if cand[m, 4] > 0.0:
                        e += (1.0 - (cand[m, 2] * c4 + cand[m, 3] * s4) * cand[m, 5]) * cand[m, 4]
                    best = min(best, e)
                cost = min(cost, best + cand_pen)
            acc[i] += _mixture(cost, a_uni, log_floor)


@njit(cache=True, nogil=True)
def line_log_likelihood(out, poses, lines, fl, rule):
    """Add each line observation's log-likelihood at every pose (``poses``: Poses) to ``out``
    (4, N) (row 0), against ``fl`` (FieldLines); ``rule``: (tol2, w_a, margin), the squared
    tolerance of eq. 5, the angle's weight and the arcs' extent margin."""
    x, y, cth, sth = poses.x, poses.y, poses.cth, poses.sth
    normals, tangents, seg, group_start, arcs = fl
    tol2, w_a, margin = rule
    n = x.shape[0]
    n_g = normals.shape[0]
    two_pi = 2.0 * math.pi
    acc = out[0]
    for k in range(lines.shape[0]):  # one observation's constants, then every pose
        row = lines[k]
        r, w_d, a_uni = row[L_R], row[L_WD], row[L_FLOOR]
        log_floor = math.log(a_uni + (1.0 - a_uni) * math.exp(-COST_CAP))
        ca, sa, omx, omy = row[L_CA], row[L_SA], row[L_MX], row[L_MY]
        hm, ratio = row[L_HM], row[L_RATIO]
        extent = row[L_EXT] > 0.0
        arc_dev = row[L_H2]
        w_e = row[L_WE]
        for i in range(n):
            px, py, c, s = x[i], y[i], cth[i], sth[i]
            ux = ca * c - sa * s
            uy = ca * s + sa * c
            # the observed segment's middle in the field frame
            mx = px + omx * c - omy * s
            my = py + omx * s + omy * c
            fx, fy = px + r * ux, py + r * uy  # the perpendicular's foot
            # the field direction the observation is most nearly parallel to
            g, top = 0, -1.0
            for h in range(n_g):
                a = abs(normals[h, 0] * ux + normals[h, 1] * uy)
                if a > top:
                    g, top = h, a
            best = BIG
            if n_g:
                nx_, ny_ = normals[g, 0], normals[g, 1]
                tx, ty = tangents[g, 0], tangents[g, 1]
                cos_d = nx_ * ux + ny_ * uy
                rc = r * cos_d
                pn = (px * nx_ + py * ny_) * rc - tol2
                q = fx * nx_ + fy * ny_
                t = mx * tx + my * ty
                least = BIG
                for m in range(group_start[g], group_start[g + 1]):
                    off = seg[m, 0]
                    if off * rc <= pn:  # eq. 5: behind the robot
                        continue
                    e = off - q
                    cost = e * e
                    if extent:
                        over = max((t + hm) - seg[m, 2], seg[m, 1] - (t - hm), 0.0)
                        cost += over * over * ratio
                    least = min(least, cost)
                best = least * w_d + (1.0 - cos_d * cos_d) * (r * r * w_d + w_a)
            for a in range(arcs.shape[0]):  # the arcs' tangents
                cx, cy, rad, a0, sweep = arcs[a, 0], arcs[a, 1], arcs[a, 2], arcs[a, 3], arcs[a, 4]
                qx, qy = (mx, my) if extent else (fx, fy)
                vx, vy = qx - cx, qy - cy
                dist = math.sqrt(vx * vx + vy * vy)
                if not abs(dist - rad) < 1.0:
                    continue
                if sweep < two_pi - 1e-9:  # the nearest point clamped to the arc's ends
                    rel = (math.atan2(vy, vx) - a0) % two_pi
                    if rel > sweep:
                        rel = sweep if rel - sweep < two_pi - rel else 0.0
                    anx, any_ = math.cos(a0 + rel), math.sin(a0 + rel)
                else:
                    dist = max(dist, 1e-9)
                    anx, any_ = vx / dist, vy / dist
                e = (rad + cx * anx + cy * any_) - (px * anx + py * any_)
                cos_d = ux * anx + uy * any_
                rc = r * cos_d
                if e * rc <= -tol2:
                    continue
                cost = (e - rc) ** 2 * w_d + (1.0 - cos_d * cos_d) * (r * r * w_d + w_a)
                if extent:  # a straight segment of half length h departs h^2 / 2r
                    dev = max(arc_dev / rad - margin, 0.0)
                    cost += dev * dev * w_e
                best = min(best, cost)
            acc[i] += _mixture(best, a_uni, log_floor)


def empty_rows(cols: int) -> np.ndarray:
    return np.zeros((0, cols))


# ---------------------------------------------------------------------- a frame's rows
# The rows of a frame's observations (observation_model.prepare): a few dozen numbers per
# frame, which numpy built in some 150 calls on arrays of four elements (0.2 ms, a fifth of a
# tracked update); here in one pass.

@njit(cache=True, nogil=True, inline="always")
def _range_sigma(d, base, elevation, h):
    """observation_model.ObservationModel.range_sigma of one distance."""
    grow = elevation * (h * h + d * d) / h
    return math.sqrt(base * base + grow * grow)


@njit(cache=True, nogil=True, inline="always")
def _uniform_share(confidence, base):
    """a_uni of section 5.3 for an observation of ``confidence`` (clipped to [0, 1])."""
    c = min(max(confidence, 0.0), 1.0)
    return base + (1.0 - base) * (1.0 - c)


@njit(cache=True, nogil=True)
def line_rows(lines, d_o, ends, weights):
    """The rows (L, N_LINE_COLS) of usable lines ``lines`` (L, 4: r, alpha, length,
    confidence), their closest distances ``d_o`` (L,) and ``ends`` (L, 4; 0 rows: none).
    ``weights``: camera height, elevation sigma, sigma_line, sigma_extent, extent_margin,
    uniform_floor, and 1.0 to charge a segment's extent (0.0 not)."""
    h, elevation, s_line, s_extent, margin, floor, extent = weights
    n = lines.shape[0]
    rows = np.zeros((n, N_LINE_COLS))
    with_ends = extent != 0.0 and ends.shape[0] == n
    for i in range(n):
        r = lines[i, 0]
        a = lines[i, 1] + (math.pi if r < 0 else 0.0)
        s = _range_sigma(d_o[i], s_line, elevation, h)
        w_d = 1.0 / (2.0 * s * s)
        rows[i, L_R] = abs(r)
        rows[i, L_CA], rows[i, L_SA] = math.cos(a), math.sin(a)
        rows[i, L_WD] = w_d
        rows[i, L_FLOOR] = _uniform_share(lines[i, 3], floor)
        if with_ends:
            x0, y0, x1, y1 = ends[i, 0], ends[i, 1], ends[i, 2], ends[i, 3]
            half = 0.5 * math.hypot(x1 - x0, y1 - y0)
            far = max(math.hypot(x0, y0), math.hypot(x1, y1))
            s = _range_sigma(far, s_extent, elevation, h)
            w_e = 1.0 / (2.0 * s * s)
            rows[i, L_MX] = 0.5 * (x0 + x1)
            rows[i, L_MY] = 0.5 * (y0 + y1)
            rows[i, L_HM] = half - margin
            rows[i, L_RATIO] = w_e / w_d
            rows[i, L_H2] = half * half / 2.0
            rows[i, L_WE] = w_e
            rows[i, L_EXT] = 1.0
    return rows


@njit(cache=True, nogil=True)
def point_rows(crossings, posts, tables, weights):
    """The rows (K, N_POINT_COLS) and sums ``part`` (K,) of usable crossings (K_c, 5: type
    0 L / 1 T / 2 X, distance, bearing, orientation, confidence) and goal posts (K_p, 3:
    distance, bearing, confidence), crossings first (the module doc's row layout).
    ``tables``: the T table's offset in ``lut``, 1.0 if the field has T crossings to take an
    L as a T's corner, and the candidate ranges (start, end) of the X crossings as an L's,
    as a T's or X's, and of the goal posts. ``weights``: camera height, the elevation sigma
    of crossings and of posts, sigma_range, uniform_floor, the posts' uniform floor and the
    crossing-type confusion probability."""
    t_offset, t_table, xl0, xl1, xt0, xt1, p0, p1 = tables
    h, elevation, post_elevation, s_range, floor, post_floor, p_conf = weights
    k_c, k_p = crossings.shape[0], posts.shape[0]
    rows = np.zeros((k_c + k_p, N_POINT_COLS))
    part = np.empty(k_c + k_p, np.int64)
    penalty = -math.log(min(p_conf, 1.0)) if p_conf > 0 else 0.0
    for i in range(k_c + k_p):
        row = rows[i]
        row[P_TABLE] = -1.0
        row[P_AS_T] = -1.0
        if i < k_c:
            kind, d, b, o = crossings[i, 0], crossings[i, 1], crossings[i, 2], crossings[i, 3]
            s = _range_sigma(d, s_range, elevation, h)
            row[P_FLOOR] = _uniform_share(crossings[i, 4], floor)
            part[i] = 1
            if p_conf > 0:
                row[P_PEN] = penalty
            if kind == 2.0:
                row[P_C0], row[P_C1] = xt0, xt1
            elif p_conf > 0:
                if kind == 0.0:
                    row[P_C0], row[P_C1] = xl0, xl1
                    if t_table != 0.0:
                        row[P_AS_T] = t_offset
                else:
                    row[P_C0], row[P_C1] = xt0, xt1
            if kind == 0.0:
                row[P_TABLE] = TABLE_L
            elif kind == 1.0:
                row[P_TABLE] = t_offset
        else:
            j = i - k_c
            d, b, o = posts[j, 0], posts[j, 1], 0.0
            s = _range_sigma(d, s_range, post_elevation, h)
            row[P_FLOOR] = _uniform_share(posts[j, 2], post_floor)
            row[P_C0], row[P_C1] = p0, p1
            part[i] = 2
        row[P_D] = d
        row[P_CB], row[P_SB] = math.cos(b), math.sin(b)
        row[P_CO], row[P_SO] = math.cos(o), math.sin(o)
        row[P_WD] = 1.0 / (2.0 * s * s)
    return rows, part
