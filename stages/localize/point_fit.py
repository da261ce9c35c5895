"""Line points fitted to the field's lines by their distance to the nearest line (the error of
Lauer, Lange and Riedmiller 2006, as MSL teams use it).

A robot-frame line point p seen from pose (x, y, theta) lies at q = (x, y) + R(theta) p in the
field; its error is d(q), the distance from q to the nearest line centre line. The cost of a
pose is

    C(pose) = sum_i w_i rho(d(q_i)),   rho(d) = d^2 / (c^2 + d^2)

(the same robust rho and scale c as the table search: quadratic for d << c, at most one per
point). d is read from a fine distance raster (``resolution``, 2 cm by default, bilinear
between raster nodes; computed from the field model when the map is loaded), which is exact at
the nodes and off by at most half the resolution on a line.

``refine`` minimises C from a start pose by Gauss-Newton on iteratively reweighted least
squares (Geman-McClure weights 2 c^2 / (c^2 + d^2)^2) with Levenberg-Marquardt damping over
(x, y, theta), and returns the pose, its cost and the Gauss-Newton normal matrix (the Hessian
of C at a good fit).
"""

from __future__ import annotations

import math

import numpy as np

from ..common.field import FieldModel
from ..common.jit import njit


class PointFit:
    """The distance raster of a field and the fits of line points against it."""

    def __init__(self, field_model: FieldModel, *, c: float = 0.25, resolution: float = 0.02,
                 margin: float = 1.0, map_path=None):
        """``map_path``: the map ``field_model`` is from; the raster is then cached beside it
        (stages.localize.lookup_cache) and mapped from there by later processes."""
        xmin, xmax, ymin, ymax = field_model.world_bounds()
        xmin, xmax, ymin, ymax = xmin - margin, xmax + margin, ymin - margin, ymax + margin
        xs = np.arange(xmin, xmax + 0.5 * resolution, resolution)
        ys = np.arange(ymin, ymax + 0.5 * resolution, resolution)

        def build():
            rows = [field_model.distance_to_lines(np.stack(np.broadcast_arrays(xs, y), axis=-1))
                    for y in ys]  # row by row: bounded memory on large fields
            return {"distance": np.ascontiguousarray(np.stack(rows), dtype=np.float32)}

        if map_path is None:
            self.table = build()["distance"]
        else:
            from .lookup_cache import load_or_build

            self.table = load_or_build(
                map_path, "line-distance raster", {"resolution": resolution, "margin": margin},
                {"distance": ((len(ys), len(xs)), np.float32)}, build)[0]["distance"]
        self.origin = (float(xmin), float(ymin))
        self.resolution = float(resolution)
        self.grid = (*self.origin, self.resolution)  # the kernels' (x0, y0, resolution)
        self.c = float(c)

    def cost(self, points: np.ndarray, weights: np.ndarray, pose) -> float:
        """C(pose) of robot-frame points (N, 2) with weights (N,)."""
        return float(fit_cost(self.table, self.grid, _points(points), _weights(weights),
                              (float(pose[0]), float(pose[1]), float(pose[2])),
                              self.c * self.c))

    def refine(self, points: np.ndarray, weights: np.ndarray, pose, *, iterations: int = 8,
               fixed_heading: bool = False, max_shift: float = math.inf,
               max_turn: float = math.inf):
        """(pose (3,), cost, normal matrix (3, 3)) of the minimum of C near ``pose``
        (``fixed_heading``: the heading is kept, the position fitted), within ``max_shift``
        (m, per axis) and ``max_turn`` (rad) of it."""
        out = np.empty(3)
        normal = np.empty((3, 3))
        cost = fit_refine(self.table, self.grid, _points(points), _weights(weights),
                          (float(pose[0]), float(pose[1]), float(pose[2])), self.c * self.c,
                          (int(iterations), bool(fixed_heading), float(min(max_shift, 1e9)),
                           float(min(max_turn, 1e9))), out, normal)
        return out, float(cost), normal


def _points(p) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(p, dtype=np.float64).reshape(-1, 2))


def _weights(w) -> np.ndarray:
    return np.ascontiguousarray(w, dtype=np.float64)


@njit(cache=True, nogil=True, inline="always")
def _distance(table, grid, x, y):
    """Bilinear distance and its gradient (d, dd/dx, dd/dy) at field point (x, y), clamped to
    the raster (``grid``: its origin x0, y0 and resolution)."""
    x0, y0, res = grid
    ny, nx = table.shape
    u = (x - x0) / res
    v = (y - y0) / res
    u = min(max(u, 0.0), nx - 1.000001)
    v = min(max(v, 0.0), ny - 1.000001)
    j = int(u)
    i = int(v)
    fu = u - j
    fv = v - i
    a = table[i, j]
    b = table[i, j + 1]
    c = table[i + 1, j]
    d = table[i + 1, j + 1]
    top = a + (b - a) * fu
    bottom = c + (d - c) * fu
    val = top + (bottom - top) * fv
    gx = ((b - a) * (1.0 - fv) + (d - c) * fv) / res
    gy = (bottom - top) / res
    return val, gx, gy


@njit(cache=True, nogil=True)
def _solve3(a, b):
    """x with a x = b for a 3 x 3 system (Cramer's rule; a is damped positive definite)."""
    det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
           - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
           + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
    x = np.empty(3)
    for k in range(3):
        m = a.copy()
        m[:, k] = b
        x[k] = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
                - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
                + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])) / det
    return x


@njit(cache=True, nogil=True)
def fit_cost(table, grid, points, weights, pose, c2):
    """C(pose) (module doc) of ``pose`` (px, py, pth) on the raster ``table`` (``grid``: its
    origin x0, y0 and resolution)."""
    px, py, pth = pose
    cs, sn = math.cos(pth), math.sin(pth)
    total = 0.0
    for i in range(points.shape[0]):
        qx = px + cs * points[i, 0] - sn * points[i, 1]
        qy = py + sn * points[i, 0] + cs * points[i, 1]
        d, _gx, _gy = _distance(table, grid, qx, qy)
        total += weights[i] * d * d / (c2 + d * d)
    return total


@njit(cache=True, nogil=True)
def fit_refine(table, grid, points, weights, start, c2, rule, out, normal):
    """Minimise C from ``start`` (px, py, pth) (module doc); ``rule``: (iterations,
    fixed_heading, max_shift, max_turn), at most ``iterations`` Gauss-Newton steps, the
    heading kept when ``fixed_heading``, within max_shift (per axis) and max_turn of the
    start. The pose into ``out`` (3,), the Gauss-Newton normal matrix at it into ``normal``
    (3, 3); returns its cost."""
    px, py, pth = start
    iterations, fixed_heading, max_shift, max_turn = rule
    n = points.shape[0]
    pose = np.array([px, py, pth])
    lam = 1e-3
    H = np.zeros((3, 3))
    g = np.zeros(3)
    cost = fit_cost(table, grid, points, weights, (pose[0], pose[1], pose[2]), c2)
    step = np.zeros(3)
    for _ in range(iterations + 1):
        cs, sn = math.cos(pose[2]), math.sin(pose[2])
        H[:, :] = 0.0
        g[:] = 0.0
        for i in range(n):
            rx = cs * points[i, 0] - sn * points[i, 1]
            ry = sn * points[i, 0] + cs * points[i, 1]
            d, gx, gy = _distance(table, grid, pose[0] + rx, pose[1] + ry)
            den = c2 + d * d
            om = weights[i] * 2.0 * c2 / (den * den)  # IRLS weight of rho
            j0, j1, j2 = gx, gy, gx * -ry + gy * rx  # dd/d(x, y, theta)
            if fixed_heading:
                j2 = 0.0
            H[0, 0] += om * j0 * j0
            H[0, 1] += om * j0 * j1
            H[0, 2] += om * j0 * j2
            H[1, 1] += om * j1 * j1
            H[1, 2] += om * j1 * j2
            H[2, 2] += om * j2 * j2
            g[0] += om * j0 * d
            g[1] += om * j1 * d
            g[2] += om * j2 * d
        H[1, 0] = H[0, 1]
        H[2, 0] = H[0, 2]
        H[2, 1] = H[1, 2]
        if _ == iterations:
            break
        improved = False
        for _try in range(6):
            A = H.copy()
            for k in range(3):
                A[k, k] += lam * H[k, k] + 1e-9
            if fixed_heading:
                A[2, 2] = 1.0
            step = _solve3(A, -g)
            if fixed_heading:
                step[2] = 0.0
            cand = pose + step
            cand[0] = min(max(cand[0], px - max_shift), px + max_shift)
            cand[1] = min(max(cand[1], py - max_shift), py + max_shift)
            cand[2] = min(max(cand[2], pth - max_turn), pth + max_turn)
            step = cand - pose
            c_new = fit_cost(table, grid, points, weights, (cand[0], cand[1], cand[2]), c2)
            if c_new < cost:
                pose = cand
                cost = c_new
                lam = max(lam * 0.3, 1e-7)
                improved = True
                break
            lam *= 10.0
        if not improved or abs(step[0]) + abs(step[1]) < 1e-5 and abs(step[2]) < 1e-6:
            break
    pose[2] = (pose[2] + math.pi) % (2 * math.pi) - math.pi
    out[:] = pose
    normal[:, :] = H
    return cost
