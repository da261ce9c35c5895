"""The map artifact (schema ``fieldloc.map``, version 1): field model plus lookup tables.

Root attributes: the common ones plus
    field        field name;  field_source: where its dimensions come from
    origin       (x, y) of the centre of cell [0, 0] (m); cell [i, j] is at
                 origin + (j, i) * resolution (row i along y, column j along x)
    resolution   cell size (m);  shape: (ny, nx);  border: world margin around the field (m)
    scanlines    JSON of the scan-line definition (stages.common.scanlines.ScanLines)

    /field/segments            (S, 2, 2) f8  m    line centre lines [[x0, y0], [x1, y1]]
    /field/arcs                (A, 5) f8     m, rad  cx, cy, r, start angle, sweep (ccw > 0)
    /field/line_width          () f8         m
    /field/penalty_marks       (P, 2) f8     m    (the centre spot first)
    /field/goal_posts          (G, 2) f8     m
    /field/crossings/position  (C, 2) f8     m
    /field/crossings/type      (C,) str      L, T or X
    /field/crossings/arms      (C, 4) f8     rad  arm directions, NaN padded
    /field/crossings/orientation (C,) f8     rad  L: bisector, T: stem, X: first arm mod 90 deg
    /field/spec_yaml           () str        the field YAML as given

    /tables/radial             (72, 4, ny, nx) u2  mm   radial scan line k at 5k deg (heading 0):
                               centre-line crossings nearest first; 65535 = none
    /tables/spiral             (2, 72, ny, nx) u2  mm   first crossing radius of the spiral with
                               start angle 5k deg, ccw (0) / cw (1); 65535 = none
    /tables/distance           (ny, nx) f4    m    distance to the nearest line centre line
    /tables/distance_gradient  (2, ny, nx) f4  -   d distance / d (x, y)
    /tables/crossing_lut_L     (4, ny, nx) i2  -   index into /field/crossings of the closest L
                               crossing of each orientation set (45, 135, 225, 315 deg), -1 none
    /tables/crossing_lut_T     (ny, nx) i2     -   index of the closest T crossing, -1 none

Each table carries its parameters as attributes. One scan line's values over all cells are
contiguous (C order, cells last), which is what the table search reads.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import yaml

from .artifacts import open_artifact, read_json_attr, stored_dataset, write_artifact
from .conf import MAX_RECORD_BYTES, load_yaml
from .errors import SchemaError
from .field import FieldModel, field_from_spec
from .resources import check_disk
from .scanlines import MAX_RANGE_M, MAX_SCAN_ANGLES, MAX_SCAN_CROSSINGS, ScanLines
from .user_numbers import json_float

log = logging.getLogger(__name__)

HDF5_OVERHEAD = 1 << 20  # bytes beyond the arrays: field, attributes, HDF5's own structures

SCHEMA = "fieldloc.map"
VERSION = 1

# m: the coarsest table cell (build-map's bound on what it writes, and the reader's on what it
# reads). A pose from the map is only as good as its cell; the narrowest areas of a field (goal
# areas, 0.5 to 1 m deep) fall into one cell of a metre, so a coarser map tells nothing (the
# default is 0.1 m, the tests' coarse maps 0.25 to 0.5 m). The finest cell is bounded by the
# grid itself: its cells must span the field (MapFile._check_grid)
MAX_RESOLUTION = 1.0
# the most cells a map may hold (build-map's bound, scaled down for a wider spiral, and the
# reader's): a cell costs build-map about 75 us with the default spiral (msl-2015 at 5 cm,
# 112,000 cells: 8.5 s of CPU; trial P: at 1.2 cm, 1.9 million, past a minute), and 300,000
# holds the largest league field (MSL, 24 x 16 m with its border) at 4 cm and SPL's at 2 cm,
# finer than the paper's 10 cm. A reader refuses more, as it refuses tables of another shape
# than the grid's, before reading them (a 25 MB file of a (72, 4, 14100, 20100) table read
# into "out of memory", trial T)
MAX_CELLS = 300_000

# each table's element type, as build-map writes it: the searches read radial and spiral as
# millimetres in uint16 and the distances as float32 (float64 of 1e300 became inf there, and
# radial tables of other types indexed past their lookups: tracebacks, trial W1-3, W1-4)
TABLE_DTYPES = {"radial": "u2", "spiral": "u2", "distance": "f4", "distance_gradient": "f4",
                "crossing_lut_L": "i2", "crossing_lut_T": "i2"}
TABLE_UNITS = {
    "radial": "mm",
    "spiral": "mm",
    "distance": "m",
    "distance_gradient": "1",
    "crossing_lut_L": "index",
    "crossing_lut_T": "index",
}


@dataclass
class Grid:
    """The world grid of the tables: cell centres on multiples of the resolution."""

    origin: tuple[float, float]
    resolution: float
    shape: tuple[int, int]  # (ny, nx)

    @classmethod
    def around(cls, fm: FieldModel, border: float, resolution: float) -> Grid:
        xmin, xmax, ymin, ymax = fm.world_bounds(border)
        # cell centres on multiples of the resolution, covering the world inclusive
        j0, j1 = np.floor(xmin / resolution + 1e-9), np.ceil(xmax / resolution - 1e-9)
        i0, i1 = np.floor(ymin / resolution + 1e-9), np.ceil(ymax / resolution - 1e-9)
        nx, ny = int(j1 - j0) + 1, int(i1 - i0) + 1
        return cls(origin=(j0 * resolution, i0 * resolution), resolution=resolution,
                   shape=(ny, nx))

    @property
    def xs(self) -> np.ndarray:
        return self.origin[0] + np.arange(self.shape[1]) * self.resolution

    @property
    def ys(self) -> np.ndarray:
        return self.origin[1] + np.arange(self.shape[0]) * self.resolution

    def cell_of(self, x, y):
        """(row, col) of the cell containing field point (x, y), clipped to the grid."""
        j = np.clip(np.rint((np.asarray(x) - self.origin[0]) / self.resolution), 0,
                    self.shape[1] - 1).astype(int)
        i = np.clip(np.rint((np.asarray(y) - self.origin[1]) / self.resolution), 0,
                    self.shape[0] - 1).astype(int)
        return i, j

    def cell_of_point(self, x: float, y: float) -> tuple[int, int]:
        """``cell_of`` for one point, in Python's scalar float arithmetic (no numpy scalars:
        the searches call it several times a frame)."""
        r = float(self.resolution)
        return (min(max(round((float(y) - float(self.origin[1])) / r), 0), self.shape[0] - 1),
                min(max(round((float(x) - float(self.origin[0])) / r), 0), self.shape[1] - 1))

    def centre_of(self, i, j):
        return (self.origin[0] + np.asarray(j) * self.resolution,
                self.origin[1] + np.asarray(i) * self.resolution)


def write_map(path: str | Path, fm: FieldModel, grid: Grid, scanlines: ScanLines,
              tables: dict[str, tuple[np.ndarray, dict]], attrs: dict) -> Path:
    """Write the map atomically. ``tables``: name -> (array, attributes). A map that does not
    fit on the disk is refused before it is written (HDF5 meeting a full disk mid-file
    fails with messages of its own, and can crash the process)."""
    path = Path(path)
    need = sum(np.asarray(arr).nbytes for arr, _ in tables.values()) + HDF5_OVERHEAD
    check_disk(f"the map {path}", path.parent if str(path.parent) else Path("."), need)
    attrs = dict(attrs)
    attrs.update(
        field=fm.name,
        field_source=fm.source,
        origin=np.asarray(grid.origin, dtype=float),
        resolution=float(grid.resolution),
        shape=np.asarray(grid.shape, dtype=np.int64),
        scanlines=json.dumps(scanlines.as_dict()),
    )
    with write_artifact(path, attrs) as h5:
        g = h5.create_group("field")
        for name, arr, units in (
            ("segments", fm.segments, "m"),
            ("arcs", fm.arcs, "m, m, m, rad, rad"),
            ("penalty_marks", fm.penalty_marks, "m"),
            ("goal_posts", fm.goal_posts, "m"),
        ):
            g.create_dataset(name, data=arr).attrs["units"] = units
        g.create_dataset("line_width", data=fm.line_width).attrs["units"] = "m"
        c = g.create_group("crossings")
        c.create_dataset("position", data=fm.crossings).attrs["units"] = "m"
        c.create_dataset("type", data=np.array(list(fm.crossing_types), dtype=h5py.string_dtype()))
        c.create_dataset("arms", data=fm.crossing_arms).attrs["units"] = "rad"
        c.create_dataset("orientation", data=fm.crossing_orientation).attrs["units"] = "rad"
        g.create_dataset("spec_yaml", data=fm.spec_text, dtype=h5py.string_dtype())
        t = h5.create_group("tables")
        for name, (arr, tattrs) in tables.items():
            ds = t.create_dataset(name, data=arr)
            ds.attrs["units"] = TABLE_UNITS.get(name, tattrs.pop("units", ""))
            for k, v in tattrs.items():
                ds.attrs[k] = v
    return path


# the (map, dataset) pairs whose difference from the spec was said in this process
_SAID: set[tuple[str, str]] = set()


def _metres(v) -> bool:
    """Whether ``v`` is a scan-line length a map may give: a number from 0 to MAX_RANGE_M."""
    x = json_float(v)
    return x is not None and 0 <= x <= MAX_RANGE_M


class MapFile:
    """Read access to a map: the field model, the grid, and tables loaded on demand."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.h5 = open_artifact(self.path, SCHEMA, VERSION)
        try:
            a = self.h5.attrs
            origin, shape = np.ravel(a["origin"]), np.ravel(a["shape"])
            if (len(origin) != 2 or len(shape) != 2 or origin.dtype.kind not in "fiu"
                    or shape.dtype.kind not in "iu"):
                raise ValueError(f"origin {str(a['origin'])[:40]} and shape"
                                 f" {str(a['shape'])[:40]} must be two real numbers and two"
                                 " whole numbers")
            self.grid = Grid(origin=tuple(float(v) for v in origin),
                             resolution=float(a["resolution"]),
                             shape=tuple(int(v) for v in shape))
            self.scanlines = ScanLines(**json.loads(a["scanlines"]))
            spec = stored_dataset(self.h5, "field/spec_yaml", "map file")
            if spec.shape != ():
                raise ValueError(f"/field/spec_yaml has shape {spec.shape}; expected one text")
            spec_text = spec[()]
            spec_text = spec_text.decode() if isinstance(spec_text, bytes) else spec_text
            if not isinstance(spec_text, str) or len(spec_text) > MAX_RECORD_BYTES:
                raise ValueError(f"/field/spec_yaml is no field YAML of at most"
                                 f" {MAX_RECORD_BYTES >> 20} MB, as a field file may weigh")
            self.field = field_from_spec(load_yaml(spec_text), str(self.path), spec_text)
            self._check_grid()
            self._check_field_lines()
        except RecursionError:  # the scanlines attribute nested 100k deep (trial W1-1)
            self.h5.close()
            raise SchemaError(f"{self.path}: damaged map file (its scanlines attribute is JSON"
                              " nested too deep)") from None
        except (KeyError, ValueError, TypeError, OSError, yaml.YAMLError) as e:
            self.h5.close()
            raise SchemaError(f"{self.path}: damaged map file ({str(e)[:200]})") from None
        except SchemaError:
            self.h5.close()
            raise
        self._cache: dict[str, np.ndarray] = {}

    def _check_grid(self) -> None:
        """The grid places every cell and covers the field, as build-map writes it: an origin
        that is not finite, or a resolution that is not a number in (0, MAX_RESOLUTION], would
        divide by zero, overflow or place cells at NaN in the searches and pictures, and a
        grid whose cells do not span the field's lines (a resolution of 1e-308 m: a grid of
        no size) would place every pose in one corner cell."""
        g = self.grid
        said = (f"{self.path}: damaged map file (origin {str(g.origin)[:40]}, resolution"
                f" {str(g.resolution)[:20]}")
        if not (all(math.isfinite(v) for v in g.origin) and math.isfinite(g.resolution)
                and 0 < g.resolution <= MAX_RESOLUTION):
            raise SchemaError(f"{said}: the origin must be finite and the resolution a finite"
                              f" number > 0 and <= {MAX_RESOLUTION:g} m)")
        (ny, nx), sl = g.shape, self.scanlines
        if not (0 < ny and 0 < nx and ny * nx <= MAX_CELLS):
            raise SchemaError(f"{said}, shape {str(g.shape)[:30]}: a map holds 1 to"
                              f" {MAX_CELLS:,} cells)")
        ranges = (sl.robot_radius, sl.max_range, sl.spiral_end_radius)
        if not all(_metres(v) for v in ranges):  # an integer of 401 digits: trial Z1-1
            raise SchemaError(f"{self.path}: damaged map file (scanlines robot_radius,"
                              f" max_range, spiral_end_radius {str(ranges)[:60]}; expected"
                              f" numbers from 0 to {MAX_RANGE_M:g} m)")
        counts = (sl.n_angles, sl.max_crossings)
        if not (all(isinstance(v, int) and not isinstance(v, bool) for v in counts)
                and 1 <= sl.n_angles <= MAX_SCAN_ANGLES
                and 1 <= sl.max_crossings <= MAX_SCAN_CROSSINGS):
            raise SchemaError(f"{self.path}: damaged map file (scanlines n_angles"
                              f" {str(sl.n_angles)[:20]}, max_crossings"
                              f" {str(sl.max_crossings)[:20]}; expected whole numbers from 1 to"
                              f" {MAX_SCAN_ANGLES} and 1 to {MAX_SCAN_CROSSINGS})")
        xmin, xmax, ymin, ymax = self.field.world_bounds(0.0)
        x0, y0 = g.origin
        tol = 1e-6  # m: the rounding of the cell centres build-map placed
        if not (x0 <= xmin + tol and x0 + (nx - 1) * g.resolution >= xmax - tol
                and y0 <= ymin + tol and y0 + (ny - 1) * g.resolution >= ymax - tol):
            raise SchemaError(f"{said}, shape {str(g.shape)[:30]}: its cells do not span the"
                              f" field {self.field.name[:40]}, {self.field.length:g} x"
                              f" {self.field.width:g} m)")

    def _check_field_lines(self) -> None:
        """The lines stored in /field (what the tables were built from) must be finite; lines
        that differ from what the stored spec gives today (a map built by a fieldloc that
        read the spec otherwise) are reported: the pictures draw the spec's."""
        for name, attr in (("segments", "segments"), ("arcs", "arcs"),
                           ("crossings/position", "crossings")):
            if name not in self.h5["field"]:
                continue
            d = stored_dataset(self.h5, f"field/{name}", "map file")
            model = np.asarray(getattr(self.field, attr), float)
            # of another shape: not read (a file's own shape may be of gigabytes)
            stored = np.asarray(d[()], float) if d.shape == model.shape else model
            if not np.isfinite(stored).all():
                raise SchemaError(f"{self.path}: damaged map file (/field/{name} holds values"
                                  " that are not finite numbers)")
            said = (str(self.path.resolve()), name)  # once a process: a run opens a map often
            if (d.shape != model.shape or not np.allclose(stored, model, rtol=0, atol=1e-6)) \
                    and said not in _SAID:
                _SAID.add(said)
                log.warning("%s: /field/%s differs from the field its spec gives now (built"
                            " by another fieldloc version?); build the map again",
                            self.path, name)

    @property
    def conf(self) -> dict:
        """The build conf; SchemaError where its attribute is no JSON text."""
        try:
            conf = read_json_attr(self.h5, "conf")
        except ValueError as e:
            raise SchemaError(f"{self.path}: damaged map file ({e})") from None
        if not isinstance(conf, dict):  # 7, a list: no conf (trial X1-6)
            raise SchemaError(f"{self.path}: damaged map file (attribute 'conf' is"
                              f" {str(conf)[:40]}; expected a JSON object)")
        return conf

    def has_table(self, name: str) -> bool:
        return "tables" in self.h5 and name in self.h5["tables"]

    def table_shape(self, name: str) -> tuple[int, ...]:
        """The shape table ``name`` has in a map of this grid and these scan lines (the
        module doc's)."""
        n, k = self.scanlines.n_angles, self.scanlines.max_crossings
        lead = {"radial": (n, k), "spiral": (2, n), "distance": (), "distance_gradient": (2,),
                "crossing_lut_L": (4,), "crossing_lut_T": ()}[name]
        return (*lead, *self.grid.shape)

    def table(self, name: str) -> np.ndarray:
        """A table fully in memory (cached), refused (SchemaError) before it is read where it
        is not of the shape its grid and scan lines give, or not of numbers."""
        if name not in self._cache:
            if not self.has_table(name):
                raise SchemaError(f"{self.path}: map has no table '{name}'")
            d = stored_dataset(self.h5, f"tables/{name}", "map file")
            want = np.dtype(TABLE_DTYPES[name])
            if d.shape != self.table_shape(name) or d.dtype != want:
                raise SchemaError(f"{self.path}: damaged map file (/tables/{name} is"
                                  f" {str(d.shape)[:40]} {str(d.dtype)[:20]}; expected {want}"
                                  f" of shape {self.table_shape(name)} for its grid)")
            try:
                table = d[()]
            except (OSError, KeyError) as e:
                raise SchemaError(f"{self.path}: damaged table '{name}' ({e})") from None
            if why := self._wrong_values(name, table):
                raise SchemaError(f"{self.path}: damaged map file (/tables/{name} {why})")
            self._cache[name] = table
        return self._cache[name]

    def _wrong_values(self, name: str, table: np.ndarray) -> str | None:
        """Why table ``name``'s values are none build-map writes, or None: its distances and
        gradients finite (NaN ended fit in a traceback, trial V1-1), its crossing indices
        within the field's crossings or -1 (none)."""
        if table.dtype.kind == "f" and not np.isfinite(table).all():
            return f"holds {table[~np.isfinite(table)].flat[0]} where finite numbers belong"
        if name.startswith("crossing_lut"):
            n = len(self.field.crossings)
            wrong = (table < -1) | (table >= n)
            if wrong.any():
                return (f"holds the index {int(table[wrong].flat[0])}; the field has {n}"
                        " crossings (-1: none)")
        return None

    def table_attrs(self, name: str) -> dict:
        return dict(self.h5["tables"][name].attrs)

    def close(self):
        self.h5.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
