"""The numba kernels of method ``fit`` (fit.py): compiled once, cached on disk.

The distance to the nearest line at a field point q, from the map's 10 cm tables
(``/tables/distance`` d_k and ``/tables/distance_gradient`` g_k, the unit vector from the
nearest line point to node k): each of the four nodes k around q predicts

    s_k(q) = d_k + g_k . (q - node_k),

the signed distance of q from the line through node k's nearest line point along g_k (exact
for a straight line, the tangent for an arc), and the distance is their bilinear blend

    d(q) = sum_k b_k(q) |s_k(q)|

(b_k the bilinear weights of q in its cell). Where the four nodes share their nearest line,
d(q) is that line's exact distance, at the line too (no flat bottom of a bilinear distance
raster); where they do not (the middle between two lines, the end of a line) it blends the
lines' distances continuously. Its gradient is the exact derivative of that blend:
sum_k b_k sign(s_k) g_k + sum_k (db_k / dq) |s_k|. Nodes that lie on a line (d_k = 0, zero
gradient in the map) take the gradient of a neighbour whose nearest point they are
(``fit.DistanceField``). Outside the table the nodes of its edge extrapolate.

The cost of a pose (x, y, theta) of robot-frame line points p_i with weights w_i:

    E = sum_i w_i rho(d(q_i)),   q_i = (x, y) + R(theta) p_i,   rho(d) = d^2 / (c^2 + d^2)

(Lauer, Lange, Riedmiller's error, 1 - c^2 / (c^2 + d^2), with their c = 0.25 m).

- ``cost_gradient``: E and dE / d(x, y, theta);
- ``rprop``: E minimised from a start pose by RPROP (Riedmiller's resilient propagation, as
  Lauer et al.; iRprop-: a step grows by 1.2 while its partial derivative keeps its sign, halves
  and skips the move when it flips), optionally with a Gaussian prior on the heading;
- ``normal_matrix``: the Gauss-Newton matrix sum_i w_i rho'(d)/d grad(d) grad(d)^T at a pose
  (for d << c the Hessian of E; its inverse shapes the fix's covariance);
- ``grid_costs``: E (with a wider scale c, a blurred floor) on a grid of positions at a list of
  headings, the starts of the multi-start global search.
"""

from __future__ import annotations

import math

import numpy as np

from ..common.jit import njit


@njit(cache=True, nogil=True, inline="always")
def line_distance(dist, grad, grid, x, y):
    """(d, dd/dx, dd/dy) at field point (x, y) (module doc)."""
    x0, y0, res = grid
    ny, nx = dist.shape
    u = (x - x0) / res
    v = (y - y0) / res
    du_ok = 1.0
    dv_ok = 1.0
    if u < 0.0:
        u = 0.0
        du_ok = 0.0
    elif u > nx - 1.000001:
        u = nx - 1.000001
        du_ok = 0.0
    if v < 0.0:
        v = 0.0
        dv_ok = 0.0
    elif v > ny - 1.000001:
        v = ny - 1.000001
        dv_ok = 0.0
    j = int(u)
    i = int(v)
    fu = u - j
    fv = v - i
    xa = x0 + j * res
    ya = y0 + i * res
    ex = x - xa  # offsets from node (i, j)
    ey = y - ya
    s00 = dist[i, j] + grad[0, i, j] * ex + grad[1, i, j] * ey
    s01 = dist[i, j + 1] + grad[0, i, j + 1] * (ex - res) + grad[1, i, j + 1] * ey
    s10 = dist[i + 1, j] + grad[0, i + 1, j] * ex + grad[1, i + 1, j] * (ey - res)
    s11 = dist[i + 1, j + 1] + grad[0, i + 1, j + 1] * (ex - res) + grad[1, i + 1, j + 1] * (
        ey - res)
    a00, a01, a10, a11 = abs(s00), abs(s01), abs(s10), abs(s11)
    g00 = 1.0 if s00 >= 0.0 else -1.0
    g01 = 1.0 if s01 >= 0.0 else -1.0
    g10 = 1.0 if s10 >= 0.0 else -1.0
    g11 = 1.0 if s11 >= 0.0 else -1.0
    b00 = (1.0 - fu) * (1.0 - fv)
    b01 = fu * (1.0 - fv)
    b10 = (1.0 - fu) * fv
    b11 = fu * fv
    d = b00 * a00 + b01 * a01 + b10 * a10 + b11 * a11
    gx = (b00 * g00 * grad[0, i, j] + b01 * g01 * grad[0, i, j + 1]
          + b10 * g10 * grad[0, i + 1, j] + b11 * g11 * grad[0, i + 1, j + 1])
    gy = (b00 * g00 * grad[1, i, j] + b01 * g01 * grad[1, i, j + 1]
          + b10 * g10 * grad[1, i + 1, j] + b11 * g11 * grad[1, i + 1, j + 1])
    gx += du_ok * ((1.0 - fv) * (a01 - a00) + fv * (a11 - a10)) / res
    gy += dv_ok * ((1.0 - fu) * (a10 - a00) + fu * (a11 - a01)) / res
    return d, gx, gy


@njit(cache=True, nogil=True)
def distance_at(dist, grad, grid, x, y):
    """``line_distance`` callable from Python (tests, pictures)."""
    return line_distance(dist, grad, grid, x, y)


@njit(cache=True, nogil=True)
def _cost_gradient(dist, grad, grid, points, weights, pose, c2, out_grad):
    px, py, pth = pose
    cs, sn = math.cos(pth), math.sin(pth)
    total = 0.0
    g0 = 0.0
    g1 = 0.0
    g2 = 0.0
    for k in range(points.shape[0]):
        rx = cs * points[k, 0] - sn * points[k, 1]
        ry = sn * points[k, 0] + cs * points[k, 1]
        d, dx, dy = line_distance(dist, grad, grid, px + rx, py + ry)
        den = c2 + d * d
        total += weights[k] * d * d / den
        f = weights[k] * 2.0 * c2 * d / (den * den)  # w rho'(d)
        g0 += f * dx
        g1 += f * dy
        g2 += f * (dx * -ry + dy * rx)
    out_grad[0] = g0
    out_grad[1] = g1
    out_grad[2] = g2
    return total


@njit(cache=True, nogil=True)
def cost_gradient(dist, grad, grid, points, weights, pose, c2, out_grad):
    """E at ``pose`` (px, py, pth) (module doc); dE / d(x, y, theta) into ``out_grad``
    (3,)."""
    return _cost_gradient(dist, grad, grid, points, weights, pose, c2, out_grad)


@njit(cache=True, nogil=True)
def rprop(dist, grad, grid, points, weights, start, c2, steps, prior, out):
    """E minimised by RPROP from ``start`` (px, py, pth) (module doc). ``steps``:
    (iterations, step_xy, step_theta, min_step_xy, min_step_theta): at most ``iterations``
    gradient evaluations, first steps ``step_xy`` (m) and ``step_theta`` (rad), stopping when
    every step is below ``min_step_xy`` / ``min_step_theta``. ``prior``: (prior_theta,
    prior_weight, prior_x, prior_y, info_xx, info_xy, info_yy): ``prior_weight`` > 0 adds
    prior_weight * wrap(theta - prior_theta)^2 / 2 (a heading measured beside the points, in
    the units of E); an information (info_xx, info_xy, info_yy) other than 0 adds the position
    prior (p - prior)^T info (p - prior) / 2 likewise. The pose into ``out`` (3,); returns E at
    it (without the prior terms), and the best pose met is kept (RPROP does not test its
    steps)."""
    iterations, step_xy, step_theta, min_step_xy, min_step_theta = steps
    prior_theta, prior_weight, prior_x, prior_y, info_xx, info_xy, info_yy = prior
    pose = np.array([start[0], start[1], start[2]])
    step = np.array([step_xy, step_xy, step_theta])
    last = np.zeros(3)
    g = np.zeros(3)
    best = pose.copy()
    best_total = np.inf
    best_e = np.inf
    for _ in range(iterations):
        e = _cost_gradient(dist, grad, grid, points, weights, (pose[0], pose[1], pose[2]),
                           c2, g)
        total = e
        if prior_weight > 0.0:
            dth = (pose[2] - prior_theta + math.pi) % (2.0 * math.pi) - math.pi
            total += 0.5 * prior_weight * dth * dth
            g[2] += prior_weight * dth
        ex = pose[0] - prior_x
        ey = pose[1] - prior_y
        total += 0.5 * (info_xx * ex * ex + 2.0 * info_xy * ex * ey + info_yy * ey * ey)
        g[0] += info_xx * ex + info_xy * ey
        g[1] += info_xy * ex + info_yy * ey
        if total < best_total:
            best_total = total
            best_e = e
            best[:] = pose
        small = True
        for k in range(3):
            if g[k] * last[k] > 0.0:
                step[k] *= 1.2
                last[k] = g[k]
            elif g[k] * last[k] < 0.0:
                step[k] *= 0.5
                last[k] = 0.0  # iRprop-: no move on a sign flip, and no adaptation next time
            else:
                last[k] = g[k]
            if last[k] > 0.0:
                pose[k] -= step[k]
            elif last[k] < 0.0:
                pose[k] += step[k]
            if step[k] > (min_step_xy if k < 2 else min_step_theta):
                small = False
        if small:
            break
    e = _cost_gradient(dist, grad, grid, points, weights, (pose[0], pose[1], pose[2]), c2, g)
    total = e
    if prior_weight > 0.0:
        dth = (pose[2] - prior_theta + math.pi) % (2.0 * math.pi) - math.pi
        total += 0.5 * prior_weight * dth * dth
    ex = pose[0] - prior_x
    ey = pose[1] - prior_y
    total += 0.5 * (info_xx * ex * ex + 2.0 * info_xy * ex * ey + info_yy * ey * ey)
    if total < best_total:
        best_e = e
        best[:] = pose
    best[2] = (best[2] + math.pi) % (2.0 * math.pi) - math.pi
    out[:] = best
    return best_e


@njit(cache=True, nogil=True)
def normal_matrix(dist, grad, grid, points, weights, pose, c2, out, out_d):
    """The Gauss-Newton matrix (3, 3) of E at ``pose`` (px, py, pth) into ``out`` (module
    doc) and every point's distance d(q_i) into ``out_d``."""
    px, py, pth = pose
    cs, sn = math.cos(pth), math.sin(pth)
    out[:, :] = 0.0
    for k in range(points.shape[0]):
        rx = cs * points[k, 0] - sn * points[k, 1]
        ry = sn * points[k, 0] + cs * points[k, 1]
        d, dx, dy = line_distance(dist, grad, grid, px + rx, py + ry)
        out_d[k] = d
        den = c2 + d * d
        om = weights[k] * 2.0 * c2 / (den * den)
        j2 = dx * -ry + dy * rx
        out[0, 0] += om * dx * dx
        out[0, 1] += om * dx * dy
        out[0, 2] += om * dx * j2
        out[1, 1] += om * dy * dy
        out[1, 2] += om * dy * j2
        out[2, 2] += om * j2 * j2
    out[1, 0] = out[0, 1]
    out[2, 0] = out[0, 2]
    out[2, 1] = out[1, 2]


@njit(cache=True, nogil=True)
def grid_costs(dist, grad, grid, points, weights, xs, ys, headings, c2, out):
    """out[h, i, j] = E at (xs[j], ys[i], headings[h]) with scale c2 (module doc)."""
    n = points.shape[0]
    rx = np.empty(n)
    ry = np.empty(n)
    for h in range(headings.shape[0]):
        cs, sn = math.cos(headings[h]), math.sin(headings[h])
        for k in range(n):
            rx[k] = cs * points[k, 0] - sn * points[k, 1]
            ry[k] = sn * points[k, 0] + cs * points[k, 1]
        for i in range(ys.shape[0]):
            for j in range(xs.shape[0]):
                total = 0.0
                for k in range(n):
                    d, _dx, _dy = line_distance(dist, grad, grid, xs[j] + rx[k],
                                                ys[i] + ry[k])
                    total += weights[k] * d * d / (c2 + d * d)
                out[h, i, j] = total


@njit(cache=True, nogil=True)
def ray_ranges(dist, grad, grid, points, pose, min_cosine, max_distance, out):
    """out[i]: the range along point i's own ray (from the robot) at which the ray meets the
    line nearest the point, to first order: r - d / (n . u) (n = grad d, u the ray's unit
    direction); NaN where the point lies farther than ``max_distance`` from a line or the ray
    meets it at a grazing angle (|n . u| < ``min_cosine``). At the true pose r - out[i] is the
    calibration's distance error at r (``pose``: px, py, pth)."""
    px, py, pth = pose
    cs, sn = math.cos(pth), math.sin(pth)
    for k in range(points.shape[0]):
        rx = cs * points[k, 0] - sn * points[k, 1]
        ry = sn * points[k, 0] + cs * points[k, 1]
        r = math.sqrt(rx * rx + ry * ry)
        out[k] = np.nan
        if r <= 0.0:
            continue
        d, dx, dy = line_distance(dist, grad, grid, px + rx, py + ry)
        nu = (dx * rx + dy * ry) / r
        if d <= max_distance and abs(nu) >= min_cosine:
            out[k] = r - d / nu
