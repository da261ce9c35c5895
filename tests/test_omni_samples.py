"""The omni extractor reads and classifies only the pixels its scan lines cross, and
the few that the field green and the local green map are estimated from.

- the YUV values of the gathered pixels are OpenCV's conversion of the frame there;
- the classes of those pixels follow the formulas (colour.classify_yuv) with the local green
  map that the colour module doc defines, computed here by array passes over the same pixels;
- the field green and the local green map are the whole-frame estimates;
- the compiled run detection and per-frame arrays equal the array passes they replace
  (tests/oracles/omni_scanlines.py) on the same classes;
- on rendered omni-default and omni-hard frames the extractor's classes and features are the
  former whole-frame path's.
"""

from __future__ import annotations

import copy

import cv2
import numpy as np
import pytest
from oracles import omni_scanlines as former
from oracles.decisions import assert_decisions_agree
from test_colour import frame, reference_classes
from test_extract_omni import CAMERA, draw, line_band

from stages import simulate
from stages.common import colour
from stages.common.dataset import open_dataset, read_image
from stages.extract import omni

CONF = omni.confs["default"]
CCONF = omni.colour_conf(CONF)  # the full colour conf the extractor passes on


def test_yuv_of_the_pixels_is_opencvs():
    """The pixels asked for, in the order asked, as rows and as planes: cv2's YUV of the
    frame at those pixels."""
    image = frame(61, 83, seed=4)
    flat = np.random.default_rng(0).permutation(61 * 83)[:900]
    want = colour.to_yuv(image).reshape(-1, 3)[flat]
    assert np.array_equal(colour.yuv_rows_at(image, flat), want)  # exact integers: uint8 YUV
    assert np.array_equal(colour.yuv_at(image, flat), want.T)  # exact integers: uint8 YUV


def local_green_map(yuv, px, fc, conf=CCONF):
    """The local green map of the colour module doc by array passes: per block the mean Y of
    its floor pixels green by chroma with Y in LOCAL_GREEN_BAND times the field's, where they
    are at least a quarter of its floor pixels (and one); else over the local_fill window; else the
    field's luminance."""
    green = colour._chroma_tests(yuv[0], yuv[1], yuv[2], fc, conf, white=False)[0]
    lo, hi = colour._local_green_band(fc)
    green &= (yuv[0] >= lo) & (yuv[0] <= hi) & px.floor
    nb = px.map_shape[0] * px.map_shape[1]
    n = np.bincount(px.block[px.floor], minlength=nb).astype(np.float32).reshape(px.map_shape)
    gs, ys = (np.bincount(px.block, w, minlength=nb).astype(np.float32).reshape(px.map_shape)
              for w in (green, green * yuv[0].astype(np.float64)))
    k = int(conf["local_fill"]) | 1
    gs_w, ys_w = (cv2.boxFilter(a, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
                  for a in (gs, ys))
    return np.where(gs >= np.maximum(0.25 * n, 1), ys / np.maximum(gs, 1e-6),
                    np.where(gs_w > 0, ys_w / np.maximum(gs_w, 1e-6), fc.y)).astype(np.float32)


@pytest.mark.parametrize("model", ["ellipse", "hue"])
def test_classes_of_the_pixels_follow_the_formulas(model):
    """A vignetted frame with lines, objects and noise; a random third of its pixels (some off
    the floor), in any order: the local green map of those pixels (the module doc's rules),
    and their classes with it (white wins; off the floor OTHER) as colour.classify_yuv gives
    them."""
    conf = dict(CCONF)
    if model == "hue":
        conf.update(green_model="hue", green_hue_tolerance_deg=12.0, green_hue_k=3.0,
                    green_saturation=[0.5, 2.0])
    image = frame(123, 170, seed=5)
    rng = np.random.default_rng(1)
    flat = rng.permutation(123 * 170)[:7000]
    yuv = colour.yuv_at(image, flat)
    fc = colour.field_colour_of_samples(colour.yuv_rows_at(image, flat[::3]), conf)
    assert fc.found and (fc.hue_dir is not None) == (model == "hue")
    shape = (123 // fc.cell, 170 // fc.cell)
    block = colour.FieldColour.block_index(flat % 170, flat // 170, shape, fc.cell)
    floor = rng.random(len(flat)) > 0.1
    px = colour.PixelBlocks.of(block.astype(np.int32), floor, shape)
    colour.local_green_map(yuv, px, fc, conf)
    np.testing.assert_allclose(fc.y_map, local_green_map(yuv, px, fc, conf), rtol=1e-6)
    labels = colour.classify_blocks(yuv, px, fc, conf)
    want = colour.classify_yuv(yuv.T, fc, conf, fc.y_map.ravel()[block])
    want[~floor] = colour.OTHER
    # exact decisions of the same float32 formulas, but a tie may round either way elsewhere
    differ = labels != want
    assert differ.mean() <= 1e-3, differ.sum()
    if model == "ellipse":  # and those of the formulas as written, where their margin is clear
        ref, margin = reference_classes(yuv.T, fc, fc.y_map.ravel()[block])
        ref[~floor] = colour.OTHER
        margin[~floor] = np.inf
        assert_decisions_agree(labels, ref, margin)
    for c in (colour.GREEN, colour.WHITE, colour.OTHER):
        assert (labels == c).mean() > 0.02


def test_a_frame_without_green_uses_the_nominal_colour_and_no_map():
    grey = np.full((64, 80, 3), 128, np.uint8)
    flat = np.arange(64 * 80)
    yuv = colour.yuv_at(grey, flat)
    fc = colour.field_colour_of_samples(colour.yuv_rows_at(grey, flat), CCONF)
    shape = (8, 10)
    block = colour.FieldColour.block_index(flat % 80, flat // 80, shape, 8)
    px = colour.PixelBlocks.of(block, np.ones(len(flat), bool), shape)
    colour.local_green_map(yuv, px, fc, CCONF)
    labels = colour.classify_blocks(yuv, px, fc, CCONF)
    assert not fc.found and fc.y_map is None
    assert_decisions_agree(labels, *reference_classes(yuv.T, fc, fc.y))


def test_scanline_pixels_each_once_in_blocks():
    """The pixels of the samples, each once; a sample's pixel is its (u, v); their blocks and
    floor counts; the field green's pixels one in 6 x 6 of the floor annulus, the local green
    map's 2 x 2 per block of it, consecutive ones in different blocks."""
    mask = np.ones((480, 480), bool)
    mask[:240, 200:280] = False
    pix = omni.build_scanline_pixels(CAMERA, CONF, mask)
    w = CAMERA.image_size[0]
    assert len(np.unique(pix.pixels)) == len(pix.pixels)
    assert np.array_equal(pix.pixels[pix.sample_pixel], pix.v * w + pix.u)  # exact integers: pixels
    px = pix.blocks
    u, v = pix.pixels % w, pix.pixels // w
    assert np.array_equal(px.block, colour.FieldColour.block_index(  # exact integers: indices
        u, v, px.map_shape, pix.cell))
    assert np.array_equal(px.floor, mask[v, u])  # exact decisions: the mask
    assert np.array_equal(px.floor_count, np.bincount(  # exact integers: counts
        px.block[px.floor], minlength=px.map_shape[0] * px.map_shape[1]))
    mp = pix.map_blocks
    assert np.all(mp.block[1:] != mp.block[:-1]) and len(pix.map_flat) == mp.floor_count.sum()
    mu, mv = pix.map_flat % w, pix.map_flat // w
    assert mask[mv, mu].all() and np.all(mu % 4 == 0) and np.all(mv % 4 == 0)
    assert np.array_equal(mp.block, colour.FieldColour.block_index(  # exact integers: indices
        mu, mv, px.map_shape, pix.cell))
    floor = former.floor_annulus(CAMERA, pix, mask)
    grid = np.zeros_like(floor)
    grid[::6, ::6] = True
    assert np.array_equal(pix.colour_flat,  # exact integers: pixel indices
                          np.flatnonzero(floor & grid))
    grid[:] = False
    grid[::4, ::4] = True
    assert np.array_equal(np.sort(pix.map_flat),  # exact integers: pixel indices
                          np.flatnonzero(floor & grid))

def test_field_green_and_local_map_are_the_whole_frame_ones():
    """On a vignetted frame with lines, noise and a mask: the field green from the omni
    extractor's few pixels, and its local green map, are estimate_field_colour's of the whole
    frame (the same pixels of the floor annulus, the same rules)."""
    img = draw(lambda p: line_band(0.0, 0.8)(p) | line_band(0.0, 2.4)(p), noise=4.0)
    img = img.astype(np.float32)
    vv, uu = np.indices(img.shape[:2])
    r = np.hypot(uu - CAMERA.centre[0], vv - CAMERA.centre[1]) / 240.0
    img = (img * (1.0 - 0.55 * r ** 2)[..., None]).astype(np.uint8)
    mask = np.ones((480, 480), bool)
    mask[:240, 200:280] = False
    pix = omni.scanline_pixels(CAMERA, CONF, mask)
    whole = colour.estimate_field_colour(colour.to_yuv(img), CCONF,
                                         former.floor_annulus(CAMERA, pix, mask))
    _, fc = omni.classify_scanlines(img, pix, CONF)
    assert fc.found and whole.found
    np.testing.assert_allclose([fc.y, fc.u, fc.v, *fc.axes, fc.share],
                               [whole.y, whole.u, whole.v, *whole.axes, whole.share],
                               rtol=1e-12, atol=0)
    crossed = np.unique(pix.blocks.block)
    np.testing.assert_allclose(fc.y_map.ravel()[crossed], whole.y_map.ravel()[crossed],
                               rtol=1e-6, atol=0)
    assert len(pix.colour_flat) + len(pix.map_flat) < 0.1 * img.shape[0] * img.shape[1]


def test_scanline_pixels_are_cached_per_calibration_and_conf():
    a = omni.scanline_pixels(CAMERA, CONF)
    assert omni.scanline_pixels(CAMERA, CONF) is a
    assert omni.scanline_pixels(copy.deepcopy(CAMERA), copy.deepcopy(CONF)) is a
    other = omni.scanline_pixels(CAMERA, {**CONF, "points_radial_lines": 36})
    assert other is not a and other.size > a.size
    assert omni.scanline_pixels(CAMERA, CONF) is a


def assert_runs_equal(got, want):
    assert np.array_equal(got.line, want.line)  # exact integers: line indices
    assert np.array_equal(got.length, want.length)  # exact integers: pixel counts
    assert np.array_equal(got.blocked, want.blocked)  # exact decisions: blocked lines
    np.testing.assert_allclose(got.mid_s, want.mid_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.width, want.width, rtol=0, atol=1e-9)


def assert_features_equal(got, want):
    for key in ("radial", "spiral"):
        assert np.array_equal(np.isnan(got[key]), np.isnan(want[key]))
        np.testing.assert_allclose(got[key], want[key], rtol=0, atol=1e-6, equal_nan=True)
    for key in ("points", "points_px"):
        np.testing.assert_allclose(got[key], want[key], rtol=0, atol=1e-4)


def fuzzed_classes(pix, seed):
    """Class sequences along the scan lines like a frame's: runs of random classes and
    lengths (1-3 samples often, so that holes, gaps and short runs occur)."""
    rng = np.random.default_rng(seed)
    lengths = np.where(rng.random(pix.size) < 0.6, rng.integers(1, 4, pix.size),
                       rng.integers(4, 40, pix.size))
    classes = rng.choice([colour.GREEN, colour.WHITE, colour.OTHER], pix.size, p=[0.6, 0.25,
                                                                                  0.15])
    per_sample = np.repeat(classes, lengths)[:pix.size].astype(np.uint8)
    per_pixel = np.empty(len(pix.pixels), np.uint8)
    per_pixel[pix.sample_pixel] = per_sample  # a pixel on several lines: one of their classes
    return per_pixel


def test_compiled_runs_equal_the_array_passes():
    """On the classes of drawn frames (lines at several distances, one with grey edges) and
    on fuzzed class sequences: the same runs, blocked lines and per-frame arrays."""
    pix = omni.scanline_pixels(CAMERA, CONF)
    frames = [draw(lambda p: line_band(0.0, 0.6)(p) | line_band(1.2, 1.4)(p)
                   | line_band(2.5, 2.2, width=0.3)(p)),
              draw(line_band(0.0, 1.0), ss=1, noise=4.0,
                   other_fn=lambda p: np.abs(np.abs(p[..., 0] - 1.0) - 0.065) <= 0.015)]
    sequences = [omni.classify_scanlines(f, pix, CONF)[0] for f in frames]
    sequences += [fuzzed_classes(pix, seed) for seed in range(3)]
    for labels in sequences:
        runs = omni.find_white_runs(labels, pix, CONF)
        want = former.white_runs(labels[pix.sample_pixel], pix, CONF)
        assert len(want.line) > 0
        assert_runs_equal(runs, want)
        assert_features_equal(omni.frame_features(pix, runs), former.features(pix, want))


@pytest.fixture(scope="module")
def rendered_frames(tmp_path_factory):
    """Three frames of each of two seeds of omni-default and omni-hard, with their camera."""
    out = {}
    for preset in ("omni-default", "omni-hard"):
        frames = []
        for seed in (0, 1):
            conf = copy.deepcopy(simulate.confs[preset])
            conf.update(frames=3, seed=seed)
            ds = open_dataset(simulate.main(conf, "msl-2015",
                                            tmp_path_factory.mktemp(preset) / str(seed)))
            frames += [(read_image(p), ds.camera()) for p in ds.images]
        out[preset] = frames
    return out


@pytest.mark.parametrize("preset", ["omni-default", "omni-hard"])
def test_the_features_are_the_whole_frame_paths(rendered_frames, preset):
    """Lab clutter, people, robots, noise and changing light: the field green of the frame,
    the classes of the scan-line samples (but for a tie's rounding: at most 1 in 10,000) and
    so the crossings and points the former whole-frame colour path gives (the same, but for a
    tie: 1 mm)."""
    for image, camera in rendered_frames[preset]:
        pix = omni.scanline_pixels(camera, CONF)
        labels, fc = omni.classify_scanlines(image, pix, CONF)
        old_labels, old_fc = former.whole_image_classes(image, camera, pix, CONF)
        np.testing.assert_allclose([fc.y, fc.u, fc.v], [old_fc.y, old_fc.u, old_fc.v],
                                   rtol=1e-12, atol=0)
        assert np.mean(labels[pix.sample_pixel] != old_labels) <= 1e-4
        new = omni.extract_frame(image, camera, CONF)
        old = former.features(pix, former.white_runs(old_labels, pix, CONF))
        for key in ("radial", "spiral"):
            differ = np.isnan(new[key]) != np.isnan(old[key])
            assert differ.sum() <= 1, (key, differ.sum())
            both = ~np.isnan(new[key]) & ~np.isnan(old[key])
            assert np.mean(np.abs(new[key][both] - old[key][both]) <= 1e-3) >= 0.99
        assert abs(len(new["points"]) - len(old["points"])) <= 1
