"""Pose search in the scan-line tables of Ribeiro et al. (2015), section IV-B.

Matching. A frame's observations are the white-line crossing distances the robot found on its
scan lines: up to 4 per radial line (``radial`` (72, 4), NaN = none) and one per spiral
(``spiral`` (2, 72)). For a robot at cell c with heading m * 5 deg, observed scan line k is
compared with table line (k + m) mod 72 of cell c (stages.common.scanlines.rotate_to_heading).
Every observed distance d is matched to the nearest table crossing of its line; its error
e = |d - t_nearest| enters the error term as

    w(d) * rho(e),   rho(e) = 1 - c^2 / (c^2 + e^2) = e^2 / (c^2 + e^2)

the paper's eq. 5: quadratic for e << c, saturating at 1 for e >> c, so a false hit or a missed
line costs at most one unit. A table entry of "none" where an observation exists costs the
saturated error (rho = 1). Scan lines without an observation are ignored. Nearer points weigh
more:  w(d) = 1 / (1 + (d / range_scale)^2)  (default range_scale 2 m: w = 0.94 at 0.5 m, 0.5 at
2 m, 0.2 at 4 m), because a catadioptric mirror maps far ground onto few pixels, so the distance
of a far crossing is much less certain than that of a near one. The error term of a pose is the
sum over observations; its normalised value e_norm = sum / sum(w) lies in [0, 1).

Speed. The search never evaluates rho inside the loop over cells. Its *error lookup* holds,
for every scan line (72 radial, 144 spiral), every observed distance quantised to
``distance_bin`` (5 cm) and every cell, the value w(d) * rho(e) quantised to 0..Q (Q = 151, so
that the sum over the at most 432 observations of a frame fits a uint16), and the error
surface of a frame is the sum of one lookup row per observation. Stored whole, that lookup
would take hundreds of MB per field (docs/results.md), so it is not stored: an entry is computed
when a search reads it, from the map's uint16 tables (millimetres, a cell's crossings side by
side) and, per distance bin, the quantised error of every table value (``Quantised``, 0.5 MB:
the entry is the least of its crossings' values, the nearest crossing's, as the value grows
with the error). The same float32 operations as the stored lookup's build, so the same
entries to the bit (tests/test_lut_layout.py holds them to that build in numpy). What is
stored, and mapped from the cache beside the map (stages.localize.lookup_cache), is the
tables (25 MB) and the lookup min-pooled on every ``coarse_step``-th cell (41 MB with lut's
coarse_step 3; tiled in 8 x 8 blocks, ``lut_kernels.TILE``): each coarse entry the least of
the fine entries within coarse_step // 2 of it, so a coarse sum bounds the fine sums of the
cells it covers from below.

The searches compute the fine surface only where that bound does not rule a cell out (branch
and bound, numba kernels in lut_kernels.py): the global search's separated minima
(``separated_minima``: the coarse cells opened in the order of their bound, a computed cell
passed to the greedy once it lies below every bound not opened: a small part of the field)
and the best cell of a window (``tracked_window``, which the local search and a track's fix
use: the cells of the least bound first, then every cell whose bound is not above
the best score they found). Both pick the same cells as the whole surface would. A whole
surface (``surface``, the grid belief's; ``local_surface``) is computed cell by cell. A
track's fix (``tracked_fix``: the window ranked by the posterior, the refinement of its basin
and of the prior's, the support, the line points' fit) is one compiled call. The quantised
surface only picks cells; the pose is then refined with the exact error (the tables in
metres as float32, no quantisation):

- sub-cell position: exact error on the 3 x 3 cells around the best cell (moving to a lower
  neighbour until the centre is the minimum), then a least-squares quadratic fit of the 9 values;
  the fitted minimum (clipped to one cell) is the position, its Hessian the shape of the fix;
- heading between the 5 deg table headings: the error at heading theta is interpolated linearly
  between the error surfaces of the two neighbouring table headings (m and m + 1, weights by the
  fraction of the step); ``refine_heading`` fits a parabola through the error at theta - 5 deg,
  theta, theta + 5 deg for a vision estimate of the heading.

``unknown_heading_search`` evaluates all 72 headings on every ``coarse_step``-th cell in x
and y (the min-pooled lookup), keeps the best few (heading, cell) candidates and refines each
in full resolution with a local search, the exact refinement, and heading refinement.
"""

from __future__ import annotations

import math
import mmap
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..common.geometry import wrap_angle
from ..common.map_file import MapFile
from ..common.scanlines import NO_HIT_MM
from . import lookup_cache
from .lut_kernels import (
    MAX_CROSSINGS,
    MAX_MM,
    NONE_M,
    TILE,
    Grid,
    LineFit,
    MinPooled,
    Observed,
    Posterior,
    Quantised,
    evidence_weights,
    exact_error_cells,
    flatten_scanlines,
    inlier_sums,
    observation_errors_cell,
    observation_points,
    observation_predictions_cell,
    refine_cell,
    separated_minima,
    tiled_sum,
    tracked_fix,
    tracked_window,
    tracked_window_bound,
    weighted_cells,
    window_sum,
)


@dataclass(frozen=True)
class MatchingParams:
    """How observations are scored against the tables (see the module doc)."""

    c: float = 0.25  # m, scale of rho(e) = e^2 / (c^2 + e^2)
    range_scale: float = 2.0  # m, w(d) = 1 / (1 + (d / range_scale)^2)
    distance_bin: float = 0.05  # m, quantisation of observed distances in the error lookup
    use_spiral: bool = True  # match spiral observations too
    coarse_step: int = 2  # cells, subsampling of the unknown-heading pass
    pair_tolerance: float = 0.6  # m, crossings of neighbouring scan lines taken as one line

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
    # the weights of the error lookup, when ``weight`` holds evidence weights
    # (``with_evidence``); None: ``weight`` is the lookup's
    lookup_weight: np.ndarray | None = None
    # the kernels' bundle (distance bin, lut_kernels.Observed), converted once
    # (TableSearch._observed; an Observation is not changed after it is made: its derived
    # copies are new ones)
    _observed: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _points: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _sums: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __len__(self):
        return len(self.distance)

    def with_evidence(self, scanlines, per_structure: float, link: float,
                      link_per_m: float) -> Observation:
        """These observations weighted as evidence: the crossings of one white structure
        (points, robot frame, chained by gaps under ``link`` + ``link_per_m`` * range m: a
        line seen by many scan lines, a cable near the robot) are one correlated measurement,
        so together they carry at most ``per_structure`` observations' worth: weight *
        min(1, per_structure / structure size). The exact error terms (refinement, support)
        use these weights; the error lookup keeps the paper's (``lookup_weight``)."""
        p = self.points(scanlines)
        base = self.weight if self.lookup_weight is None else self.lookup_weight
        weight = evidence_weights(p, np.ascontiguousarray(self.distance, dtype=np.float64),
                                  np.ascontiguousarray(base, dtype=np.float64), float(link),
                                  float(link_per_m), float(per_structure))
        out = Observation(family=self.family, angle_index=self.angle_index,
                          distance=self.distance, weight=weight, lookup_weight=base)
        out._points = self._points  # the same scan lines and distances: the same points
        return out

    def _weight_sums(self) -> tuple:
        """(total weight, total lookup weight, weight as contiguous float64), computed once."""
        if self._sums is None:
            lw = self.weight if self.lookup_weight is None else self.lookup_weight
            self._sums = (float(self.weight.sum()), float(lw.sum()),
                          np.ascontiguousarray(self.weight, dtype=np.float64))
        return self._sums

    @property
    def lookup_total_weight(self) -> float:
        """Total weight in the units of the error lookup (the paper's weights)."""
        return self._weight_sums()[1]

    @property
    def total_weight(self) -> float:
        return self._weight_sums()[0]

    @property
    def weight64(self) -> np.ndarray:
        """``weight`` as the kernels' contiguous float64 array."""
        return self._weight_sums()[2]

    @classmethod
    def from_scanlines(cls, radial, spiral, params: MatchingParams, max_range: float,
                       spiral_end_radius: float, robot_radius: float = 0.0) -> Observation:
        """From the features' ``radial`` (72, 4) and ``spiral`` (2, 72) arrays (m, NaN = none).
        Distances outside the scan lines' reach are dropped."""
        r = np.ascontiguousarray(radial, dtype=np.float64).reshape(-1, MAX_CROSSINGS)
        s = (np.ascontiguousarray(spiral, dtype=np.float64).reshape(2, -1)
             if spiral is not None else np.zeros((2, 0)))
        family, angle_index, distance, weight = flatten_scanlines(
            r, s, bool(params.use_spiral and spiral is not None), float(robot_radius),
            float(max_range), float(spiral_end_radius), float(params.range_scale))
        return cls(family=family, angle_index=angle_index, distance=distance, weight=weight)

    def subset(self, mask) -> Observation:
        """The observations selected by a boolean mask (or index array)."""
        return Observation(family=self.family[mask], angle_index=self.angle_index[mask],
                           distance=self.distance[mask], weight=self.weight[mask],
                           lookup_weight=None if self.lookup_weight is None
                           else self.lookup_weight[mask])

    def random_bearings(self, perm: np.ndarray) -> Observation:
        """The null copy of these observations: the same distances on scan lines shuffled at
        random, ``perm`` (3, n_angles) a permutation of the scan lines per family (radial,
        spiral ccw, spiral cw), so each scan line keeps its crossings but their bearings
        carry no information."""
        out = Observation(family=self.family, angle_index=perm[self.family, self.angle_index],
                          distance=self.distance, weight=self.weight,
                          lookup_weight=self.lookup_weight)
        out._sums = self._sums  # the same weights
        if self._observed is not None:  # and distance bins
            b, kern = self._observed
            out._observed = (b, kern._replace(
                angle_index=np.ascontiguousarray(out.angle_index, dtype=np.int64)))
        return out

    def points(self, scanlines) -> np.ndarray:
        """The observations as points (N, 2) in the robot frame (computed once per scan-line
        geometry; not to be written to)."""
        key = (float(scanlines.angle_step), float(scanlines.robot_radius),
               float(scanlines.spiral_end_radius))
        if self._points is None or self._points[0] != key:
            self._points = (key, observation_points(
                self.family, self.angle_index,
                np.ascontiguousarray(self.distance, dtype=np.float64), *key))
        return self._points[1]


class EvidenceTuning(NamedTuple):
    """How observations of one white structure count as one correlated measurement
    (Observation.with_evidence): ``per_structure`` observations' worth a structure carries at
    most, structures chained by gaps under ``link`` m plus ``link_per_m`` m per m of range
    (scan lines spread with distance)."""

    per_structure: float
    link: float
    link_per_m: float


# lut's and fit's (docs/manual.md: a structure counts as at most 6 independent points)
EVIDENCE = EvidenceTuning(per_structure=6.0, link=0.2, link_per_m=0.1)


def frame_observations(fr: dict, search: TableSearch, radial, evidence: EvidenceTuning
                       ) -> tuple[Observation, np.ndarray]:
    """A features frame's scan-line observations for the table search, and their distances
    as observed: the calibration's error removed when ``radial`` (a RadialCorrection or None)
    is active, then weighted as evidence (``evidence``: EvidenceTuning;
    Observation.with_evidence)."""
    sl = search.scanlines
    obs = Observation.from_scanlines(fr.get("radial", np.zeros((0, 4))), fr.get("spiral"),
                                     search.params, sl.max_range, sl.spiral_end_radius,
                                     sl.robot_radius)
    raw_distance = obs.distance
    if radial is not None and radial.active:
        d = radial.correct(raw_distance)
        obs = Observation(family=obs.family, angle_index=obs.angle_index, distance=d,
                          weight=search.params.weight(d), lookup_weight=obs.lookup_weight)
    obs = obs.with_evidence(sl, evidence.per_structure, evidence.link, evidence.link_per_m)
    return obs, raw_distance


def random_bearing_points(points: np.ndarray, perm: np.ndarray, angle_step: float
                          ) -> np.ndarray:
    """The null copy of line points (N, 2, robot frame): each point turned with its nearest
    radial scan line to where ``perm`` (n_angles,) sends that line (Observation.
    random_bearings' radial permutation), keeping its range and its offset from the line, so
    the points and the scan lines of one copy are shuffled alike."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    n = len(perm)
    bearing = np.arctan2(p[:, 1], p[:, 0])
    line = np.rint(bearing / angle_step).astype(np.int64) % n
    turned = bearing + (np.asarray(perm, np.int64)[line] - line) * angle_step
    rho = np.hypot(p[:, 0], p[:, 1])
    return np.stack([rho * np.cos(turned), rho * np.sin(turned)], axis=1)


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
    inlier_rms: float = math.nan  # m, weighted root mean square error of the inliers

    @property
    def inlier_share(self) -> float:
        """Inliers / observations."""
        return self.inliers / max(self.observations, 1)


class TableSearch:
    """The per-map data of the table search (the tables in millimetres, the quantised errors,
    the min-pooled error lookup) and the searches. Build once per map and matching
    parameters; reuse over frames. The tables and the min-pooled lookup are mapped from their
    cache beside the map (lookup_cache) when they were built before, and written there
    otherwise; ``cache=False`` builds them in memory only (``lookup_source`` says which
    happened to the min-pooled lookup)."""

    def __init__(self, map_file: MapFile, params: MatchingParams | None = None, *,
                 cache: bool = True):
        self.params = params or MatchingParams()
        self.grid = map_file.grid
        # the grid's origin and resolution as Python floats, for the scalar cell arithmetic
        # (_cell_of, local_window: the same float64 operations without numpy scalars)
        self._x0, self._y0 = float(self.grid.origin[0]), float(self.grid.origin[1])
        self._res = float(self.grid.resolution)
        self.scanlines = map_file.scanlines
        self.field = map_file.field
        ny, nx = self.grid.shape
        self.ny, self.nx, self.ncell = ny, nx, ny * nx
        # the kernels' bundles of scalars are plain tuples (lut_kernels' module doc)
        self._grid = tuple(Grid(ny, nx, self._x0, self._y0, self._res))
        n = self.scanlines.n_angles
        self.n_angles = n
        self.step = self.scanlines.angle_step
        self._map_file = map_file
        # the map's tables (uint16 mm), scan-line-major, mapped from the cache beside the map
        # like the min-pooled lookup (reading them out of the map's HDF5 file costs a process
        # 0.1-0.2 s and their memory). The radial table holds a cell's crossings side by side
        # ((line, cell, crossing)): the errors of a few neighbouring cells (refinement,
        # support, a window) read one or two cache lines per scan line and row of cells,
        # where crossing-major rows cost one per crossing. ``max_mm``: the largest distance
        # in them, the width of the quantised errors (Quantised)
        shapes_mm = {"radial": ((n, self.ncell, MAX_CROSSINGS), np.uint16),
                     "spiral": ((2 * n, self.ncell), np.uint16),
                     "max_mm": ((1,), np.uint16)}
        if cache:
            mm, _ = lookup_cache.load_or_build(map_file.path, "tables in millimetres", {},
                                               shapes_mm, self._tables_in_millimetres)
        else:
            mm = self._tables_in_millimetres()
        self.radial_table, self.spiral_table = mm["radial"], mm["spiral"]
        self._lookup_layout()
        values = self._quantised_errors(int(mm["max_mm"][0]))
        # the exact error's constants in its float32 arithmetic (lut_kernels.Quantised)
        self.quantised = Quantised(self.radial_table.reshape(-1), self.spiral_table.reshape(-1),
                                   self.ncell, n, values.reshape(-1), values.shape[1],
                                   self.nb_radial, self.nb_spiral,
                                   np.float32(self.params.pair_tolerance),
                                   np.float32(self.params.c * self.params.c))
        p = self.params
        step = max(1, p.coarse_step)
        shapes = {"coarse": ((self.lookup_rows_total,
                              self.coarse_nty * self.coarse_ntx * TILE * TILE), np.uint8)}
        if cache:  # mapped from beside the map when it was built before (lookup_cache)
            arrays, self.lookup_source = lookup_cache.load_or_build(
                map_file.path, "min-pooled error lookup",
                {"c": p.c, "range_scale": p.range_scale, "distance_bin": p.distance_bin,
                 "coarse_step": step}, shapes, self._build_coarse_lookup)
        else:
            arrays, self.lookup_source = self._build_coarse_lookup(), "built, not cached"
        self.coarse_lookup = arrays["coarse"]  # tiled (module doc; with coarse_step 1 a copy)
        self.min_pooled = MinPooled(self.coarse_lookup, step, *self.coarse_shape,
                                    self.coarse_ntx, n, self.nb_radial, self.nb_spiral,
                                    self.spiral_row0)

    @property
    def radial_mm(self) -> np.ndarray:
        """The map's radial table (uint16 mm), (n_angles, MAX_CROSSINGS, ncell)."""
        return self._map_table("radial").reshape(
            self.n_angles, MAX_CROSSINGS, self.ncell)

    @property
    def spiral_mm(self) -> np.ndarray:
        """The map's spiral table (uint16 mm), (2 n_angles, ncell)."""
        return self._map_table("spiral").reshape(2 * self.n_angles, self.ncell)

    def _map_table(self, name: str) -> np.ndarray:
        n, (ny, nx) = self.n_angles, self.grid.shape
        t = self._map_file.table(name)
        want = (n, MAX_CROSSINGS, ny, nx) if name == "radial" else (2, n, ny, nx)
        if t.shape != want:
            from ..common.errors import SchemaError

            raise SchemaError(f"{self._map_file.path}: table {name} {t.shape} does not match"
                              f" the grid {self.grid.shape} and {n} scan lines")
        return t

    def _tables_in_millimetres(self) -> dict:
        """The map's tables as the search reads them (the radial table (line, cell,
        crossing)) and the largest distance in them (``max_mm``, the columns of the quantised
        errors that are read)."""
        radial = np.ascontiguousarray(self.radial_mm.transpose(0, 2, 1))
        spiral = np.ascontiguousarray(self.spiral_mm)
        top = max(int(np.max(line, where=line != NO_HIT_MM, initial=0))
                  for table in (radial, spiral) for line in table)
        if top >= MAX_MM:
            from ..common.errors import SchemaError

            raise SchemaError(f"{self._map_file.path}: a scan-line crossing at {top} mm; the"
                              f" table search reads tables up to {MAX_MM - 1} mm")
        return {"radial": radial, "spiral": spiral, "max_mm": np.array([top], np.uint16)}

    @property
    def lookup_nbytes(self) -> int:
        """Bytes of the arrays the search maps: the tables and the min-pooled lookup."""
        return self.radial_table.nbytes + self.spiral_table.nbytes + self.coarse_lookup.nbytes

    # ------------------------------------------------------------------ error lookup
    def _lookup_layout(self):
        """The error lookup's rows: distance bins per scan line, quantisation levels."""
        n = self.n_angles
        b = self.params.distance_bin
        self.nb_radial = int(math.ceil(self.scanlines.max_range / b)) + 1
        self.nb_spiral = int(math.ceil(self.scanlines.spiral_end_radius / b)) + 1
        max_obs = n * MAX_CROSSINGS + 2 * n
        self.q_levels = int(np.iinfo(np.uint16).max // max_obs)
        self.spiral_row0 = n * self.nb_radial
        self.lookup_rows_total = n * self.nb_radial + 2 * n * self.nb_spiral
        step = max(1, self.params.coarse_step)  # the min-pooled lookup, tiled (module doc)
        self.coarse_shape = ((self.ny + step - 1) // step, (self.nx + step - 1) // step)
        self.coarse_nty = -(-self.coarse_shape[0] // TILE)
        self.coarse_ntx = -(-self.coarse_shape[1] // TILE)

    def _quantised_errors(self, max_mm: int) -> np.ndarray:
        """The quantised error of every table value per distance bin (``Quantised``): for bin
        b (distance d = b * distance_bin) and table value t (mm, 0..max_mm, then "none"),
        rint(q_levels * w(d) * rho(|t - d|)) in float32 as the search has always computed
        it; the radial bins' rows, then the spiral bins' (uint8)."""
        p = self.params
        t = np.append(np.arange(max_mm + 1).astype(np.float32) * np.float32(1e-3),
                      np.float32(NONE_M))
        d = np.concatenate([np.arange(self.nb_radial), np.arange(self.nb_spiral)]) * p.distance_bin
        scale = (float(self.q_levels) * p.weight(d)).astype(np.float32)[:, None]
        e = np.abs(t[None, :] - d[:, None].astype(np.float32))
        values = np.rint(scale * _rho32(e, p.c)).astype(np.uint8)
        # indexed by the table values as they are; the columns between the largest distance
        # and "none" are never read: zero pages of an anonymous mapping, they take no memory
        # (8 MB where a heap allocation would be written whole)
        out = np.frombuffer(mmap.mmap(-1, len(d) * (NO_HIT_MM + 1)), dtype=np.uint8).reshape(
            len(d), NO_HIT_MM + 1)
        out[:, :max_mm + 1] = values[:, :-1]
        out[:, NO_HIT_MM] = values[:, -1]
        return out

    def _build_coarse_lookup(self) -> dict:
        """The min-pooled error lookup (tiled, ``coarse``; module doc): the error lookup's
        rows, one scan line at a time, each cell the least quantised error of its crossings
        (``Quantised``), min-pooled."""
        q = self.quantised
        values = q.values.reshape(-1, q.width)
        values_radial, values_spiral = values[:self.nb_radial], values[self.nb_radial:]
        step = max(1, self.params.coarse_step)
        cy, cx = self.coarse_shape
        coarse = np.empty((self.lookup_rows_total, self.coarse_nty * self.coarse_ntx * TILE * TILE),
                          dtype=np.uint8)
        radial, spiral = self.radial_table, self.spiral_table
        for line in range(3 * self.n_angles):  # one scan line's rows at a time
            if line < self.n_angles:
                r0, block = line * self.nb_radial, values_radial[:, radial[line]].min(axis=2)
            else:
                s = line - self.n_angles
                r0, block = self.spiral_row0 + s * self.nb_spiral, values_spiral[:, spiral[s]]
            pooled = _min_pooled(block.reshape(-1, self.ny, self.nx), step)[0]
            coarse[r0:r0 + len(block)] = _tiled(pooled.reshape(-1, cy, cx))
        return {"coarse": coarse}

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
        kern = self._observed(obs)
        for h, m in enumerate(ms):
            m = int(m) % self.n_angles
            exact_error_cells(self.quantised, kern, (m, m, 0.0, False), cells, total[h])
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
        exact_error_cells(self.quantised, self._observed(obs),
                          (self.scanlines.heading_index(theta), m0, float(a), True), flat,
                          total)
        return total.reshape(cells.shape)

    def _observed(self, obs: Observation) -> Observed:
        """The observations as the kernels read them (lut_kernels.Observed), converted once
        per Observation and distance bin."""
        b = self.params.distance_bin
        if obs._observed is None or obs._observed[0] != b:
            obs._observed = (b, Observed(
                np.ascontiguousarray(obs.family, dtype=np.int64),
                np.ascontiguousarray(obs.angle_index, dtype=np.int64),
                np.rint(obs.distance / b).astype(np.int64),
                np.ascontiguousarray(obs.distance, dtype=np.float32),
                np.ascontiguousarray(obs.weight, dtype=np.float32), obs.weight64))
        return obs._observed[1]

    def observation_errors(self, obs: Observation, cell, theta: float) -> np.ndarray:
        """Per observation, the error e = |d - predicted crossing| (m) at one cell (i, j) and
        a continuous heading: the same prediction as ``exact_error_at_heading`` (the nearest
        table crossing at a table heading, angle-interpolated crossings between them); a
        "none" table entry gives an error of about NONE_M."""
        out = np.empty(len(obs))
        observation_errors_cell(self.quantised, self._observed(obs), self._at(theta),
                                int(cell[0]) * self.nx + int(cell[1]), out)
        return out

    def observation_predictions(self, obs: Observation, cell, theta: float) -> np.ndarray:
        """Per observation, the crossing distance (m) its scan line predicts at one cell and a
        continuous heading (the prediction ``observation_errors`` measures against)."""
        out = np.empty(len(obs))
        observation_predictions_cell(self.quantised, self._observed(obs), self._at(theta),
                                     int(cell[0]) * self.nx + int(cell[1]), out)
        return out

    def _at(self, theta: float) -> tuple:
        """Where the kernels score a continuous heading (lut_kernels.At, as a plain tuple):
        the nearest table heading, and the table heading below it with the fraction of the
        step, or the nearest table heading when the heading is on one."""
        m = self.scanlines.heading_index(theta)
        m0, a = self._heading_bracket(theta)
        if a < 1e-6 or a > 1 - 1e-6:
            return m, (m0 + (1 if a > 0.5 else 0)) % self.n_angles, 0.0, False
        return m, m0, float(a), True

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
        e = self.observation_errors(obs, self._cell_of(result.x, result.y), result.theta)
        return self._support(obs, *inlier_sums(e, obs.weight64, float(inlier_error),
                                               self.params.c * self.params.c))

    @staticmethod
    def _support(obs: Observation, n, w_in, rho, sq) -> Support:
        """The Support of ``inlier_sums``' (inliers, weight, weighted rho, weighted squared
        error)."""
        return Support(observations=len(obs), inliers=int(n), inlier_weight=w_in,
                       total_weight=obs.total_weight, inlier_rho=rho / w_in if w_in else 0.0,
                       inlier_rms=math.sqrt(sq / w_in) if w_in else math.nan)

    def _cell_of(self, x: float, y: float) -> tuple[int, int]:
        """Grid.cell_of for one point, in scalar arithmetic."""
        return (min(max(round((y - self._y0) / self._res), 0), self.ny - 1),
                min(max(round((x - self._x0) / self._res), 0), self.nx - 1))

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
        starts = self.separated_minima(obs, m, candidates, separation / self.grid.resolution)
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

    def surface(self, obs: Observation, theta: float) -> np.ndarray:
        """The error term of every cell (ny, nx), in full-weight observations, at the table
        heading nearest ``theta``, from the error lookup (quantised), each observation
        weighed by ``obs.weight`` (its evidence weight where ``with_evidence`` set one: a
        white structure near the robot, a cable, counts as one correlated measurement)."""
        m = self.scanlines.heading_index(theta)
        lw = obs.weight if obs.lookup_weight is None else obs.lookup_weight
        scale = np.where(lw > 0, obs.weight / np.where(lw > 0, lw, 1.0), 0.0)
        out = np.empty(self.ncell, dtype=np.float32)
        weighted_cells(self.quantised, self._observed(obs), m,
                       np.ascontiguousarray(scale, dtype=np.float32), out)
        return out.reshape(self.ny, self.nx).astype(np.float64) / float(self.q_levels)

    def _surface(self, obs: Observation, m: int) -> np.ndarray:
        """The quantised error surface of every cell (flat, uint16) at table heading m."""
        return self.local_surface(obs, m, 0, self.ny, 0, self.nx).reshape(-1)

    def separated_minima(self, obs: Observation, m: int, k: int, min_cells: float
                         ) -> np.ndarray:
        """Flat indices of up to k lowest cells of the quantised error surface at table
        heading m (lowest value, then lowest index), each outside the square of half-width
        ``min_cells`` around the ones before (non-maximum suppression, greedy), by branch and
        bound on the min-pooled lookup (lut_kernels.separated_minima): the same cells as the
        greedy on the whole surface (``_surface``), which is computed only where the bound
        does not rule a cell out (a small part of the field: docs/results.md)."""
        out = np.empty(max(k, 0), dtype=np.int64)
        n = separated_minima(self.quantised, self.min_pooled, self._observed(obs), int(m),
                             self._grid, int(k), max(1, int(math.ceil(min_cells))), out)
        return out[:n]

    def local_surface(self, obs: Observation, m: int, i0: int, i1: int, j0: int, j1: int):
        """The quantised error surface (uint16) at table heading m on the window
        [i0, i1) x [j0, j1)."""
        out = np.empty((i1 - i0, j1 - j0), dtype=np.uint16)
        window_sum(self.quantised, self._observed(obs), int(m), i0, i1, j0, j1, self.nx, out)
        return out

    def local_window(self, x: float, y: float, half_width: float):
        """Cell bounds [i0, i1) x [j0, j1) of the window around (x, y), clipped to the grid."""
        x, y = float(x), float(y)
        if math.isfinite(x) and math.isfinite(y):  # Grid.cell_of in scalar arithmetic
            ci = min(max(round((y - self._y0) / self._res), 0), self.ny - 1)
            cj = min(max(round((x - self._x0) / self._res), 0), self.nx - 1)
        else:
            ci, cj = self.grid.cell_of(x, y)
        h = int(round(half_width / self._res))
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
        best, value = tracked_window(self.quantised, self.min_pooled, self._observed(obs), m,
                                     (i0, i1, j0, j1), self._grid,
                                     _LEAST_SURFACE)  # no prior
        i, j = divmod(int(best), self.nx)
        edge = ((i == i0 and i0 > 0) or (i == i1 - 1 and i1 < self.ny)
                or (j == j0 and j0 > 0) or (j == j1 - 1 and j1 < self.nx))
        if refine:
            r = self.refine(obs, (i, j), theta)
        else:  # the best cell only, with its quantised error
            x, y = self.grid.centre_of(i, j)
            e = float(value) / self.q_levels
            r = SearchResult(x=float(x), y=float(y), theta=float(theta), error=e,
                             error_norm=e / max(obs.total_weight, 1e-12), cell=(i, j),
                             n_observations=len(obs))
        r.at_window_edge = bool(edge)
        r.mode = "local"
        return r

    def tracked_fix(self, obs: Observation, theta: float, prior_xy, prior_information,
                    temperature: float, fix_temperature: float, inlier_error: float, *,
                    half_width: float = 1.0, prior_cap: float = math.inf, fit=None):
        """The paper's local search around a tracked prior, ranked by the posterior, in one
        compiled call (``lut_kernels.tracked_fix``): in the window (2 half_width square)
        around ``prior_xy`` the cell minimising E(cell) / temperature + min(0.5 d^T
        ``prior_information`` d, ``prior_cap``) (d = cell - prior, the prior's inverse
        position covariance (2, 2); the cap: a prior that may be wrong, a Gaussian with a
        uniform floor), refined to sub-cell in its basin (``refine``). The window's choice
        rests on the lookup's quantised error term: when it lies more than two cells from
        the prior, the basin the prior lies in is refined too and taken when its exact error
        / ``fix_temperature`` + the capped Mahalanobis term is lower. ``fit``: (PointFit, the
        observations' points, max_shift, max_turn): the fix is then moved by the line
        points' fit at its heading (PointFit.refine with ``fixed_heading``) after its support
        is counted (its ``cell``, ``error`` and Hessian stay the table's). Returns (fix, its
        ``support`` with ``inlier_error``, the posterior score of the window's best cell,
        the fix's position (x, y) before the points' fit)."""
        pf, points, max_shift, max_turn = fit if fit is not None else (None, _NO_POINTS, 0, 0)
        line_fit = LineFit(
            pf is not None, *((pf.table, *pf.origin, pf.resolution) if pf is not None
                              else (_NO_RASTER, 0.0, 0.0, 1.0)),
            points, pf.c * pf.c if pf is not None else 1.0, float(theta),
            float(min(max_shift, 1e9)), float(min(max_turn, 1e9)))
        rule = (max(obs.total_weight, 1e-12), float(fix_temperature), float(inlier_error),
                self.params.c * self.params.c)  # lut_kernels.FixRule
        out = np.empty(19)
        tracked_fix(self.quantised, self.min_pooled, self._observed(obs), self._at(theta),
                    self.local_window(prior_xy[0], prior_xy[1], half_width), self._grid,
                    self._posterior(prior_xy, prior_information, temperature, prior_cap),
                    rule, line_fit, out)
        x, y, e, e_norm, ci, cj, hxx, hxy, hyy, edge, window_fit, own = out[:12].tolist()
        fix = SearchResult(x=x, y=y, theta=float(theta), error=e, error_norm=e_norm,
                           cell=(int(ci), int(cj)), n_observations=len(obs),
                           hessian=np.array([[hxx, hxy], [hxy, hyy]]),
                           at_window_edge=edge > 0, mode="local")
        n, w_in, rho, sq, fx, fy, fth = out[12:].tolist()
        if pf is not None:
            fix.x, fix.y, fix.theta = fx, fy, fth
        return fix, self._support(obs, n, w_in, rho, sq), window_fit, (x, y)

    def tracked_score(self, obs: Observation, theta: float, prior_xy, prior_information,
                      temperature: float, *, half_width: float = 1.0,
                      prior_cap: float = math.inf) -> float:
        """The best posterior score of ``tracked_fix``'s window (quantised error term /
        temperature + capped Mahalanobis term), without refining it."""
        return self._tracked_window(obs, theta, prior_xy, prior_information, temperature,
                                    half_width, prior_cap)[1]

    def tracked_score_bound(self, obs: Observation, theta: float, prior_xy, prior_information,
                            temperature: float, *, half_width: float = 1.0,
                            prior_cap: float = math.inf) -> float:
        """A lower bound of ``tracked_score`` from the min-pooled error lookup (the
        unknown-heading search's; ``tracked_window_bound``): never above it, about
        ``coarse_step``^2 times cheaper, so a score below the bound is below the score."""
        return tracked_window_bound(
            self.min_pooled, self._observed(obs), self.scanlines.heading_index(theta),
            self.local_window(prior_xy[0], prior_xy[1], half_width), self._grid,
            self._posterior(prior_xy, prior_information, temperature, prior_cap))

    def _tracked_window(self, obs, theta, prior_xy, info, temperature, half_width, cap):
        return tracked_window(
            self.quantised, self.min_pooled, self._observed(obs),
            self.scanlines.heading_index(theta),
            self.local_window(prior_xy[0], prior_xy[1], half_width), self._grid,
            self._posterior(prior_xy, info, temperature, cap))

    def _posterior(self, prior_xy, info, temperature: float, cap: float) -> tuple:
        """The tracked kernels' ranking (lut_kernels.Posterior, as a plain tuple): the error
        term's scale (1 / (q_levels temperature)), the prior's position, its information
        (xx, xy, yy) and the Mahalanobis term's cap."""
        return (1.0 / (self.q_levels * temperature), float(prior_xy[0]), float(prior_xy[1]),
                float(info[0, 0]), float(info[0, 1]), float(info[1, 1]),
                float(min(cap, 1e300)))

    def refine(self, obs: Observation, cell, theta: float, *, max_moves: int = 4) -> SearchResult:
        """Exact sub-cell refinement around ``cell``: the exact error at the continuous heading
        theta on the 3 x 3 cells around it (moving to the lowest while it is not the centre,
        at most ``max_moves`` times), then a least-squares quadratic fit of those 9 values (the
        compiled ``refine_cell``, which tracked_fix runs too)."""
        out = np.empty(9)
        refine_cell(self.quantised, self._observed(obs), self._at(theta), self._grid,
                    int(cell[0]), int(cell[1]), int(max_moves), max(obs.total_weight, 1e-12),
                    out)
        x, y, e, e_norm, ci, cj, hxx, hxy, hyy = out.tolist()
        return SearchResult(
            x=x, y=y, theta=float(theta), error=e, error_norm=e_norm, cell=(int(ci), int(cj)),
            n_observations=len(obs), hessian=np.array([[hxx, hxy], [hxy, hyy]]))

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
        out = self.refine(obs, cell, float(wrap_angle(th)))
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
        cy, cx = self.coarse_shape
        ncoarse = cy * cx
        surfaces = np.empty((n, ncoarse), dtype=np.uint16)
        kern = self._observed(obs)
        for m in range(n):
            tiled_sum(self.min_pooled, kern, m, (0, cy, 0, cx), surfaces[m].reshape(cy, cx))
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
            theta = float(wrap_angle(int(cm[q]) * self.step))
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


# ---------------------------------------------------------------------------- helpers


def _rho32(e: np.ndarray, c: float) -> np.ndarray:
    e2 = e * e
    return e2 / (np.float32(c * c) + e2)


def _parabola_vertex(e: np.ndarray, limit: float) -> tuple[float, float]:
    """Vertex offset (in sample steps, clipped to +-limit) of the parabola through three
    equally spaced values, and its second difference (0 offset if not a bowl)."""
    den = float(e[0] - 2 * e[1] + e[2])
    if den <= 1e-12:
        return 0.0, 0.0
    return float(np.clip(0.5 * (e[0] - e[2]) / den, -limit, limit)), den


def _tiled(block: np.ndarray) -> np.ndarray:
    """Rows of cells (rows, ny, nx) as the tiled error lookup's rows (module doc): blocks of
    TILE x TILE cells, the grid padded with zeros to whole blocks (never read: windows lie in
    the grid)."""
    rows, ny, nx = block.shape
    nty, ntx = -(-ny // TILE), -(-nx // TILE)
    padded = np.zeros((rows, nty * TILE, ntx * TILE), dtype=block.dtype)
    padded[:, :ny, :nx] = block
    return padded.reshape(rows, nty, TILE, ntx, TILE).transpose(0, 1, 3, 2, 4).reshape(rows, -1)


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


_NO_POINTS = np.zeros((0, 2))
_NO_RASTER = np.zeros((2, 2), dtype=np.float32)
# a tracked window ranked by its quantised surface alone (local_search: no prior)
_LEAST_SURFACE = tuple(Posterior(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
