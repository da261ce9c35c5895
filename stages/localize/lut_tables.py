"""The map's data as the table search reads it (Ribeiro et al. (2015), section IV-B): the
scan-line tables, the error lookup, and the errors of observations at a pose. Built once per
map and matching parameters and shared by every frame; the searches over it (lut_global.py,
lut_local.py, lut_tracked.py) hold no data of their own. The error term is lut_matching.py's.

The error lookup. The searches never evaluate rho inside the loop over cells. The error lookup
holds, for every scan line (72 radial, 144 spiral), every observed distance quantised to
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
tables (25 MB) and the lookup min-pooled on every ``coarse_step``-th cell and over pairs of
distance bins (20 MB with lut's coarse_step 3; tiled in 8 x 8 blocks, ``lut_kernels.TILE``):
each coarse entry the least of the fine entries within coarse_step // 2 of it and of the
``COARSE_BIN_POOL`` distance bins of its row, so a coarse sum bounds the fine sums of the
cells it covers from below (the searches' branch and bound).

The exact error. The quantised lookup only picks cells; poses are refined with the exact error
(the tables in metres as float32, no quantisation) at a table heading or, between two table
headings, with the crossings interpolated in angle (``exact_error_at_heading``). The same
prediction gives each observation's error at a fix (``observation_errors``), and from it the
fix's inliers (``support``).
"""

from __future__ import annotations

import math
import mmap
from dataclasses import dataclass

import numpy as np

from ..common.errors import SchemaError
from ..common.map_file import MapFile
from ..common.scanlines import NO_HIT_MM
from . import lookup_cache
from .lut_kernels import (
    MAX_CROSSINGS,
    MAX_MM,
    NONE_M,
    TILE,
    Grid,
    MinPooled,
    Observed,
    Quantised,
    exact_error_cells,
    inlier_sums,
    observation_errors_cell,
    observation_predictions_cell,
)
from .lut_matching import MatchingParams, Observation, RadialTable

# distance bins (of distance_bin, 5 cm) per row of the min-pooled lookup: a bound needs no
# finer observed distance than the 10 cm of the cells it pools, and two bins per row halve the
# lookup a process maps (41 -> 20 MB on msl-2015, its peak resident set 265 -> 246 MB). The
# looser bound leaves a few more cells in play: a global search with 16 minima about 10 %
# slower (docs/results.md, the table search's lookup); the picks of the branch and bound are
# the same, the unknown-heading search (which ranks by this lookup) may swap ties
COARSE_BIN_POOL = 2


@dataclass(frozen=True)
class Support:
    """What a fix explains: its inliers are the observations whose error (distance to the
    predicted crossing of their scan line, ``LutTables.observation_errors``) lies below the
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


def support_from_sums(obs: Observation, n, w_in, rho, sq) -> Support:
    """The Support of ``inlier_sums``' (inliers, weight, weighted rho, weighted squared
    error)."""
    return Support(observations=len(obs), inliers=int(n), inlier_weight=w_in,
                   total_weight=obs.total_weight, inlier_rho=rho / w_in if w_in else 0.0,
                   inlier_rms=math.sqrt(sq / w_in) if w_in else math.nan)


class LutTables:
    """The per-map data of the table search (the tables in millimetres, the quantised errors,
    the min-pooled error lookup) and the errors of observations read from them (module doc).
    Build once per map and matching parameters; reuse over frames: nothing of a frame is kept
    here (an Observation keeps its own conversion for the kernels, ``observed``). The tables
    and the min-pooled lookup are mapped from their cache beside the map (lookup_cache) when
    they were built before, and written there otherwise; ``cache=False`` builds them in
    memory only (``lookup_source`` says which happened to the min-pooled lookup)."""

    def __init__(self, map_file: MapFile, params: MatchingParams | None = None, *,
                 cache: bool = True):
        self.params = params or MatchingParams()
        self.grid = map_file.grid
        # the grid's origin and resolution as Python floats (the kernels' Grid bundle; cells
        # of single points: Grid.cell_of_point)
        self.x0, self.y0 = float(self.grid.origin[0]), float(self.grid.origin[1])
        self.resolution = float(self.grid.resolution)
        self.scanlines = map_file.scanlines
        self.field = map_file.field
        ny, nx = self.grid.shape
        self.ny, self.nx, self.ncell = ny, nx, ny * nx
        # the kernels' bundles of scalars are plain tuples (lut_kernels' module doc)
        self.kernel_grid = tuple(Grid(ny, nx, self.x0, self.y0, self.resolution))
        n = self.scanlines.n_angles
        self.n_angles = n
        self.step = self.scanlines.angle_step
        self._map_file = map_file
        mm = tables_in_millimetres(map_file, cache=cache)
        self.radial_table, self.spiral_table = mm["radial"], mm["spiral"]
        # the radial table as the unseen-crossing term reads it (lut_matching.unseen_error)
        self.radial = RadialTable(self.radial_table, self.grid, self.scanlines)
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
        shapes = {"coarse": ((self.coarse_rows_total,
                              self.coarse_nty * self.coarse_ntx * TILE * TILE), np.uint8)}
        if cache:  # mapped from beside the map when it was built before (lookup_cache)
            arrays, self.lookup_source = lookup_cache.load_or_build(
                map_file.path, "min-pooled error lookup",
                {"c": p.c, "range_scale": p.range_scale, "distance_bin": p.distance_bin,
                 "coarse_step": step, "bin_pool": COARSE_BIN_POOL}, shapes,
                self._build_coarse_lookup)
        else:
            arrays, self.lookup_source = self._build_coarse_lookup(), "built, not cached"
        self.coarse_lookup = arrays["coarse"]  # tiled (module doc; with coarse_step 1 a copy)
        self.min_pooled = MinPooled(self.coarse_lookup, step, *self.coarse_shape,
                                    self.coarse_ntx, n, self.nb_radial, self.nb_spiral,
                                    self.coarse_spiral_row0, COARSE_BIN_POOL,
                                    self.coarse_rows_radial, self.coarse_rows_spiral)

    @property
    def radial_mm(self) -> np.ndarray:
        """The map's radial table (uint16 mm), (n_angles, MAX_CROSSINGS, ncell)."""
        return _map_table(self._map_file, "radial").reshape(
            self.n_angles, MAX_CROSSINGS, self.ncell)

    @property
    def spiral_mm(self) -> np.ndarray:
        """The map's spiral table (uint16 mm), (2 n_angles, ncell)."""
        return _map_table(self._map_file, "spiral").reshape(2 * self.n_angles, self.ncell)

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
        # the min-pooled lookup's rows: per scan line its bins, COARSE_BIN_POOL to a row
        self.coarse_rows_radial = -(-self.nb_radial // COARSE_BIN_POOL)
        self.coarse_rows_spiral = -(-self.nb_spiral // COARSE_BIN_POOL)
        self.coarse_spiral_row0 = n * self.coarse_rows_radial
        self.coarse_rows_total = n * self.coarse_rows_radial + 2 * n * self.coarse_rows_spiral
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
        coarse = np.empty((self.coarse_rows_total, self.coarse_nty * self.coarse_ntx * TILE * TILE),
                          dtype=np.uint8)
        radial, spiral = self.radial_table, self.spiral_table
        for line in range(3 * self.n_angles):  # one scan line's rows at a time
            if line < self.n_angles:
                r0 = line * self.coarse_rows_radial
                block = values_radial[:, radial[line]].min(axis=2)
            else:
                s = line - self.n_angles
                r0 = self.coarse_spiral_row0 + s * self.coarse_rows_spiral
                block = values_spiral[:, spiral[s]]
            block = _bins_pooled(block, COARSE_BIN_POOL)
            pooled = _min_pooled(block.reshape(-1, self.ny, self.nx), step)[0]
            coarse[r0:r0 + len(block)] = _tiled(pooled.reshape(-1, cy, cx))
        return {"coarse": coarse}

    def lookup_rows(self, obs: Observation, m: int, *, coarse: bool = False) -> np.ndarray:
        """Rows of the error lookup for the observations at table heading index ``m`` (with
        ``coarse``: of the min-pooled lookup, as ``lut_kernels.lookup_row`` reads it)."""
        pool = COARSE_BIN_POOL if coarse else 1
        rows_r, rows_s = ((self.coarse_rows_radial, self.coarse_rows_spiral) if coarse
                          else (self.nb_radial, self.nb_spiral))
        k = (obs.angle_index + m) % self.n_angles
        bins = np.rint(obs.distance / self.params.distance_bin).astype(np.int64)
        bins_r = np.minimum(bins, self.nb_radial - 1) // pool
        bins_s = np.minimum(bins, self.nb_spiral - 1) // pool
        spiral_line = (obs.family - 1) * self.n_angles + k
        return np.where(obs.family == 0, k * rows_r + bins_r,
                        self.n_angles * rows_r + spiral_line * rows_s + bins_s)

    # ------------------------------------------------------------------ exact error
    def exact_errors(self, obs: Observation, cells, ms) -> np.ndarray:
        """Exact weighted error terms (len(ms), len(cells)) at flat cell indices ``cells`` for
        the table heading indices ``ms``."""
        cells = np.ascontiguousarray(np.asarray(cells, dtype=np.int64).ravel())
        ms = np.atleast_1d(np.asarray(ms, dtype=np.int64))
        total = np.zeros((len(ms), len(cells)))
        kern = self.observed(obs)
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
        m0, a = self.heading_bracket(theta)
        if a < 1e-6 or a > 1 - 1e-6:
            return self.exact_error(obs, cells, (m0 + (1 if a > 0.5 else 0)) % self.n_angles)
        flat = np.ascontiguousarray(cells.ravel())
        total = np.zeros(len(flat))
        exact_error_cells(self.quantised, self.observed(obs),
                          (self.scanlines.heading_index(theta), m0, float(a), True), flat,
                          total)
        return total.reshape(cells.shape)

    def observed(self, obs: Observation) -> Observed:
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
        observation_errors_cell(self.quantised, self.observed(obs), self.at_heading(theta),
                                int(cell[0]) * self.nx + int(cell[1]), out)
        return out

    def observation_predictions(self, obs: Observation, cell, theta: float) -> np.ndarray:
        """Per observation, the crossing distance (m) its scan line predicts at one cell and a
        continuous heading (the prediction ``observation_errors`` measures against)."""
        out = np.empty(len(obs))
        observation_predictions_cell(self.quantised, self.observed(obs), self.at_heading(theta),
                                     int(cell[0]) * self.nx + int(cell[1]), out)
        return out

    def at_heading(self, theta: float) -> tuple:
        """Where the kernels score a continuous heading (lut_kernels.At, as a plain tuple):
        the nearest table heading, and the table heading below it with the fraction of the
        step, or the nearest table heading when the heading is on one."""
        m = self.scanlines.heading_index(theta)
        m0, a = self.heading_bracket(theta)
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

    def support(self, obs: Observation, result, inlier_error: float) -> Support:
        """The inliers of a fix: observations with error below ``inlier_error`` (m) at the
        cell nearest the fix's position, at its heading (``result``: a lut_local.SearchResult)."""
        e = self.observation_errors(obs, self.cell_of(result.x, result.y), result.theta)
        return support_from_sums(obs, *inlier_sums(e, obs.weight64, float(inlier_error),
                                                   self.params.c * self.params.c))

    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        """Grid.cell_of for one point, in scalar arithmetic (Grid.cell_of_point)."""
        return self.grid.cell_of_point(x, y)

    def heading_bracket(self, theta: float) -> tuple[int, float]:
        """The table heading index at or below ``theta`` and the fraction of the step above
        it."""
        u = float(theta) / self.step
        m0 = math.floor(u)
        return m0 % self.n_angles, u - m0


def tables_in_millimetres(map_file: MapFile, *, cache: bool = True) -> dict:
    """The map's tables as the searches read them: ``radial`` (n_angles, ncell,
    MAX_CROSSINGS) and ``spiral`` (2 n_angles, ncell), uint16 mm, and ``max_mm``, the largest
    distance in them (the columns of the quantised errors that are read), mapped from the
    cache beside the map (reading them out of the map's HDF5 file costs a process 0.1-0.2 s
    and their memory). The radial table holds a cell's crossings side by side: the errors of
    a few neighbouring cells (refinement, support, a window) read one or two cache lines per
    scan line and row of cells, where crossing-major rows cost one per crossing."""
    n, ncell = map_file.scanlines.n_angles, map_file.grid.shape[0] * map_file.grid.shape[1]
    shapes = {"radial": ((n, ncell, MAX_CROSSINGS), np.uint16),
              "spiral": ((2 * n, ncell), np.uint16), "max_mm": ((1,), np.uint16)}

    def build() -> dict:
        radial = np.ascontiguousarray(
            _map_table(map_file, "radial").reshape(n, MAX_CROSSINGS, ncell).transpose(0, 2, 1))
        spiral = np.ascontiguousarray(_map_table(map_file, "spiral").reshape(2 * n, ncell))
        top = max(int(np.max(line, where=line != NO_HIT_MM, initial=0))
                  for table in (radial, spiral) for line in table)
        if top >= MAX_MM:
            raise SchemaError(f"{map_file.path}: a scan-line crossing at {top} mm; the"
                              f" table search reads tables up to {MAX_MM - 1} mm")
        return {"radial": radial, "spiral": spiral, "max_mm": np.array([top], np.uint16)}

    if not cache:
        return build()
    return lookup_cache.load_or_build(map_file.path, "tables in millimetres", {}, shapes,
                                      build)[0]


def radial_table(map_file: MapFile) -> RadialTable:
    """The map's radial table as the unseen-crossing term reads it (lut_matching.
    unseen_error), from the same cache as the searches' (tables_in_millimetres)."""
    return RadialTable(tables_in_millimetres(map_file)["radial"], map_file.grid,
                       map_file.scanlines)


def _map_table(map_file: MapFile, name: str) -> np.ndarray:
    """The map's table ``name`` (radial or spiral) as stored, its shape checked against the
    grid and the scan lines."""
    n, (ny, nx) = map_file.scanlines.n_angles, map_file.grid.shape
    t = map_file.table(name)
    want = (n, MAX_CROSSINGS, ny, nx) if name == "radial" else (2, n, ny, nx)
    if t.shape != want:
        raise SchemaError(f"{map_file.path}: table {name} {t.shape} does not match"
                          f" the grid {map_file.grid.shape} and {n} scan lines")
    return t


def _rho32(e: np.ndarray, c: float) -> np.ndarray:
    e2 = e * e
    return e2 / (np.float32(c * c) + e2)


def _tiled(block: np.ndarray) -> np.ndarray:
    """Rows of cells (rows, ny, nx) as the tiled error lookup's rows (module doc): blocks of
    TILE x TILE cells, the grid padded with zeros to whole blocks (never read: windows lie in
    the grid)."""
    rows, ny, nx = block.shape
    nty, ntx = -(-ny // TILE), -(-nx // TILE)
    padded = np.zeros((rows, nty * TILE, ntx * TILE), dtype=block.dtype)
    padded[:, :ny, :nx] = block
    return padded.reshape(rows, nty, TILE, ntx, TILE).transpose(0, 1, 3, 2, 4).reshape(rows, -1)


def _bins_pooled(block: np.ndarray, pool: int) -> np.ndarray:
    """A scan line's lookup rows (distance bins, cells) with every ``pool`` consecutive bins
    reduced to their least entry per cell (the last group holds the bins left)."""
    n = -(-block.shape[0] // pool)
    padded = np.full((n * pool,) + block.shape[1:], np.iinfo(block.dtype).max, block.dtype)
    padded[:block.shape[0]] = block
    return padded.reshape((n, pool) + block.shape[1:]).min(axis=1)


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

