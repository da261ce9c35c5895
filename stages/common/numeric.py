"""Numeric kernels the extractors share (compiled, cached on disk): sums of float arrays
accumulated in float64 (``sum32``, ``sum64``; ``mean32``, ``var32`` from them), the median of
non-negative float32 values by radix selection (``median32``), ``np.median`` compiled
(``median``), and the peak of a small
histogram after OpenCV's 3 x 3 Gaussian blur (``histogram_peak``). Each states the arithmetic
it does, so a test can hold it to a reference within the rounding it names.
"""

from __future__ import annotations

import numpy as np

from .jit import njit


@njit(cache=True, nogil=True)
def _sum_in_float64(a, zero):
    """The sum of a float array: one loop accumulated in float64 (float32 data rounded once
    to float32 at the end, not at every addition). ``zero``: 0 of the array's type."""
    res = 0.0
    for i in range(a.shape[0]):
        res += np.float64(a[i])
    return zero + res


@njit(cache=True, nogil=True)
def sum32(a):
    """The sum of a float32 array, accumulated in float64, rounded to float32
    (_sum_in_float64)."""
    return np.float32(_sum_in_float64(a, np.float32(0.0)))


@njit(cache=True, nogil=True)
def sum64(a):
    """The sum of a float64 array (_sum_in_float64)."""
    return _sum_in_float64(a, 0.0)


@njit(cache=True, nogil=True)
def histogram_peak(counts):
    """The bin (row, column) of the highest value of the chroma histogram ``counts`` (32,
    32) after a 3 x 3 Gaussian blur, as cv2.GaussianBlur(counts as float32, (3, 3), 0) and
    np.argmax found it: weights 1/4, 1/2, 1/4 along rows, then columns, mirrored borders
    (BORDER_REFLECT_101); on bin counts these sums are exact in float32 in any order, so the
    blurred values and the first highest are the same."""
    h, w = counts.shape
    quarter, half = np.float32(0.25), np.float32(0.5)
    rows = np.empty((h, w), np.float32)
    for r in range(h):
        for c in range(w):
            left = c - 1 if c > 0 else 1
            right = c + 1 if c < w - 1 else w - 2
            rows[r, c] = (quarter * np.float32(counts[r, left]) + half * np.float32(counts[r, c])
                          + quarter * np.float32(counts[r, right]))
    best, bi, bj = np.float32(-1.0), 0, 0
    for r in range(h):
        up = r - 1 if r > 0 else 1
        down = r + 1 if r < h - 1 else h - 2
        for c in range(w):
            v = quarter * rows[up, c] + half * rows[r, c] + quarter * rows[down, c]
            if v > best:
                best, bi, bj = v, r, c
    return bi, bj


@njit(cache=True, nogil=True)
def mean32(a):
    """The mean of a float32 array: its sum (sum32, accumulated in float64) over
    the count in float64, rounded to float32."""
    return np.float32(np.float64(sum32(a)) / np.float64(a.shape[0]))


@njit(cache=True, nogil=True)
def var32(a):
    """The variance of a float32 array (ddof 0): its mean as mean32, the squared deviations
    in float32, their mean likewise."""
    m = mean32(a)
    x = np.empty_like(a)
    for i in range(a.shape[0]):
        x[i] = a[i] - m
        x[i] = x[i] * x[i]
    return mean32(x)


@njit(cache=True, nogil=True)
def _rank_bin(bits, n, shift, mask, k, hist):
    """median32's radix step: the bin ``(bits >> shift) & mask`` of ``bits[:n]`` that holds
    their k-th smallest (0-based), k's rank within that bin, and the bin's count."""
    hist[:] = 0
    for i in range(n):
        hist[(bits[i] >> shift) & mask] += 1
    below = 0
    for b in range(mask + 1):
        if below + hist[b] > k:
            return b, k - below, hist[b]
        below += hist[b]
    return mask, 0, 0


@njit(cache=True, nogil=True)
def _keep_bin(src, n, shift, mask, b, out):
    """The values of ``src[:n]`` in bin b (as _rank_bin) copied in order to ``out`` (which
    may be ``src``); returns their number."""
    n2 = 0
    for i in range(n):
        if (src[i] >> shift) & mask == b:
            out[n2] = src[i]
            n2 += 1
    return n2


@njit(cache=True, nogil=True)
def median32(a, m):
    """numba's np.median of ``a[:m]``, float32 values >= 0 (+0.0, no NaN), m >= 1: the middle
    value, or float32(a + b) / 2 of the two middle ones, as float64. By radix selection on
    the float bits (for such floats their order as unsigned integers is the floats'): two
    histogram passes of 11 bits and one of 10 over ever fewer values, then, when the count
    is even and the upper middle value is not a tie, one pass for the next larger value.
    Exact with any number of ties, where numba's quickselect slows on the few distinct
    values that colour statistics of 8-bit pixels take (about 4x on a frame's green)."""
    bits = a.view(np.uint32)
    hist = np.empty(2048, np.int64)
    work = np.empty(m, np.uint32)
    k = (m - 1) // 2
    b, k, count = _rank_bin(bits, m, 21, 2047, k, hist)
    prefix = np.uint32(b) << np.uint32(21)
    n = _keep_bin(bits, m, 21, 2047, b, work)
    b, k, count = _rank_bin(work, n, 10, 2047, k, hist)
    prefix |= np.uint32(b) << np.uint32(10)
    n = _keep_bin(work, n, 10, 2047, b, work)
    b, k, count = _rank_bin(work, n, 0, 1023, k, hist)
    pair = np.empty(2, np.uint32)
    pair[0] = prefix | np.uint32(b)
    pair[1] = pair[0]
    if m % 2 == 0 and k + 1 >= count:  # the next value is the smallest above it
        nxt = np.uint32(0xFFFFFFFF)
        for i in range(m):
            if bits[i] > pair[0] and bits[i] < nxt:
                nxt = bits[i]
        pair[1] = nxt
    v = pair.view(np.float32)
    if m % 2 == 1:
        return np.float64(v[0])
    return np.float64(np.float32(v[0] + v[1])) / 2.0


@njit(cache=True, nogil=True)
def median(values):
    """``np.median`` of a 1-D array, compiled (the same value: the middle order statistic, or
    the mean of the two middle ones; without numpy's call overhead on short arrays)."""
    return np.median(values)

