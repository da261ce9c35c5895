"""Readable oracles of the perspective chain's sampling and sums (numpy, float64).

The compiled kernels (line_structure_kernels.bilinear_at and its callers, colour.sum32/64,
_mean32, _var32) are checked against these within stated tolerances; these say what is
computed, not in which order a library rounds.
"""

from __future__ import annotations

import math

import numpy as np


def bilinear(image: np.ndarray, x, y, border: float) -> np.ndarray:
    """A 2-D image at points (x = column, y = row), bilinear between the four pixels around
    each point, pixels outside the image ``border`` (cv2.remap's INTER_LINEAR with
    BORDER_CONSTANT, without its offset quantisation)."""
    img = np.asarray(image, np.float64)
    h, w = img.shape
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    x0, y0 = np.floor(x), np.floor(y)
    with np.errstate(invalid="ignore"):  # inf - inf: the point is NaN
        ax, ay = x - x0, y - y0

    def pixel(r, c):
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        rr = np.where(inside, r, 0).astype(np.int64)
        cc = np.where(inside, c, 0).astype(np.int64)
        return np.where(inside, img[rr, cc], border)

    with np.errstate(invalid="ignore"):
        ok = np.isfinite(x0) & np.isfinite(y0)
        r0 = np.where(ok, y0, -2)
        c0 = np.where(ok, x0, -2)
        top = pixel(r0, c0) * (1 - ax) + pixel(r0, c0 + 1) * ax
        bottom = pixel(r0 + 1, c0) * (1 - ax) + pixel(r0 + 1, c0 + 1) * ax
        out = top * (1 - ay) + bottom * ay
    return np.where(ok, out, np.nan)


def exact_sum(a) -> float:
    """The sum of an array, correctly rounded (math.fsum)."""
    return math.fsum(np.asarray(a, np.float64).ravel().tolist())


def sum_tolerance(a, dtype) -> float:
    """A bound of a sum's error when accumulated in float64 and rounded to ``dtype``: one
    rounding to dtype (eps of dtype of the result's size) plus n float64 roundings of at most
    eps64 of the running sum's magnitude each."""
    mag = float(np.sum(np.abs(np.asarray(a, np.float64))))
    n = max(np.size(a), 1)
    return float(np.finfo(dtype).eps) * abs(exact_sum(a)) + n * 2.0 ** -52 * mag
