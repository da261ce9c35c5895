"""The Carpe Noctem Cassel (dasys-lab/cnc-msl) carpet calibration: rings laid on the carpet at
the distances of ``CarpetCalibrator.conf`` and a picture of them (``CarpetCalibImage.png``).

``CarpetCalibrator.conf``: a ``[Dist]`` ... ``[!Dist]`` block of ``distN = MM`` lines, the ring
distances from the robot's centre in millimetres; ``dist0 = 0`` is the robot's centre, not a
ring. The file holds no radii: where each ring lies in the image is measured in the picture
(``detect_rings``) or given by hand, and pairing rings with distances is the user's choice
(``pair_rings``), because the team's own files do not decide it. Paired in order, their
picture's rings give a radius that gains less per metre outwards, as a convex mirror's does;
their later per-pixel table reads the outer rings as other distances. Both readings share the
pairs to 5 m; the figures of each are in docs/manual.md (``--from-cnc``). The picture is a
view centred on the mirror, smaller than the team's full frames: for those, the centre comes
from their Vision.conf (docs/manual.md gives the numbers).

``rings``: the radii (px) to pair in order with the conf's distances, ``None`` for a distance
whose ring is not in the image (the per-pixel table's reading is ``--rings
103.7,130,146.8,158.1,166.2,177.2,184.4,192.2,-``), or the string ``detected``: the rings found
in the picture, in order, which needs as many rings as distances (the reading in order).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..common.dataset import parse_number
from ..common.errors import FieldlocError, check_file

CONF_NAME = "CarpetCalibrator.conf"
IMAGE_NAME = "CarpetCalibImage.png"

confs = {
    "default": {
        "ray_step_deg": 1.0,
        "sample_px": 0.25,
        "min_radius_px": 20.0,  # inside this the robot's own body
        "min_prominence": 10.0,  # grey levels a ring rises above the carpet on both sides, in
        # the median over all rays (the weakest ring of the team's picture: 19; noise ~1-2)
        "sectors": 8,  # a ring must be seen in at least min_sectors of these
        "min_sectors": 6,
        "centre_search_px": 16.0,  # the centre is searched this far around the image middle
        "max_width_growth": 1.5,  # a ring of tape is narrower in the image than the ring
        # inside it (the radius grows ever slower with distance); a peak this much wider is
        # the glare beyond the mirror's rim, and the search stops there
    },
}


class CncCalibrationError(FieldlocError):
    """The CNC calibration files cannot give pairs."""


@dataclass
class CarpetRings:
    """Rings measured in a calibration picture."""

    centre: tuple[float, float]
    radius_px: np.ndarray  # (R,) the rings' middles, increasing
    prominence: np.ndarray  # (R,) grey levels above the carpet
    width_px: np.ndarray  # (R,) at half prominence
    sectors: np.ndarray  # (R,) in how many sectors the ring is seen
    image_size: tuple[int, int]
    spread_px: np.ndarray = field(default=None)  # (R,) std of the per-sector radii

    def as_records(self) -> list[dict]:
        return [{"radius_px": round(float(r), 2), "prominence": round(float(p), 1),
                 "width_px": round(float(w), 2), "sectors": int(s),
                 "sector_spread_px": round(float(d), 2)}
                for r, p, w, s, d in zip(self.radius_px, self.prominence, self.width_px,
                                         self.sectors, self.spread_px)]


def read_distances(path) -> np.ndarray:
    """The ring distances (m, increasing, without the centre's 0) of a CarpetCalibrator.conf."""
    path = Path(path)
    check_file(path, "CNC calibration file", CncCalibrationError)
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM, as every reader reads it
    except (OSError, UnicodeDecodeError) as e:
        raise CncCalibrationError(f"{path}: unreadable ({e})") from None
    blocks = re.findall(r"\[Dist\](.*?)\[!Dist\]", text, re.S)
    if not blocks:
        raise CncCalibrationError(f"{path}: no [Dist] ... [!Dist] block")
    if len(blocks) > 1:  # the first was read, the others went by unseen
        raise CncCalibrationError(f"{path}: section [Dist] given twice")
    values = {}
    for line in blocks[0].splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        kv = re.fullmatch(r"dist(\d+)\s*=\s*(\S+)", line)
        if not kv:
            raise CncCalibrationError(f"{path}: cannot read '{line[:40]}' (expected distN ="
                                      " MM)")
        if int(kv.group(1)) in values:  # the last was kept: a ring at two distances
            raise CncCalibrationError(f"{path}: key dist{kv.group(1)} given twice")
        try:
            values[int(kv.group(1))] = parse_number(kv.group(2))
        except ValueError:
            raise CncCalibrationError(f"{path}: '{line[:40]}' is not a number of mm") from None
    d = np.array([values[k] for k in sorted(values)], float) / 1000.0
    if not np.all(np.isfinite(d)) or np.any(d < 0):
        raise CncCalibrationError(f"{path}: distances must be finite and >= 0")
    d = d[d > 0]
    if len(d) < 2 or np.any(np.diff(d) <= 0):
        raise CncCalibrationError(f"{path}: the ring distances must increase ({d * 1000} mm)")
    return d


def _grey(image) -> np.ndarray:
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return img.astype(np.float32)


def _polar(grey, centre, radii, angles):
    import cv2

    a, r = np.meshgrid(angles, radii, indexing="ij")
    u = (centre[0] + r * np.cos(a)).astype(np.float32)
    v = (centre[1] - r * np.sin(a)).astype(np.float32)
    return cv2.remap(grey, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=float("nan"))


def _profile_peaks(profile, radii, min_prominence):
    from scipy.signal import find_peaks, peak_widths

    p = np.nan_to_num(profile, nan=float(np.nanmin(profile)))
    idx, props = find_peaks(p, prominence=min_prominence)
    if not len(idx):
        return np.zeros(0), np.zeros(0), np.zeros(0)
    w, _, left, right = peak_widths(p, idx, rel_height=0.5, prominence_data=(
        props["prominences"], props["left_bases"], props["right_bases"]))
    step = radii[1] - radii[0]
    mid = radii[0] + step * (left + right) / 2  # the middle of the ring between its edges
    return mid, props["prominences"], w * step


def _sharpness(grey, centre, radii, angles):
    prof = np.nanmedian(_polar(grey, centre, radii, angles), axis=0)
    return float(np.nansum(np.abs(np.diff(prof))))


def find_centre(grey, conf) -> tuple[float, float]:
    """The centre about which the rings are sharpest (total variation of the ray-median
    profile), searched on a 1 px grid around the image middle, then refined to 0.25 px."""
    h, w = grey.shape
    radii = np.arange(float(conf["min_radius_px"]), min(h, w) / 2 - 1, 1.0)
    angles = np.radians(np.arange(0.0, 360.0, 4.0))
    best = (-1.0, (w / 2, h / 2))
    span = float(conf["centre_search_px"])
    for step in (2.0, 1.0, 0.25):
        c0 = best[1]
        offs = np.arange(-span, span + 1e-9, step)
        for du in offs:
            for dv in offs:
                c = (c0[0] + du, c0[1] + dv)
                s = _sharpness(grey, c, radii, angles)
                if s > best[0]:
                    best = (s, c)
        span = 2 * step
    return float(best[1][0]), float(best[1][1])


def search_centre(picture_size, centre, image_size):
    """The centre to measure the rings about in a calibration picture of ``picture_size``
    (w, h), given the ``centre`` and ``image_size`` the calibration is written for (each None
    when not given): that centre when the picture is such a frame (``image_size`` None or the
    picture's), else None (the picture's own centre is found). The team's picture is a 460 x
    460 view of the mirror, their frames 640 x 480 with the centre elsewhere: the frames'
    centre searched in the picture found no ring."""
    if centre is None or (image_size is not None
                          and tuple(int(v) for v in image_size) != tuple(picture_size)):
        return None
    return centre


def detect_rings(image, *, centre=None, conf=None) -> CarpetRings:
    """The bright rings of a carpet calibration picture (BGR or grey): each a peak of the
    ray-median luminance profile (robust to the mirror holder's spokes) of at least
    ``min_prominence``, placed at the middle of its half-prominence edges and kept when it is
    also seen in ``min_sectors`` of ``sectors`` angular sectors."""
    conf = conf or confs["default"]
    grey = _grey(image)
    h, w = grey.shape
    # the rings are searched from min_radius_px outwards: a picture without room for two
    # samples beyond it around its middle holds no ring (a 1 x 1 picture met OpenCV's
    # assertion on an empty sampling grid)
    least = 2 * (float(conf["min_radius_px"]) + float(conf["centre_search_px"])) + 4
    if min(h, w) < least:
        raise CncCalibrationError(f"the calibration picture is {w} x {h} px: too small to hold"
                                  f" the rings (at least {least:.0f} px a side)")
    if centre is None:
        centre = find_centre(grey, conf)
    cu, cv = (float(c) for c in centre)
    rmax = min(cu, cv, w - 1 - cu, h - 1 - cv)
    step = float(conf["sample_px"])
    radii = np.arange(float(conf["min_radius_px"]), rmax, step)
    if len(radii) < 2:  # a centre at the picture's edge leaves no ray to sample
        raise CncCalibrationError(f"the centre ({cu:g}, {cv:g}) leaves no room for rings beyond"
                                  f" {float(conf['min_radius_px']):g} px in the {w} x {h}"
                                  " picture")
    angles = np.radians(np.arange(0.0, 360.0, float(conf["ray_step_deg"])))
    polar = _polar(grey, (cu, cv), radii, angles)
    mid, prom, width = _profile_peaks(np.nanmedian(polar, axis=0), radii,
                                      float(conf["min_prominence"]))
    n_sec = int(conf["sectors"])
    per_sector = np.full((n_sec, len(mid)), np.nan)
    for s in range(n_sec):
        rows = (np.arange(len(angles)) * n_sec) // len(angles) == s
        sm, _, _ = _profile_peaks(np.nanmedian(polar[rows], axis=0), radii,
                                  float(conf["min_prominence"]) / 2)
        for k, r in enumerate(mid):
            if len(sm):
                j = int(np.argmin(np.abs(sm - r)))
                if abs(sm[j] - r) <= max(2.0, width[k]):
                    per_sector[s, k] = sm[j]
    seen = np.isfinite(per_sector).sum(axis=0)
    keep = seen >= int(conf["min_sectors"])
    last_width = math.inf
    for k in range(len(mid)):
        if not keep[k]:
            continue
        if width[k] > float(conf["max_width_growth"]) * last_width:
            keep[k:] = False
            break
        last_width = width[k]
    spread = np.array([np.nanstd(per_sector[:, k]) if seen[k] else np.nan
                       for k in range(len(mid))])
    return CarpetRings(centre=(cu, cv), radius_px=mid[keep], prominence=prom[keep],
                       width_px=width[keep], sectors=seen[keep], image_size=(w, h),
                       spread_px=spread[keep])


def parse_rings(text: str):
    """``--rings``: 'detected', or comma-separated radii (px) with '-' for a distance whose
    ring is not in the image."""
    text = text.strip()
    if text == "detected":
        return "detected"
    out = []
    for part in text.split(","):
        part = part.strip()
        if part in ("-", ""):
            out.append(None)
            continue
        try:
            v = parse_number(part)
        except ValueError:
            raise CncCalibrationError(f"--rings: '{part[:40]}' is not a radius in px or '-'"
                                      ) from None
        if not math.isfinite(v) or v <= 0:
            raise CncCalibrationError(f"--rings: radius {part} must be > 0")
        out.append(v)
    return out


def pair_rings(distances, rings, detected: CarpetRings | None, where: str):
    """(radius_px, distance_m) pairs from the user's choice (see the module doc)."""
    d = np.asarray(distances, float)
    if isinstance(rings, str):
        if rings != "detected":
            rings = parse_rings(rings)
        else:
            if detected is None:
                raise CncCalibrationError("--rings detected needs the calibration picture"
                                          " (--calib-image)")
            if len(detected.radius_px) != len(d):
                raise CncCalibrationError(
                    f"{where}: {len(d)} ring distances but {len(detected.radius_px)} rings in"
                    " the picture; pass --rings with one radius per distance ('-' for a ring"
                    f" not seen). Rings found: {_fmt(detected.radius_px) or 'none'}"
                    + (" px" if len(detected.radius_px) else ""))
            rings = list(detected.radius_px)
    if len(rings) != len(d):
        raise CncCalibrationError(
            f"{where}: --rings gives {len(rings)} entries for {len(d)} distances"
            f" ({_fmt(d)} m); one radius (or '-') per distance")
    r = np.array([np.nan if v is None else float(v) for v in rings])
    keep = np.isfinite(r)
    if keep.sum() < 2:
        raise CncCalibrationError("--rings: at least two rings are needed")
    if np.any(np.diff(r[keep]) <= 0):
        raise CncCalibrationError(f"--rings: the radii must increase with the distance, got"
                                  f" {_fmt(r[keep])} px")
    return r[keep], d[keep]


def slopes(radius_px, distance_m) -> np.ndarray:
    """Image radius gained per metre between consecutive pairs (px/m)."""
    return np.diff(np.asarray(radius_px, float)) / np.diff(np.asarray(distance_m, float))


def _fmt(a) -> str:
    return ", ".join(f"{float(v):g}" for v in a)
