"""Colour classes (stages/common/colour.py): the fast classifier (integer luminance thresholds
per block, in-place float32 chroma tests on strips of rows, counts per cell) gives the classes
of the per-pixel formulas of the module doc, evaluated here as written (the reference, as the
extractor computed them before), on all YUV values and on whole frames."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from oracles.decisions import assert_decisions_agree, le_margin

from stages.common import colour
from stages.common.errors import FieldlocError

CONF = colour.confs["default"]


def reference_green_chroma(y, u, v, fc):
    """Green ellipse test, float32, chroma rescaled to the field's luminance (module doc):
    (decision, relative margin)."""
    y = np.maximum(np.asarray(y, np.float32), np.float32(1.0))
    du = (np.asarray(u, np.float32) - np.float32(128.0)) * np.float32(fc.y) \
        - np.float32(fc.u - 128.0) * y
    dv = (np.asarray(v, np.float32) - np.float32(128.0)) * np.float32(fc.y) \
        - np.float32(fc.v - 128.0) * y
    a2, b2 = np.float32(fc.axes[0] ** 2), np.float32(fc.axes[1] ** 2)
    return le_margin(du * du * b2 + dv * dv * a2, y * y * (a2 * b2))


def reference_white_chroma(y, u, v, conf=CONF):
    """White chroma test (saturation against luminance): (decision, relative margin)."""
    y = np.asarray(y, np.float32)
    du, dv = np.asarray(u, np.float32) - 128.0, np.asarray(v, np.float32) - 128.0
    sat = np.float32(conf["white_max_saturation"])
    return le_margin(du * du + dv * dv, (sat * sat) * (y * y))


def reference_classes(yuv, fc, y_green, conf=CONF):
    """Per-pixel classes of YUV pixels (..., 3) with local green luminance ``y_green``."""
    p = yuv.astype(np.float32)
    y, u, v = p[..., 0], p[..., 1], p[..., 2]
    yg = np.asarray(y_green, np.float32)
    white_y = np.maximum(yg + np.float32(conf["white_contrast"]) * (np.float32(255.0) - yg),
                         np.float32(conf["white_min_y"]))
    tests = [le_margin(white_y, y), reference_white_chroma(y, u, v, conf),
             le_margin(np.float32(conf["green_min_ratio"]) * yg, y),
             le_margin(y, np.float32(conf["green_max_ratio"]) * yg),
             reference_green_chroma(y, u, v, fc)]
    (w_y, w_c, g_lo, g_hi, g_c), margins = zip(*tests)
    white = w_y & w_c
    green = g_lo & g_hi & g_c
    out = np.full(y.shape, colour.OTHER, np.uint8)
    out[green] = colour.GREEN
    out[white] = colour.WHITE
    return out, np.minimum.reduce(margins)


def test_chroma_tests_equal_the_formulas_on_every_yuv_value():
    """All 2^24 (Y, U, V) for a typical field green."""
    fc = colour.FieldColour(101.5, 108.25, 93.75, (14.0, 17.5), True, 0.5)
    for y0 in range(0, 256, 32):  # slabs of 32 luminances (2^21 values each)
        y, u, v = (a.astype(np.uint8) for a in np.meshgrid(
            np.arange(y0, y0 + 32), np.arange(256), np.arange(256), indexing="ij"))
        green, white = colour._chroma_tests(y, u, v, fc, CONF)
        assert_decisions_agree(green, *reference_green_chroma(y, u, v, fc), what=y0)
        assert_decisions_agree(white, *reference_white_chroma(y, u, v), what=y0)


@pytest.mark.parametrize("seed", range(4))
def test_chroma_tests_equal_the_formulas_for_other_colours(seed):
    """Dark and bright fields, bluish and yellowish greens, narrow and wide ellipses."""
    rng = np.random.default_rng(seed)
    fc = colour.FieldColour(float(rng.uniform(0, 240)), float(rng.uniform(70, 140)),
                            float(rng.uniform(60, 140)),
                            (float(rng.uniform(14, 60)), float(rng.uniform(14, 60))), True, 0.5)
    y, u, v = rng.integers(0, 256, (3, 1_000_000)).astype(np.uint8)
    green, white = colour._chroma_tests(y, u, v, fc, CONF)
    assert_decisions_agree(green, *reference_green_chroma(y, u, v, fc))
    assert_decisions_agree(white, *reference_white_chroma(y, u, v))
    assert green.sum() > 100  # the sample reaches into the ellipse


def frame(h=123, w=170, seed=0) -> np.ndarray:
    """A BGR frame with a vignetted green carpet, white lines of several widths, a grey and a
    dark object, colour noise, and a size that is not a multiple of the 8 px blocks."""
    rng = np.random.default_rng(seed)
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.empty((h, w, 3), np.float32)
    img[:] = (40, 140, 50)
    for k, width in enumerate((1, 2, 4, 7)):
        img[np.abs(uu - 0.9 * vv - 20 - 35 * k) < width / 2] = (230, 235, 228)
    img[10:40, 120:160] = (110, 105, 100)
    img[80:110, 5:30] = (25, 30, 35)
    gain = 1.0 - 0.6 * ((uu - w / 2) ** 2 + (vv - h / 2) ** 2) / (w * w / 4 + h * h / 4)
    img = img * gain[..., None] + rng.normal(0.0, 6.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_classify_image_equals_the_reference_classifier():
    img = frame()
    valid = np.ones(img.shape[:2], bool)
    valid[:, :9] = False
    labels, fc = colour.classify_image(img, CONF, valid)
    yuv = colour.to_yuv(img)
    assert fc.found and fc.y_map is not None
    vv, uu = np.indices(img.shape[:2])
    ref, margin = reference_classes(yuv, fc, fc.local_y(uu, vv))
    ref[~valid] = colour.OTHER
    margin[~valid] = np.inf
    assert_decisions_agree(labels, ref, margin)
    # the local green luminance as an image and per pixel: the same interpolation, in grey
    # levels (0-255), equal to far below a level
    np.testing.assert_allclose(fc.local_y_image(img.shape), fc.local_y(uu, vv), rtol=0,
                               atol=1e-6)
    for c in (colour.GREEN, colour.WHITE, colour.OTHER):  # all classes occur
        assert (labels == c).mean() > 0.02
    # the same pixels through the other entry points
    flat = np.flatnonzero(valid)
    block = colour.FieldColour.block_index(uu.ravel()[flat], vv.ravel()[flat],
                                           fc.y_map.shape, fc.cell)
    assert_decisions_agree(colour.classify_pixels(yuv, flat, block, fc, CONF),
                           labels.ravel()[flat], margin.ravel()[flat])
    assert_decisions_agree(colour.classify_yuv(yuv, fc, CONF, fc.local_y_image(yuv.shape)),
                           *reference_classes(yuv, fc, fc.local_y(uu, vv)))


def test_classify_yuv_without_a_local_map_and_with_bright_local_green():
    """The frame's green luminance for all pixels; a local green above 255 (thresholds that no
    longer fit 8 bits) still gives the formulas' classes."""
    fc = colour.FieldColour(90.0, 105.0, 95.0, (14.0, 14.0), True, 0.5)
    rng = np.random.default_rng(3)
    px = rng.integers(0, 256, (50_000, 3)).astype(np.uint8)
    assert_decisions_agree(colour.classify_yuv(px, fc, CONF), *reference_classes(px, fc, fc.y))
    yg = rng.uniform(0.0, 400.0, len(px))
    assert_decisions_agree(colour.classify_yuv(px, fc, CONF, yg),
                           *reference_classes(px, fc, yg))


def test_grid_counts_are_the_counts_of_the_classes():
    img = frame(160, 200, seed=1)
    labels, _ = colour.classify_image(img, CONF)
    counts, fc = colour.classify_grid(img, CONF)
    assert counts.shape == (20, 25, 3) and np.all(counts.sum(axis=2) == 64)
    assert np.array_equal(counts, colour.class_counts(labels))  # exact integers: pixel counts
    # cells of 6 px (not a power of two) and 7 px (blocks of the local map straddle cells)
    for cell in (6, 7):
        assert np.array_equal(colour.classify_grid(img, CONF, cell=cell)[0],
                              colour.class_counts(labels, cell))  # exact integers: pixel counts
    # step 2: the classes of every 2nd pixel of every 2nd row, counted 4 times
    counts2, _ = colour.classify_grid(img, CONF, step=2)
    sub = labels[::2, ::2]
    assert np.array_equal(counts2, 4 * colour.class_counts(sub, 4))  # exact integers: pixel counts
    with pytest.raises(FieldlocError):
        colour.classify_grid(img, CONF, step=3)


def test_black_frame_and_a_frame_without_green():
    black = np.zeros((64, 80, 3), np.uint8)
    counts, fc = colour.classify_grid(black, CONF)
    assert not fc.found and np.all(counts[..., colour.OTHER] == 64)
    grey = np.full((64, 80, 3), 128, np.uint8)
    labels, fc = colour.classify_image(grey, CONF)
    assert not fc.found
    assert_decisions_agree(labels, *reference_classes(colour.to_yuv(grey), fc, fc.y))


def test_green_search_candidates_are_the_hue_window():
    """The (U, V) table of the field green search equals the hue angle test."""
    ok = colour._green_candidate_chroma(tuple(CONF["green_hue_deg"]),
                                        float(CONF["green_min_chroma"])).reshape(256, 256)
    cu, cv_ = np.meshgrid(np.arange(256) - 128, np.arange(256) - 128, indexing="ij")
    hue = np.degrees(np.arctan2(cv_, cu))
    h0, h1 = CONF["green_hue_deg"]
    (lo, m_lo), (hi, m_hi), (far, m_far) = (
        le_margin(h0, hue), le_margin(hue, h1),
        le_margin(CONF["green_min_chroma"], np.hypot(cu, cv_)))
    assert_decisions_agree(ok, lo & hi & far, np.minimum.reduce([m_lo, m_hi, m_far]))
    assert math.isclose(colour.hue_deg(100, 100), -135.0)


def test_field_colour_follows_the_carpet():
    img = frame(seed=2)
    fc = colour.estimate_field_colour(colour.to_yuv(img), CONF)
    carpet = cv2.cvtColor(np.array([[[40, 140, 50]]], np.uint8), cv2.COLOR_BGR2YUV)[0, 0]
    assert fc.found
    # the chroma centre at the field's luminance points the carpet's way
    assert abs(colour.hue_deg(fc.u, fc.v) - colour.hue_deg(*carpet[1:])) < 10.0
