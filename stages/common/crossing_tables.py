"""Crossing association tables (Schulz et al. 2011, section 5.1).

A crossing observation is not unique: a particle must decide which field crossing it saw.
Instead of searching all crossings of a type per particle, the paper splits the L crossings by
their global orientation into four sets (45, 135, 225 and 315 deg) and looks up, for the field
position where the particle places the observation, the closest L crossing of the set nearest
to the observation's global orientation. T crossings are far enough apart that the closest T
per position suffices. X crossings (and lines) are associated per particle (see
stages.localize.observation_model).

Computed from the field model by build-map, which stores them in the map under /tables (cells
as in stages.common.map_file.Grid); localize takes them from a map with ``of_map`` (which
computes them on the map's grid for a map that does not hold them), or computes them here when
it has a field and no map:

    crossing_lut_L   (4, ny, nx) i2   index into /field/crossings of the closest L crossing
                                      whose orientation is nearest to 45, 135, 225, 315 deg
                                      (first axis); -1 where the field has no L of that set
    crossing_lut_T   (ny, nx) i2      index into /field/crossings of the closest T crossing;
                                      -1 where the field has no T crossing
"""

from __future__ import annotations

import math

import numpy as np

from .field import FieldModel
from .map_file import Grid, MapFile

# The four global L orientations of the paper (bisector of the arms), in radians.
L_ORIENTATIONS = np.array([0.25, 0.75, 1.25, 1.75]) * math.pi
NO_CROSSING = -1


def l_orientation_bin(orientation) -> np.ndarray:
    """Index (0..3) of the L orientation set nearest to each global orientation (rad)."""
    a = np.mod(np.asarray(orientation, dtype=float), 2 * math.pi)
    # bins are centred on 45 + 90 k deg: floor(a / 90 deg) is exactly the nearest centre
    return np.minimum((a // (math.pi / 2)).astype(np.int64), 3)


def _closest_index(grid: Grid, positions: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(ny, nx) index (from ``indices``) of the closest of ``positions`` to each cell centre."""
    ny, nx = grid.shape
    if len(indices) == 0:
        return np.full((ny, nx), NO_CROSSING, dtype=np.int16)
    xs, ys = grid.xs, grid.ys
    # squared distance separably: (ny, 1, K) + (1, nx, K); the cells are few enough (~1e5)
    dx2 = (xs[:, None] - positions[None, :, 0]) ** 2  # (nx, K)
    dy2 = (ys[:, None] - positions[None, :, 1]) ** 2  # (ny, K)
    best = np.argmin(dy2[:, None, :] + dx2[None, :, :], axis=2)  # first index wins ties
    return np.asarray(indices, dtype=np.int16)[best]


def crossing_association_tables(field_model: FieldModel, grid: Grid) -> dict:
    """The crossing association tables of ``field_model`` on ``grid``.

    Returns name -> (array, attributes), ready for stages.common.map_file.write_map:
    ``crossing_lut_L`` (4, ny, nx) int16 and ``crossing_lut_T`` (ny, nx) int16, holding indices
    into ``field_model.crossings`` (the map's /field/crossings order), -1 where there is none.
    """
    if len(field_model.crossings) >= np.iinfo(np.int16).max:
        raise ValueError("too many crossings for an int16 table")
    types = np.asarray(field_model.crossing_types)
    pos = np.asarray(field_model.crossings, dtype=float).reshape(-1, 2)
    orient = np.asarray(field_model.crossing_orientation, dtype=float)

    l_idx = np.flatnonzero(types == "L")
    l_bin = l_orientation_bin(orient[l_idx])
    lut_l = np.stack(
        [_closest_index(grid, pos[l_idx[l_bin == k]], l_idx[l_bin == k]) for k in range(4)]
    )
    t_idx = np.flatnonzero(types == "T")
    lut_t = _closest_index(grid, pos[t_idx], t_idx)

    common = {
        "units": "index",
        "index_into": "/field/crossings",
        "none": NO_CROSSING,
        "source": "Schulz et al. (2011), section 5.1",
    }
    return {
        "crossing_lut_L": (
            lut_l,
            dict(
                common,
                orientations=L_ORIENTATIONS.copy(),
                description=(
                    "per cell, for each global L orientation set (axis 0: 45, 135, 225, 315"
                    " deg, the bisector of the arms), the index of the closest L crossing of"
                    " that set; -1 = the field has no L of that set"
                ),
            ),
        ),
        "crossing_lut_T": (
            lut_t,
            dict(
                common,
                description="per cell, the index of the closest T crossing; -1 = no T crossing",
            ),
        ),
    }


def of_map(map_file: MapFile) -> tuple[np.ndarray, np.ndarray]:
    """The crossing association tables of a map: ``crossing_lut_L`` (4, ny, nx) and
    ``crossing_lut_T`` (ny, nx), as the map holds them, or computed on the map's grid for a map
    that does not hold them."""
    if map_file.has_table("crossing_lut_L") and map_file.has_table("crossing_lut_T"):
        return map_file.table("crossing_lut_L"), map_file.table("crossing_lut_T")
    tabs = crossing_association_tables(map_file.field, map_file.grid)
    return tabs["crossing_lut_L"][0], tabs["crossing_lut_T"][0]
