"""How a frame's scan-line observations are matched against the map's tables (Ribeiro et al.
(2015), section IV-B): the error term, its parameters, and the observations as the table
search reads them.

A frame's observations are the white-line crossing distances the robot found on its scan
lines: up to 4 per radial line (``radial`` (72, 4), NaN = none) and one per spiral
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

These definitions are shared by the tables (lut_tables.py), the searches (lut_global.py,
lut_local.py, lut_tracked.py) and their kernels (lut_kernels.py); they live here, apart from
the map's data, because the point fit (fit.py) weighs the same observations without tables.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..common.map_file import Grid
from ..common.scanlines import ScanLines, rotate_to_heading
from .lut_kernels import MAX_CROSSINGS, evidence_weights, flatten_scanlines, observation_points


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
    # (LutTables.observed; an Observation is not changed after it is made: its derived
    # copies are new ones)
    _observed: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _points: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _sums: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _radial_rows: tuple | None = field(default=None, init=False, repr=False, compare=False)

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


# ---------------------------------------------------------------------------- unseen crossings

# m: a table crossing counts as seen when an observed crossing of its radial line lies within
# this distance of it (half the matching's ``pair_tolerance``: the same line seen from a pose
# a cell or a 5 deg table heading away, through a mirror calibration off by a decimetre)
UNSEEN_TOLERANCE_M = 0.3
# m: how much nearer than the farthest crossing its line observed a table crossing must be to
# count as one the line should have seen (beyond the farthest observation the line may have
# been blocked, or its crossings too thin to find; within the tolerance above it is the same)
UNSEEN_REACH_MARGIN_M = 0.3


@dataclass(frozen=True)
class RadialTable:
    """The map's radial scan-line table as the unseen-crossing term reads it: ``table``
    (n_angles, ncell, MAX_CROSSINGS) uint16 mm (65535 none; lut_tables.tables_in_millimetres),
    on ``grid`` (common.map_file.Grid) with ``scanlines``."""

    table: np.ndarray
    grid: Grid
    scanlines: ScanLines

    def rows(self, pose) -> np.ndarray:
        """The crossings (uint16 mm) a robot at ``pose`` (x, y, theta) sees on its own radial
        lines, row k its line k: the table at the pose's cell and nearest table heading
        (stages.common.scanlines.rotate_to_heading)."""
        i, j = self.grid.cell_of_point(pose[0], pose[1])
        cell = self.table[:, i * self.grid.shape[1] + j, :]
        return rotate_to_heading(cell, self.scanlines.heading_index(float(pose[2])), axis=0)

    def unseen_error(self, obs: Observation, pose, params: MatchingParams) -> float:
        """``unseen_error`` of ``obs`` at ``pose``."""
        return unseen_error(self.rows(pose), obs, params)


def _radial_rows(obs: Observation, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(observed (n, MAX_CROSSINGS), within (n,)) of ``obs``'s radial lines: per line its
    observed crossings (m; 1e9 none, farther than any table crossing) and how far a table
    crossing may lie to count as one the line should have seen (its farthest crossing less
    ``UNSEEN_REACH_MARGIN_M``; -inf for a line that saw nothing). Computed once per
    observation set: every candidate pose of a frame reads them."""
    if obs._radial_rows is None or obs._radial_rows[0].shape[0] != n:
        rad = obs.family == 0
        line, d = obs.angle_index[rad], obs.distance[rad]
        within = np.full(n, -np.inf)
        np.maximum.at(within, line, d - UNSEEN_REACH_MARGIN_M)
        observed = np.full((n, MAX_CROSSINGS), 1e9)
        order = np.argsort(line, kind="stable")
        line, d = line[order], d[order]
        slot = np.arange(len(line)) - np.searchsorted(line, line)  # place among its line's
        keep = slot < MAX_CROSSINGS
        observed[line[keep], slot[keep]] = d[keep]
        obs._radial_rows = (observed, within)
    return obs._radial_rows


def unseen_error(rows_mm: np.ndarray, obs: Observation, params: MatchingParams) -> float:
    """The paper's error term the other way round, for the map's crossings a pose predicts
    and the robot did not see (E, Ribeiro et al. 2015, charges what was seen and the map does
    not have). E alone has no cost for a map line the scan lines should have crossed: a look-
    alike place (the penalty area's front line and the halfway line, 6.75 m apart on an MSL
    field, explain the same few crossings) scores as well as the truth although it predicts
    lines (the centre circle) that nothing in the image shows.

    Per radial line k: every table crossing t (``rows_mm`` (n, MAX_CROSSINGS), the robot's
    own lines, RadialTable.rows) nearer than the farthest crossing observed on line k by more than
    ``UNSEEN_REACH_MARGIN_M`` (the line saw floor that far, so it would have crossed the line
    at t) and with no observed crossing of line k within ``UNSEEN_TOLERANCE_M`` costs w(t) *
    1, the saturated error, as an observed crossing the map does not have costs in E (the
    same units, so E + this is the error term of both kinds of miss). Lines without an
    observation tell nothing (blocked, or only far floor): they cost nothing, as in E. Spirals
    report one crossing only and are left out. ``obs``: the frame's observations (their
    radial family, distances as corrected)."""
    observed, within = _radial_rows(obs, rows_mm.shape[0])
    # m; "none" (65535 mm) lies beyond every line's reach, so it is never unseen
    t = rows_mm * 0.001
    # the nearest observed crossing of the same line to each table crossing
    near = np.min(np.abs(t[:, :, None] - observed[:, None, :]), axis=2)
    unseen = (t < within[:, None]) & (near > UNSEEN_TOLERANCE_M)
    return float(np.sum(params.weight(t[unseen])))
