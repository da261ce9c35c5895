"""Camera models read from a dataset's calib.yaml.

Omnidirectional (catadioptric) camera: the ground distance of a pixel is a function f(r) of its
radius r (pixels) from the image centre; its bearing is its image angle relative to the robot's
forward direction in the image. Two radial models:

- ``polynomial`` (the SURF template paper, eq. 2): f(r) = a0 + a1 r + ... + a5 r^5, fitted to
  measured pairs;
- ``table``: the monotone cubic (PCHIP, Fritsch-Carlson) through measured pairs (r_i, d_i),
  extended linearly beyond the first and last pair. It passes through every pair and cannot
  oscillate between them, so a team's own mirror table is used as the team measured it (the
  MINHO tables are not smooth enough for a fifth-order polynomial: see stages.calibrate).

calib.yaml for kind omni, polynomial model (version 1, the original format)::

    kind: omni
    image_size: [480, 480]          # width, height (px)
    centre: [240.0, 240.0]          # image centre (u, v) in px
    polynomial: [a0, a1, ..., a5]   # f(r) = sum a_i r^i, metres, r in px
    valid_radius: [40.0, 230.0]     # px: robot-body mask radius .. outer limit of the floor
    forward_angle: 1.5707963        # rad: image angle of the robot's +x axis, counter-clockwise
                                    # from the image's +u axis with v pointing up
    mirrored: false                 # true if the image shows the floor mirrored

table model (version 2; a reader of version 1 refuses it for want of ``polynomial``)::

    kind: omni
    version: 2
    radial_model: table
    radial_table: {radius_px: [55, 98, ...], distance_m: [0.25, 0.5, ...]}
    image_size, centre, valid_radius, forward_angle, mirrored: as above

Both may carry a ``calibration`` mapping (how the file was made: sources, pairs, residuals;
written by stages.calibrate); the camera model does not read it.

Checked on reading, each failure one line naming the file and the key: no unknown keys (a
perspective calibration's ``fx`` belongs under ``intrinsics:``), ``image_size`` two whole
numbers > 0, ``centre`` inside the image, ``valid_radius`` 0 <= RMIN < RMAX, ``polynomial``
exactly six finite coefficients a0..a5 (0 for unused higher orders) with f(r) increasing over the
valid radius, ``mirrored`` true or false.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .conf import load_yaml, read_record
from .errors import DatasetError, present, shown
from .user_numbers import user_number, user_numbers

CALIB_VERSION = 2  # newest calib.yaml version this code reads (1: polynomial only)
RADIAL_MODELS = ("polynomial", "table")
POLYNOMIAL_COEFFICIENTS = 6  # a0..a5, the SURF template paper's eq. 2
# top-level keys of calib.yaml per camera kind
CALIB_KEYS = {
    "omni": ("kind", "version", "image_size", "centre", "polynomial", "radial_model",
             "radial_table", "valid_radius", "forward_angle", "mirrored", "calibration"),
    "perspective": ("kind", "version", "image_size", "intrinsics", "distortion", "height",
                    "pitch", "roll", "yaw", "position", "pitch_offset", "roll_offset",
                    "calibration"),
}
# what the frames of each camera kind allow, asked by the stages instead of the kind's name:
# ``ground_image``: the floor all round the robot, unwarped through the mirror's radial model
# (stages.common.unwarp: template databases, template matching, the error surfaces);
# ``robot_mask``: the dataset's mask.png hides the robot's own body in every frame;
# ``head_angles``: head.csv gives the camera's pitch and roll (and more) per frame
CAMERA_CAPABILITIES = {
    "omni": frozenset({"ground_image", "robot_mask"}),
    "perspective": frozenset({"head_angles"}),
}


def camera_can(kind: str | None, capability: str) -> bool:
    """Whether frames of the camera kind ``kind`` allow ``capability`` (a name of
    CAMERA_CAPABILITIES' sets; an unknown kind allows none)."""
    return capability in CAMERA_CAPABILITIES.get(kind, ())


@dataclass
class OmniCamera:
    image_size: tuple[int, int]
    centre: tuple[float, float]
    polynomial: np.ndarray | None  # (<= 6,) a0..a5, r in px -> metres; None with a table
    valid_radius: tuple[float, float]
    forward_angle: float = math.pi / 2
    mirrored: bool = False
    radial_table: np.ndarray | None = None  # (n, 2) radius_px, distance_m: the table model
    _inverse: tuple | None = field(default=None, repr=False, compare=False)
    _table_fn: object = field(default=None, repr=False, compare=False)

    kind = "omni"

    def __post_init__(self):
        if (self.polynomial is None) == (self.radial_table is None):
            raise ValueError("an omni camera needs exactly one of polynomial and radial_table")
        if self.radial_table is not None:
            self.radial_table = np.asarray(self.radial_table, dtype=float).reshape(-1, 2)
            check_radial_table(self.radial_table[:, 0], self.radial_table[:, 1], "radial_table",
                               ValueError)

    @property
    def radial_model(self) -> str:
        return "polynomial" if self.radial_table is None else "table"

    # ------------------------------------------------------------------ radial mapping
    def distance_of_radius(self, r) -> np.ndarray:
        """Ground distance (m) of pixel radius r (px): the polynomial f(r), or the monotone
        cubic through the table's pairs (linear beyond its ends)."""
        r = np.asarray(r, dtype=float)
        if self.radial_table is None:
            return np.polynomial.polynomial.polyval(r, self.polynomial)
        if self._table_fn is None:
            self._table_fn = MonotoneTable(self.radial_table[:, 0], self.radial_table[:, 1])
        return self._table_fn(r)

    def _inverse_table(self):
        if self._inverse is None:
            r = np.linspace(self.valid_radius[0], self.valid_radius[1], 4096)
            d = self.distance_of_radius(r)
            # keep the monotonic part from the body mask outwards (f may dip inside the mask)
            inc = np.concatenate([[True], np.diff(d) > 0])
            stop = np.argmin(inc) if not inc.all() else len(inc)
            self._inverse = (d[:stop], r[:stop])
        return self._inverse

    def radius_of_distance(self, d) -> np.ndarray:
        """Pixel radius at which ground distance d (m) appears; NaN outside the valid floor."""
        dd, rr = self._inverse_table()
        d = np.asarray(d, dtype=float)
        out = np.interp(d, dd, rr, left=np.nan, right=np.nan)
        return np.where((out >= self.valid_radius[0]) & (out <= self.valid_radius[1]), out, np.nan)

    @property
    def max_distance(self) -> float:
        return float(self._inverse_table()[0][-1])

    # ------------------------------------------------------------------ pixels <-> robot frame
    def _sign(self) -> float:
        return -1.0 if self.mirrored else 1.0

    def pixel_to_robot(self, u, v) -> np.ndarray:
        """Pixels (u, v) -> points (..., 2) on the floor in the robot frame (metres)."""
        du = np.asarray(u, dtype=float) - self.centre[0]
        dv = np.asarray(v, dtype=float) - self.centre[1]
        r = np.hypot(du, dv)
        alpha = np.arctan2(-dv, du)
        bearing = self._sign() * (alpha - self.forward_angle)
        d = self.distance_of_radius(r)
        return np.stack([d * np.cos(bearing), d * np.sin(bearing)], axis=-1)

    def robot_to_pixel(self, points) -> np.ndarray:
        """Floor points (..., 2) in the robot frame -> pixels (..., 2) (u, v); NaN if unseen."""
        p = np.asarray(points, dtype=float)
        d = np.hypot(p[..., 0], p[..., 1])
        bearing = np.arctan2(p[..., 1], p[..., 0])
        alpha = self._sign() * bearing + self.forward_angle
        r = self.radius_of_distance(d)
        return np.stack(
            [self.centre[0] + r * np.cos(alpha), self.centre[1] - r * np.sin(alpha)], axis=-1
        )

    def bearing_to_image_angle(self, bearing) -> np.ndarray:
        return self._sign() * np.asarray(bearing, dtype=float) + self.forward_angle

    # ------------------------------------------------------------------ io
    def to_dict(self) -> dict:
        """The calib.yaml mapping: version 1 (the original format) for the polynomial model,
        version 2 for the table model."""
        out = {"kind": "omni"}
        if self.radial_table is None:
            radial = {"polynomial": [float(a) for a in self.polynomial]}
        else:
            out.update(version=2, radial_model="table")
            radial = {"radial_table": {
                "radius_px": [float(v) for v in self.radial_table[:, 0]],
                "distance_m": [float(v) for v in self.radial_table[:, 1]]}}
        out.update(
            image_size=[int(self.image_size[0]), int(self.image_size[1])],
            centre=[float(self.centre[0]), float(self.centre[1])],
            **radial,
            valid_radius=[float(self.valid_radius[0]), float(self.valid_radius[1])],
            forward_angle=float(self.forward_angle),
            mirrored=bool(self.mirrored),
        )
        return out

    @classmethod
    def from_dict(cls, d: dict, where: str = "calib") -> OmniCamera:
        version = d.get("version", 1)
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise DatasetError(f"{where}: 'version' must be a positive integer, got {version!r}")
        if version > CALIB_VERSION:
            raise DatasetError(
                f"{where}: calib.yaml version {version} is newer than this fieldloc reads"
                f" (up to {CALIB_VERSION}); update fieldloc")
        model = d.get("radial_model", "polynomial") if version >= 2 else "polynomial"
        if model not in RADIAL_MODELS:
            raise DatasetError(f"{where}: unknown radial_model '{model}' (polynomial or table)")
        poly = table = None
        try:
            if model == "polynomial":
                poly = np.asarray(_numbers(d["polynomial"], "polynomial", where))
                if len(poly) != POLYNOMIAL_COEFFICIENTS:
                    raise DatasetError(
                        f"{where}: 'polynomial' needs the six coefficients a0..a5 of f(r) (write"
                        f" 0 for unused higher orders), got {len(poly)} values")
            else:
                t = d["radial_table"]
                if not isinstance(t, dict):
                    raise DatasetError(
                        f"{where}: 'radial_table' needs 'radius_px' and 'distance_m' lists")
                rr = np.asarray(_numbers(t["radius_px"], "radial_table.radius_px", where))
                dd = np.asarray(_numbers(t["distance_m"], "radial_table.distance_m", where))
                check_radial_table(rr, dd, f"{where}: radial_table", DatasetError)
                table = np.stack([rr, dd], axis=1)
            size = image_size_of(d, where)
            centre = _finite_pair(d, "centre", where)
            valid = _finite_pair(d, "valid_radius", where)
            forward = user_number(d.get("forward_angle", math.pi / 2), f"{where}: 'forward_angle'",
                                  error=DatasetError)
            mirrored = d.get("mirrored", False)
        except KeyError as e:
            raise DatasetError(f"{where}: omni calibration misses key {e}") from None
        except (TypeError, ValueError, IndexError) as e:
            raise DatasetError(f"{where}: omni calibration has a malformed value ({e})") from None
        if not isinstance(mirrored, bool):
            raise DatasetError(f"{where}: 'mirrored' must be true or false, got {mirrored!r}")
        if not math.isfinite(forward) or abs(forward) > 2 * math.pi:
            raise DatasetError(f"{where}: 'forward_angle' must be an angle in radians within"
                               f" [-2 pi, 2 pi], got {forward:g} (degrees?)")
        w, h = size
        if not (0 <= centre[0] <= w and 0 <= centre[1] <= h):
            raise DatasetError(
                f"{where}: 'centre' ({centre[0]:g}, {centre[1]:g}) lies outside the {w} x {h}"
                " image")
        if not 0 <= valid[0] < valid[1]:
            raise DatasetError(
                f"{where}: 'valid_radius' needs 0 <= RMIN < RMAX (px), got [{valid[0]:g},"
                f" {valid[1]:g}]")
        if valid[1] - valid[0] < MIN_RING_PX:
            raise DatasetError(
                f"{where}: 'valid_radius' [{valid[0]:g}, {valid[1]:g}] is a ring narrower than"
                f" {MIN_RING_PX:g} px: no scan line has a pixel on the floor")
        if poly is not None:
            samples = np.linspace(valid[0], valid[1], 512)
            with np.errstate(over="ignore", invalid="ignore"):  # such an f(r) is refused next
                f = np.polynomial.polynomial.polyval(samples, poly)
            far = ~(np.abs(f) <= MAX_FLOOR_M)
            if far.any():
                i = int(np.argmax(far))
                raise DatasetError(
                    f"{where}: 'polynomial' f(r) is {f[i]:.3g} m at r = {samples[i]:.1f} px,"
                    f" within 'valid_radius'; no mirror sees floor beyond {MAX_FLOOR_M:g} m")
            slope = np.diff(f)
            if not np.all(slope > 0):
                turn = samples[1:][int(np.argmax(slope <= 0))]
                raise DatasetError(
                    f"{where}: 'polynomial' f(r) is not increasing over 'valid_radius'"
                    f" {valid[0]:g}..{valid[1]:g} px (it turns at r = {turn:.5g} px); a mirror"
                    " maps farther floor to larger radii")
        return cls(image_size=size, centre=centre, polynomial=poly, valid_radius=valid,
                   forward_angle=forward, mirrored=mirrored, radial_table=table)


def _finite_pair(d: dict, key: str, where: str) -> tuple[float, float]:
    a, b = user_numbers(d[key], f"{where}: '{key}'", count=2, error=DatasetError)
    return a, b


def _numbers(values, key: str, where: str) -> list[float]:
    """A calib.yaml list of finite numbers (stages.common.user_numbers: no YAML ``yes``, no
    integer beyond the float range), or DatasetError naming ``key``."""
    return user_numbers(values, f"{where}: '{key}'", error=DatasetError)


# px: the longest image side a conf may give (robot cameras give up to about 2000 px; a side of
# 1e12 px is a typo, and a renderer's buffers for it would not fit in memory)
MAX_IMAGE_PX = 8192


def image_size_of(d: dict, where: str) -> tuple[int, int]:
    """calib.yaml's ``image_size``: [width, height], whole numbers from 1 to MAX_IMAGE_PX."""
    v = d["image_size"]
    bad = DatasetError(
        f"{where}: 'image_size' must be [width, height] in whole pixels from 1 to"
        f" {MAX_IMAGE_PX}, got {shown(v, 40)}")
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise bad
    w, h = user_numbers(v, f"{where}: 'image_size'", whole=True, error=DatasetError)
    if not (0 < w <= MAX_IMAGE_PX and 0 < h <= MAX_IMAGE_PX):
        raise bad
    return w, h


# m: the farthest floor distance an omni calibration's f(r) may give within its valid ring. The
# largest field is 22 x 14 m, and a mirror's view ends at a few metres to tens of metres; a
# coefficient such as 1e300 makes f(r) overflow instead of describing a mirror
MAX_FLOOR_M = 1000.0

# the narrowest floor ring (px) an omni calibration may give: a scan line is sampled at whole
# pixels, so a narrower ring can hold none of its samples
MIN_RING_PX = 1.0


def load_calib(path: str | Path):
    """Read a calib.yaml and return the camera model of its kind."""
    path = Path(path)
    if not present(path):
        raise DatasetError(f"calibration not found: {path}")
    try:
        d = load_yaml(read_record(path).decode("utf-8-sig"))
    except UnicodeDecodeError:
        raise DatasetError(f"{path}: not a text YAML file (binary content)") from None
    except yaml.YAMLError as e:
        raise DatasetError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot be read ({e.strerror or e})") from None
    if not isinstance(d, dict) or "kind" not in d:
        raise DatasetError(f"{path}: calibration needs a 'kind' (omni or perspective)")
    kind = d["kind"]
    if not isinstance(kind, str) or kind not in CALIB_KEYS:
        raise DatasetError(f"{path}: unknown camera kind {kind!r} (omni or perspective)")
    unknown = [str(k) for k in d if k not in CALIB_KEYS[kind]]
    if unknown:
        hint = ""
        if kind == "perspective" and set(unknown) & {"fx", "fy", "cx", "cy"}:
            hint = "; fx, fy, cx, cy go under 'intrinsics:'"
        raise DatasetError(
            f"{path}: unknown key '{unknown[0]}' for a {kind} camera (keys:"
            f" {', '.join(CALIB_KEYS[kind])}){hint}")
    if "image_size" in d:
        image_size_of(d, str(path))
    if kind == "omni":
        return OmniCamera.from_dict(d, str(path))
    from .perspective_camera import PerspectiveCamera

    try:
        return PerspectiveCamera.from_dict(d, str(path))
    except (TypeError, ValueError, IndexError, AttributeError) as e:
        raise DatasetError(f"{path}: perspective calibration has a malformed value ({e})") from None


def save_calib(camera, path: str | Path, calibration: dict | None = None) -> Path:
    """Write ``camera`` as calib.yaml (atomically); ``calibration``: an optional record of how
    it was made, stored under that key and not read back into the model."""
    from .artifacts import atomic_path

    path = Path(path)
    d = camera.to_dict()
    if calibration:
        d["calibration"] = calibration
    type(camera).from_dict(d, str(path))  # refused here what load_calib would refuse: nothing
    # fieldloc writes is a calibration it cannot read back
    with atomic_path(path, suffix=".yaml") as tmp:
        tmp.write_text(calib_text(d))
    return path


def calib_text(d: dict) -> str:
    """The calib.yaml text of the mapping ``d``: its YAML under a comment naming the writer
    (``WRITTEN_MARK``, by which --overwrite tells it from a team's own calibration)."""
    from .artifacts import CALIB_TITLE, WRITTEN_MARK, storable

    return (f"{CALIB_TITLE}{WRITTEN_MARK}\n"
            + yaml.safe_dump(storable(d), sort_keys=False, default_flow_style=None))


def read_calibration_record(path: str | Path) -> dict:
    """The ``calibration`` record of a calib.yaml ({} when it has none)."""
    d = load_yaml(Path(path).read_text())
    rec = d.get("calibration") if isinstance(d, dict) else None
    return rec if isinstance(rec, dict) else {}


def check_radial_table(radius_px, distance_m, where: str, error=DatasetError) -> None:
    """A radial table must hold at least two finite pairs whose radius and distance both
    increase strictly (a mirror maps farther floor to larger radii)."""
    r = np.asarray(radius_px, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    if r.ndim != 1 or r.shape != d.shape:
        raise error(f"{where}: radius_px and distance_m must be lists of the same length")
    if len(r) < 2:
        raise error(f"{where}: needs at least 2 pairs, got {len(r)}")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(d))):
        raise error(f"{where}: radii and distances must be finite")
    check_pair_bounds(r, d, where, error)
    for name, v in (("radii", r), ("distances", d)):
        bad = np.flatnonzero(np.diff(v) <= 0)
        if len(bad):
            i = int(bad[0])
            raise error(
                f"{where}: the {name} must increase from pair to pair, but pair {i + 2}"
                f" ({r[i + 1]:g} px, {d[i + 1]:g} m) follows ({r[i]:g} px, {d[i]:g} m)")


# the most (radius, distance) pairs an omni calibration holds: teams' tables hold 16-100,
# the NuBot model's sampling and the CNC rings a few hundred; 1000 is a pair a pixel of a
# 2000 px image's radius. The table model's leave-one-out check costs n^2 (2000 pairs: 4 s,
# 20,000 past a minute) and calib.yaml's pairs are read on every command (trial X2-1)
MAX_PAIRS = 1000


def check_pair_bounds(radius_px, distance_m, where: str, error=DatasetError) -> None:
    """Pairs of an omni calibration (image radius, floor distance) must be ones a mirror can
    give: at most MAX_PAIRS, radii of 0 to MAX_IMAGE_PX px (a longer radius lies off any
    image) and distances of 0 to MAX_FLOOR_M m. A value such as 1e300 would otherwise
    overflow the fits and tables made from the pairs (NaN, inf, numpy's warnings) instead of
    being named."""
    if len(radius_px) > MAX_PAIRS:
        raise error(f"{where}: {len(radius_px):,} pairs, more than the {MAX_PAIRS} a mirror"
                    " table holds (teams' hold 16-100)")
    for i, (r, d) in enumerate(zip(np.asarray(radius_px, float), np.asarray(distance_m, float))):
        if not 0 <= r <= MAX_IMAGE_PX:
            raise error(f"{where}: pair {i + 1} has radius {r:.6g} px; an image radius is 0 to"
                        f" {MAX_IMAGE_PX} px")
        if not 0 <= d <= MAX_FLOOR_M:
            raise error(f"{where}: pair {i + 1} has distance {d:.6g} m; no mirror sees floor"
                        f" beyond {MAX_FLOOR_M:g} m")


class MonotoneTable:
    """The monotone piecewise cubic (PCHIP) through pairs (x_i, y_i) with increasing x and y,
    extended linearly with the end slopes beyond the first and last pair."""

    def __init__(self, x, y):
        from scipy.interpolate import PchipInterpolator

        self.x = np.asarray(x, dtype=float)
        self.y = np.asarray(y, dtype=float)
        self._f = PchipInterpolator(self.x, self.y, extrapolate=False)
        slope = self._f.derivative()
        self._ends = ((self.x[0], self.y[0], float(slope(self.x[0]))),
                      (self.x[-1], self.y[-1], float(slope(self.x[-1]))))

    def __call__(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        out = np.asarray(self._f(x), dtype=float)
        (x0, y0, s0), (x1, y1, s1) = self._ends
        out = np.where(x < x0, y0 + s0 * (x - x0), out)
        return np.where(x > x1, y1 + s1 * (x - x1), out)


def fit_polynomial(radius_px, distance_m, degree: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares fit of f(r) = sum a_i r^i (the SURF template paper, eq. 2) to measured pairs.
    Returns the coefficients a0..a_degree and the residuals (m). The fit runs on r scaled to [0, 1]
    for conditioning, then the coefficients are converted back to pixels."""
    r = np.asarray(radius_px, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    scale = float(np.max(np.abs(r))) or 1.0
    A = np.vander(r / scale, degree + 1, increasing=True)
    coef_scaled, *_ = np.linalg.lstsq(A, d, rcond=None)
    coef = coef_scaled / scale ** np.arange(degree + 1)
    residuals = np.polynomial.polynomial.polyval(r, coef) - d
    return coef, residuals
