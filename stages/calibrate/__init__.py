"""Calibrate: the omnidirectional mirror's radial mapping f(r) (pixel radius -> floor distance).

    main(conf, points_csv, output, *, geometry, line_images=None, mask=None,
         overwrite=False) -> Path
    from_minho(conf, minho_dir, output, *, image_size=None, valid_radius=None,
               line_images=None, mask=None, overwrite=False) -> Path
    from_cnc(conf, carpet_conf, output, *, rings, calib_image=None,
             geometry=MirrorGeometry(), overwrite=False) -> Path
    from_nubot(conf, nubot_dir, output, *, image_size=None, valid_radius=None,
               overwrite=False) -> Path

``geometry`` is a MirrorGeometry: the mirror's centre in the image, the image size, the valid
radius, the robot's forward direction and whether the image is mirrored, as one value.

Sources of pairs (radius_px, distance_m):
- ``points_csv``: pairs measured on the robot (marks laid on the floor at known distances and
  the image radius at which each appears), header ``radius_px,distance_m``;
- ``from_minho``: the MINHO team's ``mirror.cfg`` and ``image.cfg`` (stages.calibrate.minho);
  the image size from the first image of DIR/images unless given, DIR/mask.png for the line
  images;
- ``from_cnc``: the Carpe Noctem team's ``CarpetCalibrator.conf`` ring distances with ring radii
  measured in their calibration picture or given by hand (stages.calibrate.cnc, where the
  pairing is discussed); the centre from ``centre`` or the picture;
- ``from_nubot``: the NuBot team's ``mirror_calib.xml`` (range = 100 a tan(b rho) cm) and
  ``ROI.xml`` (the usable ring): pairs sampled from their model, the table's error against it
  recorded (stages.calibrate.nubot);
- ``line_images``: a folder of images of a straight line at known distances, each named by its
  distance (stages.calibrate.line_images). Measured pairs replace the other source's pairs
  within the measured range of distances; outside it the other source's pairs are kept (those
  that would make the mapping fall are dropped, and reported).

Models (conf ``model``):
- ``polynomial``: the fifth-order f(r) of the SURF template paper's eq. 2, a least-squares fit
  (preset ``default``, for measured pairs); refused if it is not increasing over the valid radius;
- ``table``: the monotone cubic through the pairs (stages.common.camera.MonotoneTable; preset
  ``minho``). A team's table is used as the team measured it: their robot interpolates it
  linearly, and a fifth-order polynomial bends away from the MINHO tables between the pairs,
  or over all of a table's pairs cannot be increasing at all (docs/results.md). The
  residuals of an interpolation are zero; the report gives leave-one-out residuals instead
  (each inner pair predicted from the others): large ones point at an inconsistent pair.

``max_distance_m`` limits the pairs to those up to that distance (None: all). The valid radius
defaults to the radii of the first and last pair used.

The written calib.yaml carries a ``calibration`` record (sources with content hashes, the pairs
used with their residuals, the line images' measurements beside what the other source said for
the same distance); ``report`` reads it back for the CLI.

Refused, each with one clear message: too few pairs (``min_points``), too few distinct radii
(``min_distinct_radii``, polynomial), non-finite or negative values, pairs that do not increase
together (table), a polynomial that is not increasing over the valid radius, unreadable or
incomplete team files, line images that are not named by distance or show no line ahead.
"""

from __future__ import annotations

import copy
import datetime as _dt
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import __version__
from ..common.artifacts import check_output, file_hash
from ..common.camera import (
    MonotoneTable,
    OmniCamera,
    check_pair_bounds,
    check_radial_table,
    fit_polynomial,
    read_calibration_record,
    save_calib,
)
from ..common.conf import stage_conf
from ..common.dataset import IMAGE_SUFFIXES, csv_rows, parse_number, read_image, read_mask
from ..common.errors import FieldlocError, check_file, present
from . import cnc as _cnc
from . import line_images as _line_images
from . import nubot as _nubot
from .minho import read_minho

log = logging.getLogger(__name__)

COLUMNS = ("radius_px", "distance_m")
MODELS = ("polynomial", "table")
MASK_NAME = "mask.png"

confs = {
    "default": {
        "model": "polynomial",  # the SURF template paper's eq. 2
        "degree": 5,
        "min_points": 8,
        "min_distinct_radii": 7,  # degree + 2: at least one pair checks the fit
        "monotonic_samples": 1000,  # radii checked for an increasing f(r)
        "max_distance_m": None,  # pairs farther than this are not used (None: all)
        "line_images": copy.deepcopy(_line_images.confs["default"]),
    },
}
# a team's table (mirror.cfg): the monotone cubic through all its pairs (see the module doc)
confs["minho"] = {**copy.deepcopy(confs["default"]), "model": "table", "min_points": 3}
# the Carpe Noctem rings: as few as 2 pairs, through each of them
confs["cnc"] = {**copy.deepcopy(confs["minho"]), "min_points": 2,
                "rings": copy.deepcopy(_cnc.confs["default"])}
# the NuBot mirror model a tan(b rho), sampled into the monotone table (stages.calibrate.nubot)
confs["nubot"] = {**copy.deepcopy(confs["minho"]),
                  "nubot": copy.deepcopy(_nubot.confs["default"])}


class CalibrationError(FieldlocError):
    """The measured pairs cannot give a valid mirror calibration."""


@dataclass
class CalibrationFit:
    camera: OmniCamera
    radius_px: np.ndarray
    distance_m: np.ndarray
    residuals_m: np.ndarray  # fitted minus measured distance (zero for the table model)
    model: str = "polynomial"
    leave_one_out_m: np.ndarray | None = None  # table model: inner pairs from the others
    source: list[str] = field(default_factory=list)  # per pair: where it came from

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_m**2)))

    @property
    def max_abs(self) -> float:
        return float(np.max(np.abs(self.residuals_m)))


class MirrorGeometry(NamedTuple):
    """How the mirror's picture of the floor lies in the image, the camera's fields besides
    f(r): ``centre`` (u, v) px, ``image_size`` (w, h) px, ``valid_radius`` (rmin, rmax) px
    (None: the radii of the first and last pair used), ``forward_angle`` the image angle of
    the robot's forward direction (rad, counter-clockwise from +u with v up) and whether the
    image shows the floor ``mirrored``. One value because every source hands these five on
    together (to ``fit`` and to the line images' measurement); ``from_cnc`` takes a centre and
    image size left None from its calibration picture."""

    centre: tuple[float, float] | None = None
    image_size: tuple[int, int] | None = None
    valid_radius: tuple[float, float] | None = None
    forward_angle: float = math.pi / 2
    mirrored: bool = False


class PairSource(NamedTuple):
    """The pairs one source gives and what calib.yaml records of it: ``radius_px`` and
    ``distance_m`` (arrays), ``label`` (each pair's source in the record), ``where`` (named in
    messages), ``sources`` (the record's input files and hashes; the line images add theirs)
    and ``extra`` (further record entries of the source, or None)."""

    radius_px: np.ndarray
    distance_m: np.ndarray
    label: str
    where: str
    sources: dict
    extra: dict | None = None


def read_points(path) -> tuple[np.ndarray, np.ndarray]:
    """(radius_px, distance_m) from a CSV with the header ``radius_px,distance_m``."""
    path = Path(path)
    check_file(path, "calibration points", CalibrationError)
    rows = csv_rows(path)
    if not rows:
        raise CalibrationError(f"{path}: empty; expected a header '{','.join(COLUMNS)}'")
    header = tuple(h.strip() for h in rows[0][1])
    if header != COLUMNS:
        raise CalibrationError(
            f"{path}: expected columns '{','.join(COLUMNS)}', found '{','.join(header)[:80]}'"
        )
    r, d = [], []
    for n, row in rows[1:]:
        try:
            if len(row) != 2:
                raise ValueError
            rv, dv = parse_number(row[0]), parse_number(row[1])
        except ValueError:
            raise CalibrationError(
                f"{path}: line {n}: expected two numbers 'radius_px,distance_m', got"
                f" '{','.join(row)[:40]}'"
            ) from None
        if not (math.isfinite(rv) and math.isfinite(dv)) or rv < 0 or dv < 0:
            raise CalibrationError(
                f"{path}: line {n}: radius and distance must be finite and >= 0, got {rv}, {dv}"
            )
        r.append(rv)
        d.append(dv)
    return np.asarray(r, dtype=float), np.asarray(d, dtype=float)


def leave_one_out(radius_px, distance_m) -> np.ndarray:
    """Per pair of an increasing table: the monotone cubic through the other pairs at its radius
    minus its distance (NaN for the first and last pair, which the others do not bracket)."""
    r = np.asarray(radius_px, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    out = np.full(len(r), np.nan)
    for i in range(1, len(r) - 1):
        keep = np.arange(len(r)) != i
        out[i] = float(MonotoneTable(r[keep], d[keep])(r[i])) - d[i]
    return out


def check_centre(centre, image_size, said: str = "centre") -> None:
    """CalibrationError unless ``centre`` (u, v) px lies in the image of ``image_size`` (w, h);
    ``said``: what gave it (a team file's key is named so)."""
    (cu, cv), (w, h) = (float(v) for v in centre), (int(v) for v in image_size)
    if not (0 <= cu < w and 0 <= cv < h):
        raise CalibrationError(f"{said} ({cu:g}, {cv:g}) lies outside the {w} x {h} image")


def fit(conf: dict, radius_px, distance_m, *, centre, image_size, valid_radius=None,
        forward_angle: float = math.pi / 2, mirrored: bool = False,
        where: str = "calibration points", source=None, warn: bool = True) -> CalibrationFit:
    """Fit f(r) to the pairs with the conf's model and check it; returns the camera and the
    residuals. ``valid_radius`` None: the radii of the first and last pair used. ``warn``
    False: no warning logged (a fit made again by the caller logs them once)."""
    model = conf.get("model", "polynomial")
    if model not in MODELS:
        raise CalibrationError(f"unknown model '{model}' (polynomial or table)")
    r = np.asarray(radius_px, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    check_pair_bounds(r, d, where, CalibrationError)  # before any arithmetic on them
    source = list(source) if source is not None else ["points"] * len(r)
    if conf.get("max_distance_m") is not None:
        keep = d <= float(conf["max_distance_m"]) + 1e-9
        r, d, source = r[keep], d[keep], [s for s, k in zip(source, keep) if k]
    order = np.argsort(r, kind="stable")
    r, d, source = r[order], d[order], [source[i] for i in order]
    if len(r) < conf["min_points"]:
        need = (f"a degree-{conf['degree']} fit" if model == "polynomial"
                else "the table model")
        raise CalibrationError(
            f"{where}: {len(r)} pairs, but {need} needs at least {conf['min_points']}")
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise CalibrationError(f"image size must be positive, got {w} x {h}")
    check_centre(centre, (w, h))
    cu, cv = (float(v) for v in centre)
    if valid_radius is None:
        valid_radius = (float(r[0]), float(r[-1]))
    rmin, rmax = (float(v) for v in valid_radius)
    if not 0 <= rmin < rmax:
        raise CalibrationError(f"valid radius needs 0 <= RMIN < RMAX, got {rmin:g} {rmax:g}")
    reach = max(math.hypot(cu - x, cv - y) for x in (0, w) for y in (0, h))
    if rmax > reach:  # a ring beyond the image's corners sees nothing of it
        raise CalibrationError(f"valid radius RMAX {rmax:.4g} px lies beyond the {w} x {h}"
                               f" image (its farthest corner is {reach:.0f} px from the centre)")
    loo = None
    if model == "polynomial":
        coef, residuals = _fit_polynomial(conf, r, d, (rmin, rmax), where)
        radial = {"polynomial": np.asarray(coef, dtype=float)}
    else:
        check_radial_table(r, d, where, CalibrationError)
        residuals = np.zeros(len(r))
        loo = leave_one_out(r, d)
        radial = {"polynomial": None, "radial_table": np.stack([r, d], axis=1)}
    if warn and (rmax > r.max() + 1e-9 or rmin < r.min() - 1e-9):
        log.warning(
            "valid radius %g..%g px reaches beyond the measured radii %g..%g px: f(r) is"
            " extrapolated there", rmin, rmax, r.min(), r.max(),
        )
    camera = OmniCamera(
        image_size=(w, h), centre=(cu, cv), valid_radius=(rmin, rmax),
        forward_angle=float(forward_angle), mirrored=bool(mirrored), **radial,
    )
    return CalibrationFit(camera=camera, radius_px=r, distance_m=d, residuals_m=residuals,
                          model=model, leave_one_out_m=loo, source=source)


def _fit_polynomial(conf, r, d, valid_radius, where):
    degree = int(conf["degree"])
    if not 1 <= degree <= 5:
        raise CalibrationError(
            f"conf 'degree' must be 1..5 (calib.yaml holds a0..a5), got {degree}")
    distinct = len(np.unique(np.round(r, 3)))
    if distinct < conf["min_distinct_radii"]:
        raise CalibrationError(
            f"{where}: only {distinct} distinct radii among {len(r)} pairs; a degree-{degree} fit"
            f" needs at least {conf['min_distinct_radii']} (spread the marks over the mirror)"
        )
    rmin, rmax = valid_radius
    coef, residuals = fit_polynomial(r, d, degree=degree)
    samples = np.linspace(rmin, rmax, int(conf["monotonic_samples"]))
    slope = np.diff(np.polynomial.polynomial.polyval(samples, coef))
    if not np.all(slope > 0):
        turn = samples[1:][np.argmax(slope <= 0)]
        raise CalibrationError(
            f"{where}: the fitted f(r) is not increasing between {rmin:g} and {rmax:g} px (it"
            f" turns at r = {turn:.5g} px); check the pairs or narrow --valid-radius"
        )
    return np.concatenate([coef, np.zeros(5 - degree)]), residuals  # a0..a5, as calib.yaml


# ---------------------------------------------------------------------------- line images


def merge_line_marks(radius_px, distance_m, marks, source: str):
    """The pairs of another source with the measured line marks in their place: within the
    marks' range of distances only the marks count; outside it the other pairs are kept unless
    they would make the radius fall with distance (then they are dropped, and the caller
    says so). Returns (radius, distance, per-pair source, dropped pairs as (radius,
    distance))."""
    r = np.asarray(radius_px, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    mr = np.array([round(m.radius_px, 3) for m in marks])
    md = np.array([m.distance_m for m in marks])
    lo, hi = md.min(), md.max()
    rows = [(a, b, source) for a, b in zip(r, d) if b < lo - 1e-9 or b > hi + 1e-9]
    rows += [(a, b, "line image") for a, b in zip(mr, md)]
    rows.sort(key=lambda t: t[1])
    kept, dropped = [], []
    inner = [t for t in rows if t[2] == "line image"]
    rmin, rmax = min(t[0] for t in inner), max(t[0] for t in inner)
    for t in rows:
        if t[2] != "line image" and ((t[1] < lo and t[0] >= rmin) or (t[1] > hi and t[0] <= rmax)):
            dropped.append((t[0], t[1]))
        else:
            kept.append(t)
    return (np.array([t[0] for t in kept]), np.array([t[1] for t in kept]),
            [t[2] for t in kept], dropped)


def _measure_line_images(conf, folder, *, centre, forward_angle, mirrored, valid_radius,
                         image_size, mask):
    first = _line_images.distance_images(folder)[0][0]
    img = read_image(first)
    if (img.shape[1], img.shape[0]) != tuple(image_size):
        raise CalibrationError(
            f"{first}: line image is {img.shape[1]} x {img.shape[0]} px, the calibration"
            f" {image_size[0]} x {image_size[1]}")
    return _line_images.measure_folder(folder, centre=centre, forward_angle=forward_angle,
                                       mirrored=mirrored, valid_radius=valid_radius, mask=mask,
                                       conf=conf["line_images"])


def _mark_records(marks, radius_px, distance_m) -> list[dict]:
    """Each line mark beside what the other source's pairs say for it (linear interpolation,
    as a MINHO robot reads its table)."""
    out = []
    for m in marks:
        rec = m.as_dict()
        if len(radius_px) >= 2 and distance_m[0] <= m.distance_m <= distance_m[-1]:
            rec["source_radius_px"] = round(float(np.interp(m.distance_m, distance_m,
                                                            radius_px)), 3)
        if len(radius_px) >= 2 and radius_px[0] <= m.radius_px <= radius_px[-1]:
            rec["source_error_m"] = round(
                float(np.interp(m.radius_px, radius_px, distance_m)) - m.distance_m, 4)
        out.append(rec)
    return out


# ---------------------------------------------------------------------------- stage mains


def _calibrate(conf, pairs: PairSource, output, geometry: MirrorGeometry, *, line_images=None,
               mask=None):
    """Fit the pairs of one source (merged with the line images' pairs, if given; ``mask`` the
    mask array for those) and write ``output`` with its calibration record."""
    output = Path(output)
    sources, source_label = pairs.sources, pairs.label
    order = np.argsort(pairs.distance_m, kind="stable")
    r, d = pairs.radius_px[order], pairs.distance_m[order]
    marks, dropped, labels = [], [], [source_label] * len(r)
    if line_images is not None:
        vr = geometry.valid_radius or (float(r.min()), float(r.max()))
        marks = _measure_line_images(conf, line_images, centre=geometry.centre,
                                     forward_angle=geometry.forward_angle,
                                     mirrored=geometry.mirrored, valid_radius=vr,
                                     image_size=geometry.image_size, mask=mask)
        sources["line_images"] = str(line_images)
        sources["line_image_hashes"] = {
            p.name: file_hash(p) for p, _ in _line_images.distance_images(line_images)}
        marks_rec = _mark_records(marks, r, d)
        others = len(r)
        r, d, labels, dropped = merge_line_marks(r, d, marks, source_label)
        if 2 * len(dropped) > others:
            # most of the other source contradicted: the line images' names are no distances
            # in metres (decimetres: 5.png for 0.5 m dropped 14 of MINHO's 16 pairs and
            # fitted a floor seen to 20 m, trial V2-2; the real images drop none)
            raise FieldlocError(
                f"{line_images}: the line images contradict {source_label}: {len(dropped)} of"
                f" its {others} pairs would make the distance fall with the radius beside"
                " them; name each image by its line's distance in metres (1.25.png)")
        if dropped:
            log.warning("line images: %d %s pair(s) dropped that would make f(r) fall: %s",
                        len(dropped), source_label,
                        ", ".join(f"({a:g} px, {b:g} m)" for a, b in dropped))
    result = fit(conf, r, d, **geometry._asdict(), where=pairs.where, source=labels)
    record = {
        "fieldloc_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "sources": sources,
        "conf": {k: v for k, v in conf.items() if k != "line_images" or line_images is not None},
        **(pairs.extra or {}),
        "model": result.model,
        "pairs": _pair_records(result),
    }
    if line_images is not None:
        record["line_images"] = marks_rec
        if dropped:
            record["dropped_pairs"] = [[float(a), float(b)] for a, b in dropped]
    save_calib(result.camera, output, calibration=record)
    if result.model == "table":
        loo = result.leave_one_out_m[np.isfinite(result.leave_one_out_m)]
        log.info("calibrated (table model) from %d pairs: leave-one-out RMS %.4f m", len(r),
                 float(np.sqrt(np.mean(loo**2))) if len(loo) else float("nan"))
    else:
        log.info("calibrated from %d pairs: residual RMS %.4f m, max %.4f m", len(r),
                 result.rms, result.max_abs)
    return output


def _pair_records(result: CalibrationFit) -> list[dict]:
    out = []
    fitted = result.distance_m + result.residuals_m
    for i, (a, b) in enumerate(zip(result.radius_px, result.distance_m)):
        rec = {"radius_px": float(a), "distance_m": float(b), "source": result.source[i],
               "fitted_m": round(float(fitted[i]), 6),
               "residual_m": round(float(result.residuals_m[i]), 6)}
        if result.leave_one_out_m is not None and np.isfinite(result.leave_one_out_m[i]):
            rec["leave_one_out_m"] = round(float(result.leave_one_out_m[i]), 6)
        out.append(rec)
    return out


def main(conf: str | dict | None, points_csv, output, *, geometry: MirrorGeometry,
         line_images=None, mask=None, overwrite: bool = False, progress: bool = False) -> Path:
    """Fit the mirror calibration to the pairs in ``points_csv`` (and the line images, if
    given) and write ``output`` (calib.yaml, kind omni). ``conf``: a preset name, None
    (``default``) or a dict of overrides on ``default``. ``geometry``: the MirrorGeometry
    (centre, image size and valid radius required). ``mask``: a mask image file for the line
    images. Returns ``output``."""
    conf = stage_conf(confs, conf)
    check_output(output, {"points": points_csv, "mask": mask,
                          "line images": _files_in(line_images)}, overwrite=overwrite,
                 kind="calibration", error=CalibrationError)
    r, d = read_points(points_csv)
    sources = {"points": str(points_csv), "points_hash": file_hash(points_csv)}
    mask_arr = _read_mask(mask, geometry.image_size, sources)
    return _calibrate(conf, PairSource(r, d, "points", str(points_csv), sources), output,
                      geometry, line_images=line_images, mask=mask_arr)


def from_minho(conf: dict | str | None, minho_dir, output, *, image_size=None, valid_radius=None,
               line_images=None, mask=None, overwrite: bool = False,
               progress: bool = False) -> Path:
    """calib.yaml from the MINHO team's files in ``minho_dir`` (mirror.cfg, image.cfg; see
    stages.calibrate.minho). ``conf``: a preset name, None (``minho``) or a dict of overrides
    on ``minho``.
    ``image_size`` None: the size of the first image in DIR/images. ``mask`` None:
    DIR/mask.png if it exists (used for the line images). Returns ``output``."""
    conf = stage_conf(confs, conf, default="minho")
    folder = Path(minho_dir)
    check_output(output, {"the MINHO folder": _files_in(folder),
                          "its images": _files_in(folder / "images"), "mask": mask,
                          "line images": _files_in(line_images)}, overwrite=overwrite,
                 kind="calibration", error=CalibrationError)
    team = read_minho(folder)
    if image_size is None:
        image_size = _image_size_of(folder / "images")
    check_centre(team.centre, image_size, f"{team.image_cfg}: IMG_CENTER")
    sources = {"minho": str(folder), "mirror_cfg_hash": file_hash(team.mirror_cfg),
               "image_cfg_hash": file_hash(team.image_cfg)}
    if mask is None and (folder / MASK_NAME).is_file():
        mask = folder / MASK_NAME
    mask_arr = _read_mask(mask, image_size, sources)
    pairs = PairSource(team.radius_px, team.distance_m, "mirror.cfg", str(team.mirror_cfg),
                       sources)
    geometry = MirrorGeometry(team.centre, image_size, valid_radius, team.forward_angle, False)
    return _calibrate(conf, pairs, output, geometry, line_images=line_images, mask=mask_arr)


def from_cnc(conf: dict | str | None, carpet_conf, output, *, rings, calib_image=None,
             geometry: MirrorGeometry = MirrorGeometry(), overwrite: bool = False,
             progress: bool = False) -> Path:
    """calib.yaml from the Carpe Noctem ``CarpetCalibrator.conf`` (ring distances) and ring
    radii: ``rings`` is the user's pairing (stages.calibrate.cnc: 'detected', or radii with
    '-' / None for a distance whose ring is not seen). ``calib_image`` (default
    CarpetCalibImage.png beside the conf, if there): where rings are detected, and the centre
    and image size unless ``geometry`` (a MirrorGeometry) gives them; the rings are measured
    about the picture's own centre unless the picture has the geometry's image size
    (``cnc.search_centre``): a given centre places the calibration in the camera's frames.
    The rings' detection is recorded beside the pairs. ``conf``: a preset name, None
    (``cnc``) or a dict of overrides on ``cnc``. Returns ``output``."""
    conf = stage_conf(confs, conf, default="cnc")
    carpet_conf = Path(carpet_conf)
    distances = _cnc.read_distances(carpet_conf)
    sources = {"cnc": str(carpet_conf), "carpet_conf_hash": file_hash(carpet_conf)}
    if calib_image is None and (carpet_conf.parent / _cnc.IMAGE_NAME).is_file():
        calib_image = carpet_conf.parent / _cnc.IMAGE_NAME
    check_output(output, {"the CNC calibration file": carpet_conf,
                          "the calibration picture": calib_image,
                          "its folder": _files_in(carpet_conf.parent)}, overwrite=overwrite,
                 kind="calibration", error=CalibrationError)
    centre, image_size = geometry.centre, geometry.image_size
    detected = None
    extra = {"ring_distances_m": [float(v) for v in distances]}
    if calib_image is not None:
        img = read_image(calib_image)
        search = _cnc.search_centre(img.shape[1::-1], centre, image_size)
        detected = _cnc.detect_rings(img, centre=search, conf=conf.get("rings"))
        sources["calib_image"] = str(calib_image)
        sources["calib_image_hash"] = file_hash(calib_image)
        extra["detected_rings"] = {"centre": [round(v, 2) for v in detected.centre],
                                   "rings": detected.as_records()}
        if centre is None:
            centre = detected.centre
        if image_size is None:
            image_size = detected.image_size
    if centre is None or image_size is None:
        raise CalibrationError("--from-cnc needs the calibration picture (--calib-image) or"
                               " --centre U V and --image-size W H")
    if isinstance(rings, str) and rings != "detected":
        rings = _cnc.parse_rings(rings)
    r, d = _cnc.pair_rings(distances, rings, detected, str(carpet_conf))
    slope = _cnc.slopes(r, d)
    extra["pairing"] = "detected rings in order" if rings == "detected" else "given (--rings)"
    extra["slope_px_per_m"] = [round(float(v), 2) for v in slope]
    if np.any(np.diff(slope) > 0):
        log.warning("the image radius grows faster again between %s m: check the pairing of"
                    " rings and distances", ", ".join(
                        f"{d[i + 1]:g}-{d[i + 2]:g}" for i in np.flatnonzero(np.diff(slope) > 0)))
    rest = {k: v for k, v in conf.items() if k != "rings"}
    pairs = PairSource(r, d, _cnc.CONF_NAME, str(carpet_conf), sources, extra)
    return _calibrate(rest, pairs, output,
                      geometry._replace(centre=centre, image_size=image_size))


def from_nubot(conf: dict | str | None, nubot_dir, output, *, image_size=None,
               valid_radius=None, overwrite: bool = False, progress: bool = False) -> Path:
    """calib.yaml from the NuBot team's ``mirror_calib.xml`` and ``ROI.xml`` in ``nubot_dir``
    (stages.calibrate.nubot): the monotone table sampled from their a tan(b rho) model across
    the usable ring, with the table's error against the model recorded (``model_fit``).
    ``image_size`` None: the size of the folder's first pic_save*.bmp, else the ROI's extent.
    ``conf``: a preset name, None (``nubot``) or a dict of overrides on ``nubot``. Returns
    ``output``."""
    conf = stage_conf(confs, conf, default="nubot")
    folder = Path(nubot_dir)
    if not folder.is_dir():
        raise CalibrationError(f"NuBot calibration folder not found: {folder}")
    check_output(output, {"the NuBot folder": _files_in(folder)}, overwrite=overwrite,
                 kind="calibration", error=CalibrationError)
    nconf = conf["nubot"]
    mirror = _nubot.read_mirror(folder / _nubot.MIRROR_XML)
    # a ROI.xml that is no regular file is refused, not taken as absent (present)
    roi = _nubot.read_roi(folder / _nubot.ROI_XML) if present(folder / _nubot.ROI_XML) \
        else None
    sources = {"nubot": str(folder), "mirror_calib_hash": file_hash(mirror.path)}
    if roi is not None:
        sources["roi_hash"] = file_hash(roi.path)
    if image_size is None:  # the team's saved pictures (pic_save*), else the ROI's extent
        images = sorted(folder.glob("pic_save*.bmp"))
        if images:
            image_size = _image_size_of_file(images[0])
        elif roi is not None:
            image_size = roi.size
        else:
            raise CalibrationError(f"no pic_save*.bmp and no {_nubot.ROI_XML} in {folder} to"
                                   " take the image size from; give --image-size W H")
    vr = tuple(valid_radius) if valid_radius else _nubot.valid_ring(mirror, roi, nconf)
    r, d = _nubot.table_pairs(mirror, vr, nconf)
    extra = {"nubot_model": {
        "range": "a tan(b rho) m (100 a tan(b rho) cm)", "a": mirror.a, "b": mirror.b,
        "centre": [mirror.centre[0], mirror.centre[1]],
        "horizon_px": round(mirror.horizon_px, 3), "max_radius_px": mirror.max_radius,
        "correction_cm_not_applied": [mirror.correction_cm[0], mirror.correction_cm[1]]}}
    if roi is not None:
        extra["nubot_roi"] = {"centre": [roi.centre[0], roi.centre[1]],
                              "small_radius": roi.small_radius, "big_radius": roi.big_radius}
    rest = {k: v for k, v in conf.items() if k != "nubot"}
    rest["nubot"] = nconf
    geometry = MirrorGeometry(mirror.centre, image_size, vr, 0.0, True)
    # _calibrate fits the same pairs again and warns: this fit only measures the model's gap
    fitted = fit(rest, r, d, **geometry._asdict(), where=str(mirror.path), warn=False)
    extra["model_fit"] = _nubot.model_fit(fitted.camera, mirror, nconf)
    pairs = PairSource(r, d, _nubot.MIRROR_XML, str(mirror.path), sources, extra)
    return _calibrate(rest, pairs, output, geometry)


def _image_size_of_file(path: Path) -> tuple[int, int]:
    img = read_image(path)  # refuses a FIFO, which would block the read forever
    return int(img.shape[1]), int(img.shape[0])


def _files_in(folder) -> list[Path]:
    """The files directly in ``folder`` (none if it is None or not a folder)."""
    if folder is None or not Path(folder).is_dir():
        return []
    return [p for p in Path(folder).iterdir() if p.is_file()]


def _read_mask(mask, image_size, sources):
    if mask is None:
        return None
    sources["mask"] = str(mask)
    sources["mask_hash"] = file_hash(mask) if Path(mask).is_file() else ""
    if not present(Path(mask)):
        raise CalibrationError(f"mask not found: {mask}")
    return read_mask(mask, tuple(image_size))


def _image_size_of(folder: Path) -> tuple[int, int]:
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES) \
        if folder.is_dir() else []
    if not images:
        raise CalibrationError(
            f"no image in {folder} to take the image size from; give --image-size W H")
    return _image_size_of_file(images[0])


def residual_report(camera: OmniCamera, points_csv) -> CalibrationFit:
    """The residuals of ``camera`` on the pairs in ``points_csv`` (for reporting a fit)."""
    r, d = read_points(points_csv)
    return CalibrationFit(camera=camera, radius_px=r, distance_m=d,
                          residuals_m=camera.distance_of_radius(r) - d,
                          model=camera.radial_model)


def report(calib_path) -> dict:
    """The ``calibration`` record of a calib.yaml written by this stage (see the module doc)."""
    rec = read_calibration_record(calib_path)
    if not rec:
        raise CalibrationError(f"{calib_path}: no calibration record (not written by fieldloc"
                               " calibrate)")
    return rec
