"""Issue 9's compiled kernels of the perspective chain give what the numpy and Python code
they replaced computed, exactly (the features must not change: see also
test_extract_perspective_unchanged.py), on random inputs beyond the reference frames:

- colour.classify_cells (``_hue_row``, ``_hue_cells``) against the per-pixel class masks,
  its ``_threshold_table`` against luminance_thresholds;
- colour's ``_fill_blocks`` (the local green map's gaps) against cv2.boxFilter and np.where;
- colour's ``_hue_block_sums`` and ``_sample_rows`` (the local green map's and the field
  green search's samples) against numpy's masks and strided copies;
- colour's ``_green_candidates`` against the field green search's numpy formulas, its
  ``_histogram_peak`` (the blurred chroma histogram's peak) against cv2.GaussianBlur and
  np.argmax, ``_green_cluster`` (mean shift, cluster median and variances) and
  ``_hue_turned`` and ``_hue_spread`` (the hue model's offsets and medians) against the numpy
  expressions they replaced, and
  ``pairwise_sum32`` against numpy's float32 sum;
- line_fit's ``floor_lines_parameters`` (all lines at once, compiled: ``_perpendicular_feet``)
  against floor_line_parameters,
  its ``row_dots`` against numpy's 1-D ``@`` (a dot of two 2-vectors is not the sum of
  their products to the bit);
- line_fit's ``refine_segments`` (all segments refined in one call) against refine_segment;
- line_fit's ``_similar_kernel`` (the merge's similar pairs) against its former einsums;
- line_fit's ``split_components`` and ``part_fits`` (all components split and fitted in one
  pass) against split_component, fit_line and the end points per part;
- field_boundary's ``_grey_field`` (the merged grey image binarised) against
  merged_grey_image, binarize_field and its cv2.boxFilter;
- field_boundary's ``_column_heights`` (field_height_histogram) and its median windows
  against the former cumulative-sum scan and sliding_window_view;
- goal_posts' ``_white_runs`` (bar_runs, with the columns' first field rows) against numpy;
- goal_posts' ``_opening`` (rise_above_surroundings) against cv2.morphologyEx;
- goal_posts' ``_standing_bars`` (standing_bars) against the former numpy runs and
  per-group checks, its ``_bar_share`` (is_post_bar's width) against the former numpy;
- goal_posts' ``_stands_out`` and ``bar_width`` (slices, the compiled median) against their
  former fancy-indexed numpy;
- crossings' ``_points_along`` (the candidates' arm points) against its former Python walk,
  its ``_corner_angles`` (the L candidates' angles) against the former _angle_between;
- crossings' ``_place`` (place_crossing: a candidate's arm lines fitted, refined and cut)
  against the former arm_lines, _refined_arm and crossing_point;
- perspective's ``_width_ratios`` (width_ratios) against its former numpy (BLAS's product
  of the inverse projection: fused multiply-adds, see exact_ops);
- perspective's ``_look_up`` (IdealPixels, exact_ops.remap_at) against cv2.remap;
- crossings' ``_pair_crossings`` (line_pair_crossings) against its former numpy and Python,
  its ``_distinct_arms`` (merge_line_crossings) against the former Python loop;
- crossings' ``_floor_checks`` and ``_image_checks`` (_verify_crossing, with the compiled
  ``_alternative_in_view`` and its ``_remap_sample``) against the former Python and numpy
  verification and cv2.remap;
- line_structure's ``_skeleton_grid`` (the inside, low-pass, ranking keys and skeleton of
  white shares) against white_inside_boundary, cv2's low_pass and the ranking functions;
- line_structure's ``_corner_cuts`` (every chain's corner_nodes at once) against corner_nodes;
- line_structure's ``_trace`` (trace_chains) against its former Python walk;
- line_structure's ``_nodes_by_priority`` (place_nodes) against its former numpy sort;
- line_structure's ``_smooth_chains`` (smooth_lines) against its former numpy rounds;
- line_structure's ``_turn_cosines`` (turning_angles) against its former numpy expressions;
- line_structure's ``_triangle_cuts`` (remove_triangles) against its former Python loop;
- line_structure's ``_gap_choice`` (fill_gaps' ratios, order and greedy choice) against
  the former Python;
- line_structure's ``_gap_candidates`` (fill_gaps) against its former Python loop, its
  ``_gap_grey`` (the gaps' grey level) against cv2.remap;
- line_structure's ``_farthest_pairs`` (split_isolated_nodes) against np.argmax of the
  regions' distance matrices;
- field_boundary's ``_fill_bounded_runs`` (fill_lines) and ``_window_middles``
  (smooth_field_heights' median) against the former numpy;
- line_structure's ``_path_length`` (a chain's length) against numpy's sum of np.hypot steps;
- the flat neighbour lists line_structure's kernels leave with a graph (``_short_spurs``,
  ``_triangle_cuts``, ``_linked_lists``) against the graph's sets.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from stages.common import colour
from stages.extract import line_structure as ls
from stages.extract import perspective


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
    conf = perspective.confs["default"]["colour"]
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
    np.testing.assert_array_equal(counts, colour._counts(green, white, cell))
    np.testing.assert_array_equal(white_px[:hb * cell].view(bool), white[:hb * cell])
    assert not white_px[hb * cell:].any()  # rows below the last whole cell are not classified
    assert counts[..., 0].sum() > 100 and counts[..., 1].sum() > 100  # both classes occur
    assert colour.classify_cells(yuv, fc, conf, cell) is not None  # without the white mask


def test_threshold_table_equals_luminance_thresholds():
    conf = perspective.confs["default"]["colour"]
    rng = np.random.default_rng(7)
    for _ in range(50):
        y_map = rng.uniform(-5, 300, (60, 94)).astype(np.float32)
        y_map[0, :6] = [0.0, 255.0, 256.0, 1e-3, 200.5, 100.0 / 0.35]
        out = np.empty(y_map.shape + (3,), np.int16)
        colour._threshold_table(y_map, np.float32(conf["white_contrast"]),
                                np.float32(conf["white_min_y"]),
                                np.float32(conf["green_min_ratio"]),
                                np.float32(conf["green_max_ratio"]), out)
        np.testing.assert_array_equal(out, colour.luminance_thresholds(y_map, conf))


@pytest.mark.parametrize("seed,shape", [(0, (480, 752)), (1, (483, 645))])
def test_green_samples_equal_the_numpy_masks(seed, shape):
    rng = np.random.default_rng(seed)
    yuv = _random_frame(rng, *shape)
    conf = perspective.confs["default"]["colour"]
    fc = colour.estimate_field_colour(yuv, conf)
    assert fc.hue_dir is not None
    cell, step = fc.cell, fc.cell // 2
    hb, wb = shape[0] // cell, shape[1] // cell
    valid = rng.random((hb * 2, wb * 2)) < 0.8
    gs = np.zeros((hb, wb), np.float32)
    ys = np.zeros((hb, wb), np.float32)
    lo_s, hi_s = (np.float32(v_) ** 2 for v_ in fc.saturation)
    colour._hue_block_sums(yuv, step, 2, hb, wb, valid, True, np.float32(fc.hue_dir[0]),
                           np.float32(fc.hue_dir[1]), np.float32(np.float32(fc.hue_cos) ** 2),
                           lo_s, hi_s, 30, 220, gs, ys)
    y, u, v = (np.ascontiguousarray(yuv[:hb * cell:step, :wb * cell:step, c]) for c in range(3))
    green, _ = colour._chroma_tests(y, u, v, fc, conf, white=False)
    green &= (y >= 30) & (y <= 220) & valid
    ref_g = green.reshape(hb, 2, wb, 2).sum(axis=(1, 3)).astype(np.float32)
    ref_y = (y * green).reshape(hb, 2, wb, 2).sum(axis=(1, 3)).astype(np.float32)
    np.testing.assert_array_equal(gs, ref_g)
    np.testing.assert_array_equal(ys, ref_y)
    assert ref_g.sum() > 100
    mask = rng.random((-(-shape[0] // 6), -(-shape[1] // 6))) < 0.7
    np.testing.assert_array_equal(colour._sample_pixels(yuv, 6, mask), yuv[::6, ::6][mask])
    np.testing.assert_array_equal(colour._sample_pixels(yuv, 6, None),
                                  yuv[::6, ::6].reshape(-1, 3))


@pytest.mark.parametrize("seed", range(4))
def test_green_candidates_equal_the_numpy_formulas(seed):
    rng = np.random.default_rng(seed)
    sub = rng.integers(0, 256, (5000, 3)).astype(np.uint8)
    sub[:2000, 1:] = np.clip(rng.normal(110, 10, (2000, 2)), 0, 255)
    chroma = colour._green_candidate_chroma((-170.0, -75.0), 6.0)
    y_lo, y_hi, min_sat = int(rng.integers(0, 40)), int(rng.integers(200, 256)), 0.15
    y_c, u_c, v_c, uu, vv, hist = colour._green_candidates(sub, chroma, y_lo, y_hi, True,
                                                           np.float32(min_sat * min_sat))
    y8, u8, v8 = sub[:, 0], sub[:, 1], sub[:, 2]
    cand = chroma[(u8.astype(np.int64) << 8) | v8] & (y8 >= y_lo) & (y8 <= y_hi)
    du, dv = u8.astype(np.float32) - np.float32(128.0), v8.astype(np.float32) - np.float32(128.0)
    cand &= du * du + dv * dv >= np.float32(min_sat * min_sat) * (y8.astype(np.float32) ** 2)
    assert cand.sum() > 100
    np.testing.assert_array_equal(y_c, y8[cand])
    np.testing.assert_array_equal(u_c, u8[cand])
    np.testing.assert_array_equal(v_c, v8[cand])
    scale = colour.Y_REF / np.maximum(y8[cand].astype(np.float32), 1.0)
    ref_u = (u8[cand].astype(np.float32) - 128.0) * scale
    ref_v = (v8[cand].astype(np.float32) - 128.0) * scale
    np.testing.assert_array_equal(uu, ref_u)
    np.testing.assert_array_equal(vv, ref_v)
    bins = (np.clip(ref_u + 128.0, 0, 255).astype(np.int32) >> 3) * 32 + (
        np.clip(ref_v + 128.0, 0, 255).astype(np.int32) >> 3)
    np.testing.assert_array_equal(hist, np.bincount(bins, minlength=1024))


def test_filled_green_map_equals_the_box_filter_expressions():
    import cv2

    class Frame:
        y = 0.0

    rng = np.random.default_rng(12)
    for _ in range(1000):
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
            assert got.tobytes() == ref.astype(np.float32).tobytes()


def test_histogram_peak_equals_the_blurred_argmax():
    import cv2

    rng = np.random.default_rng(9)
    for k in range(4000):
        if k % 3 == 0:
            counts = rng.integers(0, 3000, (32, 32))
        elif k % 3 == 1:  # sparse: ties and borders
            counts = (rng.random((32, 32)) < 0.05) * rng.integers(0, 5, (32, 32))
        else:
            counts = np.zeros((32, 32), np.int64)
            counts[rng.integers(0, 32), rng.integers(0, 32)] = rng.integers(0, 9000)
        blurred = cv2.GaussianBlur(counts.astype(np.float32), (3, 3), 0)
        peak = np.unravel_index(int(np.argmax(blurred)), blurred.shape)
        assert colour._histogram_peak(counts.astype(np.int64)) == tuple(int(v) for v in peak)


def _reference_cluster(uu, vv, y_c, nu, nv, rad2):
    """The field green search's mean shift and cluster statistics as numpy computed them."""
    for _ in range(3):
        near = (uu - nu) ** 2 + (vv - nv) ** 2 <= rad2
        if not near.any():
            break
        nu, nv = float(uu[near].mean()), float(vv[near].mean())
    near = (uu - nu) ** 2 + (vv - nv) ** 2 <= rad2
    if not near.any():
        return nu, nv, 0, None, None
    n = int(near.sum())
    cum = np.cumsum(np.bincount(y_c[near], minlength=256))
    lo, hi = np.searchsorted(cum, [(n - 1) // 2 + 1, n // 2 + 1])
    spread = float(np.sqrt(0.5 * (uu[near].var() + vv[near].var())))
    return nu, nv, n, 0.5 * (float(lo) + float(hi)), spread


@pytest.mark.parametrize("seed", range(6))
def test_green_cluster_equals_the_numpy_mean_shift(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 20000))
    y_c = rng.integers(0, 256, n).astype(np.uint8)
    centre = rng.uniform(-40, 10, 2)
    uu = (rng.normal(centre[0], rng.uniform(2, 20), n)).astype(np.float32)
    vv = (rng.normal(centre[1], rng.uniform(2, 20), n)).astype(np.float32)
    for start in (centre + rng.normal(0, 8, 2), centre + 100.0):  # the second finds none
        nu, nv = (float(np.round(c / 8.0) * 8.0 + 4.0) for c in start)
        ref = _reference_cluster(uu, vv, y_c, nu, nv, 196.0)
        got_u, got_v, m, y_med, var_u, var_v = colour._green_cluster(uu, vv, y_c, nu, nv,
                                                                     196.0, 3)
        assert (got_u, got_v, m) == ref[:3]
        if m:
            spread = float(np.sqrt(np.float32(0.5) * (np.float32(var_u) + np.float32(var_v))))
            assert (y_med, spread) == ref[3:]


@pytest.mark.parametrize("n", [1, 2, 7, 8, 9, 127, 128, 129, 300, 6121, 8193, 20000])
def test_float32_sums_and_medians_are_numpys(n):
    rng = np.random.default_rng(n)
    for _ in range(40):
        a = (rng.normal(size=n) * 10.0 ** rng.integers(-3, 4)).astype(np.float32)
        assert colour.pairwise_sum32(a) == a.sum()
        assert colour._mean32(a) == a.mean() and colour._var32(a) == a.var()
    # the hue model's statistics of random candidates around a random field direction
    u8, v8, y8 = (rng.integers(0, 256, n).astype(np.uint8) for _ in range(3))
    angle = rng.uniform(-math.pi, math.pi)
    hx, hy = math.cos(angle), math.sin(angle)
    du, dv = u8.astype(np.float32) - 128.0, v8.astype(np.float32) - 128.0
    num, den = colour._hue_turned(u8, v8, np.float32(hx), np.float32(hy))
    assert num.tobytes() == (dv * hx - du * hy).tobytes()
    assert den.tobytes() == (du * hx + dv * hy).tobytes()
    d = np.arctan2(num, den)
    m, med_d, med_sat = colour._hue_spread(d, u8, v8, y8, np.float32(math.radians(45.0)))
    near = np.abs(d) <= math.radians(45.0)
    assert m == near.sum()
    if m:
        assert med_d == float(np.median(np.abs(d[near])))
        assert med_sat == float(np.median(np.hypot(du[near], dv[near]) / np.maximum(
            y8[near].astype(np.float32), 1.0)))


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
            assert colour._median32(padded, n) == float(np.median(a))


def _reference_point_along(pos, chain, reach):
    """crossings.point_along as Python computed it (np.hypot steps, arcs summed in order,
    bisect)."""
    import bisect

    p = pos[chain]
    seg = np.hypot(*np.diff(p, axis=0).T).tolist()
    s = [0.0]
    for length in seg:
        s.append(s[-1] + length)
    if s[-1] <= reach:
        return p[-1].copy()
    k = bisect.bisect_left(s, reach)
    t = (reach - s[k - 1]) / max(seg[k - 1], 1e-9)
    return p[k - 1] + t * (p[k] - p[k - 1])


@pytest.mark.parametrize("seed", range(4))
def test_points_along_equal_the_python_walk(seed):
    from stages.extract import crossings

    rng = np.random.default_rng(seed)
    pos = rng.uniform(0, 40, (80, 2))
    pos[10] = pos[9]  # a step of zero length
    pos[40:44] = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 1.0], [3.0, 1.0]])  # exactly 4 long
    chains = [list(rng.integers(0, 80, int(rng.integers(1, 9)))) for _ in range(200)]
    chains += [[8, 9, 10, 11], [40, 41, 42, 43], [40, 41, 42], [5]]
    for reach in (0.5, 4.0, 6.0):
        got = crossings.points_along(pos, chains, reach)
        ref = np.array([_reference_point_along(pos, ch, reach) for ch in chains])
        assert got.tobytes() == ref.tobytes()


@pytest.mark.parametrize("seed", range(4))
def test_split_components_and_part_fits_equal_the_per_part_functions(seed):
    from stages.extract import line_fit as lf

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
        np.testing.assert_array_equal(a, b)
    fits, ends = lf.part_fits(points, got)
    for p, f, e in zip(got, fits, ends):
        fit = lf.fit_line(points[p])
        assert f.tolist() == [*fit.centroid, *fit.direction, *fit.normal, fit.rms]
        assert e.tobytes() == lf.line_end_points(points, p, fit).tobytes()


def test_grey_field_equals_the_numpy_and_opencv_binarisation():
    from stages.extract import field_boundary as fb

    conf = perspective.confs["default"]["boundary"]
    rng = np.random.default_rng(18)
    by_window = 0
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
        grey = fb.merged_grey_image(counts, conf["weights"], 64.0)
        ref = fb.binarize_field(grey, conf["t_pix"], conf["t_row"], conf["t_win"],
                                conf["t_weak"])
        got = fb.grey_field(counts, conf["weights"], 64.0, conf["t_pix"], conf["t_row"],
                            conf["t_win"], conf["t_weak"])
        np.testing.assert_array_equal(got, ref)
        by_window += int((ref & (grey < conf["t_pix"])).sum())
    assert by_window > 1000  # weak cells taken by their row or window


def _reference_field_heights(field, max_gap, from_lowest):
    """field_height_histogram as numpy computed it: cumulative sums of the empty rows."""
    h, w = field.shape
    run = max_gap + 1
    if from_lowest:
        at_or_below = np.logical_or.accumulate(field[::-1], axis=0)[::-1]
        field = field | (~at_or_below & field.any(axis=0)[None, :])
    empty = np.concatenate([~field[::-1], np.ones((run, w), bool)], axis=0)
    c = np.concatenate([np.zeros((1, w), np.int32), np.cumsum(empty, axis=0, dtype=np.int32)])
    return np.argmax((c[run:] - c[:-run]) == run, axis=0).astype(np.float64)


def test_field_heights_and_their_smoothing_equal_the_numpy_scan():
    from stages.extract import field_boundary as fb

    rng = np.random.default_rng(5)
    for _ in range(500):
        h, w = int(rng.integers(1, 70)), int(rng.integers(1, 100))
        field = rng.random((h, w)) < rng.random()
        for max_gap in (0, 2, 4):
            for from_lowest in (False, True):
                np.testing.assert_array_equal(
                    fb.field_height_histogram(field, max_gap, from_lowest),
                    _reference_field_heights(field, max_gap, from_lowest))
        heights = rng.integers(0, h + 1, w).astype(float)
        for size in (3, 5):
            r = size // 2
            windows = np.lib.stride_tricks.sliding_window_view(fb._edge_padded(heights, r),
                                                               size)
            np.testing.assert_array_equal(fb.smooth_field_heights(heights, 0.0, size),
                                          np.sort(windows, axis=1)[:, r])


def _reference_bounded_runs(cand, bound, max_run):
    """The runs of ``cand`` along each row, at most ``max_run`` long, bounded on both sides."""
    out = np.zeros(cand.shape, bool)
    for r in range(cand.shape[0]):
        row = np.concatenate([[False], cand[r], [False]]).astype(int)
        starts = np.nonzero(np.diff(row) == 1)[0]
        ends = np.nonzero(np.diff(row) == -1)[0]
        for s, e in zip(starts, ends):
            if e - s <= max_run and s > 0 and e < cand.shape[1] and bound[r, s - 1] \
                    and bound[r, e]:
                out[r, s:e] = True
    return out


def test_fill_lines_and_the_smoothing_equal_the_former_numpy():
    """field_boundary.fill_lines (``_fill_bounded_runs``: rows and columns in one pass) adds
    the bounded white runs the former numpy added; smooth_field_heights (its Gaussian made
    once, ``_window_middles``) gives the former convolution and sorted windows."""
    from stages.extract import field_boundary as fb

    rng = np.random.default_rng(8)
    for _ in range(300):
        h, w = int(rng.integers(1, 40)), int(rng.integers(1, 60))
        field = rng.random((h, w)) < rng.random()
        white = (rng.integers(0, 65, (h, w)) / 64.0).astype(np.float32)
        for t_white, max_run in ((0.3, 10), (0.5, 2)):
            cand = (white >= t_white) & ~field
            ref = field | _reference_bounded_runs(cand, field, max_run) \
                | _reference_bounded_runs(cand.T, field.T, max_run).T
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
            assert got.dtype == ref.dtype and got.tobytes() == ref.tobytes()


def test_bar_runs_equal_the_numpy_start_rows_and_walks():
    import warnings

    from stages.extract import goal_posts as gp

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
            np.testing.assert_array_equal(got, ref)


def test_surroundings_opening_equals_opencvs():
    import cv2

    from stages.extract import goal_posts as gp

    rng = np.random.default_rng(17)
    for _ in range(5000):
        n, window = int(rng.integers(1, 120)), int(rng.integers(1, 14))
        up = (rng.integers(0, 31, n) * (rng.random(n) < rng.random())).astype(np.int64)
        base = cv2.morphologyEx(up.astype(np.float32)[None, :], cv2.MORPH_OPEN,
                                np.ones((1, window), np.uint8),
                                borderType=cv2.BORDER_REPLICATE)[0]
        excess, got = gp.rise_above_surroundings(up, window)
        np.testing.assert_array_equal(got, np.round(base).astype(int))
        np.testing.assert_array_equal(excess, up - got)


def test_post_bar_checks_equal_the_fancy_indexed_numpy():
    from stages.extract import goal_posts as gp

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
            assert gp.bar_width(white, group, start, rise, cell) == width


def test_bar_share_equals_the_former_numpy():
    """goal_posts._bar_share (is_post_bar's white across a bar) gives the former numpy's
    median of the summed shares, at grid points rounded half to even and clipped."""
    from stages.extract import goal_posts as gp

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
        assert got == ref


def test_standing_bars_equal_the_former_groups_and_checks():
    """goal_posts.standing_bars (``_standing_bars``) gives the groups the former numpy runs
    (post_columns) and per-group _stands_out kept, and their lifts."""
    from stages.extract import goal_posts as gp

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


def test_key_incidence_equals_incident_per_node():
    rng = np.random.default_rng(3)
    edges = [(int(a), int(b), [int(a)] + list(rng.integers(0, 99, 3)) + [int(b)])
             for a, b in rng.integers(0, 12, (30, 2))]
    edges.append((4, 4, [4, 50, 51, 4]))  # a ring at a node
    ks = ls.KeyStructure(list(range(12)), np.zeros((12, 2)), edges)
    assert ks.incidence() == [ks.incident(k) for k in range(12)]


def test_refine_segments_equal_refine_segment_per_segment():
    import cv2

    from stages.extract import line_fit as lf

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
            assert g.ends.tobytes() == r.ends.tobytes()
            assert g.centres.tobytes() == r.centres.tobytes()
            assert g.widths.tobytes() == r.widths.tobytes()
            assert [*g.fit.centroid, *g.fit.direction, *g.fit.normal, g.fit.rms] == \
                [*r.fit.centroid, *r.fit.direction, *r.fit.normal, r.fit.rms]
    assert kept >= 5


def test_similar_pairs_equal_the_einsum_expressions():
    from stages.extract import line_fit as lf

    def reference(cen, dirs, nor, ends, rows, cos_max, max_offset, upper):
        cosine = np.abs(dirs[rows] @ dirs.T)
        to_i = np.abs(np.einsum("jkd,rd->rjk", ends, nor[rows])
                      - (cen[rows] * nor[rows]).sum(1)[:, None, None]).max(axis=2)
        to_j = np.abs(np.einsum("rkd,jd->rjk", ends[rows], nor)
                      - (cen * nor).sum(1)[None, :, None]).max(axis=2)
        off = np.maximum(to_i, to_j)
        ok = (cosine >= cos_max) & (off <= max_offset)
        ok[np.arange(len(rows)), rows] = False
        r, j = np.nonzero(ok)
        return [(float(off[a, b]), int(rows[a]), int(b)) for a, b in zip(r, j)
                if rows[a] < b or not upper]

    rng = np.random.default_rng(6)
    found = 0
    for _ in range(500):
        n = int(rng.integers(2, 30))
        # parts along a few directions, some side by side (similar pairs)
        ang = np.repeat(rng.uniform(0, math.pi, 3), n)[:n] + rng.normal(0, 0.02, n)
        dirs = np.stack([np.cos(ang), np.sin(ang)], 1)
        nor = np.stack([-dirs[:, 1], dirs[:, 0]], 1)
        cen = rng.normal(0, 200, (n, 2))
        cen[n // 2:] = cen[:n - n // 2] + rng.normal(0, 3, (n - n // 2, 2))
        ends = cen[:, None, :] + (rng.uniform(20, 100, (n, 2)) * [-1, 1])[:, :, None] \
            * dirs[:, None, :]
        for rows, upper in ((np.arange(n), True), (np.array([n - 1]), False)):
            ref = reference(cen, dirs, nor, ends, rows, math.cos(math.radians(4)), 7.0, upper)
            assert lf._similar_pairs(cen, dirs, nor, ends, rows, math.cos(math.radians(4)),
                                     7.0, upper) == ref
            found += len(ref)
    assert found > 100


def test_row_dots_are_the_single_dots():
    from stages.extract import line_fit as lf

    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 7, 8, 33, 5000):
        a = rng.normal(size=(n, 2)) * 10.0 ** rng.integers(-4, 4, (n, 1))
        b = rng.normal(size=(n, 2)) * 10.0 ** rng.integers(-4, 4, (n, 1))
        assert lf.row_dots(a, b).tobytes() == np.array([x @ y for x, y in zip(a, b)]).tobytes()


def test_floor_lines_parameters_equal_the_per_line_function():
    from stages.extract import line_fit as lf

    rng = np.random.default_rng(2)
    p0, p1 = rng.normal(0, 3, (5000, 2)), rng.normal(0, 3, (5000, 2))
    p1[:20] = p0[:20]  # no length
    p1[20:40] = -p0[20:40] * rng.uniform(0.5, 2, (20, 1))  # through the robot
    got = np.stack(lf.floor_lines_parameters(p0, p1), axis=1)
    ref = np.array([lf.floor_line_parameters(a, b) for a, b in zip(p0, p1)])
    assert got.tobytes() == ref.tobytes()


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


def _reference_fill_gaps(graph, image, max_gap, min_cos, min_grey_ratio, close_gap,
                         max_degree=4, samples=8):
    """fill_gaps as it was: the candidates' grey ratios in numpy, Python's sort and loop."""
    import cv2

    deg = graph.degree()
    loose = np.nonzero(deg <= 1)[0]
    if len(loose) == 0 or len(graph) < 2:
        return
    pos = graph.pos
    nbr, start = ls.flat_lists(graph.adj)
    score, ci, cj = ls._gap_candidates(np.ascontiguousarray(pos, np.float64), start, nbr,
                                       deg.astype(np.int64), loose.astype(np.int64),
                                       float(max_gap), float(min_cos), float(close_gap))
    cand = list(zip(score.tolist(), ci.tolist(), cj.tolist()))
    if not cand:
        return
    ij = np.stack([ci, cj], axis=1)
    t = np.linspace(0.0, 1.0, samples)[None, :, None]
    pts = (pos[ij[:, 0]][:, None, :] * (1 - t) + pos[ij[:, 1]][:, None, :] * t).astype(np.float32)
    grey = cv2.remap(image, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0).min(axis=1)
    ref = 0.5 * (graph.value[ij[:, 0]] + graph.value[ij[:, 1]])
    ratio = np.where(ref > 0, grey / np.maximum(ref, 1e-9), 0.0)
    scored = [(sc + r, i, j) for (sc, i, j), r in zip(cand, ratio) if r >= min_grey_ratio]
    scored.sort(key=lambda c: -c[0])
    for _, i, j in scored:
        if j in graph.adj[i]:
            continue
        if len(graph.adj[i]) >= 2 or len(graph.adj[j]) >= max_degree:
            continue
        graph.connect(i, j)


@pytest.mark.parametrize("seed", range(6))
def test_fill_gaps_equals_the_former_python(seed):
    rng = np.random.default_rng(seed)
    added = 0
    for _ in range(20):
        image = (rng.random((30, 40)) ** 2).astype(np.float32)
        graph = _random_graph(rng, int(rng.integers(20, 90)))
        ref = graph.copy()
        before = sum(map(len, graph.adj))
        ls.fill_gaps(graph, image, 6.0, math.cos(math.radians(30)), 0.25, 4.0)
        _reference_fill_gaps(ref, image, 6.0, math.cos(math.radians(30)), 0.25, 4.0)
        assert graph.adj == ref.adj
        added += sum(map(len, graph.adj)) - before
    assert added > 20  # gaps were filled


def _reference_outward(graph, i, reach=3):
    if len(graph.adj[i]) != 1:
        return None
    prev, cur = i, next(iter(graph.adj[i]))
    for _ in range(reach - 1):
        nxt = [k for k in graph.adj[cur] if k != prev]
        if len(nxt) != 1:
            break
        prev, cur = cur, nxt[0]
    dx = float(graph.pos[i, 0] - graph.pos[cur, 0])
    dy = float(graph.pos[i, 1] - graph.pos[cur, 1])
    n = float(np.hypot(dx, dy))
    return (dx / n, dy / n) if n > 0 else None


def _reference_candidates(graph, max_gap, min_cos, close_gap):
    """fill_gaps' candidate loop as it was written in Python before the kernel."""
    deg = graph.degree()
    loose = np.nonzero(deg <= 1)[0]
    pos = graph.pos
    d = np.hypot(*(pos[loose][:, None, :] - pos[None, :, :]).transpose(2, 0, 1))
    near_all = (d <= max_gap) & (d > 0)
    outward = {i: _reference_outward(graph, i) for i in loose.tolist()}
    xy, deg_l, cand = pos.tolist(), deg.tolist(), []
    for a, i in enumerate(loose.tolist()):
        near = np.nonzero(near_all[a])[0]
        steps, frontier = {i}, {i}
        for _ in range(3):
            frontier = {k for f in frontier for k in graph.adj[f]} - steps
            steps |= frontier
        out_i = outward[i]
        for j in near.tolist():
            if j in steps:
                continue
            dj = float(d[a][j])
            gx, gy = (xy[j][0] - xy[i][0]) / dj, (xy[j][1] - xy[i][1]) / dj
            out_j = outward.get(j) if deg_l[j] <= 1 else None
            closing = dj <= close_gap and deg_l[j] == 1 and deg_l[i] == 1
            score = 0.0
            if out_i is not None:
                ci = out_i[0] * gx + out_i[1] * gy
                if ci < min_cos and not closing:
                    continue
                score += ci
            if out_j is not None:
                cj = -out_j[0] * gx + -out_j[1] * gy
                if cj < min_cos and not closing:
                    continue
                score += cj
            if out_i is None and out_j is None and deg_l[j] > 0:
                continue
            cand.append((score - dj / max_gap, i, j))
    return cand


@pytest.mark.parametrize("seed", range(6))
def test_gap_candidates_equal_the_python_loop(seed):
    rng = np.random.default_rng(seed)
    graph = _random_graph(rng)
    sc = perspective.confs["default"]["skeleton"]
    max_gap, min_cos, close_gap = sc["max_gap"], math.cos(sc["gap_max_angle"]), sc["close_gap"]
    deg = graph.degree()
    loose = np.nonzero(deg <= 1)[0]
    nbr, start = ls.flat_lists(graph.adj)
    score, ci, cj = ls._gap_candidates(graph.pos, start, nbr, deg.astype(np.int64),
                                       loose.astype(np.int64), max_gap, min_cos, close_gap)
    ref = _reference_candidates(graph, max_gap, min_cos, close_gap)
    assert len(ref) >= 3
    assert list(zip(score.tolist(), ci.tolist(), cj.tolist())) == ref


@pytest.mark.parametrize("seed", range(3))
def test_farthest_pairs_are_the_first_argmax_of_the_distances(seed):
    rng = np.random.default_rng(seed)
    counts = rng.integers(1, 10, 30)  # pixels per region (ties: few distinct distances)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    xs = rng.integers(0, 4, start[-1]).astype(np.int64)
    ys = rng.integers(0, 4, start[-1]).astype(np.int64)
    lonely = np.sort(rng.choice(30, 20, replace=False)).astype(np.int64)
    got = ls._farthest_pairs(xs, ys, start, lonely)
    for k, i in enumerate(lonely):
        px = np.stack([xs[start[i]:start[i + 1]], ys[start[i]:start[i + 1]]], axis=1)
        if len(px) < 2:
            assert (got[k] == -1).all()
            continue
        d = np.hypot(*(px[:, None, :] - px[None, :, :]).transpose(2, 0, 1))
        a, b = np.unravel_index(np.argmax(d), d.shape)
        assert got[k].tolist() == [*px[a], *px[b]]


@pytest.mark.parametrize("seed", range(3))
def test_stretched_ends_are_the_farthest_region_pixels(seed):
    """stretch_lines (compiled) against its former numpy form: per end node, the first
    pixel in row-major order of its region at the largest distance from its neighbour."""
    rng = np.random.default_rng(seed)
    graph = _random_graph(rng, 40)
    regions = np.zeros((30, 40), np.int32)
    for i, (x, y) in enumerate(graph.pix.tolist()):  # each node's 3 x 3 region, clipped
        regions[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2] = i + 1
    for i, (x, y) in enumerate(graph.pix.tolist()):
        regions[min(max(y, 0), 29), min(max(x, 0), 39)] = i + 1
    ref = graph.pix.copy()
    deg = graph.degree()
    ends = np.nonzero(deg == 1)[0]
    ys, xs = np.nonzero(regions)
    lab = regions[ys, xs] - 1
    sel = np.isin(lab, ends)
    ys, xs, lab = ys[sel], xs[sel], lab[sel]
    other = np.zeros(len(graph), int)
    for i in ends:
        other[i] = next(iter(graph.adj[i]))
    d = np.hypot(xs - graph.pos[other[lab], 0], ys - graph.pos[other[lab], 1])
    order = np.lexsort((-d, lab))
    first = np.ones(len(order), bool)
    first[1:] = lab[order][1:] != lab[order][:-1]
    best = order[first]
    ref[lab[best]] = np.stack([xs[best], ys[best]], axis=1)
    assert len(best) >= 5
    ls.stretch_lines(graph, regions)
    np.testing.assert_array_equal(graph.pix, ref)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_subpixel_positions_equal_the_numpy_centroids(dtype):
    """subpixel_positions (compiled, numpy's summation order) against its former numpy
    form, bit for bit: windows at the image's edges, all-zero windows, ties."""
    rng = np.random.default_rng(5)
    image = rng.uniform(0, 1, (30, 40)).astype(dtype)
    image[rng.uniform(size=image.shape) < 0.3] = 0  # empty and partly empty windows
    image[10:13, 10:13] = 0
    pix = np.concatenate([rng.integers(0, [40, 30], (300, 2)), [[0, 0], [39, 29], [11, 11]]])
    pad = np.zeros((32, 42), dtype)
    pad[1:-1, 1:-1] = image
    offs = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    wts = pad[pix[:, 1:2] + 1 + offs[None, :, 1], pix[:, 0:1] + 1 + offs[None, :, 0]].astype(
        np.float64)
    wsum = wts.sum(axis=1)
    wsum[wsum <= 0] = 1.0
    ref = pix.astype(np.float64) + np.stack([(wts * offs[None, :, 0]).sum(axis=1) / wsum,
                                             (wts * offs[None, :, 1]).sum(axis=1) / wsum], 1)
    got = ls.subpixel_positions(image, pix)
    assert got.tobytes() == ref.tobytes()


@pytest.mark.parametrize("n", [1, 5, 8, 9, 17, 64, 128, 129, 300, 1000])
def test_block_sum_is_numpys_sum(n):
    rng = np.random.default_rng(n)
    for _ in range(200):
        a = rng.normal(size=n) * 10.0 ** rng.integers(-3, 4, n)
        assert ls.block_sum(a) == a.sum()


def _reference_remove_triangles(graph):
    """remove_triangles as the Python loop did it."""
    for i in range(len(graph)):
        if len(graph.adj[i]) < 2:
            continue
        for j in sorted(graph.adj[i]):
            if j <= i:
                continue
            for k in sorted(graph.adj[i] & graph.adj[j]):
                if k <= j:
                    continue
                sides = [(i, j), (j, k), (i, k)]
                lens = [np.hypot(*(graph.pos[a] - graph.pos[b])) for a, b in sides]
                a, b = sides[int(np.argmax(lens))]
                graph.disconnect(a, b)


@pytest.mark.parametrize("seed", range(6))
def test_remove_triangles_equals_the_python_loop(seed):
    def dense_graph():  # built twice the same way, so that its sets iterate alike
        rng = np.random.default_rng(seed)
        n = 40
        pos = rng.uniform(0, 8, (n, 2))
        pos[5] = pos[3] + (pos[4] - pos[3])[::-1]  # sides of equal length
        adj = [set() for _ in range(n)]
        for _ in range(int(rng.integers(60, 160))):  # dense: triangles sharing sides
            a, b = (int(v) for v in rng.integers(0, n, 2))
            if a != b:
                adj[a].add(b)
                adj[b].add(a)
        return ls.LineGraph(np.zeros((n, 2), int), pos, np.ones(n), adj)

    graph, ref = dense_graph(), dense_graph()
    before = sum(map(len, graph.adj))
    ls.remove_triangles(graph)
    _reference_remove_triangles(ref)
    assert graph.adj == ref.adj
    assert [list(a) for a in graph.adj] == [list(a) for a in ref.adj]  # the sets' order too
    assert sum(map(len, graph.adj)) < before


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
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


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
        ls._corner_cuts(turn, arc, offsets, 3.0, 0.8, cuts, cut_start, by_python)
        assert not by_python.any()
        for c in range(len(lens)):
            a, b = offsets[c], offsets[c + 1]
            ref = ls.corner_nodes(turn[a:b], arc[a:b], 3.0, 0.8)
            assert cuts[cut_start[c]:cut_start[c + 1]].tolist() == ref
            found += len(ref)
    assert found > 1000


def _reference_trace_chains(graph):
    """trace_chains as the Python walk did it."""
    adj = graph.adj
    two = [len(a) == 2 for a in adj]
    used = [False] * len(adj)
    direct = set()
    chains = []

    def walk(prev, cur, chain):
        while two[cur] and not used[cur]:
            used[cur] = True
            a, b = adj[cur]
            prev, cur = cur, (b if a == prev else a)
            chain.append(cur)
        return chain

    for s in range(len(adj)):
        if two[s] or not adj[s]:
            continue
        for n in sorted(adj[s]):
            if two[n]:
                if not used[n]:
                    chains.append(walk(s, n, [s, n]))
            elif (min(s, n), max(s, n)) not in direct:
                direct.add((min(s, n), max(s, n)))
                chains.append([s, n])
    for s in range(len(adj)):
        if two[s] and not used[s]:
            used[s] = True
            chain = walk(s, min(adj[s]), [s, min(adj[s])])
            if chain[-1] != s:
                chain.append(s)
            chains.append(chain)
    return chains


def test_trace_chains_equals_the_python_walk():
    rng = np.random.default_rng(15)
    loops = 0
    for _ in range(1000):
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
        ref = _reference_trace_chains(graph)
        assert ls.trace_chains(graph) == ref
        loops += sum(c[0] == c[-1] for c in ref)
    assert loops > 10


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
        taken = ls._greedy_nodes(sy[order], sx[order], *skeleton.shape)
        ys, xs = sy[order][taken], sx[order][taken]
        pix, regions = ls.place_nodes(lp, skeleton, c, key)
        np.testing.assert_array_equal(pix, np.stack([xs, ys], axis=1))
        np.testing.assert_array_equal(regions, ls._node_regions(skeleton, ys.astype(np.int64),
                                                                xs.astype(np.int64)))


def test_smooth_lines_equals_the_numpy_rounds():
    rng = np.random.default_rng(13)
    for _ in range(500):
        n = int(rng.integers(1, 80))
        adj = [set() for _ in range(n)]
        for _ in range(int(rng.integers(0, 2 * n))):
            a, b = (int(v) for v in rng.integers(0, n, 2))
            if a != b:
                adj[a].add(b)
                adj[b].add(a)
        graph = ls.LineGraph(np.zeros((n, 2), int), rng.normal(0, 10, (n, 2)), np.ones(n), adj)
        idx = np.nonzero(graph.degree() == 2)[0]
        for rounds in (0, 1, 2, 3):
            ref = graph.pos.copy()
            if len(idx):
                nb = np.array([sorted(graph.adj[i]) for i in idx])
                for _ in range(rounds):
                    ref[idx] = (ref[idx] + ref[nb[:, 0]] + ref[nb[:, 1]]) / 3.0
            assert ls.smooth_lines(graph, rounds).tobytes() == ref.tobytes()


def _reference_turning_angles(chains, pos, reach, floor=None):
    """turning_angles as numpy computed it (arcs, a sorted search of the chains laid end to
    end, the arms' angles by np.arccos)."""
    def turns(a, b, ends):
        na, nb = np.hypot(*a.T), np.hypot(*b.T)
        ok = (na > 0) & (nb > 0)
        cosang = np.where(ok, (a * b).sum(axis=1) / np.where(ok, na * nb, 1.0), 1.0)
        turn = np.arccos(np.clip(cosang, -1.0, 1.0))
        turn[ends] = 0.0
        return turn

    lens = np.array([len(c) for c in chains], dtype=int)
    idx = np.concatenate(chains).astype(int)
    pts = pos[idx]
    start = np.repeat(np.cumsum(lens) - lens, lens)
    last = start + np.repeat(lens, lens) - 1
    step = np.concatenate([[0.0], np.hypot(*np.diff(pts, axis=0).T)])
    step[np.cumsum(lens) - lens] = 0.0
    arc = np.cumsum(step)
    arc = arc - arc[start]
    far = np.repeat(np.arange(len(chains)), lens) * (arc.max(initial=0.0) + 4 * reach + 1.0)
    key = arc + far
    back = np.clip(np.searchsorted(key, key - reach, side="right") - 1, start, last)
    fwd = np.clip(np.searchsorted(key, key + reach, side="left"), start, last)
    ends = (np.arange(len(idx)) == start) | (np.arange(len(idx)) == last)
    a, b = pts - pts[back], pts[fwd] - pts
    floor_turn = None
    if floor is not None:
        fl = floor[idx]
        fa, fb = fl - fl[back], fl[fwd] - fl
        known = np.all(np.isfinite(fa), axis=1) & np.all(np.isfinite(fb), axis=1)
        floor_turn = turns(np.where(known[:, None], fa, a), np.where(known[:, None], fb, b),
                           ends)
    return turns(a, b, ends), floor_turn, arc, start


@pytest.mark.parametrize("seed", range(4))
def test_turning_angles_equal_the_numpy_expressions(seed):
    rng = np.random.default_rng(seed)
    for _ in range(200):
        n = 80
        pos = np.cumsum(rng.normal(0, 1.5, (n, 2)), axis=0)
        pos[5] = pos[4]  # an empty arm
        floor = pos * rng.uniform(0.01, 0.1) + rng.normal(0, 0.01, (n, 2))
        floor[rng.random(n) < 0.1] = np.nan  # above the horizon
        chains = [list(rng.integers(0, n, int(rng.integers(1, 12))))
                  for _ in range(int(rng.integers(1, 15)))]
        for fl in (None, floor):
            got = ls.turning_angles(chains, pos, 3.0, fl)
            ref = _reference_turning_angles(chains, pos, 3.0, fl)
            for g, r in zip(got, ref):
                assert (g is None) == (r is None)
                if g is not None:
                    assert g.dtype == r.dtype and g.tobytes() == r.tobytes()


def _reference_remove_short_lines(graph, min_length):
    g = graph.copy()
    deg = g.degree()
    for e in np.nonzero(deg == 1)[0]:
        path = [int(e)]
        prev, cur = -1, int(e)
        while True:
            nxt = [k for k in g.adj[cur] if k != prev]
            if len(g.adj[cur]) != (1 if cur == e else 2) or not nxt:
                break
            prev, cur = cur, nxt[0]
            path.append(cur)
        p = g.pos[path]
        length = float(np.hypot(*np.diff(p, axis=0).T).sum()) if len(path) > 1 else 0.0
        if len(g.adj[cur]) >= 3 and length < min_length:
            for a, b in zip(path[:-1], path[1:]):
                g.disconnect(a, b)
    return g


@pytest.mark.parametrize("seed", range(6))
def test_remove_short_lines_equals_the_python_walks(seed):
    """The compiled walks remove the same connections, in the same order (the sets left
    iterate alike), as the former Python loop; spurs sharing a junction see each other's
    removal."""
    rng = np.random.default_rng(seed)
    graph = _random_graph(rng, 80)
    for _ in range(12):  # spurs of one to three nodes at junctions
        j, a = int(rng.integers(0, 80)), int(rng.integers(0, 80))
        if a != j and len(graph.adj[a]) == 0:
            graph.connect(a, j)
    ref = _reference_remove_short_lines(graph, 2.5)
    got = ls.remove_short_lines(graph, 2.5)
    assert [list(a) for a in got.adj] == [list(a) for a in ref.adj]
    assert sum(map(len, ref.adj)) < sum(map(len, graph.adj))  # some were removed


def test_path_length_equals_the_numpy_sum():
    """line_structure._path_length (_chain_length, _short_spurs) gives the former numpy
    length of a chain: np.hypot of its steps, np.sum'd."""
    rng = np.random.default_rng(9)
    pos = rng.normal(0, 10, (200, 2))
    for n in list(range(2, 40)) + [100, 300]:
        chain = rng.integers(0, 200, n)
        ref = float(np.hypot(*np.diff(pos[chain], axis=0).T).sum())
        assert ls._chain_length(pos, chain.tolist()) == ref
        assert ls._path_length(pos, chain) == ref


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
    conf = {"min_white": 0.04, "max_gap": 6.0, "gap_max_angle": math.radians(30.0),
            "gap_min_grey_ratio": 0.25, "close_gap": 4.0}
    graph, _, _ = ls.line_structure_graph(lp, conf, ranked)
    assert graph.lists is not None
    _same_lists(graph.lists, graph.adj)


def _reference_connect_nodes(regions, n):
    r = regions
    pairs = []
    for a, b in ((r[:, :-1], r[:, 1:]), (r[:-1, :], r[1:, :]),
                 (r[:-1, :-1], r[1:, 1:]), (r[:-1, 1:], r[1:, :-1])):
        m = (a > 0) & (b > 0) & (a != b)
        pairs.append(np.stack([a[m], b[m]], axis=1))
    e = np.sort(np.concatenate(pairs).astype(np.int64) - 1, axis=1)
    code = np.unique(e[:, 0] * n + e[:, 1])
    adj = [set() for _ in range(n)]
    for i, j in zip((code // n).tolist(), (code % n).tolist()):
        adj[i].add(j)
        adj[j].add(i)
    return adj


@pytest.mark.parametrize("seed", range(4))
def test_connect_nodes_fills_the_sets_as_before(seed):
    """The compiled links give the same sets, iterating in the same order (set order follows
    insertion), as adding the connections one by one did."""
    rng = np.random.default_rng(seed)
    n = 150
    regions = rng.integers(0, n + 1, (40, 60)).astype(np.int32)
    regions[rng.uniform(size=regions.shape) < 0.6] = 0
    ref = _reference_connect_nodes(regions, n)
    got = ls.connect_nodes(regions, n)
    assert sum(map(len, ref)) > 100
    assert [list(a) for a in got] == [list(a) for a in ref]


def _reference_split_isolated_nodes(graph, regions, image):
    deg = graph.degree()
    ys, xs = np.nonzero(regions)
    lab = regions[ys, xs] - 1
    for i in np.nonzero(deg == 0)[0].tolist():
        px = np.stack([xs[lab == i], ys[lab == i]], axis=1)
        if len(px) < 2:
            continue
        d = np.hypot(*(px[:, None, :] - px[None, :, :]).transpose(2, 0, 1))
        a, b = np.unravel_index(np.argmax(d), d.shape)
        graph.pix[i] = px[a]
        j = graph.add_node(px[b], px[b].astype(float), image[px[b][1], px[b][0]])
        graph.connect(i, j)


@pytest.mark.parametrize("seed", range(3))
def test_split_isolated_nodes_as_before(seed):
    rng = np.random.default_rng(seed)
    graph = _random_graph(rng, 40)
    graph.pix = np.clip(graph.pix, 0, [39, 29])
    regions = np.zeros((30, 40), np.int32)
    for i, (x, y) in enumerate(graph.pix.tolist()):
        win = regions[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2]
        win[rng.uniform(size=win.shape) < 0.5] = i + 1
        regions[y, x] = i + 1
    image = rng.uniform(0, 1, regions.shape).astype(np.float32)
    ref, got = graph.copy(), graph.copy()
    _reference_split_isolated_nodes(ref, regions, image)
    ls.split_isolated_nodes(got, regions, image)
    assert len(ref) > len(graph)
    for name in ("pix", "pos", "value"):
        a, b = getattr(got, name), getattr(ref, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name
    assert [list(a) for a in got.adj] == [list(a) for a in ref.adj]


# the placement of a key-structure candidate as it was before ``crossings._place`` (arm_lines,
# _refined_arm and crossing_point of crossings.py, Python and numpy)
from stages.extract import line_fit as lf  # noqa: E402


def _reference_fit_direction(points: np.ndarray, centre: np.ndarray):
    """Least-squares line (centroid, unit direction pointing away from ``centre``)."""
    fit = lf.fit_line(points)
    c, u = fit.centroid, fit.direction
    if float((c - centre) @ u) < 0:
        u = -u
    return c, u


def _reference_arm_lines(centre: np.ndarray, chains: list[list[int]], coords: np.ndarray, skip: int,
              count: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per arm, the line fitted to its nodes number ``skip`` + 1 .. ``skip`` + ``count`` from
    the crossing (undistorted coordinates ``coords``; the nodes right next to a crossing bend
    towards it): (centroid, unit direction away from the centre, the points used)."""
    out = []
    for ch in chains:
        pts = coords[ch[1:]]
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) == 0:
            return []
        sel = pts[skip: skip + count] if len(pts) >= skip + 2 else pts[:count]
        if len(sel) < 2:
            sel = np.vstack([centre[None], sel])
        c, u = _reference_fit_direction(sel, centre)
        out.append((c, u, sel))
    return out


def _reference_intersect(c1, u1, c2, u2) -> np.ndarray | None:
    a = np.array([u1, -u2]).T
    if abs(np.linalg.det(a)) < 1e-3:  # nearly parallel (|sin| < 1e-3)
        return None
    t = np.linalg.solve(a, c2 - c1)
    return c1 + t[0] * u1


def _reference_crossing_point(kind: str, arms: list) -> np.ndarray | None:
    """The crossing as the intersection of its lines: an L's two arms, a T's bar (its two most
    nearly opposite arms fitted together) with the stem, an X's two lines (opposite arms fitted
    together). None when the lines are parallel."""
    if kind == "L":
        (c1, u1, _), (c2, u2, _) = arms
        return _reference_intersect(c1, u1, c2, u2)
    n = len(arms)
    dirs = np.array([u for _, u, _ in arms])
    cos = dirs @ dirs.T
    if kind == "T":
        pairs = [(0, 1, 2), (0, 2, 1), (1, 2, 0)]
        i, j, s = min(pairs, key=lambda p: cos[p[0], p[1]])
        cb, ub = _reference_fit_direction(np.vstack([arms[i][2], arms[j][2]]), arms[i][0])
        return _reference_intersect(cb, ub, arms[s][0], arms[s][1])
    if n != 4:
        return None
    # X: pair arm 0 with its most opposite arm, the other two form the second line
    j = int(np.argmin(cos[0, 1:])) + 1
    rest = [k for k in range(1, 4) if k != j]
    c1, u1 = _reference_fit_direction(np.vstack([arms[0][2], arms[j][2]]), arms[0][0])
    c2, u2 = _reference_fit_direction(np.vstack([arms[rest[0]][2], arms[rest[1]][2]]),
                                      arms[rest[0]][0])
    return _reference_intersect(c1, u1, c2, u2)


def _reference_refined_arm(arm, centre: np.ndarray, white_px: np.ndarray, camera, cc: dict,
                           cell: int, lens: np.ndarray | None = None):
    """An arm's line (centroid, unit direction away from the crossing, points) refined on the
    full-resolution white mask (line_fit.refine_segment) over its nodes' extent from
    ``refine_skip`` cells off the crossing on; the coarse arm where that fails. ``lens``: the
    camera's lens_parameters, if already built."""
    c, u, sel = arm
    t = (sel - centre) @ u
    t0, t1 = max(float(t.min()), cc["refine_skip"] * cell), float(t.max())
    if t1 - t0 < cell:
        return arm
    ref = lf.refine_segment(np.stack([centre + t0 * u, centre + t1 * u]), white_px,
                         lf.lens_parameters(camera) if lens is None else lens, cc["refine_step"],
                         cc["refine_reach"] * cell,
                         0.0, cc["refine_min_points"])
    if ref is None:
        return arm
    d = ref.fit.direction if float(ref.fit.direction @ u) >= 0 else -ref.fit.direction
    return ref.fit.centroid, d, ref.centres


def _reference_place(kind, centre, chains, ideal, cc, cell, white_px, lens):
    arms = _reference_arm_lines(centre, chains, ideal, cc["arm_skip"], cc["arm_nodes"])
    if len(arms) != len(chains):
        return "arm without nodes"
    if white_px is not None:
        arms = [_reference_refined_arm(arm, centre, white_px, None, cc, cell, lens)
                for arm in arms]
    x = _reference_crossing_point(kind, arms)
    if x is None or np.hypot(*(x - centre)) > cc["max_shift"] * cell:
        return "arms do not meet near the node"
    dirs = np.array([u for _, u, _ in arms])
    step = cc["arm_step"] * cell
    lengths = np.array([max(float(np.max((sel - x) @ u)), step) for _, u, sel in arms])
    return x, dirs, lengths


@pytest.mark.parametrize("seed", range(3))
def test_place_crossing_equals_the_arm_lines_refined_and_cut(seed):
    """crossings.place_crossing (``_place``) gives what arm_lines, _refined_arm and
    crossing_point gave, to the bit: on the full-resolution white mask and without it, for
    L, T and X candidates with nodes along white arms, off them and out of the lens model."""
    import cv2

    from stages.extract import crossings, perspective

    rng = np.random.default_rng(seed)
    cell = 8
    cc = {**perspective.confs["default"]["crossings"]}
    lens = np.array([330.0, 330.0, 375.5, 239.5, -0.02, 0.004, 0.0, 0.0, 0.0])

    class Camera:  # what lens_parameters reads
        fx, fy, cx, cy = lens[:4]
        distortion = lens[4:]

    kinds = {"L": 2, "T": 3, "X": 4}
    placed = {k: 0 for k in kinds}
    rejected = set()
    for trial in range(150):
        kind = list(kinds)[trial % 3]
        white = np.zeros((480, 752), np.uint8)
        centre = rng.uniform([150, 100], [600, 380])
        base = rng.uniform(0, 2 * math.pi)
        step_ang = {"L": rng.uniform(0.4, 2.5), "T": math.pi / 2, "X": math.pi / 2}[kind]
        if kind == "L":
            angles = [base, base + step_ang]
        elif kind == "T":
            angles = [base, base + math.pi, base + math.pi / 2]
        else:
            angles = [base + k * step_ang for k in range(4)]
        angles = [a + rng.normal(0, 0.05) for a in angles]
        nodes = [centre]
        chains = []
        for a in angles:
            u = np.array([math.cos(a), math.sin(a)])
            far = centre + 120 * u
            cv2.line(white, tuple(int(v) for v in centre), tuple(int(v) for v in far), 1,
                     int(rng.integers(2, 7)))
            n = int(rng.integers(1, 7)) if rng.random() > 0.03 else 0  # no nodes
            chain = [0]
            for k in range(n):
                chain.append(len(nodes))
                nodes.append(centre + (k + 1) * cell * u + rng.normal(0, 1.5, 2))
            chains.append(chain)
        ideal = np.array(nodes)
        ideal[rng.random(len(ideal)) < 0.08] = np.nan  # out of the lens model
        ideal[0] = centre + rng.normal(0, 3 if trial % 10 else 60, 2)  # some far off
        for white_px in (white, None):
            got = crossings.place_crossing(kind, ideal[0], chains, ideal, cc, cell, white_px,
                                           Camera)
            ref = _reference_place(kind, ideal[0], chains, ideal, cc, cell, white_px, lens)
            assert type(got) is type(ref)
            if isinstance(ref, str):
                assert got == ref
                rejected.add(ref)
                continue
            placed[kind] += 1
            for a, b in zip(got, ref):
                assert a.shape == b.shape and a.tobytes() == b.tobytes()
    assert min(placed.values()) >= 10 and len(rejected) == 2


# the verification of a crossing as it was before ``crossings._floor_checks`` and
# ``_image_checks`` (_verify_crossing, _continued_as_t, white_arm_lengths, _in_image and
# _alternative_in_view of crossings.py, Python and numpy)
from stages.common.geometry import polar  # noqa: E402
from stages.extract import crossings as cr  # noqa: E402


def _reference_verify_crossing(kind, x, dirs, reach, white, green, other_mean, top, camera,
                               to_floor, cc, cell, field_cells=None, lengths=None,
                               white_px=None):
    """A crossing of ``kind`` at ideal point ``x`` with arms along ``dirs`` (A, 2) reaching
    ``reach`` (A,) px, its lines extending ``lengths`` (A,) px along them -> (row, image
    position), or the reason it is rejected. The cheap floor checks come before the image
    checks."""
    step = cc["arm_step"] * cell
    n = len(dirs)
    # all floor points at once: the crossing, a step along each arm, the cell below, the ends
    pts = np.empty((n + 2 + (0 if lengths is None else n), 2))
    pts[0] = x
    pts[1:n + 1] = x + step * dirs
    pts[n + 1] = x[0] + 0.0, x[1] + float(cell)
    if lengths is not None:
        with np.errstate(invalid="ignore"):  # an arm out of the image is infinite
            pts[n + 2:] = x[None] + np.asarray(lengths)[:, None] * dirs
    on_floor = to_floor(pts)
    floor = on_floor[:n + 1]
    if not np.isfinite(floor).all():
        return "above the horizon"
    # every point's offset from the crossing on the floor and its length, at once
    rel = on_floor - on_floor[0]
    rel_m = np.hypot(rel[:, 0], rel[:, 1])
    if lengths is not None:
        arm_m = rel_m[n + 2:]  # NaN beyond the horizon: long enough
        short = arm_m < cc["min_arm_length"]
        if np.any(short) and white_px is not None:
            # the fitted nodes or lines may end early (a far arm's few nodes, a line cut at a
            # junction): the arm is as long as the white line goes on along it in the image
            lengths = _reference_white_arm_lengths(x, dirs, lengths, short, white_px, camera,
                                                   cc, cell)
            with np.errstate(invalid="ignore"):  # an arm out of the image is infinite
                ends = to_floor(x[None] + lengths[:, None] * dirs)
            arm_m = np.hypot(*(ends - floor[0]).T)
            reach = np.maximum(reach, np.minimum(cc["arm_reach"] * cell, lengths))
        if np.any(arm_m < cc["min_arm_length"]):
            return "arm too short"
    d, bearing = polar(floor[:1])
    span = rel_m[n + 1] if np.isfinite(rel_m[n + 1]) else np.inf  # the cell below
    # beyond the grid's resolution the full-resolution white mask decides (_verify_fine), as
    # far as its profiles (refine_step px apart) resolve the floor
    fine = span > cc["max_cell_span"]
    if fine and (white_px is None or not cc.get("fine", True)
                 or span * cc["refine_step"] / cell > cc["max_cell_span"]):
        return "too far"
    arm_dirs = np.arctan2(rel[1:n + 1, 1], rel[1:n + 1, 0])
    orient, misfit = cr.floor_arms(kind, arm_dirs)
    if misfit > cc["max_misfit"]:
        return f"floor angles misfit {math.degrees(misfit):.0f} deg"
    if fine:
        return cr._verify_fine(kind, x, dirs, white_px, green, other_mean, top, camera, to_floor,
                            cc, cell, d[0], bearing[0], orient, misfit, span)
    # an arm leaving the image is verified on its part in view
    reach = np.minimum(reach, _reference_in_image(x, dirs, camera, 0.5 * cell))
    px = cr.distort_ideal(cr.lens_parameters(camera),
                          np.vstack([x[None], x + reach[:, None] * dirs]))
    if not np.isfinite(px).all():
        return "outside the lens model"
    grid = (px + 0.5) / cell - 0.5
    col = min(max(round(grid[0, 0]), 0), len(top) - 1)
    near_top = top[max(col - 2, 0): col + 3].max()  # the boundary within two columns
    if grid[0, 1] - near_top < cc["edge_margin"]:
        return "at the field boundary"  # a line meeting an object or the end of the view
    row = min(max(round(grid[0, 1]), 0), other_mean.shape[0] - 1)
    r = cc["object_radius"]
    if other_mean[max(row - r, 0): row + r + 1, max(col - r, 0): col + r + 1].max() > 0.5:
        return "next to an object"  # a robot's or a person's white foot on a line
    # the arms that would make an L a T must be in view (a T's stem continued would make an
    # X, which fields hold only where the centre circle crosses the halfway line)
    # (a thin line leaves a cell mostly green: where the full-resolution mask shows an arm's
    # line going on through the crossing, the L is no L)
    if kind == "L" and (not _reference_alternative_in_view(x, dirs, camera, top, other_mean,
                                                           green, cc, cell)
                        or (white_px is not None and any(
                            cr.arm_state(x, -u, white_px, green, other_mean, top, camera,
                                      to_floor, cc, cell, dirs) == "white" for u in dirs))):
        return _reference_continued_as_t(x, dirs, reach, white, green, other_mean, top, camera,
                               to_floor, cc, cell, field_cells, lengths, white_px)
    score = cr.verify_crossing(grid[0], grid[1:], white, green, cc, field_cells)
    if score <= 0:
        if white_px is not None and cc.get("fine", True):
            # the grid's circles may take in a neighbouring line (a far goal area's lines
            # lie two cells apart): the full-resolution check decides
            return cr._verify_fine(kind, x, dirs, white_px, green, other_mean, top, camera,
                                to_floor, cc, cell, d[0], bearing[0], orient, misfit,
                                max(span, cc["max_cell_span"]))
        return "not verified in the image"
    row = [cr.CROSSING_CODES[kind], d[0], bearing[0], orient,
           score * (1.0 - misfit / math.radians(90.0))]
    return row, px[0]


def _reference_continued_as_t(x, dirs, reach, white, green, other_mean, top, camera, to_floor,
                              cc, cell, field_cells, lengths, white_px=None):
    """An L whose view opposite its arms is not carpet: where one arm's line goes on through
    the crossing (the fit of a T's bar ended at the stem, or the bar's far half was fitted as
    a line of its own that missed the pair), the crossing is that T. Each arm continued is
    verified as a T, by the same floor and image checks (the circle then counts three
    passages, and the continued arm needs its white path); the best verified one is returned,
    else the L's rejection."""
    best = "not green where a T's arm would be"
    for k in range(len(dirs)):
        arms = np.vstack([dirs, -dirs[k][None]])
        ext = np.append(reach, reach[k])
        lens = None if lengths is None else np.append(lengths, reach[k])
        v = _reference_verify_crossing("T", x, arms, ext, white, green, other_mean, top,
                                       camera, to_floor, cc, cell, field_cells, lens, white_px)
        if not isinstance(v, str) and (isinstance(best, str) or v[0][4] > best[0][4]):
            best = v
    return best


def _reference_white_arm_lengths(x: np.ndarray, dirs: np.ndarray, lengths: np.ndarray,
                                 which: np.ndarray, white_px: np.ndarray, camera, cc: dict,
                                 cell: int) -> np.ndarray:
    """Arm lengths (A,) px from the crossing ``x`` (ideal px) along ``dirs``: for the arms
    ``which`` (A,) bool, ``lengths`` grown while the full-resolution white mask still shows
    a white run on the arm's line (line_fit's profile walk: a profile across the arm every
    ``refine_step`` px, ``refine_reach`` cells to each side, its run's centre within
    ``arm_tolerance`` px of the line; it stops after two profiles without), up to
    ``arm_grow`` cells; the others as given."""
    out = np.asarray(lengths, float).copy()
    lens = cr.lens_parameters(camera)
    for k in np.nonzero(which)[0]:
        u = dirs[k]
        e = x + out[k] * u
        g = lf.grow_along(white_px, lens, e, u, cc["refine_step"], cc["refine_reach"] * cell,
                       cc["arm_grow"] * cell, cc["arm_tolerance"])
        out[k] = max(out[k], float((g - x) @ u))
        if out[k] >= _reference_in_image(x, u[None], camera, cc["refine_step"])[0]:
            out[k] = np.inf  # white up to the image's edge: longer than what is in view
    return out


def _reference_in_image(x: np.ndarray, dirs: np.ndarray, camera, margin: float) -> np.ndarray:
    """Per direction (A, 2), the distance (ideal px) from ``x`` along it to ``margin`` px
    inside the image's edge (in ideal pixels: the lens's distortion is small at the edges
    of the views this is used for)."""
    w, h = camera.image_size
    x0, x1 = float(x[0]), float(x[1])
    if not (math.isfinite(x0) and math.isfinite(x1)):  # NaN distances, as numpy gives them
        lo_, hi_ = np.array([margin, margin]), np.array([w - 1 - margin, h - 1 - margin])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(dirs > 1e-12, (hi_ - x) / dirs,
                         np.where(dirs < -1e-12, (lo_ - x) / dirs, np.inf))
        return np.maximum(t.min(axis=1), 0.0)
    hi = (float(w - 1 - margin) - x0, float(h - 1 - margin) - x1)
    lo = (float(margin) - x0, float(margin) - x1)
    out = []
    for d in np.asarray(dirs, float).reshape(-1, 2).tolist():  # a few arms: scalar arithmetic
        t = math.inf
        for k in (0, 1):
            if d[k] > 1e-12:
                t = min(t, hi[k] / d[k])
            elif d[k] < -1e-12:
                t = min(t, lo[k] / d[k])
        out.append(max(t, 0.0))
    return np.array(out)


def _reference_alternative_in_view(x, dirs, camera, top, other_mean, green, cc, cell) -> bool:
    """Whether the image shows carpet opposite an L's arms (where the third arm of a T would
    be), ``arm_reach`` cells from the crossing: inside the image and the field boundary, no
    object there, and green (at least ``t_green``). A T seen with one half of its bar out of
    view or hidden looks like an L; so do a far X's arms, flattened by the perspective."""
    pts = cr.distort_ideal(cr.lens_parameters(camera), x[None] - cc["arm_reach"] * cell * dirs)
    w, h = camera.image_size
    grid = (pts + 0.5) / cell - 0.5
    greens = cr.sample_cells(green, grid).tolist()  # all points at once (each sampled alone)
    for p, g, green_here in zip(pts.tolist(), grid.tolist(), greens):
        if not (math.isfinite(p[0]) and math.isfinite(p[1]) and 0 <= p[0] <= w - 1
                and 0 <= p[1] <= h - 1):
            return False
        col = min(max(round(g[0]), 0), len(top) - 1)
        row = min(max(round(g[1]), 0), other_mean.shape[0] - 1)
        if g[1] - top[col] < cc["edge_margin"] or other_mean[row, col] > 0.5:
            return False
        if green_here < cc["t_green"]:
            return False
    return True


def _recorded_verifications():
    """The arguments of every crossings._verify_crossing call (the candidates', the line
    pairs' and the continued Ls') of the rendered reference frames of both cameras."""
    import test_extract_perspective_unchanged as unchanged

    calls = []
    real = cr._verify_crossing

    def record(*args):
        calls.append(args)
        return real(*args)

    conf = perspective.confs["default"]
    cr._verify_crossing = record
    try:
        for preset, field_name in unchanged.RENDERS:
            for _, img, cam, pitch, roll in unchanged.rendered_frames(preset, field_name):
                perspective.extract_frame(img, cam, conf, pitch=pitch, roll=roll)
    finally:
        cr._verify_crossing = real
    return calls


def _same_verdict(got, ref):
    if isinstance(ref, str) or isinstance(got, str):
        return got == ref
    return (np.array(got[0], np.float64).tobytes() == np.array(ref[0], np.float64).tobytes()
            and np.asarray(got[1]).tobytes() == np.asarray(ref[1]).tobytes())


def test_verify_crossing_equals_the_former_python():
    """crossings._verify_crossing (``_floor_checks``, ``_image_checks``, the compiled
    ``_alternative_in_view``) gives the verdict the former Python and numpy gave, to the bit:
    on every verification of the rendered reference frames, and on each of them moved,
    turned, with shortened arms (grown on the white mask), without the white mask, and
    as an L of its first two arms."""
    rng = np.random.default_rng(5)
    calls = _recorded_verifications()
    assert len(calls) >= 20
    verdicts = set()
    for args in calls:
        (kind, x, dirs, reach, white, green, other_mean, top, camera, to_floor, cc, cell,
         field_cells, lengths, white_px) = args[:15]
        turn = rng.normal(0, 0.05)
        c, s = math.cos(turn), math.sin(turn)
        variants = [(kind, x, dirs, reach, lengths, white_px),
                    (kind, x + rng.normal(0, 4, 2), dirs, reach, lengths, white_px),
                    (kind, x, dirs @ np.array([[c, s], [-s, c]]), reach, lengths, white_px),
                    (kind, x, dirs, reach, None if lengths is None else 0.3 * lengths,
                     white_px),
                    (kind, x, dirs, reach, lengths, None)]
        if len(dirs) > 2:
            variants.append(("L", x, dirs[:2], reach[:2],
                             None if lengths is None else lengths[:2], white_px))
        for k, xx, dd, rr, ll, wp in variants:
            rest = (white, green, other_mean, top, camera, to_floor, cc, cell, field_cells)
            ref = _reference_verify_crossing(k, xx, dd, np.array(rr, float), *rest,
                                             None if ll is None else np.array(ll, float), wp)
            got = cr._verify_crossing(k, xx, dd, np.array(rr, float), *rest,
                                      None if ll is None else np.array(ll, float), wp)
            assert _same_verdict(got, ref), (k, xx, dd, rr, ll, got, ref)
            verdicts.add("verified" if not isinstance(ref, str) else ref.split(" misfit")[0])
    assert len(verdicts) >= 6, verdicts


def test_remap_sample_is_opencvs_remap():
    """crossings._remap_sample (the compiled _alternative_in_view's green) samples as
    sample_cells (cv2.remap, bilinear) does, to the bit, inside the image and across its
    edges, for float32 images of any values, of shares in 64ths and of 0/1."""
    rng = np.random.default_rng(6)
    for image in (rng.random((60, 94)).astype(np.float32),
                  (rng.integers(0, 65, (60, 94)) / np.float32(64)).astype(np.float32),
                  (rng.random((60, 94)) > 0.5).astype(np.float32)):
        pts = rng.uniform(-3, [97, 63], (20000, 2))
        pts[:2000] = np.round(pts[:2000] * 2) / 2  # on pixels and halfway
        ref = cr.sample_cells(image, pts)
        got = np.array([cr._remap_sample(image, p, q) for p, q in pts], np.float32)
        assert got.tobytes() == ref.tobytes()


# the line pairs' crossings as they were before ``crossings._pair_crossings`` (Python and
# numpy)
def _reference_line_pair_crossings(ends: np.ndarray, widths: np.ndarray, floor_of,
                                   tol: float, max_misfit: float, first_stem=None) -> list:
    """Crossings of pairs of fitted lines (``ends`` (N, 2, 2) in ideal pixels, ``widths``
    (N,) their white width across, px) that meet at about a right angle on the floor
    (``floor_of``: ideal pixels (M, 2) -> floor points; within ``max_misfit`` rad of 90 deg):
    each line either passes the intersection (by more than ``tol`` px: two arms) or ends on
    the other line (its nearer end within ``tol`` px plus the other line's width of it: one
    arm). Field lines cross at right angles; where a far corner's skeleton loses the junction
    at the grid's resolution, the lines fitted at full resolution still meet. Lines from
    ``first_stem`` on are stems (stem_lines): they are not paired with each other."""
    n = len(ends)
    if n < 2:
        return []
    floor = floor_of(ends.reshape(-1, 2)).reshape(n, 2, 2)
    fdir = floor[:, 1] - floor[:, 0]
    fang = np.arctan2(fdir[:, 1], fdir[:, 0])
    d = ends[:, 1] - ends[:, 0]
    length = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(length, 1e-9)[:, None]
    normal = np.stack([-u[:, 1], u[:, 0]], axis=1)
    out = []
    # the pairs at about a right angle on the floor, all at once
    diff = np.remainder(fang[:, None] - fang[None, :], math.pi)
    gap = np.abs(np.minimum(diff, math.pi - diff) - math.pi / 2)
    ok = np.triu(gap <= max_misfit, 1)  # NaN (off the floor) compares False
    if first_stem is not None:
        ok[first_stem:, first_stem:] = False
    pi, pj = np.nonzero(ok)
    if len(pi) == 0:
        return cr.merge_line_crossings(out, tol, floor_of=floor_of)
    # each pair's 2 x 2 system [u_i, -u_j] s = e_j - e_i, all in one batched call (LAPACK per
    # matrix, as one call per pair would be)
    a_all = np.stack([u[pi], -u[pj]], axis=2)
    det_all = np.abs(np.linalg.det(a_all))
    meet = det_all >= 1e-3
    s_all = np.zeros((len(pi), 2))
    if meet.any():
        s_all[meet] = np.linalg.solve(a_all[meet], (ends[pj, 0] - ends[pi, 0])[meet][..., None]
                                      )[..., 0]
    # of all pairs at once: the intersection, and each line's end nearer to it and that
    # end's distance from the other line (the dot products by row_dots, as ``@`` gives them)
    s0, s1 = s_all[:, 0], s_all[:, 1]
    xs = ends[pi, 0] + s0[:, None] * u[pi]
    e_i = np.where((s0 <= 0.5 * length[pi])[:, None], ends[pi, 0], ends[pi, 1])
    gap_i = np.abs(lf.row_dots(e_i - ends[pj, 0], normal[pj])).tolist()
    e_j = np.where((s1 <= 0.5 * length[pj])[:, None], ends[pj, 0], ends[pj, 1])
    gap_j = np.abs(lf.row_dots(e_j - ends[pi, 0], normal[pi])).tolist()
    lengths, line_widths = length.tolist(), np.asarray(widths, float).tolist()
    for i, j, m, t_i, t_j, g_i, g_j, x in zip(pi.tolist(), pj.tolist(), meet.tolist(),
                                              s0.tolist(), s1.tolist(), gap_i, gap_j, xs):
        if not m:
            continue
        arms_i = _reference_meeting(t_i, lengths[i], u[i], g_i, tol + line_widths[j])
        arms_j = _reference_meeting(t_j, lengths[j], u[j], g_j, tol + line_widths[i])
        if arms_i is None or arms_j is None:
            continue
        arms = np.array(arms_i[0] + arms_j[0])
        if len(arms) == 4:
            continue  # two straight lines crossing: fields have none (their X is the centre
            # circle on the halfway line), so it is no crossing of field lines
        kind = {2: "L", 3: "T"}[len(arms)]
        out.append(cr.LineCrossing(kind, x, arms, (i, j), np.array(arms_i[1] + arms_j[1])))
    return cr.merge_line_crossings(out, tol, floor_of=floor_of)




def _reference_meeting(t: float, length: float, u: np.ndarray, end_gap: float, tol: float
             ) -> tuple[list[np.ndarray], list[float]] | None:
    """Arms of a line (direction ``u``, ends at 0 and ``length`` along it) at the point ``t``
    along it where another line crosses it, and the line's length along each: two when the
    point is inside it by more than ``tol``, one when its nearer end lies within ``tol`` of
    the other line (``end_gap``: that end's distance from the other line), else None."""
    if tol < t < length - tol:
        return [u, -u], [length - t, t]
    if end_gap > tol:
        return None
    return ([u], [length - t]) if t <= 0.5 * length else ([-u], [t])


def _floor_homography(rng):
    """A random image -> floor homography (3 x 3) of a camera looking down at the floor,
    its inverse, and the floor_of of it (NaN above the horizon)."""
    h = np.array([[0.01, 0.0, -3.0], [0.0, -0.002, 1.5], [0.0, 0.004, -0.5]])
    h = h + rng.normal(0, 2e-4, (3, 3))

    def floor_of(p):
        p = np.asarray(p, float).reshape(-1, 2)
        q = np.concatenate([p, np.ones((len(p), 1))], axis=1) @ h.T
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(q[:, 2:] > 1e-9, q[:, :2] / q[:, 2:], np.nan)

    return h, np.linalg.inv(h), floor_of


def test_distinct_arms_equal_the_former_python():
    """crossings._distinct_arms (merge_line_crossings' arms of a group) keeps the arms and
    lengths the former Python loop kept, its dots as numpy's ``@`` (arms about ``same_arm``
    apart, where the test is decided by the last bit)."""
    rng = np.random.default_rng(21)
    cos_same = math.cos(math.radians(20.0))
    for _ in range(3000):
        n = int(rng.integers(1, 9))
        ang = rng.choice([0.0, math.radians(20.0), math.pi / 2, math.pi], n) \
            + rng.normal(0, 1e-9, n) * rng.integers(0, 2, n)
        cmp = np.stack([np.cos(ang), np.sin(ang)], axis=1) * rng.uniform(0.5, 2, (n, 1))
        lengths = rng.uniform(0, 50, n)
        lengths[rng.random(n) < 0.1] = np.nan
        arms, kept = [], []
        for k, ln in enumerate(lengths):
            same = [m for m, j in enumerate(arms) if float(cmp[k] @ cmp[j]) >= cos_same]
            if same:
                kept[same[0]] = max(kept[same[0]], float(ln))
            else:
                arms.append(k)
                kept.append(float(ln))
        got_arms, got_len = np.empty(n, np.int64), np.empty(n)
        m = cr._distinct_arms(cmp, lengths, cos_same, got_arms, got_len)
        assert got_arms[:m].tolist() == arms
        assert got_len[:m].tobytes() == np.array(kept).tobytes()


@pytest.mark.parametrize("seed", range(4))
def test_line_pair_crossings_equal_the_former_numpy(seed):
    """crossings.line_pair_crossings (``_pair_crossings``) gives the crossings the former numpy
    and Python gave, to the bit: of lines meeting as L, T and X on the floor, near misses,
    parallel and random lines, with stems and without."""
    rng = np.random.default_rng(seed)
    _, h_inv, floor_of = _floor_homography(rng)

    def to_image(f):
        q = np.concatenate([f, np.ones((len(f), 1))], axis=1) @ h_inv.T
        return q[:, :2] / q[:, 2:]

    found = {"L": 0, "T": 0}
    for trial in range(60):
        segs = []
        for _ in range(int(rng.integers(1, 5))):  # L, T, X shapes on the floor
            c = rng.uniform([0.5, -2.0], [5.0, 2.0])
            a = rng.uniform(0, math.pi)
            u = np.array([math.cos(a), math.sin(a)])
            v = np.array([-u[1], u[0]]) * (1 + rng.normal(0, 0.05))
            lo, hi = rng.uniform(-1.0, 0.3, 2), rng.uniform(-0.3, 1.0, 2)
            segs.append([c + lo[0] * u, c + hi[0] * u])
            segs.append([c + lo[1] * v, c + hi[1] * v])
        for _ in range(int(rng.integers(0, 4))):  # others
            segs.append(rng.uniform([0.3, -3.0], [6.0, 3.0], (2, 2)))
        floor_ends = np.array(segs)
        ends = to_image(floor_ends.reshape(-1, 2)).reshape(-1, 2, 2)
        ends = ends + rng.normal(0, 0.5, ends.shape)
        if trial % 7 == 0:
            ends[0, 1] = ends[0, 0]  # no length
        if trial % 5 == 0 and len(ends) > 2:
            ends[1] = ends[2] + 3.0  # parallel
        widths = rng.uniform(0, 6, len(ends))
        for first_stem in (None, max(1, len(ends) - 2)):
            got = cr.line_pair_crossings(ends, widths, floor_of, 12.0, math.radians(30.0),
                                         first_stem)
            ref = _reference_line_pair_crossings(ends, widths, floor_of, 12.0,
                                                 math.radians(30.0), first_stem)
            assert len(got) == len(ref)
            for g, r in zip(got, ref):
                assert (g.kind, g.lines) == (r.kind, r.lines)
                for a, b in ((g.point, r.point), (g.arms, r.arms), (g.lengths, r.lengths)):
                    a, b = np.asarray(a, float), np.asarray(b, float)
                    assert a.shape == b.shape and a.tobytes() == b.tobytes()
                found[g.kind] += 1
    assert min(found.values()) >= 10, found


def test_ideal_pixels_read_the_tables_as_cv2_remap():
    """perspective.IdealPixels (``_look_up``, exact_ops.remap_at) reads its undistortion
    tables as its former cv2.remap (INTER_LINEAR, NaN beyond the tables) did, to the bit:
    inside the image, across its edges, on pixels and halfway, and at NaN and infinite
    pixels (NaN where it gave NaN)."""
    import cv2

    class Camera:  # a wide-angle lens as the KidSize renderer's
        image_size = (752, 480)
        fx, fy, cx, cy = 330.0, 330.0, 375.5, 239.5
        distortion = np.array([-0.25, 0.06, 0.001, -0.001, 0.0])
        camera_matrix = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

        def undistort_points(self, p):
            # a smooth stand-in for the Newton iterations (the tables are what is read)
            c = np.array([self.cx, self.cy])
            r2 = np.sum(((p - c) / self.fx) ** 2, axis=-1, keepdims=True)
            return c + (p - c) * (1 + 0.2 * r2)

    ideal = perspective.IdealPixels(Camera())
    rng = np.random.default_rng(9)
    uv = rng.uniform(-10, [762, 490], (30000, 2))
    uv[200:3000] = np.round(uv[200:3000] * 2) / 2
    uv[:100] = np.nan
    uv[100:200, 0] = np.inf
    p = np.asarray(uv, np.float32).reshape(-1, 1, 2) / np.float32(ideal.stride)
    ref = np.stack([cv2.remap(m, p[..., 0], p[..., 1], cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan")).ravel()
                    for m in (ideal.map_u, ideal.map_v)], axis=1).astype(np.float64)
    got = ideal(uv)
    nan = np.isnan(ref)
    assert got.dtype == ref.dtype and np.array_equal(np.isnan(got), nan) and nan.sum() > 200
    assert got[~nan].tobytes() == ref[~nan].tobytes()  # (a NaN's sign bit aside)


# the lines' width ratios as they were before ``perspective._width_ratios`` (numpy)
def _reference_width_ratios(refs, to_floor, line_width: float) -> dict[int, float]:
    """Per refined line (by id): the median of its white runs' widths over the width a
    painted line of ``line_width`` metres has in the image at each run's floor position (both
    across the line, in ideal pixels); NaN where no run lies on the floor. All lines' points
    are projected together."""
    if not refs:
        return {}
    counts = np.array([len(r.centres) for r in refs])
    floor = to_floor(np.concatenate([r.centres for r in refs]))
    ends = to_floor(np.concatenate([r.ends for r in refs])).reshape(-1, 2, 2)
    d = ends[:, 1] - ends[:, 0]
    length = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        nf = np.stack([-d[:, 1], d[:, 0]], axis=1) / length[:, None]
    nf_pts = np.repeat(nf, counts, axis=0)
    half = 0.5 * line_width
    a = to_floor.to_ideal(floor - half * nf_pts)
    b = to_floor.to_ideal(floor + half * nf_pts)
    n_img = np.repeat(np.array([r.fit.normal for r in refs]), counts, axis=0)
    expected = np.abs(((b - a) * n_img).sum(axis=1))
    ratio = np.concatenate([r.widths for r in refs]) / np.maximum(expected, 1e-6)
    ok = np.all(np.isfinite(floor), axis=1) & np.isfinite(ratio)
    out, k = {}, 0
    for r, n in zip(refs, counts):
        sel = ok[k:k + n]
        out[id(r)] = float(lf.median(ratio[k:k + n][sel])) if sel.any() else float("nan")
        k += n
    return out


@pytest.mark.parametrize("seed", range(3))
def test_width_ratios_equal_the_former_numpy(seed):
    """perspective.width_ratios (``_width_ratios``) gives the ratios the former numpy gave, to
    the bit: for lines on the floor, partly and wholly beyond the horizon, of one run and
    many, with a lens over the floor's origin and beside it."""
    rng = np.random.default_rng(seed)
    for shifted in (False, True):
        floor = object.__new__(perspective.FloorProjection)
        pitch = 0.5 + rng.normal(0, 0.1)
        c, s = math.cos(pitch), math.sin(pitch)
        k_inv = np.linalg.inv(np.array([[330.0, 0, 375.5], [0, 330.0, 239.5], [0, 0, 1]]))
        rot = np.array([[0.0, -s, c], [-1.0, 0.0, 0.0], [0.0, -c, -s]])
        floor.m = rot @ k_inv + rng.normal(0, 1e-5, (3, 3))
        floor.m_inv = np.linalg.inv(floor.m)
        floor.height = 0.45
        floor.position = np.array([0.03, -0.02]) if shifted else np.zeros(2)
        floor._shifted = shifted
        refs = []
        for k in range(int(rng.integers(1, 12))):
            n = 1 if k == 0 and seed == 1 else int(rng.integers(2, 30))
            p = rng.uniform([0, 0], [752, 480], 2)
            q = p + rng.normal(0, 80, 2)
            t = np.sort(rng.uniform(0, 1, n))[:, None]
            centres = p * (1 - t) + q * t + rng.normal(0, 0.5, (n, 2))
            d = (q - p) / np.hypot(*(q - p))
            fit = lf.LineFit(centres.mean(axis=0), d, np.array([-d[1], d[0]]), 0.1)
            refs.append(lf.RefinedLine(np.array([p, q]), fit, centres,
                                       rng.uniform(1, 9, n)))
        got = perspective.width_ratios(refs, floor, 0.05)
        ref = _reference_width_ratios(refs, floor, 0.05)
        assert list(got) == list(ref)
        assert np.array(list(got.values())).tobytes() == np.array(list(ref.values())).tobytes()


def test_gap_grey_equals_the_remap_minimum():
    """line_structure's ``_gap_grey`` (fill_gaps' grey level along the candidate gaps) gives
    the former cv2.remap of all gaps' points and their minimum, to the bit: gaps inside the
    grid, across its edges and of no length."""
    import cv2

    rng = np.random.default_rng(10)
    image = cv2.GaussianBlur(rng.random((60, 94)).astype(np.float32), (5, 5), 1.0)
    pos = rng.uniform(-2, [95, 61], (300, 2))
    pos[:20] = np.round(pos[:20])
    ci, cj = rng.integers(0, 300, 2000), rng.integers(0, 300, 2000)
    ci[:10] = cj[:10]
    for samples in (2, 8):
        t = ls._gap_steps(samples)
        pts = (pos[ci][:, None, :] * (1 - t) + pos[cj][:, None, :] * t).astype(np.float32)
        ref = cv2.remap(image, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=0).min(axis=1)
        got = np.empty(len(ci), np.float32)
        ls._gap_grey(pos, ci, cj, t[0, :, 0], image, got)
        assert got.tobytes() == ref.tobytes()


# an L candidate's corner angle as it was before ``crossings._corner_angles``
def _reference_angle_between(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = np.hypot(*a), np.hypot(*b)
    if na == 0 or nb == 0:
        return 0.0
    return math.acos(max(-1.0, min(1.0, float(a @ b) / (na * nb))))


def test_corner_angles_equal_the_former_angle_between():
    """crossings' ``_corner_angles`` (the L candidates' angles) gives the former
    _angle_between's, to the bit: in the grid, on the floor where all three points are on it,
    and for arms of no length, straight and folded back."""
    from stages.extract import crossings as cr

    rng = np.random.default_rng(11)
    corners = rng.normal(0, 5, (3000, 3, 2))
    corners[:50, 1] = corners[:50, 0]  # an arm of no length
    corners[50:100, 2] = corners[50:100, 0] + 2.0 * (corners[50:100, 1] - corners[50:100, 0])
    corners[100:150, 2] = corners[100:150, 0] - (corners[100:150, 1] - corners[100:150, 0])
    floor = rng.normal(0, 2, corners.shape)
    floor[::7, rng.integers(0, 3)] = np.nan  # above the horizon
    for use_floor in (False, True):
        got = np.empty(len(corners))
        cr._corner_angles(corners, floor, use_floor, got)
        ref = []
        for c, f in zip(corners, floor):
            ang = _reference_angle_between(c[1] - c[0], c[2] - c[0])
            if use_floor and np.isfinite(f).all():
                ang = _reference_angle_between(f[1] - f[0], f[2] - f[0])
            ref.append(ang)
        assert got.tobytes() == np.array(ref).tobytes()
