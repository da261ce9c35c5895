"""Mirror pairs measured in images of a straight floor line at known distances.

A calibration session as the MINHO team recorded one (../shared/realdata/minho-distance): the
robot faces a straight white line and is moved back in steps; each image is named by the
distance in metres from the robot's centre to the line's middle (``1.25.png``; the team's own
``1,25.png`` is read too). Per image:

1. rays from the image centre every ``ray_step_deg`` within ``search_deg`` of the robot's
   forward direction, sampled every ``sample_px`` (bilinear luminance Y), masked pixels left out;
2. on each ray the nearest ridge: a white top-hat (Y minus its grey opening over
   2 ``ridge_px`` + 1 px: what is brighter than its surroundings and narrower than that) of at
   least ``min_contrast`` grey levels; its radius is the centroid of the top-hat above half its
   peak: the middle of the white in the image. (The extractor takes the middle in floor
   metres; the two differ by r''(d) w^2 / 8 for a line w wide, about 0.3 px for a 10 cm line
   0.5 m from the test mirror of tests/test_extract_omni and less farther out.)
3. a straight line is nearest to the robot where it crosses its normal, and around that bearing
   its image radius grows as r0 + k (b - b0)^2. A parabola is fitted to the ridge radii of the
   rays within ``fit_deg`` of the nearest ridge, refitted without rays off by more than
   ``max(1 px, 3 x the median deviation)`` until it settles; its vertex (b0, r0) is the line's
   bearing and the image radius of its distance.

An image is refused (one clear message) when too few rays (``min_rays_share`` of the fit
window) see a ridge, when the ridge radii do not bend like a straight line (k <= 0), or when the
parabola's scatter exceeds ``max_rms_px``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common.camera import MAX_PAIRS
from ..common.dataset import IMAGE_KINDS, IMAGE_SUFFIXES, read_image
from ..common.errors import FieldlocError

confs = {
    "default": {
        "search_deg": 30.0,  # the line's nearest point lies this close to the forward direction
        "fit_deg": 15.0,  # rays this close to the nearest point are fitted
        "ray_step_deg": 0.5,
        "sample_px": 0.25,
        "ridge_px": 16.0,  # half the widest line (px): 0.25 m from a MINHO mirror, ~28 px wide
        "min_contrast": 10.0,  # grey levels above the opening (floor noise ~1; the line at 2.5 m
        # of minho-distance peaks at 20-40 and is seen on 57 of 61 rays)
        "min_rays_share": 0.5,
        "max_rms_px": 1.0,
    },
}

# a distance in metres: 1.25, 1,25 (the MINHO team's own names), 2; not 01 (a frame number)
_DISTANCE_NAME = re.compile(r"^(?:0|[1-9]\d*)(?:[.,]\d+)?$")

# m: the distances a line image's line can lie at, from the robot's centre. Nearer than 0.1 m
# the line lies under the robot's own body (a robot carrying a mirror camera is wider than
# 20 cm; the MINHO table starts at 0.25 m, the simulated mirror's body edge is at 0.28 m), so
# the mirror shows no floor there. Farther than 20 m no mirror shows a line as a ridge: in the
# MINHO mirror the floor moves 16 px/m at 4 m, falling about as 1/d^2, so a 12 cm line is half
# a pixel wide at 8 m; 20 m leaves room for larger images and other mirrors. A name outside
# is a slip (cm or mm: 125.png), which would otherwise replace the other source's pairs
# (1000.png, a line at 1 m, dropped 13 of MINHO's 16 and fitted a floor seen to 1000 m)
LINE_DISTANCE_M = (0.1, 20.0)


@dataclass
class LineMark:
    """The line of one image: its distance and where the image shows it."""

    image: str  # file name
    distance_m: float
    radius_px: float  # image radius of the line's nearest point (its distance)
    bearing_deg: float  # robot frame, counter-clockwise from forward
    rays: int  # rays fitted
    rms_px: float  # scatter of the fitted ridge radii about the parabola
    contrast: float  # median top-hat peak of the fitted rays (grey levels)

    def as_dict(self) -> dict:
        return {"image": self.image, "distance_m": float(self.distance_m),
                "radius_px": round(float(self.radius_px), 3),
                "bearing_deg": round(float(self.bearing_deg), 2), "rays": int(self.rays),
                "rms_px": round(float(self.rms_px), 3), "contrast": round(float(self.contrast), 1)}


def distance_images(folder) -> list[tuple[Path, float]]:
    """(path, distance in m) of every image of ``folder``, sorted by distance; each file name
    must be a distance (``1.25.png`` or ``1,25.png``)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FieldlocError(f"line images folder not found: {folder}")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise FieldlocError(f"{folder}: no images ({IMAGE_KINDS})")
    if len(images) > MAX_PAIRS:  # each is read and measured: 3000 took 44 s (trial Y2-1)
        raise FieldlocError(f"{folder}: {len(images):,} line images, more than the {MAX_PAIRS}"
                            " pairs a calibration holds")
    bad = [p.name for p in images if not _DISTANCE_NAME.match(p.stem)]
    if bad:
        raise FieldlocError(
            f"{folder}: line images must be named by the line's distance in metres (1.25.png),"
            f" not {', '.join(bad[:3])}{' ...' if len(bad) > 3 else ''}")
    out = sorted(((p, float(p.stem.replace(",", "."))) for p in images), key=lambda t: t[1])
    dist = [d for _, d in out]
    dup = sorted({d for d in dist if dist.count(d) > 1})
    if dup:
        at = ", ".join(f"{d:g}" for d in dup)
        raise FieldlocError(f"{folder}: more than one image at {at} m")
    lo, hi = LINE_DISTANCE_M
    for p, d in out:
        if not lo <= d <= hi:
            raise FieldlocError(
                f"{p}: a line image's distance must be {lo:g} to {hi:g} m (nearer lies under"
                f" the robot, farther no mirror shows a line), not {p.stem[:24]} m")
    return out


def _ridge_radius(profile: np.ndarray, radii: np.ndarray, half: int, min_contrast: float):
    """Radius and peak of the nearest ridge of a luminance profile (NaN where masked)."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    valid = np.isfinite(profile)
    big = np.where(valid, profile, np.inf)
    eroded = minimum_filter1d(big, 2 * half + 1, mode="nearest")
    opened = maximum_filter1d(np.where(valid, eroded, -np.inf), 2 * half + 1, mode="nearest")
    tophat = np.where(valid & np.isfinite(opened), profile - opened, 0.0)
    above = np.flatnonzero(tophat >= min_contrast)
    if len(above) == 0:
        return None
    i = int(above[0])
    while i + 1 < len(tophat) and tophat[i + 1] >= tophat[i]:
        i += 1
    peak = tophat[i]
    a = i
    while a > 0 and tophat[a - 1] > peak / 2:
        a -= 1
    b = i
    while b + 1 < len(tophat) and tophat[b + 1] > peak / 2:
        b += 1
    w = tophat[a:b + 1] - peak / 2
    if w.sum() <= 0:
        return float(radii[i]), float(peak)
    return float((w * radii[a:b + 1]).sum() / w.sum()), float(peak)


def ridge_radii(image_bgr: np.ndarray, bearings_deg, *, centre, forward_angle: float,
                mirrored: bool = False, valid_radius, mask: np.ndarray | None = None,
                conf: dict | None = None, name: str = "image"):
    """The nearest ridge on rays at ``bearings_deg`` (robot frame, from forward): its radius
    (px, NaN where a ray sees none) and its top-hat peak (grey levels)."""
    import cv2

    c = {**confs["default"], **(conf or {})}
    h, w = image_bgr.shape[:2]
    y = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2YUV)[..., 0].astype(np.float32)
    if mask is not None:
        if mask.shape != (h, w):
            raise FieldlocError(f"{name}: mask is {mask.shape[1]} x {mask.shape[0]} px, the"
                                f" image {w} x {h}")
        y = np.where(mask, y, np.nan).astype(np.float32)
    r0, r1 = (float(v) for v in valid_radius)
    radii = np.arange(r0, r1, float(c["sample_px"]))
    half = max(1, int(round(float(c["ridge_px"]) / float(c["sample_px"]))))
    sign = -1.0 if mirrored else 1.0
    bearings = np.asarray(bearings_deg, dtype=float)
    alpha = forward_angle + sign * np.radians(bearings)
    cu, cv_ = (float(v) for v in centre)
    mu = (cu + radii[None, :] * np.cos(alpha)[:, None]).astype(np.float32)
    mv = (cv_ - radii[None, :] * np.sin(alpha)[:, None]).astype(np.float32)
    prof = cv2.remap(y, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=float("nan")).astype(float)
    out_r = np.full(len(bearings), np.nan)
    out_peak = np.full(len(bearings), np.nan)
    for k, p in enumerate(prof):
        hit = _ridge_radius(p, radii, half, float(c["min_contrast"]))
        if hit is not None:
            out_r[k], out_peak[k] = hit
    return out_r, out_peak


def measure_line(image_bgr: np.ndarray, *, centre, forward_angle: float, mirrored: bool = False,
                 valid_radius, mask: np.ndarray | None = None, conf: dict | None = None,
                 name: str = "image", distance_m: float = float("nan")) -> LineMark:
    """The straight line nearest to the robot ahead in one image (see the module doc)."""
    c = {**confs["default"], **(conf or {})}
    bearings = np.arange(-c["search_deg"], c["search_deg"] + 1e-9, c["ray_step_deg"])
    rr, pk = ridge_radii(image_bgr, bearings, centre=centre, forward_angle=forward_angle,
                         mirrored=mirrored, valid_radius=valid_radius, mask=mask, conf=c,
                         name=name)
    seen = np.isfinite(rr)
    found = list(zip(bearings[seen], rr[seen], pk[seen]))
    need = max(5, int(math.ceil(c["min_rays_share"] * 2 * c["fit_deg"] / c["ray_step_deg"])))
    if len(found) < need:
        raise FieldlocError(
            f"{name}: a bright line is seen on {len(found)} of {len(bearings)} rays within"
            f" {c['search_deg']:g} deg of the front, {need} are needed")
    b, r, peak = (np.array(v) for v in zip(*found))
    from scipy.ndimage import median_filter

    # the nearest point of the line: the smallest radius after a 5-ray median (one ray that
    # meets another bright thing nearer does not move it)
    b0 = float(b[np.argmin(median_filter(r, size=5, mode="nearest"))])
    keep = np.abs(b - b0) <= c["fit_deg"]
    for _ in range(20):
        if keep.sum() < need:
            break
        coef = np.polyfit(b[keep], r[keep], 2)
        if coef[0] <= 0:
            break
        b0 = float(np.clip(-coef[1] / (2 * coef[0]), b.min(), b.max()))
        dev = r - np.polyval(coef, b)
        tol = max(1.0, 3.0 * float(np.median(np.abs(dev[keep]))))
        new = (np.abs(b - b0) <= c["fit_deg"]) & (np.abs(dev) <= tol)
        if np.array_equal(new, keep):
            break
        keep = new
    if keep.sum() < need:
        raise FieldlocError(
            f"{name}: only {int(keep.sum())} rays agree on one line ahead, {need} are needed")
    coef = np.polyfit(b[keep], r[keep], 2)
    if coef[0] <= 0:
        raise FieldlocError(f"{name}: the bright ridge ahead does not bend like a straight line"
                            " (its radius does not grow on both sides of its nearest point)")
    b0 = -coef[1] / (2 * coef[0])
    rms = float(np.sqrt(np.mean((r[keep] - np.polyval(coef, b[keep])) ** 2)))
    if rms > c["max_rms_px"]:
        raise FieldlocError(f"{name}: the ridge ahead scatters by {rms:.2f} px about a straight"
                            f" line's shape (at most {c['max_rms_px']:g} px)")
    return LineMark(image=name, distance_m=float(distance_m), radius_px=float(np.polyval(coef, b0)),
                    bearing_deg=float(b0), rays=int(keep.sum()), rms_px=rms,
                    contrast=float(np.median(peak[keep])))


def measure_folder(folder, *, centre, forward_angle: float, mirrored: bool = False,
                   valid_radius, mask: np.ndarray | None = None,
                   conf: dict | None = None) -> list[LineMark]:
    """``measure_line`` on every image of ``folder`` (named by distance), nearest first."""
    marks = []
    for path, dist in distance_images(folder):
        img = read_image(path)
        marks.append(measure_line(img, centre=centre, forward_angle=forward_angle,
                                  mirrored=mirrored, valid_radius=valid_radius, mask=mask,
                                  conf=conf, name=path.name, distance_m=dist))
    return marks
