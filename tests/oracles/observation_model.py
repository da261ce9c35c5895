"""Oracle of the particle filter's observation model (stages.localize.observation_model, whose
module doc states the equations; Schulz et al. (2011), section 5): the log-likelihood of a frame's
observations at N poses, written as the equations, in float64, one observation at a time with
the poses on the last axis and every landmark it may be associated with on the first.

It differs from the compiled kernel (stages.localize.mcl_kernels) only where the kernel prunes
work whose effect is below rounding:

- a line is compared with every straight field line and arc, not only with the lines of the
  direction it is most nearly parallel to (any other direction costs at least
  sin^2(45 deg) / (2 sigma_psi^2) ~ 39, exp(-39) ~ 1e-17 next to a floor >= 0.1);
- every alternative of a crossing's type is evaluated, not only those that can still win.

What it takes from the model: the conf, ``range_sigma`` (one line of arithmetic), the usable
observations (``usable``: which rows count is a decision, not arithmetic) and the crossing
association tables (``lut``, ``grid``: the map's, built by stages.common.crossing_tables).
"""

from __future__ import annotations

import math

import numpy as np

COST_CAP = 60.0  # exp(-60): the model caps costs there (log_floor is then the likelihood)


def mixture(cost, a_uni):
    """Section 5.3: log(a_uni + (1 - a_uni) exp(-cost)), the cost capped at COST_CAP."""
    return np.log(a_uni + (1.0 - a_uni) * np.exp(-np.minimum(cost, COST_CAP)))


def uniform_share(confidence, base):
    """a_uni = a_base + (1 - a_base) (1 - confidence), the confidence clipped to [0, 1]."""
    return base + (1.0 - base) * (1.0 - np.clip(confidence, 0.0, 1.0))


def rotate(c, s, cth, sth):
    """The robot-frame unit vector (c, s) in the field frame at headings (cth, sth) (N,)."""
    return c * cth - s * sth, c * sth + s * cth


def point_cost(lx, ly, x, y, ux, uy, d_o, w_d, w_b):
    """Eq. 3 for a landmark at (lx, ly): range error weighted by w_d, bearing error as
    2 (1 - cos) weighted by w_b = 1 / sigma_phi^2."""
    vx, vy = lx - x, ly - y
    d_e = np.hypot(vx, vy)
    cos_b = (ux * vx + uy * vy) / np.maximum(d_e, 1e-9)
    return (d_e - d_o) ** 2 * w_d + (1.0 - cos_b) * w_b


def line_cost(nx, ny, offset, x, y, ux, uy, r, w_d, w_a, tol2):
    """Eqs. 4-5 against the straight line {p : n . p = offset}: the expected perpendicular
    l_e = e n (e = offset - n . pose), the observed l_o = r u; infinite (None's BIG) when
    <l_e, l_o> <= -tol^2 (the line is behind the robot)."""
    e = offset - (nx * x + ny * y)
    cos_d = nx * ux + ny * uy
    dist2 = (e * nx - r * ux) ** 2 + (e * ny - r * uy) ** 2  # |l_e - l_o|^2
    cost = dist2 * w_d + (1.0 - cos_d ** 2) * w_a  # sin^2 of the direction error
    return np.where(e * r * cos_d <= -tol2, np.inf, cost)


def log_likelihood(model, x, y, theta, obs) -> dict:
    """Log-likelihood parts ("lines", "crossings", "posts"), each (N,), of ``obs`` at the
    poses (x, y, theta) by ``model``'s (an ObservationModel) field, tables and conf."""
    c = {**model.conf, **model.tuning._asdict()}
    fm = model.field
    x, y, theta = (np.asarray(v, float).ravel() for v in (x, y, theta))
    cth, sth = np.cos(theta), np.sin(theta)
    obs = model.usable(obs)
    out = {k: np.zeros(len(x)) for k in ("lines", "crossings", "posts")}

    # ---- lines
    w_a = 1.0 / (2.0 * c["sigma_line_angle"] ** 2)
    tol2 = c["oriented_tolerance"] ** 2
    seg = np.asarray(fm.segments, float).reshape(-1, 2, 2)
    t = (seg[:, 1] - seg[:, 0]) / np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)[:, None]
    n = np.stack([-t[:, 1], t[:, 0]], axis=1)
    offset = np.sum(n * seg[:, 0], axis=1)
    along = np.sort(np.stack([np.sum(t * seg[:, 0], axis=1), np.sum(t * seg[:, 1], axis=1)],
                             axis=1), axis=1)
    arcs = np.asarray(fm.arcs, float).reshape(-1, 5) if c["arc_lines"] else np.zeros((0, 5))
    ends = obs.line_ends if c["line_extent"] else None
    for k, (r_raw, a_raw, _length, conf_k) in enumerate(obs.lines):
        r = abs(r_raw)
        a = a_raw + (math.pi if r_raw < 0 else 0.0)  # the perpendicular's direction
        ux, uy = rotate(math.cos(a), math.sin(a), cth, sth)
        fx, fy = x + r * ux, y + r * uy  # the perpendicular's foot
        if obs.line_ends is not None:
            e0, e1 = obs.line_ends[k, 0:2], obs.line_ends[k, 2:4]
            step = e1 - e0
            s = np.clip(-(e0 @ step) / max(step @ step, 1e-12), 0.0, 1.0)
            d_o = float(np.hypot(*(e0 + s * step)))  # the line's closest observed point
        else:
            d_o = r
        w_d = 1.0 / (2.0 * model.range_sigma(d_o, c["sigma_line"]) ** 2)
        costs = []
        if ends is not None:
            e0, e1 = ends[k, 0:2], ends[k, 2:4]
            half = 0.5 * float(np.hypot(*(e1 - e0)))
            far = max(np.hypot(*e0), np.hypot(*e1))
            w_e = 1.0 / (2.0 * model.range_sigma(far, c["sigma_extent"]) ** 2)
            mid_x, mid_y = 0.5 * (e0 + e1)
            mx = x + mid_x * cth - mid_y * sth  # the observed middle in the field frame
            my = y + mid_x * sth + mid_y * cth
        for i in range(len(seg)):
            cost = line_cost(n[i, 0], n[i, 1], offset[i], x, y, ux, uy, r, w_d, w_a, tol2)
            if ends is not None:  # the part beyond the segment's ends, less the margin
                tm = t[i, 0] * mx + t[i, 1] * my
                hm = half - c["extent_margin"]
                over = np.maximum.reduce([tm + hm - along[i, 1], along[i, 0] - (tm - hm),
                                          np.zeros_like(tm)])
                cost = cost + over ** 2 * w_e
            costs.append(cost)
        for cx, cy, rad, a0, sweep in arcs:  # the tangent at the arc point nearest to q
            qx, qy = (mx, my) if ends is not None else (fx, fy)
            vx, vy = qx - cx, qy - cy
            dist = np.hypot(vx, vy)
            if sweep < 2 * math.pi - 1e-9:
                rel = np.mod(np.arctan2(vy, vx) - a0, 2 * math.pi)
                past = rel > sweep  # outside the arc: its nearer end
                rel = np.where(past & (rel - sweep < 2 * math.pi - rel), sweep,
                               np.where(past, 0.0, rel))
                anx, any_ = np.cos(a0 + rel), np.sin(a0 + rel)
            else:
                anx, any_ = vx / np.maximum(dist, 1e-9), vy / np.maximum(dist, 1e-9)
            cost = line_cost(anx, any_, rad + cx * anx + cy * any_, x, y, ux, uy, r, w_d, w_a,
                             tol2)
            if ends is not None:  # a straight segment of half length h departs h^2 / 2r
                cost = cost + max(half * half / (2.0 * rad) - c["extent_margin"], 0.0) ** 2 * w_e
            costs.append(np.where(np.abs(dist - rad) < 1.0, cost, np.inf))  # within 1 m only
        best = np.min(costs, axis=0) if costs else np.full(len(x), np.inf)
        out["lines"] += mixture(best, uniform_share(conf_k, c["uniform_floor"]))

    # ---- crossings (L 0, T 1, X 2) and goal posts
    w_b = 1.0 / c["sigma_bearing"] ** 2
    so = c["sigma_crossing_orientation"]
    w_o = 1.0 / so ** 2 if so > 0 else 0.0
    w_x = 1.0 / (16.0 * so ** 2) if so > 0 else 0.0
    cross = np.asarray(fm.crossings, float).reshape(-1, 2)
    orient = np.asarray(fm.crossing_orientation, float)
    x_of_field = np.flatnonzero(np.asarray(fm.crossing_types) == "X")
    posts = np.asarray(fm.goal_posts, float).reshape(-1, 2)
    grid, lut = model.grid, model.lut
    ny, nx = grid.shape
    cells = nx * ny
    p_conf = float(c["crossing_type_confusion"])
    pen = -math.log(min(p_conf, 1.0)) if p_conf > 0 else np.inf

    def at_table(offset, px, py, ux, uy, gx, gy, d_o, w_d, l_at_t):
        """Eq. 3 and the orientation term at the crossing the table holds at offset + the
        cell where each pose places the point (the cap where it holds none)."""
        inv_res = 1.0 / grid.resolution  # the cell: a decision, computed as the model does
        j = np.clip(((px - grid.origin[0]) * inv_res + 0.5).astype(np.int64), 0, nx - 1)
        i = np.clip(((py - grid.origin[1]) * inv_res + 0.5).astype(np.int64), 0, ny - 1)
        idx = lut[offset + i * nx + j]
        held = np.maximum(idx, 0)
        cost = point_cost(cross[held, 0], cross[held, 1], x, y, ux, uy, d_o, w_d, w_b)
        ci, si = np.cos(orient[held]), np.sin(orient[held])
        cos_o = ci * gx + si * gy
        if l_at_t:  # an L at a T: its bisector lies 45 deg from the stem, on either side
            cos_o = (cos_o + np.abs(ci * gy - si * gx)) * math.sqrt(0.5)
        return np.where(idx < 0, COST_CAP, cost + (1.0 - cos_o) * w_o)

    def as_x(sign, ux, uy, gx, gy, d_o, w_d):
        """The least cost over the field's X crossings, the orientation modulo 90 deg (sign
        -1: the observed orientation lies halfway between two arms)."""
        four = 4.0 * np.arctan2(gy, gx)
        return np.min([point_cost(cross[m, 0], cross[m, 1], x, y, ux, uy, d_o, w_d, w_b)
                       + (1.0 - sign * np.cos(4.0 * orient[m] - four)) * w_x
                       for m in x_of_field], axis=0)

    for kind, d_o, b, o, conf_k in obs.crossings:
        if kind == 2 and not len(x_of_field):
            continue  # nothing to associate an X with
        w_d = 1.0 / (2.0 * model.range_sigma(d_o, c["sigma_range"]) ** 2)
        ux, uy = rotate(math.cos(b), math.sin(b), cth, sth)
        gx, gy = rotate(math.cos(o), math.sin(o), cth, sth)
        px, py = x + d_o * ux, y + d_o * uy
        if kind == 0:  # L: the quadrant of the global orientation picks one of four tables
            quad = 2 * (gy < 0) + ((gy < 0) != (gx < 0))
            cost = at_table(quad * cells, px, py, ux, uy, gx, gy, d_o, w_d, False)
            cost = np.minimum(cost, at_table(4 * cells, px, py, ux, uy, gx, gy, d_o, w_d, True)
                              + pen)  # an L of a T (an arm unseen)
        elif kind == 1:
            cost = at_table(4 * cells, px, py, ux, uy, gx, gy, d_o, w_d, False)
        else:
            cost = as_x(1.0, ux, uy, gx, gy, d_o, w_d)
        if kind < 2 and len(x_of_field) and p_conf > 0:  # an L or T of an X
            cost = np.minimum(cost, as_x(-1.0 if kind == 0 else 1.0, ux, uy, gx, gy, d_o, w_d)
                              + pen)
        out["crossings"] += mixture(cost, uniform_share(conf_k, c["uniform_floor"]))

    post_base = c["post_uniform_floor"]
    post_base = c["uniform_floor"] if post_base is None else post_base
    for d_o, b, conf_k in obs.posts if len(posts) else ():
        w_d = 1.0 / (2.0 * model.range_sigma(d_o, c["sigma_range"], c["post_elevation_sigma"])
                     ** 2)
        ux, uy = rotate(math.cos(b), math.sin(b), cth, sth)
        cost = np.min([point_cost(px_, py_, x, y, ux, uy, d_o, w_d, w_b)
                       for px_, py_ in posts], axis=0)
        out["posts"] += mixture(cost, uniform_share(conf_k, post_base))
    return out
