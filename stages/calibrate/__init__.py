"""Calibrate: the omnidirectional mirror's radial mapping from measured pairs (seed 004, eq. 2).

    main(conf, points_csv, output, *, centre, image_size, valid_radius,
         forward_angle=pi/2, mirrored=False, overwrite=False) -> Path

``points_csv`` holds pairs measured on the robot (marks laid on the floor at known distances and
the image radius at which each appears), with the header ``radius_px,distance_m``. The
fifth-order polynomial f(r) = a0 + a1 r + ... + a5 r^5 (metres at pixel radius r) is fitted by
least squares (``camera.fit_polynomial``) and written as calib.yaml (kind omni) with the given
image centre, size, valid radii and forward angle.

Refused, each with one clear message: fewer than ``min_points`` pairs; fewer than
``min_distinct_radii`` distinct radii (degenerate: the fit would be under-determined or
unchecked); non-finite or negative values; a fit that is not increasing over the valid radius
(a mirror mapping must grow outwards, or pixels would map to the same floor point twice).
"""

from __future__ import annotations

import csv
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common.camera import OmniCamera, fit_polynomial, save_calib
from ..common.errors import FieldlocError

log = logging.getLogger(__name__)

COLUMNS = ("radius_px", "distance_m")

confs = {
    "default": {
        "degree": 5,  # seed 004 eq. 2
        "min_points": 8,
        "min_distinct_radii": 7,  # degree + 2: at least one pair checks the fit
        "monotonic_samples": 1000,  # radii checked for an increasing f(r)
    },
}


class CalibrationError(FieldlocError):
    """The measured pairs cannot give a valid mirror calibration."""


@dataclass
class CalibrationFit:
    camera: OmniCamera
    radius_px: np.ndarray
    distance_m: np.ndarray
    residuals_m: np.ndarray  # fitted minus measured distance

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_m**2)))

    @property
    def max_abs(self) -> float:
        return float(np.max(np.abs(self.residuals_m)))


def read_points(path) -> tuple[np.ndarray, np.ndarray]:
    """(radius_px, distance_m) from a CSV with the header ``radius_px,distance_m``."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"calibration points not found: {path}")
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].strip().startswith("#")]
    if not rows:
        raise CalibrationError(f"{path}: empty; expected a header '{','.join(COLUMNS)}'")
    header = tuple(h.strip() for h in rows[0])
    if header != COLUMNS:
        raise CalibrationError(
            f"{path}: expected columns '{','.join(COLUMNS)}', found '{','.join(header)}'"
        )
    r, d = [], []
    for n, row in enumerate(rows[1:], start=2):
        try:
            if len(row) != 2:
                raise ValueError
            rv, dv = float(row[0]), float(row[1])
        except ValueError:
            raise CalibrationError(
                f"{path}: line {n}: expected two numbers 'radius_px,distance_m', got"
                f" '{','.join(row)}'"
            ) from None
        if not (math.isfinite(rv) and math.isfinite(dv)) or rv < 0 or dv < 0:
            raise CalibrationError(
                f"{path}: line {n}: radius and distance must be finite and >= 0, got {rv}, {dv}"
            )
        r.append(rv)
        d.append(dv)
    return np.asarray(r, dtype=float), np.asarray(d, dtype=float)


def fit(conf: dict, radius_px, distance_m, *, centre, image_size, valid_radius,
        forward_angle: float = math.pi / 2, mirrored: bool = False,
        where: str = "calibration points") -> CalibrationFit:
    """Fit f(r) to the pairs and check it; returns the camera and the residuals."""
    r = np.asarray(radius_px, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    degree = int(conf["degree"])
    if len(r) < conf["min_points"]:
        raise CalibrationError(
            f"{where}: {len(r)} pairs, but a degree-{degree} fit needs at least"
            f" {conf['min_points']}"
        )
    distinct = len(np.unique(np.round(r, 3)))
    if distinct < conf["min_distinct_radii"]:
        raise CalibrationError(
            f"{where}: only {distinct} distinct radii among {len(r)} pairs; a degree-{degree} fit"
            f" needs at least {conf['min_distinct_radii']} (spread the marks over the mirror)"
        )
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise CalibrationError(f"image size must be positive, got {w} x {h}")
    cu, cv = (float(v) for v in centre)
    if not (0 <= cu < w and 0 <= cv < h):
        raise CalibrationError(f"centre ({cu:g}, {cv:g}) lies outside the {w} x {h} image")
    rmin, rmax = (float(v) for v in valid_radius)
    if not 0 <= rmin < rmax:
        raise CalibrationError(f"valid radius needs 0 <= RMIN < RMAX, got {rmin:g} {rmax:g}")
    coef, residuals = fit_polynomial(r, d, degree=degree)
    samples = np.linspace(rmin, rmax, int(conf["monotonic_samples"]))
    slope = np.diff(np.polynomial.polynomial.polyval(samples, coef))
    if not np.all(slope > 0):
        turn = samples[1:][np.argmax(slope <= 0)]
        raise CalibrationError(
            f"{where}: the fitted f(r) is not increasing between {rmin:g} and {rmax:g} px (it"
            f" turns at r = {turn:.1f} px); check the pairs or narrow --valid-radius"
        )
    if rmax > r.max() + 1e-9 or rmin < r.min() - 1e-9:
        log.warning(
            "valid radius %g..%g px reaches beyond the measured radii %g..%g px: f(r) is"
            " extrapolated there", rmin, rmax, r.min(), r.max(),
        )
    camera = OmniCamera(
        image_size=(w, h), centre=(cu, cv), polynomial=np.asarray(coef, dtype=float),
        valid_radius=(rmin, rmax), forward_angle=float(forward_angle), mirrored=bool(mirrored),
    )
    return CalibrationFit(camera=camera, radius_px=r, distance_m=d, residuals_m=residuals)


def main(conf: dict, points_csv, output, *, centre, image_size, valid_radius,
         forward_angle: float = math.pi / 2, mirrored: bool = False,
         overwrite: bool = False) -> Path:
    """Fit the mirror calibration to the pairs in ``points_csv`` and write ``output``
    (calib.yaml, kind omni). Returns ``output``."""
    output = Path(output)
    if output.exists() and not overwrite:
        raise CalibrationError(f"{output} exists (use --overwrite to replace it)")
    r, d = read_points(points_csv)
    result = fit(conf, r, d, centre=centre, image_size=image_size, valid_radius=valid_radius,
                 forward_angle=forward_angle, mirrored=mirrored, where=str(points_csv))
    save_calib(result.camera, output)
    log.info("calibrated from %d pairs: residual RMS %.4f m, max %.4f m", len(r), result.rms,
             result.max_abs)
    return output


def residual_report(camera: OmniCamera, points_csv) -> CalibrationFit:
    """The residuals of ``camera`` on the pairs in ``points_csv`` (for reporting a fit)."""
    r, d = read_points(points_csv)
    return CalibrationFit(camera=camera, radius_px=r, distance_m=d,
                          residuals_m=camera.distance_of_radius(r) - d)
