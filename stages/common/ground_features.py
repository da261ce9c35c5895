"""Local features of the floor around the robot (the SURF template paper, steps 3-5 of its method):
an omni frame unwarped to the robot-centred ground image (stages.common.unwarp), local features
detected there (stages.common.local_features: our SURF, OpenCV's SIFT or ORB) on the field
only, and returned in the robot frame (metres, radians). build_templates makes its templates
with this and localize's template method its queries, with the same conf (the templates file
stores it), so that both see the floor alike.

    feats = ground_features(image_bgr, camera, conf, mask)

The field (the SURF template paper: "we assume that the green region is the ground"). The colour
classes of the frame (stages.common.colour, its field green estimated per frame) are computed in the
omni image and carried to the ground image (nearest pixel); the field is

    valid  &  (green | white | (close(green | white, field.close_m) & not dark))

``close`` is a morphological closing with a disc of ``close_m`` metres: it joins green and the
white lines across the blurred line edges (mixed pixels that are neither class, and never
darker than the green) and fills small holes (a sheet of paper, a cable), but not with dark
pixels, darker than ``dark_ratio`` times the local field green's luminance: the robot's mirror
struts, other robots, people's legs stay out however thin they are. A keypoint is kept
only when everything its detector measured lies on the field (local_features' mask rule), so
features of the robot's own body, which would match in every frame, never enter.

Keypoints come back to the robot frame through the ground grid: position (m), orientation
(rad, counter-clockwise from the robot's +x; 0 for upright SURF means "along the image's
columns": the same in every frame, so rotation between frames is left to the matching pose),
scale (m: the detector's sigma), the sign of the Laplacian (SURF; 0 for SIFT and ORB) and the
response.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import cv2
import numpy as np

from . import colour, local_features, unwarp
from .conf import check_bounds
from .errors import FieldlocError

confs = {
    "default": {
        # the ground image: +-4 m at 1.5 cm/px, about the reach of a MSL mirror (the rendered
        # team mirror sees 3.96 m) at the resolution it has at 1-2 m
        "ground": {"size": 534, "metres_per_pixel": 0.015},
        "features": copy.deepcopy(local_features.confs["surf"]),
        "field": {
            "close_m": 0.2,  # m, closing disc: joins line and green across blurred edges
            "dark_ratio": 0.7,  # closing adds no pixel darker than this times the local green
            "colour": copy.deepcopy(colour.confs["default"]),
        },
    },
}

# the ranges the keys above must lie in (common.conf.check_bounds, in check_conf: build-templates
# checks them when its conf is resolved, localize checks a database's): a ground image of 1e12
# px runs out of memory; the closing disc is close_m / metres_per_pixel px across, and its cost
# grows with its area (MAX_CLOSE_PX: a disc of 64 px takes 0.05 s on the 534 px image)
MAX_GROUND_PX = 4096  # px, ground image side (534 px: +-4 m at 1.5 cm)
MAX_CLOSE_PX = 64  # px, closing disc
# m per ground pixel: no omni camera resolves the floor finer than 1 mm; 1 m pixels hold nothing
GROUND_PIXEL_M = (0.001, 1.0)
BOUNDS = {"ground.size": (8, MAX_GROUND_PX), "ground.metres_per_pixel": GROUND_PIXEL_M,
          "field.close_m": (0, 1.0), "field.dark_ratio": (0, 1),
          **{f"field.colour.{k}": b for k, b in colour.BOUNDS.items()}}


@dataclass
class GroundFeatures:
    """The local features of one frame in the robot frame (N rows, strongest first)."""

    points: np.ndarray  # (N, 2) m, robot frame
    orientation: np.ndarray  # (N,) rad, robot frame
    scale: np.ndarray  # (N,) m
    laplacian: np.ndarray  # (N,) int8, +1 dark blob, -1 bright blob, 0 unknown
    response: np.ndarray  # (N,)
    descriptors: np.ndarray  # (N, D) float32 (surf, sift) or uint8 (orb)

    def __len__(self) -> int:
        return len(self.points)

    @classmethod
    def empty(cls, size: int, dtype) -> GroundFeatures:
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0, np.int8),
                   np.zeros(0), np.zeros((0, size), dtype))


def check_conf(conf: dict) -> dict:
    """The conf with its ground grid and feature conf checked (user errors otherwise)."""
    unknown = set(conf) - set(confs["default"])
    if unknown:
        raise FieldlocError(f"unknown ground feature key(s): {', '.join(sorted(unknown))}")
    missing = set(confs["default"]) - set(conf)
    if missing:
        raise FieldlocError(f"ground feature conf misses {', '.join(sorted(missing))}")
    kind = conf["features"].get("features") if isinstance(conf["features"], dict) else None
    bounds = {**BOUNDS, **{f"features.{k}": b  # named as the user gives them (features.KEY)
                           for k, b in local_features.BOUNDS.get(kind, {}).items()}}
    # a database's stored ground conf may hold the ground grid as another two of size,
    # metres_per_pixel and extent
    check_bounds(conf, bounds, optional=True)
    grid = unwarp.grid_of_conf(conf["ground"])
    local_features.resolve_feature_conf(conf["features"])
    f = conf["field"]
    try:
        if not (float(f["close_m"]) >= 0 and 0 <= float(f["dark_ratio"]) <= 1):
            raise ValueError
    except (KeyError, TypeError, ValueError):
        raise FieldlocError("ground feature conf: field needs close_m >= 0 (m) and dark_ratio"
                            " in [0, 1]") from None
    if float(f["close_m"]) / grid.metres_per_pixel > MAX_CLOSE_PX:
        raise FieldlocError(f"conf 'field.close_m' must be <= {MAX_CLOSE_PX} px of the ground"
                            f" image ({MAX_CLOSE_PX * grid.metres_per_pixel:g} m), got"
                            f" {float(f['close_m']):g}")
    return conf


def feature_kind(conf: dict) -> str:
    """surf, sift or orb."""
    return local_features.resolve_feature_conf(conf["features"])["features"]


def descriptor_shape(conf: dict) -> tuple[int, type]:
    """(descriptor length, dtype) of the conf's features."""
    kind = feature_kind(conf)
    return local_features.DESCRIPTOR_SIZE[kind], (np.uint8 if kind == "orb" else np.float32)


def field_mask(image_bgr: np.ndarray, camera, conf: dict, mask: np.ndarray | None = None,
               ) -> tuple[np.ndarray, np.ndarray]:
    """(ground image BGR, bool field mask) of an omni frame (module doc)."""
    grid = unwarp.grid_of_conf(conf["ground"])
    fconf = conf["field"]
    cconf = fconf["colour"]
    ground, valid = unwarp.unwarp(image_bgr, camera, grid, mask)
    m = unwarp.unwarp_map(camera, grid, mask)
    yuv = colour.to_yuv(image_bgr)
    fc = colour.estimate_field_colour(yuv, cconf, mask)
    green, white = colour.classify_masks(yuv, fc, cconf, mask)
    bright = yuv[..., 0] >= np.float32(fconf["dark_ratio"]) * fc.local_y_image(yuv.shape)
    classes = (green | white).view(np.uint8) | (bright.view(np.uint8) << 1)
    g = cv2.remap(classes, m.map_u, m.map_v, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                  borderValue=0)
    field = (g & 1).astype(np.uint8)
    r = float(fconf["close_m"]) / grid.metres_per_pixel
    if r >= 1:
        k = 2 * int(round(r / 2)) + 1
        closed = cv2.morphologyEx(field, cv2.MORPH_CLOSE,
                                  cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
        field |= closed & (g >> 1)
    return ground, valid & field.astype(bool)


def ground_features(image_bgr: np.ndarray, camera, conf: dict,
                    mask: np.ndarray | None = None, heading: float | None = None
                    ) -> GroundFeatures:
    """The local features of an omni frame's floor, on the field only (module doc).
    ``camera``: the dataset's OmniCamera; ``mask``: its mask.png as a bool image or None.
    ``heading`` (rad): detect and describe in the ground image turned to the field's axes (the
    robot's heading on the field, known or assumed), so that upright descriptors of two frames
    compare; the features are returned in the robot frame all the same."""
    grid = unwarp.grid_of_conf(conf["ground"])
    ground, field = field_mask(image_bgr, camera, conf, mask)
    grey = cv2.cvtColor(ground, cv2.COLOR_BGR2GRAY)  # turned as one channel, not three
    turn = None
    if heading is not None and float(heading) != 0.0:
        # robot-frame points turned counter-clockwise by ``heading`` are the image turned by
        # +heading as cv2 counts (the image's row axis points down, the robot's y left)
        c = grid.centre
        turn = cv2.getRotationMatrix2D((c, c), math.degrees(float(heading)), 1.0)
        grey = cv2.warpAffine(grey, turn, (grid.size, grid.size), flags=cv2.INTER_LINEAR)
        field = cv2.warpAffine(field.view(np.uint8), turn, (grid.size, grid.size),
                               flags=cv2.INTER_NEAREST).astype(bool)
    kp, desc = local_features.detect_and_describe(grey, field, conf["features"])
    if not len(kp):
        return GroundFeatures.empty(*descriptor_shape(conf))
    pts = grid.pixel_to_robot(kp[:, 0], kp[:, 1])
    ori = np.asarray(grid.angle_to_robot(kp[:, 3]), float)
    if turn is not None:  # back to the robot's axes
        h = float(heading)
        c, s = math.cos(-h), math.sin(-h)
        pts = np.stack([c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1]], axis=1)
        ori = np.asarray(np.angle(np.exp(1j * (ori - h))), float)
    return GroundFeatures(
        points=pts, orientation=ori, scale=kp[:, 2] * grid.metres_per_pixel,
        laplacian=kp[:, 5].astype(np.int8), response=kp[:, 4].copy(), descriptors=desc)


def reach(conf: dict) -> float:
    """Metres from the robot to the ground image's border (features lie within it)."""
    return unwarp.grid_of_conf(conf["ground"]).extent * math.sqrt(2.0)
