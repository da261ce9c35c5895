"""The robot-centred ground image of an omnidirectional frame (the SURF template paper, fig. 1b).

A ``GroundGrid`` is a square top view of the floor around the robot: ``size`` x ``size`` pixels
of ``metres_per_pixel``, covering +-``extent`` metres from the robot centre (any two of the three
fix the third). The robot stands at the image centre ((size - 1) / 2 in both axes, between
pixels when size is even), its forward direction (+x) points up the image (decreasing row) and
its left (+y) to the left (decreasing column): the floor seen from above, not mirrored.

Every ground pixel is a floor point in the robot frame; the calibration
(stages.common.camera.OmniCamera, the SURF template paper, eq. 2) places it in the omni image at the
radius where the fitted f(r) reaches its distance (f inverted by ``OmniCamera.radius_of_distance``)
and at its bearing. ``unwarp_map`` computes that pixel map once per calibration, grid and
dataset mask (cached); ``unwarp`` resamples a frame through it (bilinear) and returns the
ground image with its mask of valid pixels: floor the camera sees (between the robot body and
the outer limit of the calibration's valid radii) and not excluded by the dataset's mask.

Keypoints found in a ground image come back to the robot frame by ``GroundGrid.pixel_to_robot``
(positions) and ``GroundGrid.angle_to_robot`` (orientations measured in pixel axes).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import camera_can
from .errors import DatasetError, FieldlocError

confs = {
    # 512 x 512 px of 1 cm: +-2.56 m around the robot, about as fine as the default mirror's
    # image at 1 m (1.5 cm/px along the ray, 0.9 cm/px across it)
    "default": {"size": 512, "metres_per_pixel": 0.01},
}


@dataclass(frozen=True)
class GroundGrid:
    """A robot-centred square top view of the floor (see the module docstring)."""

    size: int  # px, width = height
    metres_per_pixel: float

    @property
    def extent(self) -> float:
        """Metres from the robot centre to the image border (the image covers +-extent)."""
        return 0.5 * self.size * self.metres_per_pixel

    @property
    def centre(self) -> float:
        """Column (= row) of the robot centre in pixel coordinates (pixel centres at integers)."""
        return 0.5 * (self.size - 1)

    def pixel_to_robot(self, col, row) -> np.ndarray:
        """Ground pixels (col, row) -> floor points (..., 2) in the robot frame (metres)."""
        c = self.centre
        m = self.metres_per_pixel
        col = np.asarray(col, dtype=float)
        row = np.asarray(row, dtype=float)
        return np.stack([(c - row) * m, (c - col) * m], axis=-1)

    def robot_to_pixel(self, points) -> np.ndarray:
        """Floor points (..., 2) in the robot frame (m) -> ground pixels (..., 2) (col, row)."""
        p = np.asarray(points, dtype=float)
        c = self.centre
        m = self.metres_per_pixel
        return np.stack([c - p[..., 1] / m, c - p[..., 0] / m], axis=-1)

    def angle_to_robot(self, angle) -> np.ndarray:
        """An orientation in pixel axes (rad, from +col towards +row, as keypoints carry it) ->
        the same direction in the robot frame (rad, counter-clockwise from +x)."""
        a = np.asarray(angle, dtype=float)
        # (dcol, drow) = (cos a, sin a) is (dx, dy) = (-sin a, -cos a) in the robot frame
        return np.arctan2(-np.cos(a), -np.sin(a))

    def to_dict(self) -> dict:
        return {"size": int(self.size), "metres_per_pixel": float(self.metres_per_pixel)}


def ground_grid(size: int | None = None, metres_per_pixel: float | None = None,
                extent: float | None = None) -> GroundGrid:
    """The grid from any two of ``size`` (px), ``metres_per_pixel`` and ``extent`` (m from the
    robot centre to the border); all three must agree when all are given."""
    given = [v is not None for v in (size, metres_per_pixel, extent)]
    if sum(given) < 2:
        raise FieldlocError("a ground grid needs two of size, metres_per_pixel and extent")
    try:
        if size is None:
            size = int(round(2.0 * float(extent) / float(metres_per_pixel)))
        size = int(size)
        if metres_per_pixel is None:
            metres_per_pixel = 2.0 * float(extent) / size
        metres_per_pixel = float(metres_per_pixel)
    except (TypeError, ValueError, ZeroDivisionError) as e:
        raise FieldlocError(f"ground grid: malformed value ({e})") from None
    if size < 8 or not metres_per_pixel > 0 or not math.isfinite(metres_per_pixel):
        raise FieldlocError(f"ground grid: needs size >= 8 px and metres_per_pixel > 0, got"
                            f" size {size}, metres_per_pixel {metres_per_pixel}")
    grid = GroundGrid(size, metres_per_pixel)
    if extent is not None and not math.isclose(grid.extent, float(extent), rel_tol=1e-6):
        raise FieldlocError(f"ground grid: size {size} px of {metres_per_pixel} m cover"
                            f" +-{grid.extent:g} m, not +-{float(extent):g} m")
    return grid


def grid_of_conf(conf: dict) -> GroundGrid:
    """The grid of a conf with two or three of the keys size, metres_per_pixel, extent."""
    unknown = set(conf) - {"size", "metres_per_pixel", "extent"}
    if unknown:
        raise FieldlocError(f"unknown ground grid key(s): {', '.join(sorted(unknown))}")
    return ground_grid(conf.get("size"), conf.get("metres_per_pixel"), conf.get("extent"))


@dataclass(frozen=True)
class UnwarpMap:
    """Where every ground pixel lies in the omni image, for cv2.remap."""

    grid: GroundGrid
    map_u: np.ndarray  # (size, size) float32, image column of each ground pixel
    map_v: np.ndarray  # (size, size) float32, image row
    valid: np.ndarray  # (size, size) bool: seen floor, inside the image, not masked


def build_unwarp_map(camera, grid: GroundGrid, mask: np.ndarray | None = None) -> UnwarpMap:
    """The pixel map of ``grid`` through ``camera`` (an OmniCamera). ``mask``: the dataset's
    bool (h, w) mask of usable image pixels (stages.common.dataset.read_mask), or None."""
    if not camera_can(getattr(camera, "kind", None), "ground_image"):
        raise FieldlocError("a ground image needs an omnidirectional camera (calib kind omni)")
    idx = np.arange(grid.size, dtype=float)
    col, row = np.meshgrid(idx, idx)
    pts = grid.pixel_to_robot(col, row)
    uv = camera.robot_to_pixel(pts)  # NaN where f(r) does not reach (body, beyond the range)
    u, v = uv[..., 0], uv[..., 1]
    w, h = camera.image_size
    valid = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (h, w):
            raise FieldlocError(f"mask is {mask.shape[1]} x {mask.shape[0]} px, the camera's"
                                f" images are {w} x {h}")
        ui = np.clip(np.nan_to_num(np.rint(u)), 0, w - 1).astype(np.intp)
        vi = np.clip(np.nan_to_num(np.rint(v)), 0, h - 1).astype(np.intp)
        valid &= mask[vi, ui]
    map_u = np.where(valid, u, -1.0).astype(np.float32)
    map_v = np.where(valid, v, -1.0).astype(np.float32)
    for a in (map_u, map_v, valid):
        a.setflags(write=False)
    return UnwarpMap(grid, map_u, map_v, valid)


_CACHE: dict[str, UnwarpMap] = {}


def unwarp_map(camera, grid: GroundGrid, mask: np.ndarray | None = None) -> UnwarpMap:
    """``build_unwarp_map`` cached per calibration, grid and mask."""
    h = hashlib.sha256(json.dumps([camera.to_dict(), grid.to_dict()], sort_keys=True).encode())
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        h.update(str(m.shape).encode() + np.packbits(m).tobytes())
    key = h.hexdigest()
    if key not in _CACHE:
        if len(_CACHE) >= 8:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = build_unwarp_map(camera, grid, mask)
    return _CACHE[key]


def unwarp(image: np.ndarray, camera, grid: GroundGrid,
           mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The ground image of an omni frame (grey or colour, as given) and its bool mask of valid
    pixels. Invalid pixels are 0."""
    image = np.asarray(image)
    w, h = camera.image_size
    if image.shape[:2] != (h, w):
        raise DatasetError(f"image is {image.shape[1]} x {image.shape[0]} px, the"
                           f" calibration's is {w} x {h}")  # a frame's fault: callers skip it
    m = unwarp_map(camera, grid, mask)
    ground = cv2.remap(image, m.map_u, m.map_v, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    ground = cv2.bitwise_and(ground, ground, mask=m.valid.view(np.uint8))  # invalid: 0
    return ground, m.valid
