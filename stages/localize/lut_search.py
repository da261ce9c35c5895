"""Pose search in the scan-line tables of seed 002 (section IV-B).

Matching. A frame's observations are the white-line crossing distances the robot found on its
scan lines: up to 4 per radial line (``radial`` (72, 4), NaN = none) and one per spiral
(``spiral`` (2, 72)). For a robot at cell c with heading m * 5 deg, observed scan line k is
compared with table line (k + m) mod 72 of cell c (stages.common.scanlines.rotate_to_heading).
Every observed distance d is matched to the nearest table crossing of its line; its error
e = |d - t_nearest| enters the error term as

    w(d) * rho(e),   rho(e) = 1 - c^2 / (c^2 + e^2) = e^2 / (c^2 + e^2)

the seed's eq. 5: quadratic for e << c, saturating at 1 for e >> c, so a false hit or a missed
line costs at most one unit. A table entry of "none" where an observation exists costs the
saturated error (rho = 1). Scan lines without an observation are ignored. Nearer points weigh
more:  w(d) = 1 / (1 + (d / range_scale)^2)  (default range_scale 2 m: w = 0.94 at 0.5 m, 0.5 at
2 m, 0.2 at 4 m), because a catadioptric mirror maps far ground onto few pixels, so the distance
of a far crossing is much less certain than that of a near one. The error term of a pose is the
sum over observations; its normalised value e_norm = sum / sum(w) lies in [0, 1).

Speed. The search never evaluates rho inside the loop over cells. At load time an *error
lookup* is precomputed from the tables: for every scan line (72 radial, 144 spiral), every
observed distance quantised to ``distance_bin`` (5 cm) and every cell, the value
w(d) * rho(e) quantised to 0..Q (Q = 151, so that the sum over the at most 432 observations of a
frame fits a uint16). It is stored scan-line-major ((line, bin) rows of all cells, contiguous),
so the error surface of a frame over the whole world is the sum of one contiguous row per
observation: one gather and one reduction (``global_search``), or the same restricted to a
window (``local_search``), both in one numba kernel (``_lookup_sum``; the exact error and
the refinement's cell moves are numba kernels too). The quantised surface only picks cells;
the pose is then refined with the exact error (float32 tables in metres, no quantisation):

- sub-cell position: exact error on the 3 x 3 cells around the best cell (moving to a lower
  neighbour until the centre is the minimum), then a least-squares quadratic fit of the 9 values;
  the fitted minimum (clipped to one cell) is the position, its Hessian the shape of the fix;
- heading between the 5 deg table headings: the error at heading theta is interpolated linearly
  between the error surfaces of the two neighbouring table headings (m and m + 1, weights by the
  fraction of the step); ``refine_heading`` fits a parabola through the error at theta - 5 deg,
  theta, theta + 5 deg for a vision estimate of the heading.

``unknown_heading_search`` evaluates all 72 headings on every other cell in x and y (the error
lookup subsampled once at load), keeps the best few (heading, cell) candidates and refines each
in full resolution with a local search, the exact refinement, and heading refinement.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from ..common.map_file import MapFile
from ..common.scanlines import NO_HIT_MM

MAX_CROSSINGS = 4
NONE_M = 1.0e3  # a "none" table entry in metres: far from any observation -> saturated error


@dataclass(frozen=True)
class MatchingParams:
    """How observations are scored against the tables (see the module doc)."""

    c: float = 0.25  # m, scale of rho(e) = e^2 / (c^2 + e^2)
    range_scale: float = 2.0  # m, w(d) = 1 / (1 + (d / range_scale)^2)
    distance_bin: float = 0.05  # m, quantisation of observed distances in the error lookup
    use_spiral: bool = True  # match spiral observations too
    coarse_step: int = 2  # cells, subsampling of the unknown-heading pass
    pair_tolerance: float = 0.6  # m, crossings of neighbouring scan lines taken as one line

    @classmethod
    def from_conf(cls, conf: dict) -> MatchingParams:
        return cls(c=float(conf["c"]), range_scale=float(conf["range_scale"]),
                   distance_bin=float(conf["distance_bin"]),
                   use_spiral=bool(conf["use_spiral"]),
                   coarse_step=int(conf["coarse_step"]),
                   pair_tolerance=float(conf["pair_tolerance"]))

    def weight(self, d):
        return 1.0 / (1.0 + (np.asarray(d, dtype=np.float64) / self.range_scale) ** 2)

    def rho(self, e):
        e2 = np.square(e)
        return e2 / (self.c * self.c + e2)


@dataclass
class Observation:
    """One frame's scan-line observations, flattened: observation i lies on scan line
    ``angle_index[i]`` of ``family[i]`` (0 radial, 1 spiral ccw, 2 spiral cw) at distance
    ``distance[i]`` (m) and weighs ``weight[i]``."""

    family: np.ndarray
    angle_index: np.ndarray
    distance: np.ndarray
    weight: np.ndarray

    def __len__(self):
        return len(self.distance)

    @property
    def total_weight(self) -> float:
        return float(self.weight.sum())

    @classmethod
    def from_scanlines(cls, radial, spiral, params: MatchingParams, max_range: float,
                       spiral_end_radius: float, robot_radius: float = 0.0) -> Observation:
        """From the features' ``radial`` (72, 4) and ``spiral`` (2, 72) arrays (m, NaN = none).
        Distances outside the scan lines' reach are dropped."""
        fams, idxs, dists = [], [], []
        r = np.asarray(radial, dtype=np.float64)
        if r.size:
            k, _slot = np.nonzero(np.isfinite(r) & (r >= robot_radius) & (r <= max_range))
            fams.append(np.zeros(len(k), np.int64))
            idxs.append(k)
            dists.append(r[np.isfinite(r) & (r >= robot_radius) & (r <= max_range)])
        if params.use_spiral and spiral is not None:
            s = np.asarray(spiral, dtype=np.float64)
            ok = np.isfinite(s) & (s >= robot_radius) & (s <= spiral_end_radius)
            direction, k = np.nonzero(ok)
            fams.append(1 + direction)
            idxs.append(k)
            dists.append(s[ok])
        family = np.concatenate(fams) if fams else np.zeros(0, np.int64)
        distance = np.concatenate(dists) if dists else np.zeros(0)
        return cls(family=family.astype(np.int64),
                   angle_index=(np.concatenate(idxs) if idxs else np.zeros(0)).astype(np.int64),
                   distance=distance, weight=params.weight(distance))

    def subset(self, mask) -> Observation:
        """The observations selected by a boolean mask (or index array)."""
        return Observation(family=self.family[mask], angle_index=self.angle_index[mask],
                           distance=self.distance[mask], weight=self.weight[mask])

    def points(self, scanlines) -> np.ndarray:
        """The observations as points (N, 2) in the robot frame."""
        ang = self.angle_index * scanlines.angle_step
        pts = np.zeros((len(self), 2))
        rad = self.family == 0
        pts[rad, 0] = self.distance[rad] * np.cos(ang[rad])
        pts[rad, 1] = self.distance[rad] * np.sin(ang[rad])
        sp = ~rad
        if sp.any():
            r0, r1 = scanlines.robot_radius, scanlines.spiral_end_radius
            phi = (self.distance[sp] - r0) / (r1 - r0) * 2 * math.pi
            sign = np.where(self.family[sp] == 1, 1.0, -1.0)
            a = ang[sp] + sign * phi
            pts[sp, 0] = self.distance[sp] * np.cos(a)
            pts[sp, 1] = self.distance[sp] * np.sin(a)
        return pts


@dataclass
class SearchResult:
    """A pose found by the search. ``error`` is the weighted error term (sum over
    observations), ``error_norm`` = error / total weight in [0, 1)."""

    x: float
    y: float
    theta: float
    error: float
    error_norm: float
    cell: tuple[int, int]
    n_observations: int
    hessian: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))  # m^-2, of e_norm
    at_window_edge: bool = False
    mode: str = ""
    candidates: list = field(default_factory=list)  # (x, y, theta, error_norm) of runners-up
    # the fix's own error_norm computed as its candidates' are (global search: exact error on
    # the best cell at the nearest table heading, before the sub-cell and heading refinement),
    # so a fix and its runners-up compare like with like
    candidate_error_norm: float = math.nan

    @property
    def pose(self) -> np.ndarray:
        return np.array([self.x, self.y, self.theta])


@dataclass(frozen=True)
class Support:
    """What a fix explains: its inliers are the observations whose error (distance to the
    predicted crossing of their scan line, ``TableSearch.observation_errors``) lies below the
    inlier error (default c / 2, where rho(e) = 0.2). Unlike e_norm, which averages over every
    observation and so grows with the share of clutter (cables, feet, reflections) in a frame,
    the inliers count what the field lines at the fix actually account for."""

    observations: int
    inliers: int
    inlier_weight: float  # sum of the inliers' weights w(d)
    total_weight: float  # sum of all observations' weights
    inlier_rho: float  # weighted mean of rho(e) over the inliers, in [0, 0.2) for c / 2

    @property
    def inlier_share(self) -> float:
        """Inliers / observations."""
        return self.inliers / max(self.observations, 1)


class TableSearch:
    """The per-map data of the table search (float tables in metres, the error lookup) and the
    searches. Build once per map and matching parameters; reuse over frames."""

    def __init__(self, map_file: MapFile, params: MatchingParams | None = None):
        self.params = params or MatchingParams()
        self.grid = map_file.grid
        self.scanlines = map_file.scanlines
        self.field = map_file.field
        ny, nx = self.grid.shape
        self.ny, self.nx, self.ncell = ny, nx, ny * nx
        n = self.scanlines.n_angles
        self.n_angles = n
        self.step = self.scanlines.angle_step
        radial = map_file.table("radial")
        spiral = map_file.table("spiral")
        if radial.shape != (n, MAX_CROSSINGS, ny, nx) or spiral.shape != (2, n, ny, nx):
            from ..common.errors import SchemaError

            raise SchemaError(
                f"{map_file.path}: tables radial {radial.shape} / spiral {spiral.shape} do not"
                f" match the grid {self.grid.shape} and {n} scan lines"
            )
        self.radial_mm = radial.reshape(n, MAX_CROSSINGS, self.ncell)
        self.spiral_mm = spiral.reshape(2 * n, self.ncell)
        # exact tables in metres, scan-line-major; "none" -> NONE_M (saturated error)
        self.radial_m = _to_metres(self.radial_mm)
        self.spiral_m = _to_metres(self.spiral_mm)
        self._radial_flat = self.radial_m.reshape(-1)
        self._spiral_flat = self.spiral_m.reshape(-1)
        self._build_error_lookup()

    # ------------------------------------------------------------------ error lookup
    def _build_error_lookup(self):
        p = self.params
        n = self.n_angles
        b = p.distance_bin
        self.nb_radial = int(math.ceil(self.scanlines.max_range / b)) + 1
        self.nb_spiral = int(math.ceil(self.scanlines.spiral_end_radius / b)) + 1
        max_obs = n * MAX_CROSSINGS + 2 * n
        self.q_levels = int(np.iinfo(np.uint16).max // max_obs)
        q = float(self.q_levels)
        rows = n * self.nb_radial + 2 * n * self.nb_spiral
        lut = np.empty((rows, self.ncell), dtype=np.uint8)
        d_r = np.arange(self.nb_radial) * b
        scale_r = (q * p.weight(d_r)).astype(np.float32)[:, None]
        for k in range(n):
            t = self.radial_m[k]  # (4, ncell)
            e = np.abs(t[0][None, :] - d_r[:, None].astype(np.float32))
            for h in range(1, MAX_CROSSINGS):
                np.minimum(e, np.abs(t[h][None, :] - d_r[:, None].astype(np.float32)), out=e)
            lut[k * self.nb_radial:(k + 1) * self.nb_radial] = np.rint(
                scale_r * _rho32(e, p.c))
        self.spiral_row0 = n * self.nb_radial
        d_s = np.arange(self.nb_spiral) * b
        scale_s = (q * p.weight(d_s)).astype(np.float32)[:, None]
        for s in range(2 * n):
            e = np.abs(self.spiral_m[s][None, :] - d_s[:, None].astype(np.float32))
            r0 = self.spiral_row0 + s * self.nb_spiral
            lut[r0:r0 + self.nb_spiral] = np.rint(scale_s * _rho32(e, p.c))
        self.error_lookup = lut
        self.error_lookup_3d = lut.reshape(rows, self.ny, self.nx)
        self.coarse_lookup, self.coarse_shape = _min_pooled(self.error_lookup_3d,
                                                            max(1, p.coarse_step))

    def lookup_rows(self, obs: Observation, m: int) -> np.ndarray:
        """Rows of the error lookup for the observations at table heading index ``m``."""
        k = (obs.angle_index + m) % self.n_angles
        b = self.params.distance_bin
        rad = obs.family == 0
        bins_r = np.minimum(np.rint(obs.distance / b).astype(np.int64), self.nb_radial - 1)
        bins_s = np.minimum(np.rint(obs.distance / b).astype(np.int64), self.nb_spiral - 1)
        spiral_line = (obs.family - 1) * self.n_angles + k
        return np.where(rad, k * self.nb_radial + bins_r,
                        self.spiral_row0 + spiral_line * self.nb_spiral + bins_s)

    # ------------------------------------------------------------------ exact error
    def exact_errors(self, obs: Observation, cells, ms) -> np.ndarray:
        """Exact weighted error terms (len(ms), len(cells)) at flat cell indices ``cells`` for
        the table heading indices ``ms``."""
        cells = np.ascontiguousarray(np.asarray(cells, dtype=np.int64).ravel())
        ms = np.atleast_1d(np.asarray(ms, dtype=np.int64))
        total = np.zeros((len(ms), len(cells)))
        arrays = self._kernel_arrays(obs)
        for h, m in enumerate(ms):
            _exact_error_cells(*arrays, cells, int(m) % self.n_angles, 0.0, False, total[h])
        return total

    def exact_error(self, obs: Observation, cells, m: int) -> np.ndarray:
        """Exact weighted error term at flat cell indices ``cells`` (any shape) for table
        heading index m."""
        cells = np.asarray(cells, dtype=np.int64)
        return self.exact_errors(obs, cells, [m])[0].reshape(cells.shape)

    def exact_error_at_heading(self, obs: Observation, cells, theta: float) -> np.ndarray:
        """Exact error term at flat cell indices ``cells`` (any shape) for a continuous heading.

        Between the table headings m and m + 1 (fraction a of the step) an observed scan line
        lies between table lines k + m and k + m + 1, so its predicted crossings are
        interpolated in angle: each crossing of line k + m paired with the nearest crossing of
        line k + m + 1: the crossings t, t' nearest the observed distance on either line, when
        they differ by less than ``pair_tolerance`` (the same white line seen by both), predict
        (1 - a) t + a t'; otherwise the crossing of the angularly nearer table line is the
        prediction. (Keeping the raw crossing as a second candidate biases the fix: next to
        the true cell the 2.5 deg-off raw crossings fit by chance.)"""
        cells = np.asarray(cells, dtype=np.int64)
        m0, a = self._heading_bracket(theta)
        if a < 1e-6 or a > 1 - 1e-6:
            return self.exact_error(obs, cells, (m0 + (1 if a > 0.5 else 0)) % self.n_angles)
        flat = np.ascontiguousarray(cells.ravel())
        total = np.zeros(len(flat))
        _exact_error_cells(*self._kernel_arrays(obs), flat, m0, float(a), True, total)
        return total.reshape(cells.shape)

    def _kernel_arrays(self, obs: Observation) -> tuple:
        """The leading arguments of ``_exact_error_cells`` for the observations."""
        return (self._radial_flat, self._spiral_flat, self.ncell, self.n_angles,
                np.ascontiguousarray(obs.family, dtype=np.int64),
                np.ascontiguousarray(obs.angle_index, dtype=np.int64),
                np.ascontiguousarray(obs.distance, dtype=np.float32),
                np.ascontiguousarray(obs.weight, dtype=np.float32),
                np.float32(self.params.pair_tolerance),
                np.float32(self.params.c * self.params.c))

    def observation_errors(self, obs: Observation, cell, theta: float) -> np.ndarray:
        """Per observation, the error e = |d - predicted crossing| (m) at one cell (i, j) and
        a continuous heading: the same prediction as ``exact_error_at_heading`` (the nearest
        table crossing at a table heading, angle-interpolated crossings between them); a
        "none" table entry gives an error of about NONE_M."""
        flat = np.array([int(cell[0]) * self.nx + int(cell[1])], dtype=np.int64)
        m0, a = self._heading_bracket(theta)
        rad = obs.family == 0
        out = np.empty(len(obs), dtype=np.float64)
        if a < 1e-6 or a > 1 - 1e-6:
            m = (m0 + (1 if a > 0.5 else 0)) % self.n_angles
            k = (obs.angle_index + m) % self.n_angles
            if rad.any():
                rows = (k[rad][:, None] * MAX_CROSSINGS + np.arange(MAX_CROSSINGS)).ravel()
                t = np.take(self._radial_flat, rows * self.ncell + flat[0])
                t = t.reshape(-1, MAX_CROSSINGS)
                out[rad] = np.abs(t - obs.distance[rad][:, None].astype(np.float32)).min(axis=1)
            if (~rad).any():
                line = (obs.family[~rad] - 1) * self.n_angles + k[~rad]
                t = np.take(self._spiral_flat, line * self.ncell + flat[0])
                out[~rad] = np.abs(t - obs.distance[~rad].astype(np.float32))
            return out
        e_rad, e_sp = self._interpolated_errors(obs, flat, m0, a)
        if e_rad is not None:
            out[rad] = e_rad[:, 0]
        if e_sp is not None:
            out[~rad] = e_sp[:, 0]
        return out

    def inliers(self, obs: Observation, x: float, y: float, theta: float,
                inlier_error: float) -> tuple[np.ndarray, np.ndarray]:
        """(errors (n,), inlier mask (n,)) of the observations at the cell nearest (x, y) and
        heading theta: inliers have an error below ``inlier_error`` (m)."""
        cell = self.grid.cell_of(x, y)
        e = self.observation_errors(obs, (int(cell[0]), int(cell[1])), theta)
        return e, e < inlier_error

    def support(self, obs: Observation, result: SearchResult, inlier_error: float) -> Support:
        """The inliers of a fix: observations with error below ``inlier_error`` (m) at the
        cell nearest the fix's position, at its heading."""
        e, inl = self.inliers(obs, result.x, result.y, result.theta, inlier_error)
        w_in = float(obs.weight[inl].sum())
        rho = float((obs.weight[inl] * self.params.rho(e[inl])).sum() / w_in) if w_in else 0.0
        return Support(observations=len(obs), inliers=int(inl.sum()), inlier_weight=w_in,
                       total_weight=obs.total_weight, inlier_rho=rho)

    def _interpolated_errors(self, obs: Observation, flat: np.ndarray, m0: int, a: float):
        """Errors (radial (n_r, C) or None, spiral (n_s, C) or None) of the observations at
        flat cells ``flat`` for the heading at fraction ``a`` between table headings m0 and
        m0 + 1 (see ``exact_error_at_heading``)."""
        C = len(flat)
        tol = np.float32(self.params.pair_tolerance)
        a32 = np.float32(a)
        k0 = (obs.angle_index + m0) % self.n_angles
        k1 = (k0 + 1) % self.n_angles
        near = k1 if a > 0.5 else k0
        rad = obs.family == 0
        e_rad = e_sp = None
        if rad.any():
            slots = np.arange(MAX_CROSSINGS)

            def gather(k):
                rows = (k[rad][:, None] * MAX_CROSSINGS + slots).ravel()
                t = np.take(self._radial_flat, rows[:, None] * self.ncell + flat[None, :])
                return t.reshape(-1, MAX_CROSSINGS, C)

            t0, t1 = gather(k0), gather(k1)
            d = obs.distance[rad].astype(np.float32)[:, None, None]
            n_r = len(t0)
            r_, c_ = np.arange(n_r)[:, None], np.arange(C)[None, :]
            n0 = t0[r_, np.abs(t0 - d).argmin(axis=1), c_]  # crossing nearest d on line k+m
            n1 = t1[r_, np.abs(t1 - d).argmin(axis=1), c_]  # ... on line k+m+1
            d = d[:, :, 0]
            t_near = n1 if a > 0.5 else n0  # unpaired: the angularly nearer line
            pred = np.where(np.abs(n0 - n1) < tol, (1 - a32) * n0 + a32 * n1, t_near)
            e_rad = np.abs(pred - d)
        sp = ~rad
        if sp.any():
            base = (obs.family[sp] - 1) * self.n_angles
            idx = lambda k: (base + k[sp])[:, None] * self.ncell + flat[None, :]  # noqa: E731
            t0 = np.take(self._spiral_flat, idx(k0))
            t1 = np.take(self._spiral_flat, idx(k1))
            tn = np.take(self._spiral_flat, idx(near))
            d = obs.distance[sp].astype(np.float32)[:, None]
            pred = np.where(np.abs(t0 - t1) < tol, (1 - a32) * t0 + a32 * t1, tn)
            e_sp = np.abs(pred - d)
        return e_rad, e_sp

    def _heading_bracket(self, theta: float) -> tuple[int, float]:
        u = float(theta) / self.step
        m0 = math.floor(u)
        return m0 % self.n_angles, u - m0

    # ------------------------------------------------------------------ searches
    def global_search(self, obs: Observation, theta: float, *, candidates: int = 3,
                      separation: float = 0.5) -> SearchResult | None:
        """Best pose over all cells for a known heading, refined to sub-cell."""
        if len(obs) == 0:
            return None
        m = self.scanlines.heading_index(theta)
        surface = self._surface(obs, m)
        starts = np.array(_best_separated(surface, self.grid.shape, candidates,
                                          separation / self.grid.resolution))
        # exact error (nearest table heading) on each candidate's 3 x 3 neighbourhood
        ci, cj = np.divmod(starts, self.nx)
        off = np.arange(-1, 2)
        ni = np.clip(ci[:, None, None] + off[None, :, None], 0, self.ny - 1)
        nj = np.clip(cj[:, None, None] + off[None, None, :], 0, self.nx - 1)
        nb = (ni * self.nx + nj).reshape(len(starts), 9)
        exact = self.exact_error(obs, nb, m)
        low = exact.argmin(axis=1)
        order = np.argsort(exact[np.arange(len(starts)), low], kind="stable")
        first = nb[order[0], low[order[0]]]
        best = self.refine(obs, divmod(int(first), self.nx), theta)
        best.mode = "global"
        W = max(obs.total_weight, 1e-12)
        best.candidate_error_norm = float(exact[order[0], low[order[0]]] / W)
        for c in order[1:]:
            x, y = self.grid.centre_of(*divmod(int(nb[c, low[c]]), self.nx))
            best.candidates.append((float(x), float(y), float(theta),
                                    float(exact[c, low[c]] / W)))
        return best

    def _surface(self, obs: Observation, m: int) -> np.ndarray:
        out = np.empty((self.ny, self.nx), dtype=np.uint16)
        _lookup_sum(self.error_lookup, *self._row_arrays(obs, m), 0, self.ny, 0, self.nx,
                    self.nx, out)
        return out.reshape(-1)

    def _row_arrays(self, obs: Observation, m: int) -> tuple:
        """The arguments of ``_lookup_sum`` that select the rows ``lookup_rows(obs, m)``."""
        bins = np.rint(obs.distance / self.params.distance_bin).astype(np.int64)
        return (np.ascontiguousarray(obs.family, dtype=np.int64),
                np.ascontiguousarray(obs.angle_index, dtype=np.int64), bins, int(m),
                self.n_angles, self.nb_radial, self.nb_spiral, self.spiral_row0)

    def local_surface(self, obs: Observation, m: int, i0: int, i1: int, j0: int, j1: int):
        out = np.empty((i1 - i0, j1 - j0), dtype=np.uint16)
        _lookup_sum(self.error_lookup, *self._row_arrays(obs, m), i0, i1, j0, j1, self.nx, out)
        return out

    def local_window(self, x: float, y: float, half_width: float):
        """Cell bounds [i0, i1) x [j0, j1) of the window around (x, y), clipped to the grid."""
        g = self.grid
        if math.isfinite(x) and math.isfinite(y):  # Grid.cell_of in scalar arithmetic
            ci = min(max(round((y - g.origin[1]) / g.resolution), 0), self.ny - 1)
            cj = min(max(round((x - g.origin[0]) / g.resolution), 0), self.nx - 1)
        else:
            ci, cj = g.cell_of(x, y)
        h = int(round(half_width / self.grid.resolution))
        return (max(0, int(ci) - h), min(self.ny, int(ci) + h + 1),
                max(0, int(cj) - h), min(self.nx, int(cj) + h + 1))

    def local_search(self, obs: Observation, theta: float, prior_xy, *,
                     half_width: float = 1.0, refine: bool = True) -> SearchResult | None:
        """Best pose in a window (2 half_width square) around the prior for a known heading.
        ``at_window_edge`` is set when the best cell lies on a window side that is not the
        world's edge (the true minimum may lie outside)."""
        if len(obs) == 0:
            return None
        m = self.scanlines.heading_index(theta)
        i0, i1, j0, j1 = self.local_window(prior_xy[0], prior_xy[1], half_width)
        s = self.local_surface(obs, m, i0, i1, j0, j1)
        bi, bj = divmod(int(np.argmin(s)), s.shape[1])
        i, j = i0 + int(bi), j0 + int(bj)
        edge = ((i == i0 and i0 > 0) or (i == i1 - 1 and i1 < self.ny)
                or (j == j0 and j0 > 0) or (j == j1 - 1 and j1 < self.nx))
        if refine:
            r = self.refine(obs, (i, j), theta)
        else:  # the best cell only, with its quantised error
            x, y = self.grid.centre_of(i, j)
            e = float(s[bi, bj]) / self.q_levels
            r = SearchResult(x=float(x), y=float(y), theta=float(theta), error=e,
                             error_norm=e / max(obs.total_weight, 1e-12), cell=(i, j),
                             n_observations=len(obs))
        r.at_window_edge = bool(edge)
        r.mode = "local"
        return r

    def refine(self, obs: Observation, cell, theta: float, *, max_moves: int = 4) -> SearchResult:
        """Exact sub-cell refinement around ``cell``: the exact error at the continuous heading
        theta on the 3 x 3 cells around it (moving to the lowest while it is not the centre),
        then a least-squares quadratic fit of those 9 values."""
        m0, a = self._heading_bracket(theta)
        interpolate = not (a < 1e-6 or a > 1 - 1e-6)
        if not interpolate:
            m0, a = (m0 + (1 if a > 0.5 else 0)) % self.n_angles, 0.0
        e = np.empty(9)
        # the moves and the exact error on the final 3 x 3 patch (clipped to the grid)
        i, j = divmod(_refine_moves(*self._kernel_arrays(obs), int(cell[0]), int(cell[1]),
                                    self.ny, self.nx, m0, float(a), interpolate, max_moves, e),
                      self.nx)
        e = e.reshape(3, 3)
        W = max(obs.total_weight, 1e-12)
        dx, dy, fmin, hess = _quadratic_minimum(e / W)
        res = self.grid.resolution
        x, y = self.grid.origin[0] + j * res, self.grid.origin[1] + i * res  # Grid.centre_of
        e_norm = float(min(max(fmin, 0.0), float(e[1, 1]) / W))
        return SearchResult(
            x=float(x) + dx * res, y=float(y) + dy * res, theta=float(theta),
            error=e_norm * W, error_norm=e_norm, cell=(i, j), n_observations=len(obs),
            hessian=hess / (res * res))

    def refine_heading(self, obs: Observation, cell, theta: float, *, max_shifts: int = 2,
                       fine: bool = True) -> tuple[SearchResult, float]:
        """Vision estimate of the heading near ``theta``: the position is refined (exactly) at
        the three table headings m - 1, m, m + 1 around theta, and a parabola through their
        error terms gives the heading between table steps (shifting m while the lowest is at
        an end); with ``fine`` a second parabola through theta +- a quarter step (errors with
        the angle-interpolated predictions) sharpens it. The pose is then refined at that
        heading. Returns the result and the curvature of e_norm over the heading (rad^-2, 0 if
        flat)."""
        m = int(round(float(theta) / self.step))
        W = max(obs.total_weight, 1e-12)
        res: dict[int, SearchResult] = {}
        for _ in range(max_shifts + 1):
            for mm in (m - 1, m, m + 1):
                if mm not in res:
                    start = res[m].cell if m in res else cell
                    res[mm] = self.refine(obs, start, mm * self.step)
            e = np.array([res[mm].error / W for mm in (m - 1, m, m + 1)])
            lowest = int(np.argmin(e))
            if lowest == 1:
                break
            cell = res[m - 1 + lowest].cell
            m = m - 1 + lowest
        off, den = _parabola_vertex(e, 0.5)
        curvature = den / self.step**2
        th = (m + off) * self.step
        cell = res[m].cell
        if fine:  # the same fit at a quarter step with the angle-interpolated predictions
            h = 0.25 * self.step
            fine_res = [self.refine(obs, cell, th + dh) for dh in (-h, 0.0, h)]
            off2, den2 = _parabola_vertex(np.array([r.error for r in fine_res]) / W, 1.0)
            th += off2 * h
            cell = fine_res[1].cell
            if den2 > 1e-12:
                curvature = den2 / h**2
        out = self.refine(obs, cell, float(_wrap(th)))
        return out, float(max(curvature, 0.0))

    def unknown_heading_search(self, obs: Observation, *, candidates: int = 8,
                               separation: float = 1.0, half_width: float = 0.3
                               ) -> SearchResult | None:
        """Pose and heading with no heading known: the error lookup on every
        ``coarse_step``-th cell for all 72 table headings, the best ``candidates``
        (heading, cell) pairs (distinct: more than ``separation`` apart or more than one
        table step in heading) refined in full resolution: a local search around each, the
        heading refined between table steps, the pose refined exactly."""
        if len(obs) == 0:
            return None
        n = self.n_angles
        cs = max(1, self.params.coarse_step)
        ncoarse = self.coarse_lookup.shape[1]
        surfaces = np.empty((n, ncoarse), dtype=np.uint16)
        cy, cx = self.coarse_shape
        row_arrays = self._row_arrays(obs, 0)
        for m in range(n):
            _lookup_sum(self.coarse_lookup, *row_arrays[:3], m, *row_arrays[4:], 0, cy, 0, cx,
                        cx, surfaces[m].reshape(cy, cx))
        flat = surfaces.ravel()
        pool = min(flat.size, 64 * candidates)
        cand = np.argpartition(flat, pool - 1)[:pool]
        cand = cand[np.argsort(flat[cand], kind="stable")]
        cm, cc = np.divmod(cand, ncoarse)
        ci, cj = np.divmod(cc, self.coarse_shape[1])
        px, py = self.grid.centre_of(ci * cs, cj * cs)
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
            theta = float(_wrap(int(cm[q]) * self.step))
            r = self.local_search(obs, theta, (float(px[q]), float(py[q])),
                                  half_width=half_width, refine=False)
            r, _ = self.refine_heading(obs, r.cell, theta, fine=False)
            results.append(r)
        results.sort(key=lambda r: r.error)
        for n in range(min(2, len(results))):  # the fine heading fit for the two best
            results[n], _ = self.refine_heading(obs, results[n].cell, results[n].theta)
        best = min(results, key=lambda r: r.error)
        best.mode = "global-heading"
        best.candidates = [(r.x, r.y, r.theta, r.error_norm) for r in results if r is not best]
        best.candidate_error_norm = best.error_norm
        return best

    # ------------------------------------------------------------------ bench reference
    def table_rows_touched(self, obs: Observation, theta: float) -> tuple[np.ndarray, ...]:
        """Raw uint16 table rows (all cells) of the scan lines the observations lie on."""
        m = self.scanlines.heading_index(theta)
        k = (obs.angle_index + m) % self.n_angles
        rad_lines = np.unique(k[obs.family == 0])
        sp = obs.family > 0
        sp_lines = np.unique((obs.family[sp] - 1) * self.n_angles + k[sp])
        return rad_lines, sp_lines

    def time_table_reads(self, obs: Observation, theta: float, repeats: int = 50) -> dict:
        """Median seconds to just read (sum) the memory a global search with known heading
        touches: ``table_rows`` = the raw uint16 table rows of the observed scan lines (all
        crossing slots, all cells), ``lookup_rows`` = the error-lookup rows the search gathers.
        The memory-bound reference for ``fieldloc bench``."""
        rad_lines, sp_lines = self.table_rows_touched(obs, theta)
        rows = self.lookup_rows(obs, self.scanlines.heading_index(theta))

        def read_tables():  # a max over each row: one vectorised pass over its memory
            return ([self.radial_mm[k].max() for k in rad_lines]
                    + [self.spiral_mm[k].max() for k in sp_lines])

        def read_lookup():
            return [self.error_lookup[r].max() for r in rows]

        return {"table_rows": _median_time(read_tables, repeats),
                "lookup_rows": _median_time(read_lookup, repeats),
                "table_bytes": int((len(rad_lines) * MAX_CROSSINGS + len(sp_lines))
                                   * self.ncell * 2),
                "lookup_bytes": int(len(rows) * self.ncell)}


# ---------------------------------------------------------------------------- kernels
# Three numba kernels (compiled once, cached on disk): the error-lookup sum of the searches,
# the exact error term on a few cells, and the cell moves of the sub-cell refinement. They
# follow the numpy definitions above exactly (same float32 arithmetic per observation; the sum
# over observations is accumulated in float64).


@njit("void(uint8[:, ::1], int64[::1], int64[::1], int64[::1], int64, int64, int64, int64,"
      " int64, int64, int64, int64, int64, int64, uint16[:, ::1])", cache=True, nogil=True)
def _lookup_sum(lookup, family, angle_index, bins, m, n_angles, nb_radial, nb_spiral,
                spiral_row0, i0, i1, j0, j1, nx, out):
    """out[i - i0, j - j0] = sum over the observations of lookup[row, i * nx + j] (uint16), the
    quantised error surface on the window [i0, i1) x [j0, j1) of a grid nx cells wide; the
    rows are ``TableSearch.lookup_rows`` at heading index m (``bins``: the observed distances
    in distance bins, rounded)."""
    w = j1 - j0
    out[:, :] = 0
    for o in range(family.shape[0]):
        k = (angle_index[o] + m) % n_angles
        if family[o] == 0:
            r = k * nb_radial + min(bins[o], nb_radial - 1)
        else:
            r = spiral_row0 + ((family[o] - 1) * n_angles + k) * nb_spiral + min(bins[o],
                                                                                nb_spiral - 1)
        row = lookup[r]
        for i in range(i0, i1):
            src = row[i * nx + j0:i * nx + j1]
            dst = out[i - i0]
            for j in range(w):
                dst[j] += src[j]


@njit("void(float32[::1], float32[::1], int64, int64, int64[::1], int64[::1], float32[::1],"
      " float32[::1], float32, float32, int64[::1], int64, float64, boolean, float64[::1])",
      cache=True, nogil=True)
def _exact_error_cells(radial_flat, spiral_flat, ncell, n_angles, family, angle_index, dist,
                       weight, tol, c2, cells, m0, a, interpolate, out):
    """out[c] = sum_i weight[i] * rho(e_i) at flat cell cells[c]: at table heading m0 with
    e = distance to the nearest crossing of the scan line (``interpolate`` False), or at the
    fraction ``a`` between m0 and m0 + 1 with the angle-interpolated prediction of
    ``TableSearch.exact_error_at_heading``."""
    a32 = np.float32(a)
    b32 = np.float32(1.0) - a32
    upper = a > 0.5
    out[:] = 0.0
    for o in range(dist.shape[0]):
        k0 = (angle_index[o] + m0) % n_angles
        k1 = (k0 + 1) % n_angles
        d = dist[o]
        w = weight[o]
        if family[o] == 0:
            r0 = k0 * MAX_CROSSINGS * ncell
            r1 = k1 * MAX_CROSSINGS * ncell
            for ci in range(cells.shape[0]):
                c = cells[ci]
                n0 = radial_flat[r0 + c]
                e0 = abs(n0 - d)
                for h in range(1, MAX_CROSSINGS):
                    t = radial_flat[r0 + h * ncell + c]
                    if abs(t - d) < e0:
                        n0 = t
                        e0 = abs(t - d)
                if interpolate:
                    n1 = radial_flat[r1 + c]
                    e1 = abs(n1 - d)
                    for h in range(1, MAX_CROSSINGS):
                        t = radial_flat[r1 + h * ncell + c]
                        if abs(t - d) < e1:
                            n1 = t
                            e1 = abs(t - d)
                    if abs(n0 - n1) < tol:
                        e = abs((b32 * n0 + a32 * n1) - d)
                    elif upper:
                        e = e1
                    else:
                        e = e0
                else:
                    e = e0
                e2 = e * e
                out[ci] += w * (e2 / (c2 + e2))
        else:
            base = (family[o] - 1) * n_angles
            s0 = (base + k0) * ncell
            s1 = (base + k1) * ncell
            for ci in range(cells.shape[0]):
                c = cells[ci]
                t0 = spiral_flat[s0 + c]
                if interpolate:
                    t1 = spiral_flat[s1 + c]
                    if abs(t0 - t1) < tol:
                        e = abs((b32 * t0 + a32 * t1) - d)
                    elif upper:
                        e = abs(t1 - d)
                    else:
                        e = abs(t0 - d)
                else:
                    e = abs(t0 - d)
                e2 = e * e
                out[ci] += w * (e2 / (c2 + e2))


@njit("int64(float32[::1], float32[::1], int64, int64, int64[::1], int64[::1], float32[::1],"
      " float32[::1], float32, float32, int64, int64, int64, int64, int64, float64, boolean,"
      " int64, float64[::1])", cache=True, nogil=True)
def _refine_moves(radial_flat, spiral_flat, ncell, n_angles, family, angle_index, dist, weight,
                  tol, c2, i, j, ny, nx, m0, a, interpolate, max_moves, out):
    """The cell search of ``TableSearch.refine``: the exact error (``_exact_error_cells``) on
    the 3 x 3 cells around (i, j) (clipped to the grid, row-major, into ``out`` (9,)), moving
    to the lowest while it is not the centre, at most ``max_moves`` times. Returns the final
    cell as the flat index i * nx + j; ``out`` holds the last patch evaluated."""
    cells = np.empty(9, dtype=np.int64)
    for _ in range(max_moves + 1):
        for di in range(3):
            ii = min(max(i - 1 + di, 0), ny - 1)
            for dj in range(3):
                jj = min(max(j - 1 + dj, 0), nx - 1)
                cells[3 * di + dj] = ii * nx + jj
        _exact_error_cells(radial_flat, spiral_flat, ncell, n_angles, family, angle_index,
                           dist, weight, tol, c2, cells, m0, a, interpolate, out)
        b = np.argmin(out)
        ni, nj = cells[b] // nx, cells[b] % nx
        if ni == i and nj == j:
            break
        i, j = ni, nj
    return i * nx + j


# ---------------------------------------------------------------------------- helpers


def _to_metres(mm: np.ndarray) -> np.ndarray:
    out = mm.astype(np.float32) * np.float32(1e-3)
    out[mm == NO_HIT_MM] = NONE_M
    return np.ascontiguousarray(out)


def _rho32(e: np.ndarray, c: float) -> np.ndarray:
    e2 = e * e
    return e2 / (np.float32(c * c) + e2)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _median_time(fn, repeats: int) -> float:
    ts = []
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def _parabola_vertex(e: np.ndarray, limit: float) -> tuple[float, float]:
    """Vertex offset (in sample steps, clipped to +-limit) of the parabola through three
    equally spaced values, and its second difference (0 offset if not a bowl)."""
    den = float(e[0] - 2 * e[1] + e[2])
    if den <= 1e-12:
        return 0.0, 0.0
    return float(np.clip(0.5 * (e[0] - e[2]) / den, -limit, limit)), den


def _min_pooled(lookup_3d: np.ndarray, step: int):
    """The error lookup on every ``step``-th cell, each coarse cell holding the minimum over
    the fine cells within ``step // 2`` cells of it (so every fine cell is covered): per
    observation a lower bound, so the coarse sum never exceeds the fine error term of any
    covered cell and the true basin cannot be skipped by the subsampling."""
    if step == 1:
        return lookup_3d.reshape(lookup_3d.shape[0], -1), lookup_3d.shape[1:]
    rows, ny, nx = lookup_3d.shape
    cy, cx = (ny + step - 1) // step, (nx + step - 1) // step
    r = step // 2
    out = np.full((rows, cy, cx), 255, dtype=np.uint8)
    for di in range(-r, r + 1):
        ci0 = max(0, -(di // step))  # first coarse row whose fine row ci * step + di >= 0
        ci1 = min(cy, (ny - 1 - di) // step + 1)
        if ci1 <= ci0:
            continue
        for dj in range(-r, r + 1):
            cj0 = max(0, -(dj // step))
            cj1 = min(cx, (nx - 1 - dj) // step + 1)
            if cj1 <= cj0:
                continue
            src = lookup_3d[:, ci0 * step + di:(ci1 - 1) * step + di + 1:step,
                            cj0 * step + dj:(cj1 - 1) * step + dj + 1:step]
            np.minimum(out[:, ci0:ci1, cj0:cj1], src, out=out[:, ci0:ci1, cj0:cj1])
    return out.reshape(rows, -1), (cy, cx)


def _best_separated(surface: np.ndarray, shape, k: int, min_cells: float) -> list[int]:
    """Flat indices of up to k lowest cells of a surface (modified in place), each outside the
    square of half-width ``min_cells`` around the ones before (non-maximum suppression)."""
    s = surface.reshape(shape)
    r = max(1, int(math.ceil(min_cells)))
    top = np.iinfo(s.dtype).max if s.dtype.kind in "ui" else np.inf
    out: list[int] = []
    for _ in range(k):
        c = int(np.argmin(surface))
        if out and surface[c] == top:
            break
        out.append(c)
        i, j = divmod(c, shape[1])
        s[max(0, i - r):i + r + 1, max(0, j - r):j + r + 1] = top
    return out


# least-squares quadratic on the 3 x 3 offsets (-1, 0, 1)^2:
# f = a + b x + c y + d x^2 + e x y + f y^2
_QY, _QX = np.mgrid[-1:2, -1:2]
_QA = np.stack([np.ones(9), _QX.ravel(), _QY.ravel(), _QX.ravel() ** 2,
                (_QX * _QY).ravel(), _QY.ravel() ** 2], axis=1)
_QPINV = np.linalg.pinv(_QA)


def _quadratic_minimum(e: np.ndarray):
    """Sub-cell minimum of a 3 x 3 error patch (rows y, columns x): (dx, dy, value, Hessian in
    cell units). Falls back to per-axis parabolas where the fit is not a bowl; offsets are
    clipped to one cell."""
    a, bx, by, dxx, dxy, dyy = (_QPINV @ e.ravel()).tolist()
    hxx, hyy = 2 * dxx, 2 * dyy
    det = hxx * hyy - dxy * dxy
    if det > 1e-12 and hxx > 0:
        ox = -(hyy * bx - dxy * by) / det
        oy = -(hxx * by - dxy * bx) / det
    else:
        ox = oy = 0.0
        for ax, (lo, mid, hi) in enumerate(((e[1, 0], e[1, 1], e[1, 2]),
                                            (e[0, 1], e[1, 1], e[2, 1]))):
            den = float(lo - 2 * mid + hi)
            off = 0.5 * float(lo - hi) / den if den > 1e-12 else 0.0
            ox, oy = (off, oy) if ax == 0 else (ox, off)
    ox, oy = min(max(ox, -1.0), 1.0), min(max(oy, -1.0), 1.0)
    val = a + bx * ox + by * oy + dxx * ox * ox + dxy * ox * oy + dyy * oy * oy
    return ox, oy, val, np.array([[hxx, dxy], [dxy, hyy]])
