"""The robot-centred ground image (stages.extract.unwarp): grid geometry, and rendered lines at
known distances landing on the ground pixels they should."""

from __future__ import annotations

import copy
import math

import cv2
import numpy as np
import pytest

from stages import simulate
from stages.common.errors import FieldlocError
from stages.common.field import load_field
from stages.extract.unwarp import build_unwarp_map, grid_of_conf, ground_grid, unwarp
from stages.simulate import scene
from stages.simulate.omni_renderer import OmniRenderer, camera_from_conf


def test_grid_from_any_two_of_size_resolution_extent():
    g = ground_grid(size=512, metres_per_pixel=0.01)
    assert g.extent == pytest.approx(2.56) and g.centre == 255.5
    assert ground_grid(metres_per_pixel=0.01, extent=2.56) == g
    assert ground_grid(size=512, extent=2.56) == g
    assert grid_of_conf({"size": 512, "metres_per_pixel": 0.01, "extent": 2.56}) == g
    with pytest.raises(FieldlocError, match="not \\+-3"):
        ground_grid(512, 0.01, 3.0)
    with pytest.raises(FieldlocError, match="two of"):
        ground_grid(size=512)
    with pytest.raises(FieldlocError, match="metres_per_pixel > 0"):
        ground_grid(512, -0.01)
    with pytest.raises(FieldlocError, match="unknown ground grid key"):
        grid_of_conf({"size": 512, "resolution": 0.01})


def test_forward_is_up_and_left_is_left():
    g = ground_grid(101, 0.02)  # centre pixel 50
    col, row = g.robot_to_pixel([[1.0, 0.0], [0.0, 0.5], [0.0, 0.0]]).T
    assert (col[0], row[0]) == pytest.approx((50.0, 0.0))  # 1 m ahead: 50 px up
    assert (col[1], row[1]) == pytest.approx((25.0, 50.0))  # 0.5 m left: 25 px left
    assert (col[2], row[2]) == pytest.approx((50.0, 50.0))
    pts = np.random.default_rng(0).uniform(-1, 1, (20, 2))
    np.testing.assert_allclose(g.pixel_to_robot(*g.robot_to_pixel(pts).T), pts, atol=1e-12)
    # orientations in pixel axes: up the image (-pi/2, towards -row) is the robot's forward,
    # towards -col (pi) its left
    np.testing.assert_allclose(g.angle_to_robot([-math.pi / 2, math.pi, 0.0]),
                               [0.0, math.pi / 2, -math.pi / 2], atol=1e-12)


@pytest.fixture(scope="module")
def clean_renderer():
    conf = copy.deepcopy(simulate.confs["omni-clean"])
    world = scene.build(load_field("msl-2015"), conf["scene"], np.zeros(1), 0)
    return OmniRenderer(conf["omni"], world, 0)


def _line_centre(profile: np.ndarray, expected: float, half: int = 15) -> float:
    """Brightness-weighted centre of the white band near ``expected`` in a 1D profile."""
    lo = int(expected) - half
    seg = profile[lo:lo + 2 * half + 1]
    w = np.clip(seg - np.median(profile), 0, None)
    return lo + float((w * np.arange(len(seg))).sum() / w.sum())


# from (-1, 4): the touch line's middle (y = B/2 - K/2 = 5.9375 m) is 1.9375 m away
TOUCH_FROM_Y4 = load_field("msl-2015").width / 2 - 4.0


@pytest.mark.parametrize("heading, ahead_m, side_m", [
    # at (-1, 4) facing +x: the halfway line (x = 0) is 1 m ahead, the touch line to the left
    (0.0, 1.0, TOUCH_FROM_Y4),
    # facing +y: the touch line is ahead, the halfway line 1 m to the right
    (math.pi / 2, TOUCH_FROM_Y4, -1.0),
])
def test_rendered_lines_land_at_their_ground_pixels(clean_renderer, heading, ahead_m, side_m):
    grid = ground_grid(512, 0.01)
    img = clean_renderer.render((-1.0, 4.0, heading), 0)
    ground, valid = unwarp(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), clean_renderer.camera, grid)
    assert ground.shape == (512, 512) and valid.shape == (512, 512)
    c = grid.centre
    m = grid.metres_per_pixel
    # profiles up the image and across it, a strip beside the robot's axes (off the struts)
    up = np.median(ground[:, int(c) + 30:int(c) + 60].astype(float), axis=1)
    across = np.median(ground[int(c) + 30:int(c) + 60, :].astype(float), axis=0)
    assert _line_centre(up, c - ahead_m / m) == pytest.approx(c - ahead_m / m, abs=1.5)
    assert _line_centre(across, c - side_m / m) == pytest.approx(c - side_m / m, abs=1.5)


def test_valid_mask_is_the_seen_floor_and_honours_the_dataset_mask():
    cam = camera_from_conf(simulate.confs["omni-clean"]["omni"])
    grid = ground_grid(200, 0.04)  # +-4 m
    m = build_unwarp_map(cam, grid)
    c = grid.centre
    d = np.hypot(*np.meshgrid(np.arange(200) - c, np.arange(200) - c)) * grid.metres_per_pixel
    body = float(cam.distance_of_radius(cam.valid_radius[0]))
    assert not m.valid[d < body - 0.05].any()  # the robot's own body
    assert m.valid[(d > body + 0.05) & (d < 3.9)].all()
    # a dataset mask excluding the image's right half (u > centre) removes the robot's right
    # (forward is up in the image for this camera: image right = robot -y)
    w, h = cam.image_size
    mask = np.ones((h, w), bool)
    mask[:, int(cam.centre[0]) + 2:] = False
    mm = build_unwarp_map(cam, grid, mask)
    y = grid.pixel_to_robot(*np.meshgrid(np.arange(200), np.arange(200)))[..., 1]
    assert not mm.valid[y < -0.1].any()
    assert mm.valid[(y > 0.1) & m.valid].all()


def test_unwarp_rejects_wrong_inputs():
    cam = camera_from_conf(simulate.confs["omni-clean"]["omni"])
    with pytest.raises(FieldlocError, match="calibration's is 480 x 480"):
        unwarp(np.zeros((100, 100), np.uint8), cam, ground_grid(64, 0.05))
    with pytest.raises(FieldlocError, match="mask is"):
        build_unwarp_map(cam, ground_grid(64, 0.05), np.ones((10, 10), bool))

    class Perspective:
        kind = "perspective"

    with pytest.raises(FieldlocError, match="omnidirectional"):
        build_unwarp_map(Perspective(), ground_grid(64, 0.05))
