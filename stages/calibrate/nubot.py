"""The NuBot team's omni calibration (nubot-nudt/nubot_ws, ``omni_vision/calib_results/N/``):
``mirror_calib.xml`` (the mirror model) and ``ROI.xml`` (the usable image ring), OpenCV
FileStorage XML files.

Mirror model (the team's calibration fits it jointly with the robot's pose against a table of
distances to the field lines): a pixel at radius rho (px) from the image centre
(``center_coloum``, ``center_row``) and image angle phi = atan2(row - centre_row, col -
centre_col) lies on the floor at range

    r = 100 a tan(b rho) cm  (``para_a`` = a, ``para_b`` = b; a tan(b rho) metres)

in the robot frame (x = r cos phi, y = r sin phi): the robot's +x axis is the image's +u axis
and +y its +v axis (rows down), i.e. the image shows the floor mirrored (a floor seen through a
mirror is), in the project's terms ``forward_angle`` 0 and ``mirrored`` true. The range grows
without bound towards rho = pi / (2 b) (``max_radius``, the horizon). ``correction_x`` /
``correction_y`` (cm) are the mirror's offset from the robot's centre; the project's omni model
has no such offset: they are recorded, not applied.

The project's radial models (stages.common.camera) are a fifth-order polynomial and a monotone
cubic table; a tan is neither, so the table is sampled from the model every ``sample_px``
pixels and every ``sample_m`` metres of range (the finer of the two: near the horizon one
pixel spans metres) across the usable ring, up to ``max_range_m``; the error of the monotone
cubic between the samples is measured against the exact model on a fine grid (``model_fit``),
and the command states it.

``ROI.xml``: the ring the team's vision uses, ``center_point_row`` / ``center_point_column``,
``small_radius`` (the robot's own body) and ``big_radius`` (the mirror's rim), in the
coordinates of the saved pictures; ``start_row`` / ``start_column`` say where those pictures
were cut from the camera's frame (in the 2019-08 files a 505 x 480 picture with
``start_column`` 76 and ``cols`` 505), so they are not added. The ring's centre is not the
mirror model's (9 px apart in the team's 2020-07 files, 28 px in 2019-08), and the project's
valid radius is a ring about the model's centre: [small - d, big - d], d the distance of the
two centres. The outer edge stays inside the team's ring (beyond the mirror's rim lie glare
and the robot's frame); the inner edge is the generous one, so that a crescent up to 2 d px
wide of the robot's own dark body is scanned: it holds no green-white-green run, while the ring
inside the team's (small + d) would start at 0.71 m in the 2020-07 files and lose the centre
circle (radius 0.63 m, whose pixels the team's own detector lists) seen from the centre spot.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common.errors import FieldlocError, check_file
from ..common.user_numbers import parse_number

MIRROR_XML = "mirror_calib.xml"
MAX_IMAGE_SIDE = 65535  # px: PNG's and OpenCV's practical limit; beyond it a value is a typo
ROI_XML = "ROI.xml"

confs = {
    "default": {
        "sample_px": 1.0,  # the table's pairs: one per this many pixels of radius ...
        "sample_m": 0.05,  # ... and one per this many metres of range
        "max_range_m": 15.0,  # the valid radius ends where the model reaches this range
        "check_step_px": 0.05,  # the fine grid the table's error is measured on
        "horizon_margin_px": 2.0,  # the valid radius stays this far inside pi / (2 b)
    },
}


class NubotCalibrationError(FieldlocError):
    """The NuBot calibration files cannot be read."""


@dataclass
class NubotMirror:
    centre: tuple[float, float]  # (u, v) = (center_coloum, center_row), px
    a: float  # metres (the file's 100 a cm)
    b: float  # 1 / px
    correction_cm: tuple[float, float]
    max_radius: float  # px, as the file gives it
    path: Path

    def range_m(self, rho) -> np.ndarray:
        """The team's model: floor range (m) of pixel radius rho."""
        return self.a * np.tan(self.b * np.asarray(rho, float))

    def radius_px(self, range_m) -> np.ndarray:
        """The model's inverse: pixel radius of floor range (m)."""
        return np.arctan(np.asarray(range_m, float) / self.a) / self.b

    @property
    def horizon_px(self) -> float:
        return math.pi / (2 * self.b)


@dataclass
class NubotRoi:
    centre: tuple[float, float]  # (u, v) in the saved image's pixels
    small_radius: float
    big_radius: float
    size: tuple[int, int]  # (cols, rows) of the region
    start: tuple[int, int]  # (start_column, start_row) in the camera's frame (not used)
    path: Path


def _storage(path: Path, what: str) -> dict[str, str]:
    check_file(path, f"NuBot {what}", NubotCalibrationError)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as e:
        raise NubotCalibrationError(f"{path}: not an OpenCV XML file ({e})") from None
    if root.tag != "opencv_storage":
        raise NubotCalibrationError(f"{path}: not an OpenCV FileStorage file (root"
                                    f" <{root.tag[:30]}>)")
    return {child.tag: (child.text or "").strip() for child in root}


def _number(values: dict, key: str, path: Path, positive: bool = False) -> float:
    if key not in values:
        raise NubotCalibrationError(f"{path}: no <{key}>")
    try:
        v = parse_number(values[key])  # strict: "1_5" is no 15, "٣" no 3
    except ValueError:
        raise NubotCalibrationError(
            f"{path}: <{key}> is not a number ('{values[key][:30]}')") from None
    if not math.isfinite(v) or (positive and v <= 0):
        raise NubotCalibrationError(f"{path}: <{key}> must be a finite"
                                    f"{' positive' if positive else ''} number, got {v:g}")
    return v


def read_mirror(path) -> NubotMirror:
    path = Path(path)
    v = _storage(path, MIRROR_XML)
    b = _number(v, "para_b", path, positive=True)
    mirror = NubotMirror(
        centre=(_number(v, "center_coloum", path), _number(v, "center_row", path)),
        a=_number(v, "para_a", path, positive=True), b=b,
        correction_cm=tuple(_number(v, k, path) if k in v else 0.0
                            for k in ("correction_x", "correction_y")),
        max_radius=_number(v, "max_radius", path) if "max_radius" in v else math.pi / (2 * b),
        path=path)
    return mirror


def read_roi(path) -> NubotRoi:
    path = Path(path)
    v = _storage(path, ROI_XML)
    start = tuple(int(_number(v, k, path)) if k in v else 0
                  for k in ("start_column", "start_row"))
    small = _number(v, "small_radius", path)
    big = _number(v, "big_radius", path, positive=True)
    if not 0 <= small < big:
        raise NubotCalibrationError(f"{path}: needs 0 <= small_radius < big_radius, got"
                                    f" {small:g}, {big:g}")
    size = tuple(_number(v, k, path, positive=True) for k in ("cols", "rows"))
    if max(size) > MAX_IMAGE_SIDE:
        raise NubotCalibrationError(f"{path}: a region of {size[0]:g} x {size[1]:g} px is no"
                                    f" camera picture (at most {MAX_IMAGE_SIDE} px a side)")
    return NubotRoi(
        centre=(_number(v, "center_point_column", path), _number(v, "center_point_row", path)),
        small_radius=small, big_radius=big,
        size=(int(size[0]), int(size[1])),
        start=start, path=path)


def valid_ring(mirror: NubotMirror, roi: NubotRoi | None, conf: dict) -> tuple[float, float]:
    """The valid radii about the mirror centre from the team's ring (module doc), inside the
    model's horizon."""
    horizon = min(mirror.horizon_px, mirror.max_radius) - float(conf["horizon_margin_px"])
    horizon = min(horizon, mirror.radius_px(float(conf["max_range_m"])))
    if roi is None:
        return 0.0, horizon
    d = math.hypot(roi.centre[0] - mirror.centre[0], roi.centre[1] - mirror.centre[1])
    rmin, rmax = max(roi.small_radius - d, 1.0), min(roi.big_radius - d, horizon)
    if not rmin < rmax:
        raise NubotCalibrationError(
            f"{roi.path}: the ring ({roi.small_radius:g}..{roi.big_radius:g} px about"
            f" {roi.centre}) holds no ring about the mirror centre"
            f" ({mirror.centre[0]:.1f}, {mirror.centre[1]:.1f}) inside the model's horizon"
            f" ({mirror.horizon_px:.1f} px)")
    return rmin, rmax


def table_pairs(mirror: NubotMirror, valid_radius, conf: dict) -> tuple[np.ndarray, np.ndarray]:
    """(radius_px, distance_m): the model sampled at the multiples of ``sample_px`` and at the
    radii of the multiples of ``sample_m`` inside the valid radius, and at both its ends."""
    rmin, rmax = valid_radius
    step, step_m = float(conf["sample_px"]), float(conf["sample_m"])
    if not (step > 0 and step_m > 0):
        raise NubotCalibrationError(f"sample_px and sample_m must be > 0, got {step:g},"
                                    f" {step_m:g}")
    by_px = np.arange(math.floor(rmin / step) + 1, math.ceil(rmax / step)) * step
    d0, d1 = mirror.range_m([rmin, rmax])
    by_m = mirror.radius_px(np.arange(math.floor(d0 / step_m) + 1, math.ceil(d1 / step_m))
                            * step_m)
    inner = np.concatenate([by_px, by_m])
    r = np.unique(np.concatenate([[rmin], inner[(inner > rmin) & (inner < rmax)], [rmax]]))
    r = r[np.concatenate([[True], np.diff(r) > 1e-6])]
    d = mirror.range_m(r)
    keep = d > 0  # radius 0 is range 0: the table's distances must rise from > 0
    return r[keep], d[keep]


def model_fit(camera, mirror: NubotMirror, conf: dict) -> dict:
    """How far the written camera's radial model is from the team's a tan(b rho) over the valid
    radius: the largest error (m), where (px, m), and the largest error relative to the
    range."""
    rmin, rmax = camera.valid_radius
    r = np.arange(rmin, rmax, float(conf["check_step_px"]))
    r = np.append(r, rmax)
    exact = mirror.range_m(r)
    err = camera.distance_of_radius(r) - exact
    i = int(np.argmax(np.abs(err)))
    rel = np.abs(err) / np.maximum(exact, 1e-9)
    j = int(np.argmax(rel))
    return {"max_error_m": float(abs(err[i])), "at_radius_px": round(float(r[i]), 2),
            "at_range_m": round(float(exact[i]), 3),
            "rms_error_m": float(np.sqrt(np.mean(err ** 2))),
            "max_relative_error": float(rel[j]), "samples": int(len(r))}
