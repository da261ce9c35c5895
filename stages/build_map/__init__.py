"""Stage build-map: a field model plus the lookup tables of Ribeiro et al. (2015) in one HDF5 map.

    from stages import build_map
    build_map.main(build_map.confs["default"], "msl-2015", "msl-2015.map.h5")
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

from ..common.artifacts import check_output, root_attrs, text_hash
from ..common.conf import check_bounds, stage_conf
from ..common.crossing_tables import crossing_association_tables
from ..common.errors import FieldlocError
from ..common.field import MAX_BORDER_M, FieldModel, field_file, load_field
from ..common.map_file import MAX_CELLS, MAX_RESOLUTION, SCHEMA, VERSION, Grid, write_map
from ..common.resources import check_memory
from ..common.scanlines import MAX_RANGE_M, ScanLines
from . import tables

log = logging.getLogger(__name__)

confs = {
    "default": {
        "resolution": 0.1,  # m, table cell size (Ribeiro et al. 2015: 10 cm)
        "border": 1.0,  # m of world around the field (Ribeiro et al. 2015: 20 x 14 m for 18 x 12)
        "max_range": 4.0,  # m, radial scan-line search limit
        "robot_radius": 0.25,  # m, where every scan line starts
        "spiral_end_radius": 2.0,  # m, spiral radius after one full turn
    },
}

# the widest world margin around the field a map covers (m): a field's own border's bound
# (common.field.MAX_BORDER_M); 1e308 m overflowed the grid's cell count before memory was
# checked

# the ranges a conf's values must lie in for the tables to be built at all
# (common.conf.check_bounds): the scan lines' ranges are extract's (common.scanlines)
BOUNDS = {"border": (0, MAX_BORDER_M), "max_range": ((0,), MAX_RANGE_M),
          # m: a robot of no radius divided by zero in the scan lines' tables (trial Q8), one
          # of 1e-300 m overflowed there (trial R); the smallest robots (NAO) are about 0.1 m
          # in radius, the largest (MSL) about 0.26 m: 1 cm to 2 m
          "robot_radius": (0.01, 2.0),
          "spiral_end_radius": ((0,), MAX_RANGE_M)}

# peak memory of building the tables per world cell (measured: spl at 5 and 2.5 cm, 4.5 KB)
BYTES_PER_CELL = 4.6e3
DEFAULT_SPIRAL_M = 2.0


def scanlines_of(conf: dict) -> ScanLines:
    return ScanLines(
        robot_radius=float(conf["robot_radius"]),
        max_range=float(conf["max_range"]),
        spiral_end_radius=float(conf["spiral_end_radius"]),
    )


def check_conf(conf: dict) -> None:
    """A build-map conf's values checked (FieldlocError), without a field: what a batch SPEC's
    ``build_map`` is refused for before anything runs."""
    values = {k: conf[k] for k in confs["default"]}
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values.values()):
        raise FieldlocError(f"build-map conf values must be finite numbers, got {values}")
    if conf["resolution"] <= 0 or conf["border"] < 0:
        raise FieldlocError("resolution must be > 0 and border >= 0")
    if conf["resolution"] > MAX_RESOLUTION:
        raise FieldlocError(f"resolution {conf['resolution']:g} m is coarser than"
                            f" {MAX_RESOLUTION:g} m: a map places the robot no better than its"
                            " cells, and cells that size cover a goal area's lines in one")
    check_bounds(conf, BOUNDS)
    scanlines_of(conf).check()


def check_size(fm: FieldModel, conf: dict) -> Grid:
    """The grid of the map of ``fm`` with ``conf`` (checked), refused (FieldlocError) where it
    holds more cells than a map may (MAX_CELLS, fewer with a wider spiral): what a batch SPEC
    is refused for before anything runs (trial X3-5), and build-map before it builds."""
    check_conf(conf)
    grid = Grid.around(fm, float(conf["border"]), float(conf["resolution"]))
    ny, nx = grid.shape
    # a cell's cost grows with the spiral's radius about as 1 + r / 2 (measured at 0.1 m on
    # msl-2015, 28,000 cells: 1.5-2.1 s at 2 m after one turn, 11 s at 10 m, 21 s at 49.9 m;
    # the radial lines' max_range barely counts, 2.7 s at 50 m); MAX_CELLS is the default's
    spiral = max(float(conf["spiral_end_radius"]), DEFAULT_SPIRAL_M)
    most = int(MAX_CELLS * (1 + DEFAULT_SPIRAL_M / 2) / (1 + spiral / 2))
    if nx * ny > most:
        raise FieldlocError(
            f"build-map of {fm.name} at {conf['resolution']:g} m: {nx} x {ny} cells, more than"
            f" the {most:,} a map may hold with a {spiral:g} m spiral (about 75 us of CPU a"
            " cell); choose a coarser --resolution (the paper's is 0.1 m)")
    return grid


def build_tables(fm: FieldModel, conf: dict) -> tuple[Grid, ScanLines, dict]:
    """All tables of a map, in memory: name -> (array, attributes)."""
    grid = check_size(fm, conf)
    ny, nx = grid.shape
    log.info("build-map %s: %d x %d cells of %g m", fm.name, nx, ny, grid.resolution)
    check_memory(
        f"build-map of {fm.name} ({fm.length:g} x {fm.width:g} m + {conf['border']:g} m border"
        f" at {conf['resolution']:g} m: {nx} x {ny} cells)",
        {"tables": float(nx) * float(ny) * BYTES_PER_CELL})
    sl = scanlines_of(conf)
    common = {"resolution": grid.resolution, "robot_radius": sl.robot_radius}
    out = {}
    t0 = time.perf_counter()
    out["radial"] = (
        tables.radial_table(fm, grid, sl),
        dict(common, heading=0.0, angle_step_deg=360.0 / sl.n_angles, max_range=sl.max_range,
             max_crossings=sl.max_crossings, no_hit=65535,
             description="centre-line crossings along radial scan line k at 5k deg"),
    )
    t1 = time.perf_counter()
    out["spiral"] = (
        tables.spiral_table(fm, grid, sl),
        dict(common, heading=0.0, angle_step_deg=360.0 / sl.n_angles,
             spiral_end_radius=sl.spiral_end_radius, no_hit=65535,
             description="first crossing radius of spiral [ccw, cw][start angle 5k deg]"),
    )
    t2 = time.perf_counter()
    dist, grad = tables.distance_table(fm, grid)
    out["distance"] = (dist, dict(common, description="distance to nearest line centre line"))
    out["distance_gradient"] = (grad, dict(common, description="gradient (d/dx, d/dy)"))
    t3 = time.perf_counter()
    log.info("tables: radial %.2fs, spiral %.2fs, distance %.2fs", t1 - t0, t2 - t1, t3 - t2)
    out.update(crossing_association_tables(fm, grid))
    log.info("crossing association tables %.2fs", time.perf_counter() - t3)
    return grid, sl, out


def main(conf: str | dict | None, field: str | Path | FieldModel, output: str | Path, *,
         overwrite: bool = False, progress: bool = False) -> Path:
    """Build the map of ``field`` (preset name, YAML path or FieldModel) into ``output``.
    ``conf``: a preset name, None, or a dict of values replacing the default preset's."""
    conf = stage_conf(confs, conf)
    yaml_file = None if isinstance(field, FieldModel) else field_file(field)
    output = check_output(output, {"field": yaml_file}, overwrite=overwrite, schema=SCHEMA)
    fm = field if isinstance(field, FieldModel) else load_field(field)
    grid, sl, tabs = build_tables(fm, conf)
    attrs = root_attrs(SCHEMA, VERSION, conf=conf,
                       inputs={"field": fm.name, "field_yaml": text_hash(fm.spec_text)})
    attrs["border"] = float(conf["border"])
    return write_map(output, fm, grid, sl, tabs, attrs)
