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
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

COST_CAP = 60.0  # exp(-60) ~ 1e-26, far below any uniform floor
BIG = 1e6  # cost of an excluded association
TABLE_L = 0  # the point row's table: an L (the T table's offset is 4 cells > 0)

# columns of the point rows and the line rows
P_D, P_CB, P_SB, P_CO, P_SO, P_WD, P_FLOOR, P_TABLE, P_AS_T, P_PEN, P_C0, P_C1 = range(12)
N_POINT_COLS = 12
L_R, L_CA, L_SA, L_WD, L_FLOOR, L_MX, L_MY, L_HM, L_RATIO, L_H2, L_WE, L_EXT = range(12)
N_LINE_COLS = 12


class Poses(NamedTuple):
    """N poses: positions ``x``, ``y`` and the cosine and sine of the heading, (N,) each."""

    x: np.ndarray
    y: np.ndarray
    cth: np.ndarray
    sth: np.ndarray


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
    ``out`` (3, N) (row ``part[k]``), against ``fp`` (FieldPoints); ``weights``: (w_b, w_o),
    1 / sigma_b^2 and 1 / sigma_o^2 (0: no orientation term)."""
    x, y, cth, sth = poses
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
    (3, N) (row 0), against ``fl`` (FieldLines); ``rule``: (tol2, w_a, margin), the squared
    tolerance of eq. 5, the angle's weight and the arcs' extent margin."""
    x, y, cth, sth = poses
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
