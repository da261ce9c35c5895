"""Bilinear texture sampling on a fixed 1/32-pixel grid, the same under every OpenCV version.

``cv2.remap`` with floating-point maps is not one function across OpenCV's major versions:
4.x rounds each map coordinate to 1/32 pixel and interpolates with tabulated weights, 5.x
interpolates at the exact coordinate. Rendered images would then depend on the installed
OpenCV. ``fixed_maps`` does the rounding here, with plain arithmetic (x * 32 rounded half to
even, split into the integer texel and the 1/32 fraction), and hands ``cv2.remap`` OpenCV's
fixed-point map pair (CV_16SC2 texels, CV_16UC1 fraction indices), which both versions
sample the same way: for 8-bit textures with integer weights (exact), for float textures
with the tabulated float weights.

The pair equals ``cv2.convertMaps(mx, my, cv2.CV_16SC2)``; coordinates beyond the int16
texel range saturate as OpenCV's do, and so fall into the border.
"""

from __future__ import annotations

import cv2
import numpy as np

TAB_BITS = 5  # OpenCV's INTER_BITS: 32 sub-pixel positions per texel
TAB_SIZE = 1 << TAB_BITS


def fixed_maps(mx: np.ndarray, my: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's fixed-point remap maps of float map coordinates ``mx``, ``my`` (same shape):
    (texel x, y as (..., 2) int16, fraction index fy * 32 + fx as uint16)."""
    big = np.float32(2 ** 30)  # far outside the int16 texel range, inside int32
    qx, qy = (np.rint(np.clip(np.asarray(m, np.float32) * np.float32(TAB_SIZE), -big, big))
              .astype(np.int32) for m in (mx, my))
    xy = np.empty(qx.shape + (2,), np.int16)
    xy[..., 0] = np.clip(qx >> TAB_BITS, -32768, 32767)
    xy[..., 1] = np.clip(qy >> TAB_BITS, -32768, 32767)
    frac = ((qy & (TAB_SIZE - 1)) * TAB_SIZE + (qx & (TAB_SIZE - 1))).astype(np.uint16)
    return xy, frac


def remap_linear(src: np.ndarray, mx: np.ndarray, my: np.ndarray, border: int,
                 value=0) -> np.ndarray:
    """``src`` sampled bilinearly at (``mx``, ``my``) on the 1/32-texel grid (``fixed_maps``),
    ``border`` an OpenCV border mode (``value`` its constant)."""
    xy, frac = fixed_maps(mx, my)
    return cv2.remap(src, xy, frac, cv2.INTER_LINEAR, borderMode=border, borderValue=value)
