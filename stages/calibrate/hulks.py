"""Perspective camera import from a HULKs (SPL team) camera-matrix JSON.

    main(conf, source, output, *, overwrite=False) -> Path

HULKs' robots store, with each captured NAO frame, the camera matrix of that moment (their
``CameraMatrix``, see ../shared/realdata/hulks-goalbox-labels/SOURCE.txt)::

    {"camera_matrix": {"focal_length": [fx, fy], "optical_center": [cx, cy],
                       "camera_to_ground": {"rotation": [x, y, z, w], "translation": [x, y, z]},
                       ...},
     "position": "Top" | "Bottom", ...}

Conventions of that format (HULKs' ``projection`` crate): a pinhole without distortion; the
camera frame has x forward along the optical axis, y left, z up; a pixel (u, v) is the ray
(1, (cx - u) / fx, (cy - v) / fy); every ``*_to_*`` entry is a rigid transform whose rotation
is a unit quaternion in nalgebra order (x, y, z, w) with p_target = R p_source + t.
``camera_to_ground`` takes camera points to the ground frame (origin on the floor under the
robot, x forward, y left, z up), so its translation is the optical centre over the floor
(x, y) and its height (z).

What becomes of it here (``camera_from_hulks``): fx, fy as given; the principal point moved by
half a pixel (HULKs' pixel coordinates start at the top-left pixel's corner, fieldloc's at its
centre: an image 640 px wide has its centre at 320 there and 319.5 here); no distortion; the
rotation decomposed into yaw, pitch and roll (intrinsic z-y-x, the order of
``PerspectiveCamera``: HULKs' camera axes are exactly the camera axes of that model turned by
its ``_CAMERA_AXES``, so R = Rz(yaw) Ry(pitch) Rx(roll)); height = translation z; position =
translation x, y.

``source`` is either one JSON file (``output`` is then the calib.yaml to write) or a folder of
HULKs captures ``<stamp>.json`` beside ``<stamp>.jpg`` (or .png), as the "Manual Crossing
Marker" panel writes them. A folder becomes a dataset folder (GUIDE section 4) at ``output``:

- ``images/<stamp>.jpg``: the frames, copied unchanged (the numeric stem is the stamp);
- ``calib.yaml``: the intrinsics (which must be the same in every file) and, as the nominal
  pose, the median height, pitch and roll of the frames (yaw 0, position 0);
- ``head.csv``: per frame its stamp and its own pitch, roll, yaw, height, x, y: the robot turns
  and tilts its head between captures (HULKs' frames: yaw -124..122 deg, pitch -6..32 deg,
  height 0.37..0.51 m), so each frame is projected with its own camera matrix by
  ``fieldloc extract``, which reads these columns. Top and bottom camera frames may share one
  dataset this way when their intrinsics agree.

Refused, each with one clear message naming the input's field: an unreadable or malformed
file (a key given twice included: json keeps the last one), a value that is no number (a
``true``), a focal length no lens has, an optical centre outside the image, a quaternion that
is not of unit length, a camera that does not look below the horizon, intrinsics that differ
between the files of a folder, an output that exists (without ``overwrite``).
"""

from __future__ import annotations

import logging
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common.artifacts import (
    WRITTEN_FILES,
    atomic_dir,
    check_importer_target,
    check_output,
    record_text,
    tree_files,
    written_files,
)
from ..common.camera import MAX_IMAGE_PX, save_calib
from ..common.conf import check_bounds, load_json, read_record, stage_conf
from ..common.dataset import MAX_VALUE, write_csv
from ..common.errors import FieldlocError, real_path, shown
from ..common.perspective_camera import FOCAL_SHARE, PerspectiveCamera
from ..common.user_numbers import user_numbers

log = logging.getLogger(__name__)

confs = {
    "default": {
        "image_size": [640, 480],  # px: NAO v6 frames as HULKs capture them (not in the JSON)
        "pixel_origin_shift": -0.5,  # px added to the principal point (corner -> centre origin)
        "unit_tolerance": 1e-3,  # |q| may differ from 1 by this much (float32 in the files)
    },
}
# the ranges of the conf's keys (common.conf.check_bounds), held where the conf is resolved
BOUNDS = {"image_size": (1, MAX_IMAGE_PX, 2)}
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
# the record a folder import writes into its dataset: what made it (the marker that lets
# --overwrite replace it) and from where
IMPORT_RECORD = "import.yaml"
GENERATOR = "fieldloc calibrate perspective --from-hulks"


class HulksImportError(FieldlocError):
    """A HULKs camera-matrix file that cannot be imported."""


@dataclass
class HulksFrame:
    """One HULKs capture: its camera at the frame's pose, which camera of the NAO took it, and
    the stamp (the file's numeric name, seconds)."""

    camera: PerspectiveCamera
    position: str  # "Top" or "Bottom"
    stamp: float
    path: Path


def quaternion_matrix(q_xyzw) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion given as [x, y, z, w]."""
    x, y, z, w = (float(v) for v in q_xyzw)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def zyx_angles(rotation: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) with rotation = Rz(yaw) Ry(pitch) Rx(roll) (intrinsic z-y-x), pitch
    in [-pi/2, pi/2]; Ry(p) turns x towards -z for p > 0 (a camera pitched down)."""
    r = np.asarray(rotation, float)
    pitch = math.asin(max(-1.0, min(1.0, -r[2, 0])))
    yaw = math.atan2(r[1, 0], r[0, 0])
    roll = math.atan2(r[2, 1], r[2, 2])
    return yaw, pitch, roll


def _numbers(d: dict, key: str, n: int, where: str) -> np.ndarray:
    """The ``n`` finite numbers of ``d[key]`` (a JSON list), or one line naming the field of
    the input file: a ``true`` read as 1 was refused later under the output's name."""
    return np.array(user_numbers(d[key], f"{where}: {key}", count=n, error=HulksImportError))


def _transform(d, key: str, where: str, tol: float) -> tuple[np.ndarray, np.ndarray]:
    t = d.get(key)
    if not isinstance(t, dict) or "rotation" not in t or "translation" not in t:
        raise HulksImportError(f"{where}: '{key}' needs 'rotation' [x, y, z, w] and "
                               "'translation' [x, y, z]")
    q = _numbers(t, "rotation", 4, f"{where}: {key}")
    p = _numbers(t, "translation", 3, f"{where}: {key}")
    # |q| from components within 1 + tol: a component of 1e308 overflowed numpy's norm
    if np.abs(q).max() > 1 + tol or abs(math.hypot(*q) - 1.0) > tol:
        raise HulksImportError(f"{where}: '{key}' rotation is not a unit quaternion "
                               f"(|q| = {math.hypot(*q):.4g})")
    if np.abs(p).max() > MAX_VALUE:
        raise HulksImportError(f"{where}: '{key}' translation {shown(p.tolist(), 40)} is"
                               f" beyond {MAX_VALUE:g} m")
    return quaternion_matrix(q), p


def camera_from_hulks(d: dict, conf: dict | None = None, where: str = "HULKs camera matrix"
                      ) -> PerspectiveCamera:
    """The PerspectiveCamera of a HULKs ``camera_matrix`` mapping (see the module doc) at the
    pose of its ``camera_to_ground``. Its numbers are checked before any maths, each refusal
    naming the field of ``where``: a focal length within FOCAL_SHARE of the image (as a
    calib.yaml's), the optical centre in the image, a unit quaternion, a camera above the
    floor."""
    conf = {**confs["default"], **(conf or {})}
    if not isinstance(d, dict):
        raise HulksImportError(f"{where}: 'camera_matrix' must be a mapping")
    missing = [k for k in ("focal_length", "optical_center", "camera_to_ground") if k not in d]
    if missing:
        raise HulksImportError(f"{where}: camera matrix misses '{missing[0]}'")
    w, h = (int(v) for v in conf["image_size"])
    fx, fy = _numbers(d, "focal_length", 2, where)
    cx, cy = _numbers(d, "optical_center", 2, where)
    low, high = FOCAL_SHARE
    if not (low * w <= fx <= high * w and low * h <= fy <= high * h):
        raise HulksImportError(f"{where}: focal_length ({fx:g}, {fy:g}) must lie between"
                               f" {low:g} and {high:g} times the {w} x {h} px image's width"
                               " and height")
    if not (0 <= cx <= w and 0 <= cy <= h):
        raise HulksImportError(f"{where}: optical_center ({cx:g}, {cy:g}) must lie in the"
                               f" {w} x {h} px image")
    rot, t = _transform(d, "camera_to_ground", where, float(conf["unit_tolerance"]))
    yaw, pitch, roll = zyx_angles(rot)
    if t[2] <= 0:
        raise HulksImportError(f"{where}: camera_to_ground puts the camera {t[2]:.3f} m above "
                               "the floor (must be > 0)")
    shift = float(conf["pixel_origin_shift"])
    cam = PerspectiveCamera(image_size=(w, h), fx=fx, fy=fy, cx=cx + shift, cy=cy + shift,
                            distortion=np.zeros(5), height=float(t[2]), pitch=pitch, roll=roll,
                            yaw=yaw, position=(float(t[0]), float(t[1])))
    bottom = np.array([[0.0, h - 1.0], [(w - 1) / 2, h - 1.0], [w - 1.0, h - 1.0]])
    if np.all(np.isnan(cam.pixel_to_floor(bottom))):
        raise HulksImportError(f"{where}: the camera looks at or above the horizon "
                               f"(pitch {math.degrees(pitch):.1f} deg); no floor in view")
    return cam


def read_frame(path, conf: dict | None = None) -> HulksFrame:
    """One HULKs capture JSON -> HulksFrame."""
    path = Path(path)
    if not path.is_file():
        raise HulksImportError(f"HULKs camera file not found: {path}")
    try:
        d = load_json(read_record(path))
    except (OSError, ValueError, RecursionError) as e:  # ValueError: bad JSON, a key twice
        raise HulksImportError(f"{path}: not a readable JSON file ({e})") from None
    if not isinstance(d, dict) or "camera_matrix" not in d:
        raise HulksImportError(f"{path}: no 'camera_matrix' (not a HULKs capture file)")
    cam = camera_from_hulks(d["camera_matrix"], conf, str(path))
    try:
        stamp = float(path.stem)
    except ValueError:
        stamp = math.nan
    return HulksFrame(cam, str(d.get("position", "")), stamp, path)


def _frames_of_folder(folder: Path, conf: dict) -> list[tuple[HulksFrame, Path]]:
    out = []
    for js in sorted(folder.glob("*.json")):
        image = next((js.with_suffix(s) for s in IMAGE_SUFFIXES
                      if js.with_suffix(s).is_file()), None)
        if image is None:
            log.warning("%s: no image beside it, skipped", js)
            continue
        fr = read_frame(js, conf)
        if not math.isfinite(fr.stamp):
            raise HulksImportError(f"{js}: the file name must be the capture's stamp "
                                   "(a number of seconds), as HULKs writes it")
        out.append((fr, image))
    if not out:
        raise HulksImportError(f"{folder}: no HULKs capture (<stamp>.json with its image)")
    first = out[0][0].camera
    for fr, _ in out[1:]:
        c = fr.camera
        if (c.fx, c.fy, c.cx, c.cy) != (first.fx, first.fy, first.cx, first.cy):
            raise HulksImportError(
                f"{fr.path}: intrinsics ({c.fx:g}, {c.fy:g}, {c.cx:g}, {c.cy:g}) differ from "
                f"{out[0][0].path.name}'s ({first.fx:g}, {first.fy:g}, {first.cx:g}, "
                f"{first.cy:g}); import the cameras into separate datasets")
    return out


def main(conf: str | dict | None, source, output, *, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Import ``source`` (a HULKs capture JSON, or a folder of them with their images) and
    write ``output`` (calib.yaml, or a dataset folder for a folder). ``conf``: a preset name,
    None or a dict of overrides on ``default``. Returns ``output``."""
    conf = stage_conf(confs, conf)
    check_bounds(conf, BOUNDS)
    source, output = Path(source), Path(output)
    if source.is_file():
        check_output(output, {"the HULKs capture": source}, overwrite=overwrite,
                     kind="calibration", error=HulksImportError)
        fr = read_frame(source, conf)
        save_calib(fr.camera, output)
        log.info("imported %s (%s camera): height %.3f m, pitch %.1f deg, roll %.1f deg, "
                 "yaw %.1f deg", source, fr.position or "?", fr.camera.height,
                 math.degrees(fr.camera.pitch), math.degrees(fr.camera.roll),
                 math.degrees(fr.camera.yaw))
        return output
    if not source.is_dir():
        raise HulksImportError(f"HULKs camera file or folder not found: {source}")
    check_importer_target(output, {"the HULKs captures": [p for p in source.iterdir()
                                                          if p.is_file()],
                                   "the HULKs capture folder": source},
                          overwrite, record=IMPORT_RECORD, generator=GENERATOR,
                          error=HulksImportError)
    frames = _frames_of_folder(source, conf)
    cams = [fr.camera for fr, _ in frames]
    nominal = cams[0].with_pose(
        pitch=float(np.median([c.pitch for c in cams])),
        roll=float(np.median([c.roll for c in cams])), yaw=0.0,
        height=float(np.median([c.height for c in cams])), position=(0.0, 0.0))
    with atomic_dir(output, overwrite=overwrite) as tmp:
        (tmp / "images").mkdir()
        for _, image in frames:
            # the bytes only: a capture's mode (read-only where it came from) is not the
            # dataset's, whose files --overwrite must be able to replace
            shutil.copyfile(image, tmp / "images" / image.name)
        save_calib(nominal, tmp / "calib.yaml")
        write_csv(tmp / "head.csv", "head", {
            "stamp": [fr.stamp for fr, _ in frames],
            "pitch": [c.pitch for c in cams], "roll": [c.roll for c in cams],
            "yaw": [c.yaw for c in cams], "height": [c.height for c in cams],
            "x": [c.position[0] for c in cams], "y": [c.position[1] for c in cams]})
        (tmp / IMPORT_RECORD).write_bytes(record_text(
            {"generator": GENERATOR, "source": str(real_path(source)), "frames": len(frames),
             WRITTEN_FILES: written_files(tmp, tree_files(tmp))},  # --overwrite's test
            IMPORT_RECORD).encode())
    log.info("imported %d HULKs frames from %s into %s", len(frames), source, output)
    return output
