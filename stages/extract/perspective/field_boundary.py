"""Field boundary extraction on the subsampled colour-class images (Schulz et al. 2011,
section 3.1).

Three steps, each its own function:

1. ``merged_grey_image``: a weighted sum of the colour-class counts by how likely each class
   is part of the field (green) or an object on it (white lines), so that the field region
   stands out in one grey-level image of the grid size (94 x 60 for a 752 x 480 frame).
2. ``binarize_field``: the three thresholds, obvious cases first: the pixel itself
   (``t_pix``), the pre-computed row sum over the row and the row above it (``t_row``), then
   the sum of its neighbours in an 8 x 4 window below it (``t_win``).
3. ``field_height_histogram``: per column, from the bottom up, the height of the last field
   pixel before more than four consecutive non-field pixels; then
   ``smooth_field_heights`` (1D Gaussian for slightly uneven bins, median for small gaps and
   peaks) and one pass of ``local_convex_filling`` (v = (Rx-Lx)(Py-Ly) - (Px-Lx)(Ry-Ly); the
   bins with v < 0 are replaced by the chord of the remaining ones).

Heights are counted in grid rows from the bottom of the image; ``boundary_rows`` turns them
into the first field row (from the top) per column, the form the later steps use.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from types import MappingProxyType
from typing import NamedTuple

import cv2
import numpy as np

from ...common.jit import njit
from ...common.numeric import sum32

# Weights of the colour classes in the merged grey image: green is field; white is a line on
# it, but also a wall or banner behind it, so a cell of white alone stays below the weak
# threshold (t_weak) and counts only mixed with green; other colours (robots, people) occlude.
DEFAULT_WEIGHTS = MappingProxyType({"green": 1.0, "white": 0.3, "other": 0.0})


class BoundaryTuning(NamedTuple):
    """The numbers of ``field_boundary`` (section 3.1), grid cells and grey levels (1 = a cell
    all green). Tuned on the rendered KidSize and NAO frames and the HULKs NAO frames (docs/
    manual.md "Perspective extraction on real frames")."""

    weights: Mapping[str, float]  # the colour classes' weights (DEFAULT_WEIGHTS)
    t_pix: float  # a cell this green (grey level, 1 = all green) is field
    t_row: float  # mean grey of the row and the row above for weak cells
    t_win: float  # mean grey of the 8 x 4 window below for weak cells
    t_weak: float  # weak cells below this are never field
    max_gap: int  # scan stops after more than this many non-field cells
    # the scan starts at each column's lowest field cell (the robot's own body and feet cover
    # the bottom of a NAO's lower camera)
    from_lowest: bool
    # white runs between field cells of a row or column, up to line_run cells, are lines on
    # the field (a near line along the view is many cells tall)
    line_white: float
    line_run: int
    gauss_sigma: float  # bins
    median_size: int  # bins


BOUNDARY = BoundaryTuning(weights=DEFAULT_WEIGHTS, t_pix=0.45, t_row=0.6, t_win=0.75,
                          t_weak=0.2, max_gap=4, from_lowest=True, line_white=0.3, line_run=10,
                          gauss_sigma=0.7, median_size=5)


def merged_grey_image(counts: dict[str, np.ndarray], weights: dict[str, float],
                      area: float = 64.0) -> np.ndarray:
    """Weighted sum of the per-cell colour counts (H, W) -> float32 grey image in [0, 1] (a cell
    of ``area`` green pixels is 1)."""
    first = next(iter(counts.values()))
    grey = np.zeros(first.shape, np.float32)
    for name, w in weights.items():
        if w and name in counts:
            grey += np.float32(w) * counts[name].astype(np.float32)
    return grey / np.float32(area)


def binarize_field(grey: np.ndarray, t_pix: float, t_row: float, t_win: float,
                   t_weak: float) -> np.ndarray:
    """Field pixels (H, W) bool by the three thresholds of the paper.

    A pixel with ``grey >= t_pix`` is field (the obvious case). A weaker pixel (but at least
    ``t_weak``, so empty background never becomes field) is field if the row sum over its row
    and the row above, divided by the width, exceeds ``t_row`` (a largely green row), or else
    if the mean of its 8 x 4 neighbourhood below exceeds ``t_win`` (enough field below it).
    Thresholds are fractions of a full green cell."""
    h, w = grey.shape
    strong = grey >= t_pix
    weak = (grey >= t_weak) & ~strong
    rows = grey.sum(axis=1)
    row_sum = rows + np.concatenate([[0.0], rows[:-1]])
    by_row = (row_sum / (2.0 * w) > t_row)[:, None] & weak
    # 8 x 4 window below (rows y+1..y+4, columns x-4..x+3): box sums over rows y..y+3 moved
    # up by one row
    box = cv2.boxFilter(grey.astype(np.float32), -1, (8, 4), anchor=(4, 0), normalize=False,
                        borderType=cv2.BORDER_CONSTANT)
    window = np.zeros_like(box)
    window[:-1] = box[1:]
    by_window = (window / 32.0 > t_win) & weak & ~by_row
    return strong | by_row | by_window


def grey_field(counts: dict[str, np.ndarray], weights: dict[str, float], area: float,
               t_pix: float, t_row: float, t_win: float, t_weak: float) -> np.ndarray:
    """binarize_field(merged_grey_image(counts, weights, area), ...) by one compiled pass
    (``_grey_field``): the same float32 grey levels, the rows' sums (accumulated in float64,
    numeric.sum32) and the 8 x 4 windows' sums in float64, rounded once to float32."""
    names = [n for n, w in weights.items() if w and n in counts]
    if not names:  # no class weighs: the grey image is 0
        return binarize_field(merged_grey_image(counts, weights, area), t_pix, t_row, t_win,
                              t_weak)
    classes = np.empty((len(names),) + np.shape(counts[names[0]]), np.float32)
    for k, n in enumerate(names):
        classes[k] = counts[n]
    field = np.empty(classes.shape[1:], np.bool_)
    _grey_field(classes, np.array([weights[n] for n in names], np.float32),
                np.float32(area), float(t_pix), float(t_row), float(t_win), float(t_weak),
                field)
    return field


@njit(cache=True, nogil=True)
def _grey_field(classes, weights, area, t_pix, t_row, t_win, t_weak, field):
    """grey_field's pass: grey = (sum of weight * class count, in order, float32) / area; a
    cell is strong at t_pix, weak from t_weak; a weak one is field when the mean of its row
    and the row above (float32 row sums, added in float64) exceeds t_row, else when its
    8 x 4 window below (rows under it, columns -4..3) averages above t_win."""
    k, h, w = classes.shape
    grey = np.zeros((h, w), np.float32)
    for c in range(k):
        for y in range(h):
            for x in range(w):
                grey[y, x] += weights[c] * classes[c, y, x]
    for y in range(h):
        for x in range(w):
            grey[y, x] = grey[y, x] / area
    rows = np.empty(h, np.float32)
    for y in range(h):
        rows[y] = sum32(grey[y])
    t_pix32, t_win32, t_weak32 = np.float32(t_pix), np.float32(t_win), np.float32(t_weak)
    for y in range(h):
        row_sum = np.float64(rows[y]) + (np.float64(rows[y - 1]) if y > 0 else 0.0)
        by_row_y = row_sum / (2.0 * w) > t_row
        for x in range(w):
            g = grey[y, x]
            strong = g >= t_pix32
            weak = g >= t_weak32 and not strong
            by_row = by_row_y and weak
            by_window = False
            if weak and not by_row and y + 1 < h:
                s = 0.0  # the window of the cell below: rows y + 1..y + 4, columns x - 4..x + 3
                for yy in range(y + 1, min(y + 5, h)):
                    for xx in range(max(x - 4, 0), min(x + 4, w)):
                        s += np.float64(grey[yy, xx])
                by_window = np.float32(s) / np.float32(32.0) > t_win32
            field[y, x] = strong or by_row or by_window


@njit(cache=True, nogil=True)
def _mark_bounded_runs(candidate, bound, max_run, out):
    """Mark in ``out`` the runs of ``candidate`` cells along each row (H, W), at most
    ``max_run`` long, with a ``bound`` cell right before and right after them."""
    h, w = candidate.shape
    for r in range(h):
        c = 0
        while c < w:
            if not candidate[r, c]:
                c += 1
                continue
            s = c
            while c < w and candidate[r, c]:
                c += 1
            # the run is s .. c - 1
            if c - s <= max_run and s > 0 and c < w and bound[r, s - 1] and bound[r, c]:
                for k in range(s, c):
                    out[r, k] = True


def fill_lines(field: np.ndarray, white: np.ndarray, t_white: float, max_run: int
               ) -> np.ndarray:
    """Field cells (H, W) with the lines on the field added: runs of white cells (share >=
    ``t_white``) between two field cells of the same row or column, at most ``max_run`` cells
    long. A near line seen along its length (steep in the image) holds more white cells in a
    column than the height scan's gap allows; bounded by carpet, it is field."""
    white = np.ascontiguousarray(white)
    out = np.array(field, np.bool_)  # a copy
    _fill_bounded_runs(white, white.dtype.type(t_white), int(max_run), out)
    return out


@njit(cache=True, nogil=True)
def _fill_bounded_runs(white, t_white, max_run, field):
    """fill_lines in place, compiled: the candidates (white >= t_white, not field) taken from
    ``field`` as it was, then their bounded runs along the rows and along the columns
    (_mark_bounded_runs) added to it."""
    cand = np.empty(field.shape, np.bool_)
    for r in range(field.shape[0]):
        for c in range(field.shape[1]):
            cand[r, c] = white[r, c] >= t_white and not field[r, c]
    bound = field.copy()
    _mark_bounded_runs(cand, bound, max_run, field)
    _mark_bounded_runs(cand.T, bound.T, max_run, field.T)


def field_height_histogram(field: np.ndarray, max_gap: int = 4, from_lowest: bool = False
                           ) -> np.ndarray:
    """Per column, the field height in rows counted from the bottom: scanning bottom-up, the
    height of the last field pixel before more than ``max_gap`` consecutive non-field pixels
    (0 when the bottom rows are not field). With ``from_lowest`` the scan starts at the
    column's lowest field pixel (the robot's own body or feet may cover the image's bottom).
    Returns (W,) float."""
    out = np.empty(field.shape[1], np.float64)
    _column_heights(np.ascontiguousarray(field, np.bool_), int(max_gap) + 1, bool(from_lowest),
                    out)
    return out


@njit(cache=True, nogil=True)
def _column_heights(field, run, from_lowest, out):
    """field_height_histogram per column, compiled: from the bottom row up (with
    ``from_lowest`` the cells below the column's lowest field cell count as field: the covered
    bottom of the column), the rows before the first ``run`` empty ones in a row (rows above
    the image are empty, so the scan stops)."""
    h, w = field.shape
    for c in range(w):
        lowest = -1  # the lowest field row, counted from the top
        if from_lowest:
            for r in range(h - 1, -1, -1):
                if field[r, c]:
                    lowest = r
                    break
        empty = 0
        for i in range(h + run):  # i: rows from the bottom
            r = h - 1 - i
            if r >= 0 and (field[r, c] or r > lowest >= 0):
                empty = 0
            else:
                empty += 1
                if empty == run:
                    out[c] = i - run + 1
                    break


def _edge_padded(values: np.ndarray, r: int) -> np.ndarray:
    """``np.pad(values, r, mode="edge")`` of a 1-D array, without np.pad's per-call overhead."""
    if len(values) == 0:
        return np.pad(values, r, mode="edge")  # its error
    return np.concatenate([np.full(r, values[0]), values, np.full(r, values[-1])])


def smooth_field_heights(heights: np.ndarray, sigma: float, median: int) -> np.ndarray:
    """1D Gaussian filter (slightly uneven bins), then a median filter (small gaps and peaks)."""
    out = np.asarray(heights, np.float64)
    if sigma > 0:
        k = _gauss_weights(float(sigma))
        out = np.convolve(_edge_padded(out, len(k) // 2), k, mode="valid")
    if median > 1:
        r = int(median) // 2
        padded = _edge_padded(out, r)
        out = np.empty(len(padded) - 2 * r)
        _window_middles(padded, 2 * r + 1, out)
    return out


@functools.lru_cache(maxsize=8)
def _gauss_weights(sigma: float) -> np.ndarray:
    """smooth_field_heights' Gaussian of ``sigma`` bins over +-ceil(3 sigma) (at least one),
    normalised (made once, read only)."""
    r = max(1, int(np.ceil(3 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k = k / k.sum()
    k.setflags(write=False)
    return k


@njit(cache=True, nogil=True)
def _window_middles(values, size, out):
    """The median of every window of odd ``size`` along ``values`` into ``out``: the middle of
    the window sorted (by insertion, NaN last, as np.sort puts it)."""
    window = np.empty(size)
    for i in range(out.shape[0]):
        for a in range(size):
            v = values[i + a]
            b = a
            while b > 0 and (v < window[b - 1] or (np.isnan(window[b - 1])
                                                   and not np.isnan(v))):
                window[b] = window[b - 1]
                b -= 1
            window[b] = v
        out[i] = window[size // 2]


def local_convexity(heights: np.ndarray) -> np.ndarray:
    """v = (Rx - Lx)(Py - Ly) - (Px - Lx)(Ry - Ly) per bin with its left and right neighbours;
    > 0: the bin is above the chord of its neighbours, < 0 below it (the end bins get 0)."""
    p = np.asarray(heights, np.float64)
    v = np.zeros_like(p)
    ly, py, ry = p[:-2], p[1:-1], p[2:]
    # Lx = x - 1, Px = x, Rx = x + 1
    v[1:-1] = 2.0 * (py - ly) - 1.0 * (ry - ly)
    return v


def local_convex_filling(heights: np.ndarray) -> np.ndarray:
    """One pass of the local convex corner algorithm: the field's locally convex hull is given
    by the bins with non-negative local convexity; the others are filled in from the chord
    between the nearest kept bins. One pass fills narrow gaps but not wide dents such as a
    robot's body standing on the field edge."""
    p = np.asarray(heights, np.float64)
    keep = local_convexity(p) >= 0
    if keep.all() or not keep.any():
        return p.copy()
    x = np.arange(len(p))
    return np.interp(x, x[keep], p[keep])


def boundary_rows(heights: np.ndarray, grid_rows: int) -> np.ndarray:
    """Field heights (rows from the bottom) -> first field row per column (from the top)."""
    return grid_rows - np.asarray(heights, np.float64)


def field_boundary(counts: dict[str, np.ndarray], tuning: BoundaryTuning = BOUNDARY,
                   area: float = 64.0) -> tuple[np.ndarray, np.ndarray]:
    """The whole section 3.1: colour counts (cells of ``area`` pixels) -> (first field row per
    column (W,) float, binary field image (H, W))."""
    t = tuning
    field = grey_field(counts, t.weights, area, t.t_pix, t.t_row, t.t_win, t.t_weak)
    if t.line_run > 0:
        white = counts["white"].astype(np.float32) / np.float32(area)
        field = fill_lines(field, white, t.line_white, int(t.line_run))
    heights = field_height_histogram(field, t.max_gap, bool(t.from_lowest))
    heights = smooth_field_heights(heights, t.gauss_sigma, t.median_size)
    heights = local_convex_filling(heights)
    return boundary_rows(heights, field.shape[0]), field


def boundary_polyline(top: np.ndarray, cell: int) -> np.ndarray:
    """First field row per column -> (W, 2) polyline (u, v) in full-resolution pixels: the
    upper edge of the field region at each column's centre."""
    x = np.arange(len(top), dtype=np.float64)
    out = np.empty((len(top), 2), np.float32)
    out[:, 0] = (x + 0.5) * cell - 0.5
    out[:, 1] = top * cell - 0.5
    return out
