"""Local image features behind one interface: our SURF (stages.common.surf), OpenCV's SIFT
and ORB, so that users can compare them (``--features surf|sift|orb``).

    keypoints, descriptors = detect_and_describe(image_gray, mask, "surf")

``keypoints`` is an (N, 6) float64 array, strongest first, with the columns ``KEYPOINT_COLUMNS``:
- x, y: position in pixels (x = column, y = row; pixel centres at integers);
- scale: the characteristic scale, the sigma of the Gaussian the detector matched (SURF: 1.2 L
  / 9 for the box filter size L; SIFT: OpenCV's size / 2). ORB has none; its patch radius
  (OpenCV's size / 2) is taken as 3 sigma, so that 3 x scale is the measured region for all;
- orientation: rad in pixel axes, from +x towards +y (row down), as all three compute it;
  0 for upright SURF;
- response: the detector's strength (SURF det(H), SIFT |DoG| contrast, ORB Harris score);
- laplacian: the sign of the Laplacian (+1 dark blob, -1 bright blob) for SURF, 0 where the
  detector does not give it (SIFT and ORB): matching only pairs equal signs, 0 matches all.

``descriptors`` is (N, D): SURF 64 float32 (unit length), SIFT 128 float32, ORB 32 uint8 bytes
(compared by Hamming distance, ``DESCRIPTOR_METRIC``).

``mask`` (bool, True where the image may be used, or None): every detector sees the invalid
pixels filled with the mean of the valid ones (no artificial edge), and a keypoint is kept only
if what its detector measured lies on valid pixels: SURF checks each box filter (see surf.py);
SIFT keeps keypoints at least 3 sigma (the support of the difference of Gaussians), ORB at
least its FAST circle (radius 3 px at the keypoint's pyramid level) from any invalid pixel.
"""

from __future__ import annotations

import math

import numpy as np

from . import surf
from .conf import check_bounds, resolve_conf
from .errors import FieldlocError

KEYPOINT_COLUMNS = ("x", "y", "scale", "orientation", "response", "laplacian")
FEATURES = ("surf", "sift", "orb")
DESCRIPTOR_METRIC = {"surf": "l2", "sift": "l2", "orb": "hamming"}
DESCRIPTOR_SIZE = {"surf": surf.DESCRIPTOR_SIZE, "sift": 128, "orb": 32}
DEFAULT_PRESET = "surf"
ORB_PATCH_SIGMAS = 3.0  # an ORB patch radius counts as this many sigma-equivalents
SIFT_SUPPORT_SIGMAS = 3.0  # SIFT keypoints this many sigma from invalid pixels
ORB_FAST_RADIUS = 3.0  # px at the keypoint's pyramid level

confs = {
    "surf": {"features": "surf", **surf.confs["default"]},
    "surf-upright": {"features": "surf", **surf.confs["upright"]},
    # SURF with the Gaussian derivatives its box filters stand for (surf.py, ``hessian``)
    "surf-gaussian": {"features": "surf", **surf.confs["gaussian"]},
    # the same at SIFT's layout of scales, 3 per octave, refined as SIFT's (surf.py,
    # ``geometric_layers``, ``refine_moves``)
    "surf-geometric": {"features": "surf", **surf.confs["geometric"]},
    # OpenCV's defaults (cv2.SIFT_create)
    "sift": {"features": "sift", "max_keypoints": 0, "octave_layers": 3,
             "contrast_threshold": 0.04, "edge_threshold": 10.0, "sigma": 1.6},
    # OpenCV's defaults (cv2.ORB_create), 1000 keypoints
    "orb": {"features": "orb", "max_keypoints": 1000, "scale_factor": 1.2, "levels": 8,
            "edge_threshold": 31, "patch_size": 31, "fast_threshold": 20},
}

# the ranges of OpenCV's detectors' keys (common.conf.check_bounds, in resolve_feature_conf; our
# SURF checks its own, surf.check_conf): OpenCV takes C ints and crashes, hangs or answers with
# a page of its source for values outside (SIFT with 0 layers per octave ran for hours, ORB's
# pyramid with a scale factor of 1e12 asserted in resize)
MAX_KEYPOINTS = 1_000_000
BOUNDS = {
    "sift": {"max_keypoints": (0, MAX_KEYPOINTS), "octave_layers": (1, 10),
             "contrast_threshold": (0, 1), "edge_threshold": ((0,), None),
             # px, the blur of octave 0: an image is blurred by half a pixel already; 10 px
             # blurs the ground image's line crossings away
             "sigma": (0.5, 10.0)},
    # a pyramid that shrinks (scale factor > 1) by at most half per level; widths in px and
    # FAST's threshold in grey levels of a uint8 image
    "orb": {"max_keypoints": (1, MAX_KEYPOINTS), "scale_factor": ((1,), 2.0), "levels": (1, 16),
            "edge_threshold": (0, 255), "patch_size": (2, 255), "fast_threshold": (0, 255)},
}


def resolve_feature_conf(conf: str | dict | None = None, overrides: dict | None = None) -> dict:
    """The conf of a preset name (default ``DEFAULT_PRESET``) or a conf dict (complete, or a few
    keys replacing those of its kind's preset: ``{"features": "sift", "max_keypoints": 500}``),
    then ``overrides``. Unknown presets, kinds and keys are user errors."""
    if isinstance(conf, dict):
        kind = conf.get("features", DEFAULT_PRESET)
        if kind not in FEATURES:
            raise FieldlocError(f"unknown features '{kind}' (known: {', '.join(FEATURES)})")
        base = resolve_conf(confs, kind, {k: v for k, v in conf.items() if k != "features"})
        resolved = resolve_conf(confs, base, overrides)
    else:
        resolved = resolve_conf(confs, conf or DEFAULT_PRESET, overrides)
    check_bounds(resolved, BOUNDS.get(resolved["features"], {}))
    return resolved


def descriptor_metric(conf: str | dict | None) -> str:
    """'l2' or 'hamming': how the descriptors of ``conf`` are compared."""
    return DESCRIPTOR_METRIC[resolve_feature_conf(conf)["features"]]


def detect_and_describe(image_gray: np.ndarray, mask: np.ndarray | None = None,
                        conf: str | dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints (N, 6) and descriptors (N, D) of a grey image; see the module docstring."""
    c = resolve_feature_conf(conf)
    img = np.asarray(image_gray)
    if img.ndim != 2:
        raise FieldlocError(f"features need a 2D grey image, got shape {img.shape}")
    kind = c["features"]
    if kind == "surf":
        return surf.detect_and_describe(img, mask, {k: v for k, v in c.items()
                                                    if k != "features"})
    if img.dtype != np.uint8:
        raise FieldlocError(f"OpenCV's {kind.upper()} needs a uint8 image, got {img.dtype}")
    m = None if mask is None else surf.check_mask(mask, img.shape)
    if m is not None and not m.all():
        img = surf.fill_invalid(img, m)
    else:
        m = None
    detector = _opencv_detector(c)
    kps, desc = detector.detectAndCompute(img, None if m is None else m.view(np.uint8))
    d = DESCRIPTOR_SIZE[kind]
    if not kps:
        dtype = np.uint8 if kind == "orb" else np.float32
        return np.zeros((0, len(KEYPOINT_COLUMNS))), np.zeros((0, d), dtype)
    kp = np.array([(k.pt[0], k.pt[1], k.size, math.radians(k.angle), k.response, k.octave)
                   for k in kps], dtype=np.float64)
    if kind == "sift":
        sigma = kp[:, 2] / 2.0
        support = SIFT_SUPPORT_SIGMAS * sigma
    else:
        level = kp[:, 5].astype(np.int64) & 0xFF  # ORB stores the pyramid level in octave
        sigma = kp[:, 2] / (2.0 * ORB_PATCH_SIGMAS)
        support = ORB_FAST_RADIUS * float(c["scale_factor"]) ** level
    kp[:, 2] = sigma
    kp[:, 3] = np.angle(np.exp(1j * kp[:, 3]))  # (-pi, pi]
    kp[:, 5] = 0.0
    if m is not None:
        keep = _clearance(m, kp[:, 0], kp[:, 1]) >= support
        kp, desc = kp[keep], desc[keep]
    order = np.argsort(-kp[:, 4], kind="stable")
    return np.ascontiguousarray(kp[order]), np.ascontiguousarray(desc[order])


def _opencv_detector(c: dict):
    import cv2

    try:
        if c["features"] == "sift":
            return cv2.SIFT_create(nfeatures=int(c["max_keypoints"]),
                                   nOctaveLayers=int(c["octave_layers"]),
                                   contrastThreshold=float(c["contrast_threshold"]),
                                   edgeThreshold=float(c["edge_threshold"]),
                                   sigma=float(c["sigma"]))
        return cv2.ORB_create(nfeatures=int(c["max_keypoints"]),
                              scaleFactor=float(c["scale_factor"]), nlevels=int(c["levels"]),
                              edgeThreshold=int(c["edge_threshold"]),
                              patchSize=int(c["patch_size"]),
                              fastThreshold=int(c["fast_threshold"]))
    except (TypeError, ValueError, cv2.error) as e:
        raise FieldlocError(f"{c['features']} conf is invalid ({str(e).strip()})") from None


def _clearance(mask: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Distance (px) from (x, y) to the nearest invalid pixel of ``mask``."""
    import cv2

    dist = cv2.distanceTransform(mask.view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    h, w = mask.shape
    xi = np.clip(np.rint(x).astype(np.int64), 0, w - 1)
    yi = np.clip(np.rint(y).astype(np.int64), 0, h - 1)
    return dist[yi, xi]
