"""The compiled kernels of the perspective chain compute what a readable version of each
stage computes: the oracles in tests/oracles/perspective_*.py (numpy, np.linalg, OpenCV),
or the stage's own numpy function where one exists (colour.classify_masks,
field_boundary.binarize_field, line_structure.corner_nodes, ...). Continuous results are
compared within the tolerance each test states (assert_allclose, assert_array_max_ulp for
float32); decisions (a crossing found, a pair merged, a cell of field) where their margin to
the threshold is clear, the few near it counted and bounded; graph kernels by the
properties their result must have (every connection on one chain, no triangle left).
Properties with hypothesis: turning the robot frame turns the floor lines, permuting the
lines keeps the crossings, turning the chains keeps their turning angles.

The features of whole frames are compared in test_extract_perspective_unchanged.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from oracles import perspective_boundary as boundary
from oracles import perspective_crossings as crossing_oracle
from oracles import perspective_geometry as geometry
from oracles import perspective_sampling as sampling

from stages.common import colour, colour_kernels, numeric
from stages.extract import perspective
from stages.extract.perspective import crossing_kernels as ck
from stages.extract.perspective import crossings as cr
from stages.extract.perspective import line_structure as ls
from stages.extract.perspective import line_structure_kernels as lsk


def _counts(a: np.ndarray) -> np.ndarray:
    """A float array of whole numbers (counts, sums of 8-bit levels, rows) as int64, after
    checking that its values are whole."""
    a = np.asarray(a)
    assert np.all(a == np.round(a))
    return a.astype(np.int64)


# ---------------------------------------------------------------------------- colour


def _random_frame(rng, h, w):
    """A YUV frame (h, w, 3) uint8: noisy green carpet, white strokes, grey and coloured
    patches, clipped bright and dark areas."""
    yuv = np.empty((h, w, 3), np.uint8)
    yuv[..., 0] = np.clip(rng.normal(95, 25, (h, w)), 0, 255)
    yuv[..., 1] = np.clip(rng.normal(105, 8, (h, w)), 0, 255)
    yuv[..., 2] = np.clip(rng.normal(100, 8, (h, w)), 0, 255)
    for _ in range(12):  # white strokes, other colours, saturated blocks
        r, c = rng.integers(0, h - 8), rng.integers(0, w - 8)
        hh, ww = rng.integers(2, 40), rng.integers(2, 40)
        kind = rng.integers(3)
        patch = yuv[r:r + hh, c:c + ww]
        if kind == 0:
            patch[..., 0] = rng.integers(170, 256)
            patch[..., 1:] = 128 + rng.integers(-6, 7, patch[..., 1:].shape)
        elif kind == 1:
            patch[...] = rng.integers(0, 256, patch.shape)
        else:
            patch[..., 0] = rng.choice([0, 255])
    return yuv


@pytest.mark.parametrize("seed,shape,local_map", [(0, (480, 752), True), (1, (480, 640), True),
                                                   (2, (483, 757), True), (3, (96, 120), False)])
def test_classify_cells_equals_the_class_masks(seed, shape, local_map):
    rng = np.random.default_rng(seed)
    yuv = _random_frame(rng, *shape)
    conf = perspective.COLOUR
    fc = colour.estimate_field_colour(yuv, conf)
    assert fc.hue_dir is not None
    fc.hue_cos = math.cos(rng.uniform(0.2, 0.6))  # a few tolerances, bands and thresholds
    fc.saturation = (rng.uniform(0.02, 0.1), rng.uniform(0.2, 0.6))
    if not local_map:
        fc.y_map = None
    cell = 8
    white_px = np.zeros(shape, np.uint8)
    counts = colour.classify_cells(yuv, fc, conf, cell, white_px)
    green, white = colour.classify_masks(yuv, fc, conf)
    hb = shape[0] // cell
    # exact integers: per-cell pixel counts
    np.testing.assert_array_equal(counts, colour._counts(green, white, cell))
    # exact decisions: the white mask
    np.testing.assert_array_equal(white_px[:hb * cell].view(bool), white[:hb * cell])
    assert not white_px[hb * cell:].any()  # rows below the last whole cell are not classified
    assert counts[..., 0].sum() > 100 and counts[..., 1].sum() > 100  # both classes occur
    assert colour.classify_cells(yuv, fc, conf, cell) is not None  # without the white mask


def test_threshold_table_equals_luminance_thresholds():
    conf = perspective.COLOUR
    rng = np.random.default_rng(7)
    for _ in range(50):
        y_map = rng.uniform(-5, 300, (60, 94)).astype(np.float32)
        y_map[0, :6] = [0.0, 255.0, 256.0, 1e-3, 200.5, 100.0 / 0.35]
        out = np.empty(y_map.shape + (3,), np.int16)
        colour_kernels._threshold_table(y_map, np.float32(conf["white_contrast"]),
                                        np.float32(conf["white_min_y"]),
                                        np.float32(conf["green_min_ratio"]),
                                        np.float32(conf["green_max_ratio"]), out)
        # exact integers: int16 thresholds
        np.testing.assert_array_equal(out, colour.luminance_thresholds(y_map, conf))


@pytest.mark.parametrize("seed,shape", [(0, (480, 752)), (1, (483, 645))])
def test_green_samples_equal_the_numpy_masks(seed, shape):
    rng = np.random.default_rng(seed)
    yuv = _random_frame(rng, *shape)
    conf = perspective.COLOUR
    fc = colour.estimate_field_colour(yuv, conf)
    assert fc.hue_dir is not None
    cell, step = fc.cell, fc.cell // 2
    hb, wb = shape[0] // cell, shape[1] // cell
    valid = rng.random((hb * 2, wb * 2)) < 0.8
    gs = np.zeros((hb, wb), np.float32)
    ys = np.zeros((hb, wb), np.float32)
    colour_kernels._hue_block_sums(yuv, (step, 2, hb, wb), valid, True, colour._hue_test(fc),
                                   (30, 220), gs, ys)
    y, u, v = (np.ascontiguousarray(yuv[:hb * cell:step, :wb * cell:step, c]) for c in range(3))
    green, _ = colour._chroma_tests(y, u, v, fc, conf, white=False)
    green &= (y >= 30) & (y <= 220) & valid
    ref_g = green.reshape(hb, 2, wb, 2).sum(axis=(1, 3)).astype(np.float32)
    ref_y = (y * green).reshape(hb, 2, wb, 2).sum(axis=(1, 3)).astype(np.float32)
    # sums of counts and 8-bit levels: integers, exact in float32
    # exact integers: sums of counts and 8-bit levels
    np.testing.assert_array_equal(_counts(gs), ref_g.astype(np.int64))
    # exact integers: sums of counts and 8-bit levels
    np.testing.assert_array_equal(_counts(ys), ref_y.astype(np.int64))
    assert ref_g.sum() > 100
    mask = rng.random((-(-shape[0] // 6), -(-shape[1] // 6))) < 0.7
    # exact integers: uint8 pixels
    np.testing.assert_array_equal(colour._sample_pixels(yuv, 6, mask), yuv[::6, ::6][mask])
    # exact integers: uint8 pixels
    np.testing.assert_array_equal(colour._sample_pixels(yuv, 6, None),
                                  yuv[::6, ::6].reshape(-1, 3))


@pytest.mark.parametrize("seed", range(4))
def test_green_candidates_equal_the_numpy_formulas(seed):
    rng = np.random.default_rng(seed)
    sub = rng.integers(0, 256, (5000, 3)).astype(np.uint8)
    sub[:2000, 1:] = np.clip(rng.normal(110, 10, (2000, 2)), 0, 255)
    chroma = colour._green_candidate_chroma((-170.0, -75.0), 6.0)
    y_lo, y_hi, min_sat = int(rng.integers(0, 40)), int(rng.integers(200, 256)), 0.15
    y_c, u_c, v_c, uu, vv, hist = colour_kernels._green_candidates(
        sub, chroma, y_lo, y_hi, True, np.float32(min_sat * min_sat))
    y8, u8, v8 = sub[:, 0], sub[:, 1], sub[:, 2]
    cand = chroma[(u8.astype(np.int64) << 8) | v8] & (y8 >= y_lo) & (y8 <= y_hi)
    du, dv = u8.astype(np.float32) - np.float32(128.0), v8.astype(np.float32) - np.float32(128.0)
    cand &= du * du + dv * dv >= np.float32(min_sat * min_sat) * (y8.astype(np.float32) ** 2)
    assert cand.sum() > 100
    # exact integers: uint8 levels
    np.testing.assert_array_equal(y_c, y8[cand])
    # exact integers: uint8 levels
    np.testing.assert_array_equal(u_c, u8[cand])
    # exact integers: uint8 levels
    np.testing.assert_array_equal(v_c, v8[cand])
    scale = colour.Y_REF / np.maximum(y8[cand].astype(np.float32), 1.0)
    ref_u = (u8[cand].astype(np.float32) - 128.0) * scale
    ref_v = (v8[cand].astype(np.float32) - 128.0) * scale
    # float32 element by element: one ulp apart at most
    np.testing.assert_array_max_ulp(uu, ref_u, maxulp=1)
    np.testing.assert_array_max_ulp(vv, ref_v, maxulp=1)
    bins = (np.clip(ref_u + 128.0, 0, 255).astype(np.int32) >> 3) * 32 + (
        np.clip(ref_v + 128.0, 0, 255).astype(np.int32) >> 3)
    # exact integers: histogram counts
    np.testing.assert_array_equal(hist, np.bincount(bins, minlength=1024))


def test_filled_green_map_equals_the_box_filter_expressions():
    import cv2

    class Frame:
        y = 0.0

    rng = np.random.default_rng(12)
    for _ in range(300):
        h, w, k = int(rng.integers(1, 70)), int(rng.integers(1, 100)), int(rng.choice([1, 2]))
        gs = (rng.integers(0, k * k + 1, (h, w)) * (rng.random((h, w)) < rng.random())
              ).astype(np.float32)
        ys = (gs * rng.integers(0, 256, (h, w))).astype(np.float32)
        fc = Frame()
        fc.y = float(rng.uniform(20, 200))
        for fill in (3, 7):
            gs_f = cv2.boxFilter(gs, -1, (fill, fill), normalize=False,
                                 borderType=cv2.BORDER_CONSTANT)
            ys_f = cv2.boxFilter(ys, -1, (fill, fill), normalize=False,
                                 borderType=cv2.BORDER_CONSTANT)
            ref = np.where(gs >= 0.25 * k * k, ys / np.maximum(gs, 1e-6),
                           np.where(gs_f > 0, ys_f / np.maximum(gs_f, 1e-6), fc.y))
            got = colour._fill_green_luminance(gs, ys, k, fc, {"local_fill": fill})
            # box sums of integers are exact; the ratio one float32 division
            np.testing.assert_array_max_ulp(got, ref.astype(np.float32), maxulp=1)


def test_histogram_peak_equals_the_blurred_argmax():
    import cv2

    rng = np.random.default_rng(9)
    for k in range(1500):
        if k % 3 == 0:
            counts = rng.integers(0, 3000, (32, 32))
        elif k % 3 == 1:  # sparse: ties and borders
            counts = (rng.random((32, 32)) < 0.05) * rng.integers(0, 5, (32, 32))
        else:
            counts = np.zeros((32, 32), np.int64)
            counts[rng.integers(0, 32), rng.integers(0, 32)] = rng.integers(0, 9000)
        blurred = cv2.GaussianBlur(counts.astype(np.float32), (3, 3), 0)
        peak = np.unravel_index(int(np.argmax(blurred)), blurred.shape)
        assert numeric.histogram_peak(counts.astype(np.int64)) == tuple(int(v) for v in peak)


@pytest.mark.parametrize("seed", range(6))
def test_radix_median_is_numpys_with_ties(seed):
    # colour statistics of 8-bit pixels take few distinct values: ties across the middle,
    # even and odd counts, zeros, one value only, and values spanning many binades
    rng = np.random.default_rng(seed)
    for n in (1, 2, 3, 4, 10, 11, 257, 6000, 6001):
        for a in ((rng.integers(0, 5, n) / 7.0).astype(np.float32),
                  np.full(n, np.float32(0.3)),
                  np.abs(rng.normal(size=n) * 10.0 ** rng.integers(-6, 6, n)).astype(np.float32),
                  np.where(rng.random(n) < 0.5, 0.0, rng.random(n)).astype(np.float32)):
            padded = np.concatenate([a, rng.random(3).astype(np.float32)])  # only a[:m] counts
            # a middle value, or the mean of two: within an ulp of float32
            np.testing.assert_allclose(numeric.median32(padded, n), np.median(a), rtol=2.0 ** -23)


# ------------------------------------------------------------------ field boundary, goal posts


def test_grey_field_equals_the_numpy_and_opencv_binarisation():
    from stages.extract.perspective import field_boundary as fb

    conf = fb.BOUNDARY
    rng = np.random.default_rng(18)
    by_window = differ = cells = 0
    for _ in range(1500):
        h, w = int(rng.integers(1, 70)), int(rng.integers(1, 100))
        # carpet with weak cells (grey 0.2..0.45): their row or the window below decides
        g = (rng.uniform(0.7, 1.0, (h, w)) * 64).astype(np.int64)
        weak = rng.random((h, w)) < rng.uniform(0.05, 0.6)
        g[weak] = (rng.uniform(0.15, 0.45, weak.sum()) * 64).astype(np.int64)
        g[rng.random((h, w)) < 0.05] = 0
        wh = np.minimum(64 - g, rng.integers(0, 65, (h, w)) * (rng.random((h, w)) < 0.3))
        counts = {"green": g.astype(np.uint16), "white": wh.astype(np.uint16),
                  "other": (64 - g - wh).astype(np.uint16)}
        grey = fb.merged_grey_image(counts, conf.weights, 64.0)
        ref = fb.binarize_field(grey, conf.t_pix, conf.t_row, conf.t_win,
                                conf.t_weak)
        got = fb.grey_field(counts, conf.weights, 64.0, conf.t_pix, conf.t_row,
                            conf.t_win, conf.t_weak)
        # the rows' sums (float64 accumulation here, numpy's float32 pairwise sum there)
        # may decide a row whose mean lies within float32 rounding of t_row either way
        differ += int((got != ref).sum())
        cells += got.size
        by_window += int((ref & (grey < conf.t_pix)).sum())
    assert by_window > 1000  # weak cells taken by their row or window
    assert differ <= 1e-4 * cells


def test_field_heights_and_their_smoothing_equal_the_numpy_scan():
    from stages.extract.perspective import field_boundary as fb

    rng = np.random.default_rng(5)
    for _ in range(500):
        h, w = int(rng.integers(1, 70)), int(rng.integers(1, 100))
        field = rng.random((h, w)) < rng.random()
        for max_gap in (0, 2, 4):
            for from_lowest in (False, True):
                # exact integers: field heights in rows
                np.testing.assert_array_equal(
                    _counts(fb.field_height_histogram(field, max_gap, from_lowest)),
                    boundary.field_heights(field, max_gap, from_lowest))
        heights = rng.integers(0, h + 1, w).astype(float)
        for size in (3, 5):
            r = size // 2
            windows = np.lib.stride_tricks.sliding_window_view(fb._edge_padded(heights, r),
                                                               size)
            # exact integers: medians of row counts
            np.testing.assert_array_equal(_counts(fb.smooth_field_heights(heights, 0.0, size)),
                                          np.sort(windows, axis=1)[:, r].astype(np.int64))


def test_fill_lines_and_the_smoothing_equal_the_former_numpy():
    """field_boundary.fill_lines (``_fill_bounded_runs``: rows and columns in one pass) adds
    the bounded white runs (the oracle's); smooth_field_heights (its Gaussian made once,
    ``_window_middles``) is np.convolve's and the sorted windows' median, within 1e-12."""
    from stages.extract.perspective import field_boundary as fb

    rng = np.random.default_rng(8)
    for _ in range(300):
        h, w = int(rng.integers(1, 40)), int(rng.integers(1, 60))
        field = rng.random((h, w)) < rng.random()
        white = (rng.integers(0, 65, (h, w)) / 64.0).astype(np.float32)
        for t_white, max_run in ((0.3, 10), (0.5, 2)):
            cand = (white >= t_white) & ~field
            ref = field | boundary.bounded_runs(cand, field, max_run) \
                | boundary.bounded_runs(cand.T, field.T, max_run).T
            # exact decisions: the field mask
            np.testing.assert_array_equal(fb.fill_lines(field, white, t_white, max_run), ref)
        heights = rng.integers(0, h + 1, w).astype(float)
        for sigma, size in ((0.7, 5), (1.3, 3), (0.7, 1)):
            r = max(1, int(np.ceil(3 * sigma)))
            k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
            ref = np.convolve(np.pad(heights, r, mode="edge"), k / k.sum(), mode="valid")
            if size > 1:
                windows = np.lib.stride_tricks.sliding_window_view(
                    np.pad(ref, size // 2, mode="edge"), size)
                ref = np.sort(windows, axis=1)[:, size // 2]
            got = fb.smooth_field_heights(heights, sigma, size)
            np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_bar_runs_equal_the_numpy_start_rows_and_walks():
    import warnings

    from stages.extract.perspective import goal_posts as gp

    rng = np.random.default_rng(19)
    for _ in range(1000):
        h, w = int(rng.integers(1, 70)), int(rng.integers(1, 100))
        white = (rng.random((h, w)) ** 2).astype(np.float32)
        top = rng.uniform(-5, h + 5, w)
        top[rng.random(w) < 0.1] = float(rng.integers(0, h + 1))  # whole rows
        top[rng.random(w) < 0.05] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # numpy's NaN to int cast
            start = np.clip(np.ceil(top).astype(int), 0, h)
        is_white = white >= 0.2
        up, down = np.zeros(w, int), np.zeros(w, int)
        for c in range(w):
            while (up[c] < 30 and 0 <= start[c] - 1 - up[c] < h
                   and is_white[start[c] - 1 - up[c], c]):
                up[c] += 1
            while (down[c] < 30 and 0 <= start[c] + down[c] < h
                   and is_white[start[c] + down[c], c]):
                down[c] += 1
        for got, ref in zip(gp.bar_runs(white, top, 0.2, 30, 30), (up, down, start)):
            # exact integers: run lengths and rows
            np.testing.assert_array_equal(got, ref)


def test_surroundings_opening_equals_opencvs():
    import cv2

    from stages.extract.perspective import goal_posts as gp

    rng = np.random.default_rng(17)
    for _ in range(5000):
        n, window = int(rng.integers(1, 120)), int(rng.integers(1, 14))
        up = (rng.integers(0, 31, n) * (rng.random(n) < rng.random())).astype(np.int64)
        base = cv2.morphologyEx(up.astype(np.float32)[None, :], cv2.MORPH_OPEN,
                                np.ones((1, window), np.uint8),
                                borderType=cv2.BORDER_REPLICATE)[0]
        excess, got = gp.rise_above_surroundings(up, window)
        # exact integers: opened run lengths
        np.testing.assert_array_equal(got, np.round(base).astype(int))
        # exact integers: run lengths
        np.testing.assert_array_equal(excess, up - got)


def test_post_bar_checks_equal_the_fancy_indexed_numpy():
    from stages.extract.perspective import goal_posts as gp

    rng = np.random.default_rng(11)
    for _ in range(2000):
        white = (rng.random((60, 94)) ** 3).astype(np.float32)
        g0 = int(rng.integers(0, 94))
        group = np.arange(g0, min(g0 + int(rng.integers(1, 5)), 94))
        start, rise = int(rng.integers(-3, 61)), int(rng.integers(0, 8))
        rows = np.arange(max(start - rise, 0), max(start, 0))
        cols = np.arange(max(group[0] - 1, 0), min(group[-1] + 2, 94))
        sides = [c for c in (group[0] - 2, group[-1] + 2) if 0 <= c < 94]
        stands = len(rows) > 0 and all(np.mean(white[rows, c] >= 0.2) <= 1 / 3 for c in sides)
        assert gp._stands_out(white, int(group[0]), int(group[-1]), start, rise,
                              np.float32(0.2), 2) == stands
        for cell in (8, 6):
            width = float(np.median(white[np.ix_(rows, cols)].sum(axis=1)) * cell) \
                if len(rows) else 0.0
            np.testing.assert_allclose(gp.bar_width(white, group, start, rise, cell), width,
                                       rtol=1e-6)  # float32 row sums of a few shares


def test_bar_share_equals_the_former_numpy():
    """goal_posts._bar_share (is_post_bar's white across a bar) is numpy's median of the
    summed shares, at grid points rounded half to even and clipped."""
    from stages.extract.perspective import goal_posts as gp

    rng = np.random.default_rng(13)
    for _ in range(3000):
        h, w = int(rng.integers(1, 61)), int(rng.integers(1, 95))
        cell = int(rng.choice([8, 6, 4]))
        white = (rng.integers(0, cell * cell + 1, (h, w)) / (cell * cell)).astype(np.float32)
        if rng.random() < 0.5:
            white = (rng.random((h, w)) ** 3).astype(np.float32)
        foot = rng.uniform(-20, [w * cell + 20, h * cell + 20])
        up = foot + rng.normal(0, 40, 2)
        if rng.random() < 0.3:  # on half-cell grid points: rounding half to even decides
            foot, up = (np.round(foot / cell * 2) / 2) * cell, (np.round(up / cell * 2) / 2) * cell
        t = np.linspace(0.5, 0.9, 5)[:, None]
        grid = ((foot[None] * (1 - t) + up[None] * t) + 0.5) / cell - 0.5
        rows = np.clip(np.round(grid[:, 1]).astype(int), 0, h - 1)
        cols = np.clip(np.round(grid[:, 0]).astype(int)[:, None] + np.arange(-2, 3)[None], 0,
                       w - 1)
        ref = float(np.median(white[rows[:, None], cols].sum(axis=1))) * cell
        got = float(gp._bar_share(white, foot[0], foot[1], up[0], up[1], cell,
                                  gp._BAR_STEPS)) * cell
        # five float32 shares summed in float64 here, in float32 there: 1e-6 of 5
        np.testing.assert_allclose(got, ref, rtol=0, atol=5e-6 * cell)


def test_standing_bars_equal_the_former_groups_and_checks():
    """goal_posts.standing_bars (``_standing_bars``) gives the groups the former numpy runs
    (post_columns) and per-group _stands_out kept, and their lifts."""
    from stages.extract.perspective import goal_posts as gp

    rng = np.random.default_rng(12)
    found = 0
    for _ in range(500):
        w = int(rng.integers(1, 94))
        white = (rng.random((60, w)) ** 3).astype(np.float32)
        excess = rng.integers(-2, 8, w) * (rng.random(w) < 0.4)
        base = rng.integers(0, 4, w)
        start = rng.integers(0, 61, w)
        for min_rise, max_width in ((3, 4), (1, 2)):
            rising = np.concatenate([[0], (excess >= min_rise).astype(int), [0]])
            edges = np.diff(rising)
            groups = [np.arange(a, b) for a, b in zip(np.nonzero(edges == 1)[0],
                                                      np.nonzero(edges == -1)[0])
                      if b - a <= max_width]
            lift = [int(base[g].max()) for g in groups]
            keep = [k for k, g in enumerate(groups)
                    if gp._stands_out(white, int(g[0]), int(g[-1]),
                                      int(start[g].min()) - lift[k], 3, np.float32(0.2), 2)]
            got_groups, got_lift = gp.standing_bars(excess, base, start, white, 0.2, min_rise,
                                                    max_width, 3)
            assert [g.tolist() for g in got_groups] == [groups[k].tolist() for k in keep]
            assert got_lift == [lift[k] for k in keep]
            found += len(keep)
    assert found > 100


# ------------------------------------------------------------------ line fits, line structure


@pytest.mark.parametrize("seed", range(4))
def test_split_components_and_part_fits_equal_the_per_part_functions(seed):
    from stages.extract.perspective import line_fit as lf

    rng = np.random.default_rng(seed)
    # polylines with corners and noise, some points outside the lens model (NaN)
    points = np.cumsum(rng.normal(0, 4, (300, 2)), axis=0)
    points[rng.random(300) < 0.03] = np.nan
    order = rng.permutation(300)
    components, k = [], 0
    while k < 300:
        n = int(rng.integers(1, 30))
        components.append([int(i) for i in order[k:k + n]])
        k += n
    got = lf.split_components(points, components, 7.0, 3)
    ref = []
    for comp in components:
        idx = np.asarray(comp)
        idx = idx[np.all(np.isfinite(points[idx]), axis=1)]
        ref += lf.split_component(points, idx, 7.0, 3)
    assert len(got) == len(ref) > 10
    for a, b in zip(got, ref):
        # exact decisions: the split parts' point indices
        np.testing.assert_array_equal(a, b)
    fits, ends = lf.part_fits(points, got)
    for p, f, e in zip(got, fits, ends):
        fit = lf.fit_line(points[p])
        np.testing.assert_allclose(f, [*fit.centroid, *fit.direction, *fit.normal, fit.rms],
                                   rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(e, lf.line_end_points(points, p, fit), rtol=1e-12,
                                   atol=1e-9)


def test_refine_segments_equal_refine_segment_per_segment():
    import cv2

    from stages.extract.perspective import line_fit as lf

    rng = np.random.default_rng(8)
    white = np.zeros((480, 640), np.uint8)
    for _ in range(12):  # white lines of a few px, some crossing
        p, q = rng.uniform(0, [640, 480], (2, 2)).astype(int)
        cv2.line(white, tuple(int(v) for v in p), tuple(int(v) for v in q), 1,
                 int(rng.integers(2, 8)))
    lens = np.array([500.0, 500.0, 320.0, 240.0, -0.2, 0.04, 0.0, 0.0, 0.0])
    ends = rng.uniform(0, [640, 480], (40, 2, 2))
    ends[:3, 1] = ends[:3, 0]  # no length
    got = lf.refine_segments(ends, white, lens, 4.0, 16.0, 4.0, 4, 32.0)
    kept = 0
    for e, g in zip(ends, got):
        r = lf.refine_segment(e, white, lens, 4.0, 16.0, 4.0, 4, 32.0)
        assert (g is None) == (r is None)
        if r is not None:
            kept += 1
            for a, b in ((g.ends, r.ends), (g.centres, r.centres), (g.widths, r.widths),
                         ([*g.fit.centroid, *g.fit.direction, *g.fit.normal, g.fit.rms],
                          [*r.fit.centroid, *r.fit.direction, *r.fit.normal, r.fit.rms])):
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)
    assert kept >= 5


def test_key_incidence_equals_incident_per_node():
    rng = np.random.default_rng(3)
    edges = [(int(a), int(b), [int(a)] + list(rng.integers(0, 99, 3)) + [int(b)])
             for a, b in rng.integers(0, 12, (30, 2))]
    edges.append((4, 4, [4, 50, 51, 4]))  # a ring at a node
    ks = ls.KeyStructure(list(range(12)), np.zeros((12, 2)), edges)
    assert ks.incidence() == [ks.incident(k) for k in range(12)]


def _random_graph(rng, n=60):
    """A LineGraph of polylines, isolated nodes and a few junctions on a 40 x 30 grid."""
    pos = rng.uniform(0, [40, 30], (n, 2))
    adj = [set() for _ in range(n)]
    k = 0
    while k < n - 6:
        length = int(rng.integers(1, 6))
        for a in range(k, min(k + length, n - 1)):
            adj[a].add(a + 1)
            adj[a + 1].add(a)
            pos[a + 1] = pos[a] + rng.normal(0, 1.2, 2)
        k += length + 1 + int(rng.integers(0, 2))
    for _ in range(3):  # junctions
        a, b = (int(v) for v in rng.integers(0, n, 2))
        if a != b:
            adj[a].add(b)
            adj[b].add(a)
    pix = np.round(pos).astype(int)
    return ls.LineGraph(pix, pos, rng.uniform(0.1, 1.0, n).astype(np.float32), adj)


def _same_lists(lists, adj):
    """Flat neighbour lists (start, nbr) hold each node's neighbours of ``adj``."""
    start, nbr = lists
    assert start.dtype == nbr.dtype == np.int64 and len(start) == len(adj) + 1
    assert start[-1] == len(nbr)
    assert [sorted(nbr[start[i]:start[i + 1]].tolist()) for i in range(len(adj))] == \
        [sorted(a) for a in adj]


@pytest.mark.parametrize("seed", range(6))
def test_kept_flat_lists_equal_the_sets(seed):
    """The flat neighbour lists the kernels leave with a graph (``_short_spurs``' and
    ``_triangle_cuts``' connections left, ``_linked_lists``' gaps filled and nodes split,
    ``node_links``) hold the graph's sets, as flat_lists of the sets would make them anew."""
    rng = np.random.default_rng(seed)
    graph = _random_graph(rng, 80)
    for _ in range(12):
        j, a = int(rng.integers(0, 80)), int(rng.integers(0, 80))
        if a != j and len(graph.adj[a]) == 0:
            graph.connect(a, j)
    pruned = ls.remove_short_lines(graph, 2.5)
    assert pruned.lists is not None
    _same_lists(pruned.lists, pruned.adj)
    _same_lists(graph.lists, graph.adj)
    before = sum(map(len, graph.adj))
    ls.fill_gaps(graph, rng.uniform(0.2, 1.0, (30, 40)).astype(np.float32), 6.0,
                 math.cos(math.radians(30.0)), 0.25, 4.0)
    assert sum(map(len, graph.adj)) > before and graph.lists is not None  # gaps were filled
    _same_lists(graph.lists, graph.adj)
    regions = np.zeros((30, 40), np.int32)
    regions[rng.integers(0, 30, 300), rng.integers(0, 40, 300)] = rng.integers(1, 50, 300)
    _same_lists(ls.node_links(regions, 49), ls.connect_nodes(regions, 49))
    # the whole graph (triangles cut: ``_triangle_cuts``; isolated nodes split and gaps
    # filled: ``_linked_lists``) on a white image of strokes and specks
    white = np.zeros((40, 60), np.float32)
    for _ in range(8):
        (x0, y0), (x1, y1) = rng.uniform(0, [60, 40], (2, 2))
        t = np.linspace(0, 1, 80)
        white[np.round(y0 + t * (y1 - y0)).astype(int) % 40,
              np.round(x0 + t * (x1 - x0)).astype(int) % 60] = 1.0
    white[rng.integers(0, 40, 30), rng.integers(0, 60, 30)] = 0.5
    _, lp, ranked = ls.skeleton_grid(white, np.zeros(60), 0, 0.04, True)
    graph, _, _ = ls.line_structure_graph(lp, ls.SKELETON, ranked)
    assert graph.lists is not None
    _same_lists(graph.lists, graph.adj)


@pytest.mark.parametrize("cell", [8, 4])
def test_skeleton_grid_equals_the_numpy_and_opencv_path(cell):
    rng = np.random.default_rng(cell)
    area = cell * cell
    for _ in range(500):
        h, w = int(rng.integers(1, 70)), int(rng.integers(1, 100))
        counts = (rng.integers(0, area + 1, (h, w)) * (rng.random((h, w)) < rng.random())
                  ).astype(np.uint16)
        white = counts / np.float32(area)
        top = rng.uniform(-2, h + 2, w)
        top[rng.random(w) < 0.05] = np.nan
        fast = ls.skeleton_grid(white, top, 1, 0.04, True)
        slow = ls.skeleton_grid(white, top, 1, 0.04, False)
        for a, b in ((fast[0], slow[0]), (fast[1], slow[1]), *zip(fast[2], slow[2])):
            assert a.dtype == b.dtype
            if a.dtype.kind == "f":  # shares of 1/64: far coarser than the tolerance
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
            else:
                # exact integers: ranking keys, skeleton and counts
                np.testing.assert_array_equal(a, b)


def test_corner_cuts_equal_corner_nodes_per_chain():
    rng = np.random.default_rng(16)
    found = 0
    for _ in range(1000):
        lens = rng.integers(1, 30, int(rng.integers(1, 20)))
        n = int(lens.sum())
        turn = rng.uniform(0, 2.5, n) * (rng.random(n) < 0.5)
        turn[rng.random(n) < 0.05] = 1.0  # equal turns
        arc = np.concatenate([np.cumsum(np.concatenate([[0], rng.uniform(0.2, 3, k - 1)]))
                              for k in lens])
        offsets = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
        cuts, cut_start = np.empty(n, np.int64), np.empty(len(lens) + 1, np.int64)
        by_python = np.zeros(len(lens), np.bool_)
        lsk._corner_cuts(turn, arc, offsets, 3.0, 0.8, cuts, cut_start, by_python)
        assert not by_python.any()
        for c in range(len(lens)):
            a, b = offsets[c], offsets[c + 1]
            ref = ls.corner_nodes(turn[a:b], arc[a:b], 3.0, 0.8)
            assert cuts[cut_start[c]:cut_start[c + 1]].tolist() == ref
            found += len(ref)
    assert found > 1000


def test_place_nodes_equals_the_numpy_sort():
    rng = np.random.default_rng(14)
    for _ in range(200):
        img = (rng.random((60, 94)) ** 4).astype(np.float32)
        img[rng.random(img.shape) < 0.5] = 0
        lp = ls.low_pass(img)
        key = ls.ranking_keys(lp)
        skeleton, c = ls.ranking_skeleton(lp, 0.02, key)
        priority = np.where(skeleton, key + np.where(c == 0, 2.0 ** 45, 0.0), -1.0)
        sy, sx = np.nonzero(skeleton)
        order = np.argsort(-priority[sy, sx], kind="stable")
        taken = lsk._greedy_nodes(sy[order], sx[order], *skeleton.shape)
        ys, xs = sy[order][taken], sx[order][taken]
        pix, regions = ls.place_nodes(lp, skeleton, c, key)
        # exact integers: node pixels
        np.testing.assert_array_equal(pix, np.stack([xs, ys], axis=1))
        # exact integers: region labels
        np.testing.assert_array_equal(regions, lsk._node_regions(skeleton, ys.astype(np.int64),
                                                                xs.astype(np.int64)))


# ---------------------------------------------------------------------------- sampling, sums


def test_bilinear_samples_equal_the_oracle_and_opencv():
    """line_structure_kernels.bilinear_at (and its callers: the gaps' grey level, the crossings'
    green samples, the undistortion tables) interpolates as the oracle: inside, across the
    edges (border value), on pixels and halfway. Both are float64 of float32 pixels: 1e-12
    of the image's range. cv2.remap agrees within its offset quantisation (OpenCV 4.x rounds
    offsets to 1/32 px: an error up to 1/32 of the largest step between neighbours)."""
    import cv2

    rng = np.random.default_rng(10)
    image = cv2.GaussianBlur(rng.random((60, 94)).astype(np.float32), (5, 5), 1.0)
    x, y = rng.uniform(-2, 96, 20000), rng.uniform(-2, 62, 20000)
    x[:500], y[:500] = np.round(x[:500] * 2) / 2, np.round(y[:500] * 2) / 2
    for border in (0.0, 0.5):
        got = np.array([lsk.bilinear_at(image, a, b, border) for a, b in zip(x, y)])
        np.testing.assert_allclose(got, sampling.bilinear(image, x, y, border), rtol=0,
                                   atol=1e-12)
    got = np.array([lsk.bilinear_at(image, a, b, 0.0) for a, b in zip(x, y)])
    p = np.stack([x, y], 1).astype(np.float32).reshape(-1, 1, 2)
    ref = cv2.remap(image, p[..., 0], p[..., 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0).ravel()
    step = max(np.abs(np.diff(image, axis=0)).max(), np.abs(np.diff(image, axis=1)).max(),
               np.abs(image).max())  # the border (0) is a neighbour too
    np.testing.assert_allclose(got, ref, rtol=0, atol=step / 32 + 1e-6)


def test_gap_grey_is_the_least_bilinear_sample_along_each_gap():
    rng = np.random.default_rng(10)
    image = rng.random((60, 94)).astype(np.float32)
    pos = rng.uniform(-2, [95, 61], (300, 2))
    ci, cj = rng.integers(0, 300, 2000), rng.integers(0, 300, 2000)
    ci[:10] = cj[:10]  # gaps of no length
    for samples in (2, 8):
        t = ls._gap_steps(samples)[0, :, 0]
        px = pos[ci][:, None, :] * (1 - t)[None, :, None] + pos[cj][:, None, :] * t[None, :, None]
        ref = sampling.bilinear(image, px[..., 0], px[..., 1], 0.0).min(axis=1)
        got = np.empty(len(ci), np.float32)
        lsk._gap_grey(pos, ci, cj, t, image, got)
        # float32 out: half an ulp of the float32 result
        np.testing.assert_allclose(got, ref, rtol=2.0 ** -24, atol=1e-30)


@pytest.mark.parametrize("n", [1, 2, 7, 8, 9, 129, 6121, 20000])
def test_sums_means_and_variances_equal_the_exact_ones(n):
    """colour's sums (sum32/64: float64 accumulators), means and variances of
    float32 arrays are the exactly rounded ones (math.fsum, np.var in float64) within the
    error bound of a float64 accumulation rounded once to the result's type
    (oracles.perspective_sampling.sum_tolerance); line_structure's block_sum and
    _path_length alike in float64."""
    rng = np.random.default_rng(n)
    for _ in range(20):
        a = (rng.normal(size=n) * 10.0 ** rng.integers(-3, 4)).astype(np.float32)
        exact = sampling.exact_sum(a)
        assert abs(float(numeric.sum32(a)) - exact) <= sampling.sum_tolerance(
            a, np.float32)
        mean = exact / n
        np.testing.assert_allclose(numeric.mean32(a), mean, rtol=2.0 ** -22,
                                   atol=sampling.sum_tolerance(a, np.float32) / n)
        # the squared deviations are float32 (a relative error of 2^-23 each and of the mean)
        var = float(np.var(a.astype(np.float64)))
        np.testing.assert_allclose(numeric.var32(a), var, rtol=1e-5,
                                   atol=4 * 2.0 ** -23 * abs(mean) * np.abs(a).max())
        b = rng.normal(size=n) * 10.0 ** rng.integers(-3, 4, n)
        assert abs(lsk.block_sum(b) - sampling.exact_sum(b)) <= sampling.sum_tolerance(
            b, np.float64)
    pos = rng.normal(0, 10, (200, 2))
    chain = rng.integers(0, 200, n + 1)
    steps = np.hypot(*np.diff(pos[chain], axis=0).T)
    np.testing.assert_allclose(lsk._path_length(pos, chain), sampling.exact_sum(steps),
                               rtol=n * 2.0 ** -52 + 2.0 ** -52)


def test_hue_model_statistics_equal_numpys():
    """colour_kernels' ``_hue_turned`` (the chroma turned onto the field's hue, float32, element by
    element: at most one ulp apart from numpy's float32) and ``_hue_spread`` (the count
    within 45 deg of it, a decision clear of the bound, and the medians)."""
    rng = np.random.default_rng(4)
    n = 20000
    u8, v8, y8 = (rng.integers(0, 256, n).astype(np.uint8) for _ in range(3))
    angle = rng.uniform(-math.pi, math.pi)
    hx, hy = math.cos(angle), math.sin(angle)
    du, dv = u8.astype(np.float32) - 128.0, v8.astype(np.float32) - 128.0
    num, den = colour_kernels._hue_turned(u8, v8, np.float32(hx), np.float32(hy))
    np.testing.assert_array_max_ulp(num, dv * np.float32(hx) - du * np.float32(hy), maxulp=1)
    np.testing.assert_array_max_ulp(den, du * np.float32(hx) + dv * np.float32(hy), maxulp=1)
    d = np.arctan2(num, den)
    m, med_d, med_sat = colour_kernels._hue_spread(d, u8, v8, y8,
                                                   np.float32(math.radians(45.0)))
    near = np.abs(d) <= math.radians(45.0)
    assert m == near.sum() > 1000
    np.testing.assert_allclose(med_d, np.median(np.abs(d[near])), rtol=2.0 ** -22)
    np.testing.assert_allclose(med_sat, np.median(np.hypot(du[near], dv[near]) / np.maximum(
        y8[near].astype(np.float32), 1.0)), rtol=2.0 ** -21)


@pytest.mark.parametrize("seed", range(4))
def test_green_cluster_is_the_mean_shift_of_the_candidates(seed):
    """colour_kernels' ``_green_cluster`` (the field green search's mean shift, its cluster's count,
    median luminance and chroma variances) against the same mean shift in numpy float64:
    the centres within 1e-4 (float32 chroma, float32 means), the count, median and spread
    where no candidate lies within 2e-5 of the search circle's squared radius (float32
    distances of chroma up to about 50: a relative error of 1e-5; else the shift may go
    either way: such runs are counted, at most one in four)."""
    rng = np.random.default_rng(seed)
    unclear = 0
    for trial in range(8):
        n = int(rng.integers(5, 20000))
        y_c = rng.integers(0, 256, n).astype(np.uint8)
        centre = rng.uniform(-40, 10, 2)
        uu = rng.normal(centre[0], rng.uniform(2, 20), n).astype(np.float32)
        vv = rng.normal(centre[1], rng.uniform(2, 20), n).astype(np.float32)
        start = centre + rng.normal(0, 8, 2) if trial else centre + 100.0  # none near
        nu, nv = (float(np.round(c / 8.0) * 8.0 + 4.0) for c in start)
        u64, v64 = uu.astype(np.float64), vv.astype(np.float64)
        clear = True
        for _ in range(4):
            d2 = (u64 - nu) ** 2 + (v64 - nv) ** 2
            clear &= not np.any(np.abs(d2 - 196.0) < 2e-5 * 196.0)
            near = d2 <= 196.0
            if _ == 3 or not near.any():
                break
            nu, nv = float(u64[near].mean()), float(v64[near].mean())
        got = colour_kernels._green_cluster(uu, vv, y_c, float(np.round(start[0] / 8) * 8 + 4),
                                            float(np.round(start[1] / 8) * 8 + 4), 196.0, 3)
        if not clear:
            unclear += 1
            continue
        assert got[2] == near.sum()
        np.testing.assert_allclose(got[:2], (nu, nv), rtol=0, atol=1e-4)
        if got[2]:
            assert got[3] == np.median(y_c[near].astype(np.float64))
            np.testing.assert_allclose(got[4:], (u64[near].var(), v64[near].var()), rtol=1e-4,
                                       atol=1e-4)
    assert unclear <= 2


# ---------------------------------------------------------------------------- floor geometry


class _Camera:
    """What FloorProjection and IdealPixels read of a camera: a wide-angle lens as the
    KidSize renderer's, tilted down by ``pitch``, its lens ``position`` over the floor."""

    image_size = (752, 480)
    fx, fy, cx, cy = 330.0, 331.0, 375.5, 239.5
    distortion = np.array([-0.25, 0.06, 0.001, -0.001, 0.0])
    height = 0.45

    def __init__(self, pitch=0.5, roll=0.0, position=(0.0, 0.0)):
        self.pitch, self.roll = pitch, roll
        self.position = np.asarray(position, float)

    @property
    def camera_matrix(self):
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def rotation(self, pitch=None, roll=None):
        from stages.common.perspective_camera import head_rotation

        return head_rotation(0.0, self.pitch if pitch is None else pitch,
                             self.roll if roll is None else roll)

    def undistort_points(self, p):
        # a smooth stand-in for the Newton iterations (the tables are what is read)
        c = np.array([self.cx, self.cy])
        r2 = np.sum(((p - c) / self.fx) ** 2, axis=-1, keepdims=True)
        return c + (p - c) * (1 + 0.2 * r2)


def _oracle_args(cam, pitch=None, roll=None):
    return cam.rotation(pitch, roll), cam.camera_matrix, cam.height, cam.position


@pytest.mark.parametrize("position", [(0.0, 0.0), (0.03, -0.02)])
def test_floor_projection_equals_the_oracle(position):
    """FloorProjection (ideal pixels to the floor, and back: to_ideal) and below_horizon
    against the np.linalg oracle: floor points within 1e-12 (1 + range)^2 m (the error grows
    with the range r as r^2 / height near the horizon), pixels within
    1e-9 px; NaN (on or above the horizon, behind the camera) where the oracle has NaN, the
    horizon decided where the ray's height is clear of 0."""
    rng = np.random.default_rng(1)
    for pitch, roll in ((0.5, 0.0), (0.2, 0.05), (1.2, -0.1)):
        cam = _Camera(pitch, roll, position)
        proj = perspective.FloorProjection(cam, pitch, roll)
        args = _oracle_args(cam, pitch, roll)
        ideal = rng.uniform(-100, [852, 580], (5000, 2))
        got, ref = proj(ideal), geometry.to_floor(*args, ideal)
        ray_down = (proj.m @ np.c_[ideal, np.ones(len(ideal))].T)[2]
        clear = np.abs(ray_down) > 1e-6
        np.testing.assert_array_equal(np.isnan(got[clear]), np.isnan(ref[clear]))
        ok = clear & np.isfinite(ref).all(axis=1)
        assert ok.sum() > 500
        rng_m = np.hypot(*ref[ok].T)
        np.testing.assert_array_less(np.abs(got[ok] - ref[ok]).max(axis=1),
                                     1e-12 * (1 + rng_m) ** 2)
        back = proj.to_ideal(got[ok])
        np.testing.assert_allclose(back, geometry.to_ideal(*args, got[ok]), rtol=0, atol=1e-9)
        np.testing.assert_allclose(back, ideal[ok], rtol=0, atol=1e-6)  # a round trip
        shape = (480, 752)
        mask = perspective.below_horizon(cam, shape, 8, pitch, roll)
        centres = perspective.ideal_pixels(cam).cell_centres(shape, 8)
        down = np.isfinite(geometry.to_floor(*args, centres)).all(axis=1)
        height = (proj.m @ np.c_[centres, np.ones(len(centres))].T)[2]
        sure = np.abs(height) > 1e-9
        # exact decisions: below the horizon or not
        np.testing.assert_array_equal(mask.blocks.ravel()[sure], down[sure])


def test_ideal_pixels_interpolate_the_tables():
    """IdealPixels reads its undistortion tables bilinearly (the oracle, at the pixel over the
    table's stride), NaN beyond them and at NaN or infinite pixels: within 1e-9 px."""
    ideal = perspective.IdealPixels(_Camera())
    rng = np.random.default_rng(9)
    uv = rng.uniform(-10, [762, 490], (30000, 2))
    uv[200:3000] = np.round(uv[200:3000] * 2) / 2
    uv[:100] = np.nan
    uv[100:200, 0] = np.inf
    got = ideal(uv)
    with np.errstate(invalid="ignore"):
        p = uv / ideal.stride
    ref = np.stack([sampling.bilinear(m, p[:, 0], p[:, 1], np.nan)
                    for m in (ideal.map_u, ideal.map_v)], axis=1)
    nan = np.isnan(ref)
    assert nan.sum() > 200
    # exact decisions: NaN where the tables end
    np.testing.assert_array_equal(np.isnan(got), nan)
    np.testing.assert_allclose(got[~nan], ref[~nan], rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_width_ratios_equal_the_oracle(seed):
    """perspective.width_ratios (``_width_ratios``) against the oracle's per-line medians:
    for lines on the floor, partly and wholly beyond the horizon, of one run and many, with
    a lens over the floor's origin and beside it; within 1e-9 relative (a median picks the
    same run unless two runs' ratios lie within that of each other)."""
    from stages.extract.perspective import line_fit as lf

    rng = np.random.default_rng(seed)
    for position in ((0.0, 0.0), (0.03, -0.02)):
        cam = _Camera(0.5 + rng.normal(0, 0.1), 0.0, position)
        proj = perspective.FloorProjection(cam)
        refs = []
        for k in range(int(rng.integers(1, 12))):
            n = 1 if k == 0 and seed == 1 else int(rng.integers(2, 30))
            p = rng.uniform([0, 0], [752, 480], 2)
            q = p + rng.normal(0, 80, 2)
            t = np.sort(rng.uniform(0, 1, n))[:, None]
            centres = p * (1 - t) + q * t + rng.normal(0, 0.5, (n, 2))
            d = (q - p) / np.hypot(*(q - p))
            fit = lf.LineFit(centres.mean(axis=0), d, np.array([-d[1], d[0]]), 0.1)
            refs.append(lf.RefinedLine(np.array([p, q]), fit, centres, rng.uniform(1, 9, n)))
        got = perspective.width_ratios(refs, proj, 0.05)
        ref = geometry.width_ratios(refs, *_oracle_args(cam), 0.05)
        assert list(got) == [id(r) for r in refs]
        np.testing.assert_allclose(list(got.values()), ref, rtol=1e-9, atol=0)


def test_floor_lines_parameters_equal_the_oracle():
    from stages.extract.perspective import line_fit as lf

    rng = np.random.default_rng(2)
    p0, p1 = rng.normal(0, 3, (5000, 2)), rng.normal(0, 3, (5000, 2))
    p1[:20] = p0[:20]  # no length
    p1[20:40] = -p0[20:40] * rng.uniform(0.5, 2, (20, 1))  # through the robot
    got = np.stack(lf.floor_lines_parameters(p0, p1), axis=1)
    ref = np.array([geometry.floor_line_parameters(a, b) for a, b in zip(p0, p1)])
    # distances and lengths of metres within 1e-12 m, angles within 1e-9 rad away from the
    # robot (a foot 1e-3 m from it has a bearing good to 1e-13 / 1e-3 rad); through it, the
    # line's direction turned a quarter
    np.testing.assert_allclose(got[:, [0, 2]], ref[:, [0, 2]], rtol=0, atol=1e-12)
    far = ref[:, 0] > 1e-3
    assert far.sum() > 4900
    np.testing.assert_allclose(np.angle(np.exp(1j * (got[far, 1] - ref[far, 1]))), 0,
                               atol=1e-9)
    np.testing.assert_allclose(lf.floor_line_parameters(p0[30], p1[30]), ref[30], atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-3, 3), st.floats(-3, 3), st.floats(-3, 3),
       st.floats(-3, 3))
def test_rotating_the_robot_frame_rotates_the_floor_lines(turn, x0, y0, x1, y1):
    """The floor lines seen from a robot turned by ``turn`` keep their distance and length,
    and their perpendicular's bearing turns by -turn."""
    from stages.extract.perspective import line_fit as lf

    p0, p1 = np.array([[x0, y0]]), np.array([[x1, y1]])
    assume(np.hypot(x1 - x0, y1 - y0) > 1e-3)
    c, s = math.cos(turn), math.sin(turn)
    rot = np.array([[c, s], [-s, c]])  # the points in the turned robot's frame
    d0, a0, l0 = lf.floor_lines_parameters(p0, p1)
    d1, a1, l1 = lf.floor_lines_parameters(p0 @ rot.T, p1 @ rot.T)
    np.testing.assert_allclose([d1[0], l1[0]], [d0[0], l0[0]], rtol=1e-12, atol=1e-12)
    assume(d0[0] > 1e-6)  # a line through the robot has no foot to turn
    assert abs(np.angle(np.exp(1j * (a1[0] - a0[0] + turn)))) < 1e-9 / d0[0]


# ---------------------------------------------------------------------------- line fits


def test_line_fits_equal_the_major_axis():
    """line_fit.fit_line (``_fit_points``) is the oracle's major axis of the points' scatter:
    centroid within 1e-12 of the points' scale, direction (up to its sign) within 1e-9, rms
    residual within 1e-6 relative or 2e-8 of the points' spread; point_line_distance is the
    points' distance from it."""
    from stages.extract.perspective import line_fit as lf

    rng = np.random.default_rng(3)
    for _ in range(300):
        n = int(rng.integers(2, 60))
        a = rng.uniform(0, math.pi)
        t = rng.normal(0, rng.uniform(5, 50), n)
        pts = rng.normal(0, 200, 2) + t[:, None] * [math.cos(a), math.sin(a)] \
            + rng.normal(0, rng.uniform(0.01, 3), (n, 1)) * [-math.sin(a), math.cos(a)]
        fit = lf.fit_line(pts)
        c, u, rms = geometry.fit_line(pts)
        scale = np.abs(pts).max()
        np.testing.assert_allclose(fit.centroid, c, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(abs(float(fit.direction @ u)), 1.0, atol=1e-9)
        # (the rms from the scatter's smaller eigenvalue: sqrt(2^-52) of the points' spread)
        np.testing.assert_allclose(fit.rms, rms, rtol=1e-6, atol=2e-8 * np.ptp(pts, 0).max())
        np.testing.assert_allclose(lf.point_line_distance(pts, fit),
                                   np.abs((pts - c) @ [-u[1], u[0]]), rtol=0,
                                   atol=1e-9 * scale)


def test_similar_pairs_decide_as_the_oracle():
    """line_fit's merge test (``_similar_pairs``): parts within acos(cos_max) of each other's
    direction and with each one's ends within ``max_offset`` of the other's line, decided as
    the oracle (np.einsum) where both margins exceed 1e-9; the offsets within 1e-9 px."""
    from stages.extract.perspective import line_fit as lf

    def oracle(cen, dirs, nor, ends, rows, cos_max, max_offset, upper):
        cosine = np.abs(dirs[rows] @ dirs.T)
        to_i = np.abs(np.einsum("jkd,rd->rjk", ends, nor[rows])
                      - (cen[rows] * nor[rows]).sum(1)[:, None, None]).max(axis=2)
        to_j = np.abs(np.einsum("rkd,jd->rjk", ends[rows], nor)
                      - (cen * nor).sum(1)[None, :, None]).max(axis=2)
        off = np.maximum(to_i, to_j)
        margin = np.minimum(np.abs(cosine - cos_max), np.abs(off - max_offset))
        ok = (cosine >= cos_max) & (off <= max_offset)
        pairs = {}
        for a, i in enumerate(rows):
            for j in range(len(dirs)):
                if j != i and (i < j or not upper):
                    pairs[(int(i), j)] = (bool(ok[a, j]), float(off[a, j]), margin[a, j])
        return pairs

    rng = np.random.default_rng(6)
    found = unclear = 0
    for _ in range(500):
        n = int(rng.integers(2, 30))
        ang = np.repeat(rng.uniform(0, math.pi, 3), n)[:n] + rng.normal(0, 0.02, n)
        dirs = np.stack([np.cos(ang), np.sin(ang)], 1)
        nor = np.stack([-dirs[:, 1], dirs[:, 0]], 1)
        cen = rng.normal(0, 200, (n, 2))
        cen[n // 2:] = cen[:n - n // 2] + rng.normal(0, 3, (n - n // 2, 2))
        ends = cen[:, None, :] + (rng.uniform(20, 100, (n, 2)) * [-1, 1])[:, :, None] \
            * dirs[:, None, :]
        for rows, upper in ((np.arange(n), True), (np.array([n - 1]), False)):
            cos_max = math.cos(math.radians(4))
            got = {(i, j): off for off, i, j in lf._similar_pairs(cen, dirs, nor, ends, rows,
                                                                  cos_max, 7.0, upper)}
            for key, (ok, off, margin) in oracle(cen, dirs, nor, ends, rows, cos_max, 7.0,
                                                 upper).items():
                if margin < 1e-9:
                    unclear += 1
                    continue
                assert (key in got) == ok, key
                if ok:
                    np.testing.assert_allclose(got[key], off, rtol=0, atol=1e-9)
                    found += 1
    assert found > 100 and unclear <= 2


# ---------------------------------------------------------------------------- crossings


def test_corner_angles_equal_the_oracle():
    """crossing_kernels' ``_corner_angles`` (acos of the clipped cosine) against the oracle's atan2
    of cross and dot: within 1e-7 rad (acos near 0 and pi loses half the digits: sqrt(2^-52)
    is 1.5e-8), in the grid and on the floor where all three points are on it, for arms of
    no length, straight and folded back."""
    rng = np.random.default_rng(11)
    corners = rng.normal(0, 5, (3000, 3, 2))
    corners[:50, 1] = corners[:50, 0]  # an arm of no length
    corners[50:100, 2] = corners[50:100, 0] + 2.0 * (corners[50:100, 1] - corners[50:100, 0])
    corners[100:150, 2] = corners[100:150, 0] - (corners[100:150, 1] - corners[100:150, 0])
    floor = rng.normal(0, 2, corners.shape)
    floor[::7, rng.integers(0, 3)] = np.nan  # above the horizon
    for use_floor in (False, True):
        got = np.empty(len(corners))
        ck._corner_angles(corners, floor, use_floor, got)
        ref = [geometry.angle_between(*((f if use_floor and np.isfinite(f).all() else c)[1:]
                                        - (f if use_floor and np.isfinite(f).all() else c)[0]))
               for c, f in zip(corners, floor)]
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-7)


def test_points_along_interpolate_the_chains():
    """crossings.points_along: the point ``reach`` along each chain (by arc length, the last
    node when the chain is shorter), as np.interp over the chain's arc lengths; 1e-9 px."""
    rng = np.random.default_rng(4)
    pos = rng.uniform(0, 40, (80, 2))
    pos[10] = pos[9]  # a step of no length
    chains = [list(rng.integers(0, 80, int(rng.integers(1, 9)))) for _ in range(300)]
    chains += [[8, 9, 10, 11], [5]]
    for reach in (0.5, 4.0, 6.0):
        got = cr.points_along(pos, chains, reach)
        for g, ch in zip(got, chains):
            p = pos[ch]
            arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
            keep = np.concatenate([[True], np.diff(arc) > 0])  # np.interp wants rising arcs
            ref = [np.interp(reach, arc[keep], p[keep, k]) for k in range(2)]
            np.testing.assert_allclose(g, ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_placed_crossings_lie_where_the_white_lines_meet(seed):
    """crossings.place_crossing (``_place``) of L, T and X candidates drawn as white lines 5 px
    wide at right angles (L: within about 6 deg), five to seven nodes along each with 1.5 px
    noise: with the full-resolution mask the crossing lies within 1.5 px of where the drawn
    lines meet and each arm within 6 deg of its line; without it (the nodes' lines only)
    within a cell (8 px). A candidate without nodes on an arm is rejected as such."""
    import cv2

    rng = np.random.default_rng(seed)
    cell = 8
    cc = cr.CROSSINGS

    class Camera:  # what lens_parameters reads: no distortion, ideal = image pixels
        fx, fy, cx, cy = 330.0, 330.0, 375.5, 239.5
        distortion = np.zeros(5)

    placed, rejected = 0, set()
    for trial in range(60):
        kind = "LTX"[trial % 3]
        white = np.zeros((480, 752), np.uint8)
        centre = rng.uniform([150, 100], [600, 380])
        base = rng.uniform(0, 2 * math.pi)
        angles = {"L": [base, base + math.pi / 2 + rng.normal(0, 0.1)],
                  "T": [base, base + math.pi, base + math.pi / 2],
                  "X": [base + k * math.pi / 2 for k in range(4)]}[kind]
        nodes, chains = [centre], []
        for k, a in enumerate(angles):
            u = np.array([math.cos(a), math.sin(a)])
            cv2.line(white, tuple(int(round(v * 16)) for v in centre),
                     tuple(int(round(v * 16)) for v in centre + 120 * u), 1, 5, cv2.LINE_AA,
                     4)
            n = 0 if trial % 20 == 19 and k == 0 else int(rng.integers(5, 8))
            chains.append([0] + list(range(len(nodes), len(nodes) + n)))
            nodes += [centre + (j + 1) * cell * u + rng.normal(0, 1.5, 2) for j in range(n)]
        ideal = np.array(nodes)
        ideal[0] = centre + rng.normal(0, 3, 2)
        for white_px, tol in ((white, 1.5), (None, 8.0)):
            got = cr.place_crossing(kind, ideal[0], chains, ideal, cc, cell, white_px, Camera)
            if isinstance(got, str):
                rejected.add(got)
                continue
            placed += 1
            x, dirs, lengths = got
            assert np.hypot(*(x - centre)) <= tol, (kind, x, centre)
            if white_px is not None:
                want = np.array([[math.cos(a), math.sin(a)] for a in angles])
                assert np.all(np.sum(dirs * want, axis=1) >= math.cos(math.radians(6)))
            assert np.all(lengths >= cc.arm_step * cell)
    assert placed >= 110 and rejected == {"arm without nodes"}


def _floor_homography(rng):
    """floor_of of a random image -> floor homography of a camera looking down at the floor
    (NaN above the horizon), and its inverse (floor -> image)."""
    h = np.array([[0.01, 0.0, -3.0], [0.0, -0.002, 1.5], [0.0, 0.004, -0.5]])
    h = h + rng.normal(0, 2e-4, (3, 3))
    h_inv = np.linalg.inv(h)

    def apply(m, p):
        p = np.asarray(p, float).reshape(-1, 2)
        q = p @ m[:, :2].T + m[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(q[:, 2:] > 1e-9, q[:, :2] / q[:, 2:], np.nan)

    return (lambda p: apply(h, p)), (lambda f: apply(h_inv, f))


def _floor_shapes(rng, floor_of, to_image):
    """Fitted lines (N, 2, 2 ideal px) of L, T and X shapes on the floor, near misses,
    parallel and random lines, their widths, and their floor angles."""
    segs = []
    for _ in range(int(rng.integers(1, 5))):
        c = rng.uniform([0.5, -2.0], [5.0, 2.0])
        a = rng.uniform(0, math.pi)
        u = np.array([math.cos(a), math.sin(a)])
        v = np.array([-u[1], u[0]]) * (1 + rng.normal(0, 0.05))
        lo, hi = rng.uniform(-1.0, 0.3, 2), rng.uniform(-0.3, 1.0, 2)
        segs += [[c + lo[0] * u, c + hi[0] * u], [c + lo[1] * v, c + hi[1] * v]]
    for _ in range(int(rng.integers(0, 4))):
        segs.append(rng.uniform([0.3, -3.0], [6.0, 3.0], (2, 2)))
    ends = to_image(np.array(segs).reshape(-1, 2)).reshape(-1, 2, 2)
    ends = ends + rng.normal(0, 0.5, ends.shape)
    widths = rng.uniform(0, 6, len(ends))
    f = floor_of(ends.reshape(-1, 2)).reshape(-1, 2, 2)
    return ends, widths, np.arctan2(*(f[:, 1] - f[:, 0]).T[::-1])


@pytest.mark.parametrize("seed", range(3))
def test_pair_crossings_decide_as_the_oracle(seed):
    """crossings' ``_pair_crossings``: each pair of lines is a crossing (L or T) or not as the
    oracle (oracles.perspective_crossings) decides, where every threshold's margin exceeds
    1e-6 (rad, |sin| or px); the crossing point within 1e-6 px of the lines' intersection.
    Near-threshold pairs are counted: at most one in a thousand."""
    rng = np.random.default_rng(seed)
    floor_of, to_image = _floor_homography(rng)
    found, unclear, pairs = {2: 0, 3: 0}, 0, 0
    for _ in range(120):
        ends, widths, fang = _floor_shapes(rng, floor_of, to_image)
        n = len(ends)
        cap = n * (n - 1) // 2
        kinds, lines = np.empty(cap, np.int64), np.empty((cap, 2), np.int64)
        points, arms, lengths = np.empty((cap, 2)), np.empty((cap, 3, 2)), np.empty((cap, 3))
        m = ck._pair_crossings(ends, widths, fang, 12.0, math.radians(30.0), n, kinds, lines,
                               points, arms, lengths)
        got = {(int(i), int(j)): (int(k), p) for k, (i, j), p in zip(kinds[:m], lines[:m],
                                                                     points[:m])}
        for i in range(n):
            for j in range(i + 1, n):
                pairs += 1
                kind, point, margin = crossing_oracle.pair_crossing(
                    ends[i], ends[j], widths[i], widths[j], fang[i], fang[j], 12.0,
                    math.radians(30.0))
                if margin < 1e-6:
                    unclear += 1
                    continue
                assert ((i, j) in got) == (kind is not None), (i, j)
                if kind is not None:
                    assert got[(i, j)][0] == kind
                    np.testing.assert_allclose(got[(i, j)][1], point, rtol=0, atol=1e-6)
                    found[kind] += 1
    assert min(found.values()) >= 10 and unclear <= pairs / 1000, (found, unclear)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.randoms(use_true_random=False))
def test_permuting_the_lines_keeps_the_crossings(seed, shuffler):
    """The line pairs' crossings (``_pair_crossings``) are the same, of the same kinds and
    points (within 1e-9 px), whatever the order of the lines, and so are the crossings
    merge_line_crossings makes of them (within 1e-6 px: the merged point is a mean)."""
    rng = np.random.default_rng(seed)
    floor_of, to_image = _floor_homography(rng)
    ends, widths, fang = _floor_shapes(rng, floor_of, to_image)
    n = len(ends)
    order = list(range(n))
    shuffler.shuffle(order)

    def pairs(perm):
        cap = n * (n - 1) // 2
        kinds, lines = np.empty(cap, np.int64), np.empty((cap, 2), np.int64)
        points, arms, lengths = np.empty((cap, 2)), np.empty((cap, 3, 2)), np.empty((cap, 3))
        m = ck._pair_crossings(ends[perm], widths[perm], fang[perm], 12.0, math.radians(30.0),
                               n, kinds, lines, points, arms, lengths)
        return {frozenset((perm[i], perm[j])): (int(k), p)
                for k, (i, j), p in zip(kinds[:m], lines[:m], points[:m])}

    a, b = pairs(list(range(n))), pairs(order)
    assert a.keys() == b.keys()
    for key, (kind, point) in a.items():
        assert b[key][0] == kind
        np.testing.assert_allclose(b[key][1], point, rtol=0, atol=1e-9)
    merged = [cr.line_pair_crossings(e, w, floor_of, 12.0, math.radians(30.0))
              for e, w in ((ends, widths), (ends[order], widths[order]))]
    one, other = ({(c.kind, tuple(np.round(c.point, 6))) for c in m} for m in merged)
    assert len(merged[0]) == len(merged[1])
    for kind, point in one:  # the same crossings: kinds alike, points within 1e-6 px
        assert any(k == kind and math.dist(p, point) <= 1e-6 for k, p in other), (kind, point)


def test_distinct_arms_decide_as_the_oracle():
    """crossing_kernels._distinct_arms (merge_line_crossings' arms of a group): an arm within
    acos(cos_same) of a kept arm joins the first such (its length the larger), else it is
    kept; as a Python loop decides, where the cosines are further than 1e-12 from cos_same
    (arms drawn about ``same_arm`` apart); such close calls are counted, not failed."""
    rng = np.random.default_rng(21)
    cos_same = math.cos(math.radians(20.0))
    close = 0
    for _ in range(3000):
        n = int(rng.integers(1, 9))
        ang = rng.choice([0.0, math.radians(20.0), math.pi / 2, math.pi], n) \
            + rng.normal(0, 1e-3, n) * rng.integers(0, 2, n)
        cmp = np.stack([np.cos(ang), np.sin(ang)], axis=1) * rng.uniform(0.5, 2, (n, 1))
        lengths = rng.uniform(0, 50, n)
        lengths[rng.random(n) < 0.1] = np.nan
        cos = cmp @ cmp.T
        if np.any(np.abs(cos - cos_same) < 1e-12):
            close += 1
            continue
        arms, kept = [], []
        for k, ln in enumerate(lengths):
            same = [m for m, j in enumerate(arms) if cos[k, j] >= cos_same]
            if same:
                kept[same[0]] = max(kept[same[0]], float(ln))
            else:
                arms.append(k)
                kept.append(float(ln))
        got_arms, got_len = np.empty(n, np.int64), np.empty(n)
        m = ck._distinct_arms(cmp, lengths, cos_same, got_arms, got_len)
        assert got_arms[:m].tolist() == arms
        np.testing.assert_allclose(got_len[:m], kept, rtol=0, atol=0)  # lengths chosen
    assert close <= 30


# ---------------------------------------------------------------------------- line structure


def test_subpixel_positions_are_the_windows_centroids():
    """subpixel_positions: each node pixel moved to its 3 x 3 window's grey-weighted centroid
    (0 outside the image; no move for an empty window), within 1e-12 px."""
    rng = np.random.default_rng(5)
    for dtype in (np.float32, np.float64):
        image = rng.uniform(0, 1, (30, 40)).astype(dtype)
        image[rng.uniform(size=image.shape) < 0.3] = 0
        image[10:13, 10:13] = 0
        pix = np.concatenate([rng.integers(0, [40, 30], (300, 2)), [[0, 0], [39, 29], [11, 11]]])
        pad = np.pad(image.astype(np.float64), 1)
        offs = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
        w = pad[pix[:, 1:2] + 1 + offs[None, :, 1], pix[:, 0:1] + 1 + offs[None, :, 0]]
        total = np.where(w.sum(axis=1) > 0, w.sum(axis=1), 1.0)
        ref = pix + (w[:, :, None] * offs[None]).sum(axis=1) / total[:, None]
        np.testing.assert_allclose(ls.subpixel_positions(image, pix), ref, rtol=0, atol=1e-12)


def test_smooth_lines_average_each_inner_node_with_its_neighbours():
    rng = np.random.default_rng(13)
    for _ in range(300):
        n = int(rng.integers(1, 80))
        adj = [set() for _ in range(n)]
        for _ in range(int(rng.integers(0, 2 * n))):
            a, b = (int(v) for v in rng.integers(0, n, 2))
            if a != b:
                adj[a].add(b)
                adj[b].add(a)
        graph = ls.LineGraph(np.zeros((n, 2), int), rng.normal(0, 10, (n, 2)), np.ones(n), adj)
        idx = np.nonzero(graph.degree() == 2)[0]
        for rounds in (0, 1, 3):
            ref = graph.pos.copy()
            if len(idx):
                nb = np.array([sorted(graph.adj[i]) for i in idx])
                for _ in range(rounds):
                    ref[idx] = (ref[idx] + ref[nb[:, 0]] + ref[nb[:, 1]]) / 3.0
            np.testing.assert_allclose(ls.smooth_lines(graph, rounds), ref, rtol=0,
                                       atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.floats(-math.pi, math.pi))
def test_turning_angles_do_not_change_when_the_chains_turn(seed, turn):
    """turning_angles (per node, the angle between the chain's direction ``reach`` behind and
    ahead) of chains turned and shifted as a whole are the same within 1e-9 rad; a straight
    chain does not turn, a right-angled one turns by pi/2 at its corner."""
    rng = np.random.default_rng(seed)
    pos = np.cumsum(rng.normal(0, 1.5, (60, 2)), axis=0)
    chains = [list(rng.integers(0, 60, int(rng.integers(2, 12))))
              for _ in range(int(rng.integers(1, 10)))]
    c, s = math.cos(turn), math.sin(turn)
    turned = pos @ np.array([[c, s], [-s, c]]) + rng.normal(0, 100, 2)
    a, b = ls.turning_angles(chains, pos, 3.0)[0], ls.turning_angles(chains, turned, 3.0)[0]
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    line = np.array([[k, 0.0] for k in range(8)] + [[7.0, k] for k in range(1, 8)])
    line = line @ np.array([[c, s], [-s, c]])
    straight = ls.turning_angles([list(range(8))], line, 3.0)[0]
    np.testing.assert_allclose(straight, 0.0, atol=1e-6)
    corner = ls.turning_angles([list(range(15))], line, 1.0)[0]
    np.testing.assert_allclose(corner[7], math.pi / 2, atol=1e-6)


def test_trace_chains_cover_every_connection_once():
    """trace_chains: every connection of the graph lies on exactly one chain, each chain is a
    walk along connections whose inner nodes have two neighbours, and a ring closes on its
    first node."""
    rng = np.random.default_rng(15)
    rings = 0
    for _ in range(500):
        n = int(rng.integers(1, 120))
        adj = [set() for _ in range(n)]
        k = 0
        while k < n - 1:  # polylines, some closed into rings
            length = int(rng.integers(1, 10))
            for a in range(k, min(k + length, n - 1)):
                adj[a].add(a + 1)
                adj[a + 1].add(a)
            if rng.random() < 0.2 and length > 2 and k + length < n:
                adj[k].add(k + length)
                adj[k + length].add(k)
            k += length + 1
        for _ in range(int(rng.integers(0, n // 4 + 1))):  # junctions
            a, b = (int(v) for v in rng.integers(0, n, 2))
            if a != b:
                adj[a].add(b)
                adj[b].add(a)
        graph = ls.LineGraph(np.zeros((n, 2), int), np.zeros((n, 2)), np.ones(n), adj)
        seen = []
        for chain in ls.trace_chains(graph):
            assert len(chain) >= 2
            assert all(len(adj[i]) == 2 for i in chain[1:-1])
            seen += [frozenset(e) for e in zip(chain[:-1], chain[1:])]
            rings += chain[0] == chain[-1]
        assert sorted(map(sorted, seen)) == sorted(
            sorted((i, j)) for i in range(n) for j in adj[i] if i < j)
    assert rings > 10


def test_remove_triangles_cuts_the_longest_side_of_each():
    """remove_triangles leaves no triangle, and each connection it removes was the longest
    side of a triangle of the graph."""
    rng = np.random.default_rng(6)
    for _ in range(20):
        n = 40
        pos = rng.uniform(0, 8, (n, 2))
        adj = [set() for _ in range(n)]
        for _ in range(int(rng.integers(60, 160))):
            a, b = (int(v) for v in rng.integers(0, n, 2))
            if a != b:
                adj[a].add(b)
                adj[b].add(a)
        graph = ls.LineGraph(np.zeros((n, 2), int), pos, np.ones(n), [set(a) for a in adj])
        ls.remove_triangles(graph)
        left = graph.adj
        assert all(not (left[i] & left[j]) for i in range(n) for j in left[i])
        removed = {(i, j) for i in range(n) for j in adj[i] - left[i] if i < j}
        assert removed and all(left[i] <= adj[i] for i in range(n))
        d = np.hypot(*(pos[:, None, :] - pos[None, :, :]).transpose(2, 0, 1))
        for i, j in removed:
            assert any(d[i, j] >= max(d[i, k], d[j, k]) - 1e-12 for k in adj[i] & adj[j])


@pytest.mark.parametrize("seed", range(3))
def test_filled_gaps_join_loose_ends_nearby(seed):
    """fill_gaps only adds connections, each from a node that had at most one neighbour to a
    node within ``max_gap``, none of them making a node of more than four."""
    rng = np.random.default_rng(seed)
    added = 0
    for _ in range(20):
        image = (rng.random((30, 40)) ** 2).astype(np.float32)
        graph = _random_graph(rng, int(rng.integers(20, 90)))
        before = [set(a) for a in graph.adj]
        ls.fill_gaps(graph, image, 6.0, math.cos(math.radians(30)), 0.25, 4.0)
        for i, (a, b) in enumerate(zip(before, graph.adj)):
            assert a <= b and len(b) <= 4
            for j in b - a:
                assert len(before[i]) <= 1 or len(before[j]) <= 1
                assert np.hypot(*(graph.pos[i] - graph.pos[j])) <= 6.0 + 1e-9
                added += 1
    assert added > 20


def test_connect_nodes_links_the_touching_regions():
    """connect_nodes: nodes whose regions touch (8-neighbourhood) are linked, the others not
    (np.unique of the neighbouring labels)."""
    rng = np.random.default_rng(4)
    n = 150
    regions = rng.integers(0, n + 1, (40, 60)).astype(np.int32)
    regions[rng.uniform(size=regions.shape) < 0.6] = 0
    r, pairs = regions, set()
    for a, b in ((r[:, :-1], r[:, 1:]), (r[:-1, :], r[1:, :]),
                 (r[:-1, :-1], r[1:, 1:]), (r[:-1, 1:], r[1:, :-1])):
        m = (a > 0) & (b > 0) & (a != b)
        pairs |= {(int(x) - 1, int(y) - 1) for x, y in zip(a[m], b[m])}
    got = ls.connect_nodes(regions, n)
    assert sum(map(len, got)) > 100
    assert got == [{j for i2, j in pairs if i2 == i} | {i2 for i2, j in pairs if j == i}
                   for i in range(n)]


def test_farthest_pairs_are_as_far_apart_as_any():
    """_farthest_pairs (split_isolated_nodes): per region, two of its pixels at its largest
    pixel distance (ties: any such pair); -1 for a region of one pixel."""
    rng = np.random.default_rng(1)
    counts = rng.integers(1, 10, 30)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    xs = rng.integers(0, 4, start[-1]).astype(np.int64)
    ys = rng.integers(0, 4, start[-1]).astype(np.int64)
    lonely = np.sort(rng.choice(30, 20, replace=False)).astype(np.int64)
    got = lsk._farthest_pairs(xs, ys, start, lonely)
    for k, i in enumerate(lonely):
        px = np.stack([xs[start[i]:start[i + 1]], ys[start[i]:start[i + 1]]], axis=1)
        if len(px) < 2:
            assert (got[k] == -1).all()
            continue
        d2 = ((px[:, None, :] - px[None, :, :]) ** 2).sum(-1)
        a, b = got[k, :2], got[k, 2:]
        assert any((a == p).all() for p in px) and any((b == p).all() for p in px)
        assert int(((a - b) ** 2).sum()) == d2.max()
