"""Shared code (stages/common/colour.py, stages/simulate/scene.py) serves the perspective camera
too, and its perspective-only parts must not touch the omni camera: the omni renderer's frames, the
omni extractor's features and the colour classes of the omni conf must stay as they were.
tests/data/omni_unchanged_reference.npz holds them as the omni code produced them (summaries of two
rendered frames of msl-2015 as 16 x 16 px block means, the extractor's output, the colour grid's
class counts); a deliberate change of the omni renderer or extractor regenerates it (the commit says
how it moved).

Compared with tolerances, not bits: another CPU's rounding may move a pixel across a colour
threshold or a scan-line crossing by a fraction of a pixel, which is no change of the product;
a change of the renderer or the extractor moves lines, points and blocks by far more."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from stages import simulate
from stages.common import colour
from stages.common.field import load_field
from stages.extract import omni
from stages.simulate import scene, trajectory
from stages.simulate.omni_renderer import OmniRenderer

REFERENCE = Path(__file__).parent / "data" / "omni_unchanged_reference.npz"


def _blocks(img, b=16):
    """Mean of each b x b block and channel (the frame's content without its pixel noise)."""
    h, w, c = img.shape
    return img.reshape(h // b, b, w // b, b, c).mean(axis=(1, 3))


def _matched_share(got, want, radius) -> float:
    """Share of the points ``want`` (M, 2) with a point of ``got`` within ``radius``."""
    if not len(want):
        return 1.0
    if not len(got):
        return 0.0
    d = np.hypot(*(want[:, None, :] - got[None, :, :]).transpose(2, 0, 1))
    return float(np.mean(d.min(axis=1) <= radius))


@pytest.fixture(scope="module")
def omni_frames():
    field = load_field("msl-2015")
    conf = copy.deepcopy(simulate.confs["omni-default"])
    conf["scene"]["texture_resolution"] = 0.02
    path = trajectory.generate(field, 6, conf["rate_hz"], conf["trajectory"],
                               np.random.default_rng(1))
    world = scene.build(field, conf["scene"], path.stamps, 1, robot_poses=path.poses)
    renderer = OmniRenderer(conf["omni"], world, 1)
    renderer.prepare(path)
    return renderer, [renderer.render(path.poses[i], i) for i in (0, 5)]


def test_omni_frames_are_unchanged(omni_frames):
    """Block means within 1 grey level everywhere and 0.05 on average (rounding moves single
    pixels by a level or so; any change of the scene moves blocks by several)."""
    ref = np.load(REFERENCE)
    for i, img in enumerate(omni_frames[1]):
        d = np.abs(_blocks(img) - ref[f"blocks{i}"])
        assert d.max() <= 1.0 and d.mean() <= 0.05, (i, d.max(), d.mean())


def test_omni_features_are_unchanged(omni_frames):
    """The extractor's points: counts within 3 %, >= 97 % of them matched within 1 cm (and
    1 px in the image); the radial and spiral crossings: the same present within 2 % of the
    slots, those present in both within 1 cm (a rounding difference moves a crossing by a
    fraction of a pixel, ~1-3 mm at these distances)."""
    renderer, images = omni_frames
    ref = np.load(REFERENCE)
    for i, img in enumerate(images):
        f = omni.extract_frame(img, renderer.camera, omni.confs["default"])
        for key, radius in (("points", 0.01), ("points_px", 1.0)):
            got, want = np.asarray(f[key], float), ref[f"{key}{i}"].astype(float)
            assert abs(len(got) - len(want)) <= 0.03 * len(want), (i, key, len(got), len(want))
            assert _matched_share(got, want, radius) >= 0.97, (i, key)
            assert _matched_share(want, got, radius) >= 0.97, (i, key)
        for key in ("radial", "spiral"):
            got, want = np.asarray(f[key], float), ref[f"{key}{i}"].astype(float)
            assert got.shape == want.shape
            presence = np.isnan(got) != np.isnan(want)
            assert presence.mean() <= 0.02, (i, key, presence.sum())
            both = ~np.isnan(got) & ~np.isnan(want)
            np.testing.assert_allclose(got[both], want[both], rtol=0, atol=0.01,
                                       err_msg=f"{i} {key}")


def test_omni_colour_classes_are_unchanged(omni_frames):
    """The colour grid's class counts (integers per 8 x 8 px cell and class): a pixel near a
    class threshold may flip on another CPU; at most 1 % of the counts differ, by at most 0.2 %
    of the pixels in all."""
    ref = np.load(REFERENCE)
    for i, img in enumerate(omni_frames[1]):
        got = colour.classify_grid(img, colour.confs["default"])[0].astype(np.int64)
        want = ref[f"grid{i}"].astype(np.int64)
        assert got.shape == want.shape
        d = np.abs(got - want)
        assert np.mean(d > 0) <= 0.01, (i, np.mean(d > 0))
        assert d.sum() <= 0.002 * img.shape[0] * img.shape[1], (i, d.sum())
