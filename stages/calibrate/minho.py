"""The MINHO team's calibration files (minhoteam-msl/minho_team_ros, localization_node config).

``mirror.cfg``: ``MAX_DISTANCE`` and ``STEP`` (m) and ``PIXEL_DISTANCES``, the image radii (px) at
which the floor lies STEP, 2 STEP, ..., MAX_DISTANCE m from the robot (the first radius belongs to
STEP, not to 0: the team's reader pairs radius i with (i + 1) STEP and refuses a file whose count
is not MAX_DISTANCE / STEP). Their robot maps a pixel by linear interpolation in that table.

``image.cfg``: ``IMG_CENTER=u,v`` (px) and ``TILT`` (deg), the image angle of the robot's front,
counter-clockwise from +u with v up (90: the front is at the top of the image).

Lines are ``KEY=VALUE``; ``#`` starts a comment, and a comment can run into the next key on the
same line (``#DONT CHANGE THE ORDER OF THE CONFIGURATIONSMAX_DISTANCE=4``), so keys are found
anywhere in a line.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common.dataset import parse_number
from ..common.errors import FieldlocError, check_file

MIRROR_CFG = "mirror.cfg"
IMAGE_CFG = "image.cfg"
_KEY_VALUE = re.compile(r"([A-Z][A-Z0-9_]*)=([^#\n]*)")
# the keys read here, found also at the end of a comment they run into (the comment's last word
# and the key are one run of capitals: CONFIGURATIONSMAX_DISTANCE=4 was read as a key of that
# name, and its MAX_DISTANCE, or a STEP given a second time there, went unseen)
_READ_KEYS = ("MAX_DISTANCE", "PIXEL_DISTANCES", "STEP", "IMG_CENTER", "TILT")
_RUN_IN_KEY = re.compile(r"#[^\n]*?[A-Za-z0-9](" + "|".join(_READ_KEYS) + r")=([^#\n]*)")


@dataclass
class MinhoCalibration:
    """What the team's files say: pairs (radius_px, distance_m), image centre, forward angle."""

    radius_px: np.ndarray
    distance_m: np.ndarray
    centre: tuple[float, float]
    forward_angle: float  # rad
    mirror_cfg: Path
    image_cfg: Path


def read_cfg(path: Path) -> dict[str, str]:
    """KEY=VALUE pairs of a MINHO .cfg file (see the module doc)."""
    path = Path(path)
    check_file(path, "MINHO calibration file")  # a folder, a FIFO: said, not "not found"
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM, as every reader reads it
    except (OSError, UnicodeDecodeError) as e:
        raise FieldlocError(f"{path}: unreadable ({e})") from None
    out: dict[str, str] = {}
    for line in text.splitlines():
        code, hashed, comment = line.partition("#")
        for key, value in _KEY_VALUE.findall(code) + _RUN_IN_KEY.findall(hashed + comment):
            if key in out:  # the last was kept: a TILT given twice went by unseen
                raise FieldlocError(f"{path}: key {key} given twice")
            out[key] = value.strip()
    return out


def _value(cfg: dict, key: str, path: Path) -> str:
    if key not in cfg:
        raise FieldlocError(f"{path}: missing key {key}")
    return cfg[key]


def _numbers(cfg: dict, key: str, path: Path, count: int | None = None) -> list[float]:
    text = _value(cfg, key, path)
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [parse_number(p) for p in parts]
    except ValueError:
        raise FieldlocError(
            f"{path}: {key} must be {'a number' if count == 1 else 'comma-separated numbers'},"
            f" got '{text[:40]}'") from None
    if not all(math.isfinite(v) for v in values):
        raise FieldlocError(f"{path}: {key} must be finite, got '{text[:40]}'")
    if count is not None and len(values) != count:
        raise FieldlocError(f"{path}: {key} needs {count} value(s), got '{text[:40]}'")
    return values


def read_minho(folder) -> MinhoCalibration:
    """The pairs, centre and forward angle of a folder holding mirror.cfg and image.cfg."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FieldlocError(f"MINHO calibration folder not found: {folder}")
    mpath, ipath = folder / MIRROR_CFG, folder / IMAGE_CFG
    mirror, image = read_cfg(mpath), read_cfg(ipath)
    (step,) = _numbers(mirror, "STEP", mpath, 1)
    radii = np.asarray(_numbers(mirror, "PIXEL_DISTANCES", mpath), dtype=float)
    if step <= 0:
        raise FieldlocError(f"{mpath}: STEP must be > 0, got {step:g}")
    if "MAX_DISTANCE" in mirror:
        (max_distance,) = _numbers(mirror, "MAX_DISTANCE", mpath, 1)
        expected = int(round(max_distance / step))
        if expected != len(radii):
            raise FieldlocError(
                f"{mpath}: MAX_DISTANCE / STEP = {max_distance:g} / {step:g} asks for"
                f" {expected} PIXEL_DISTANCES, the file has {len(radii)}")
    if np.any(radii < 0):
        raise FieldlocError(f"{mpath}: PIXEL_DISTANCES must be >= 0")
    cu, cv = _numbers(image, "IMG_CENTER", ipath, 2)
    (tilt,) = _numbers(image, "TILT", ipath, 1)
    return MinhoCalibration(
        radius_px=radii, distance_m=step * np.arange(1, len(radii) + 1), centre=(cu, cv),
        forward_angle=math.radians(tilt), mirror_cfg=mpath, image_cfg=ipath)
