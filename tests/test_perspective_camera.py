"""The perspective (humanoid head) camera model: distortion, floor projection, calib.yaml."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import yaml

from stages.common.camera import load_calib, save_calib
from stages.common.errors import DatasetError
from stages.common.perspective_camera import PerspectiveCamera

HEAD_ANGLES = [(0.45, 0.0), (0.30, 0.06), (0.60, -0.08), (0.45, 0.15)]


@pytest.fixture
def cam():
    return PerspectiveCamera()


def _image_grid(cam, step=16):
    w, h = cam.image_size
    u, v = np.meshgrid(np.arange(0, w, step, dtype=float), np.arange(0, h, step, dtype=float))
    return np.stack([u.ravel(), v.ravel()], -1)


def test_distortion_inverse_over_the_whole_image(cam):
    uv = _image_grid(cam, 7)
    ideal = cam.undistort_points(uv)
    assert np.isfinite(ideal).all()
    assert np.abs(cam.distort_points(ideal) - uv).max() < 1e-6
    # the wide-angle lens is strongly barrel-shaped: corners move far when undistorted
    corner = cam.undistort_points(np.array([[0.0, 0.0]]))[0]
    assert np.hypot(*(corner - [cam.cx, cam.cy])) > 1.3 * np.hypot(cam.cx, cam.cy)


def test_distortion_is_opencv_model(cam):
    """distort_points follows cv2.projectPoints with the same intrinsics and coefficients."""
    ideal = cam.undistort_points(_image_grid(cam, 23))
    xy = (ideal - [cam.cx, cam.cy]) / [cam.fx, cam.fy]
    pts = np.concatenate([xy, np.ones((len(xy), 1))], 1).reshape(-1, 1, 3)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.camera_matrix, cam.distortion)
    assert np.abs(ref.reshape(-1, 2) - cam.distort_points(ideal)).max() < 1e-6


@pytest.mark.parametrize("pitch,roll", HEAD_ANGLES)
def test_floor_pixel_floor_round_trip(cam, pitch, roll):
    xs, ys = np.meshgrid(np.linspace(0.3, 6.0, 25), np.linspace(-4.0, 4.0, 25))
    pts = np.stack([xs.ravel(), ys.ravel()], -1)
    uv = cam.floor_to_pixel(pts, pitch, roll)
    seen = np.isfinite(uv).all(1)
    assert seen.sum() > 100
    back = cam.pixel_to_floor(uv[seen], pitch, roll)
    assert np.abs(back - pts[seen]).max() < 1e-3
    # and pixel -> floor -> pixel for every pixel below the horizon
    grid = _image_grid(cam)
    floor = cam.pixel_to_floor(grid, pitch, roll)
    ok = np.isfinite(floor).all(1)
    again = cam.floor_to_pixel(floor[ok], pitch, roll)
    assert np.abs(again - grid[ok]).max() < 1e-6


def test_pitch_looks_down_and_roll_tilts_the_horizon(cam):
    # the optical axis meets the floor at height / tan(pitch) straight ahead
    centre = cam.distort_points(np.array([[cam.cx, cam.cy]]))
    p = cam.pixel_to_floor(centre, pitch=0.5, roll=0.0)[0]
    assert p == pytest.approx([cam.height / math.tan(0.5), 0.0], abs=1e-9)
    # looking further down moves the horizon up in the image (off it at the top)
    assert cam.horizon_row([cam.cx], 0.3, 0.0)[0] > cam.horizon_row([cam.cx], 0.5, 0.0)[0]
    # roll > 0 turns the camera clockwise seen from behind: the horizon rises on the right
    h = cam.horizon_row(np.array([100.0, 650.0]), 0.3, 0.1)
    assert h[1] < h[0]
    # a floor point to the left of the robot appears left of the image centre
    assert cam.floor_to_pixel(np.array([[2.0, 1.0]]))[0, 0] < cam.cx


@pytest.mark.parametrize("pitch,roll", HEAD_ANGLES)
def test_above_the_horizon_is_nan(cam, pitch, roll):
    w, _ = cam.image_size
    u = np.arange(20, w - 20, 37, dtype=float)
    v = cam.horizon_row(u, pitch, roll)
    ok = np.isfinite(v)
    assert ok.sum() > 5
    above = cam.pixel_to_floor(np.stack([u[ok], v[ok] - 2.0], -1), pitch, roll)
    below = cam.pixel_to_floor(np.stack([u[ok], v[ok] + 2.0], -1), pitch, roll)
    assert np.isnan(above).all()
    assert np.isfinite(below).all()
    # points just below the horizon are far away
    assert np.hypot(*below.T).min() > 8.0
    # floor points behind the camera have no pixel; nor have points off the image
    assert np.isnan(cam.floor_to_pixel(np.array([[-1.0, 0.0], [0.2, 5.0]]), pitch, roll)).all()


def test_calib_yaml_round_trip(tmp_path):
    cam = PerspectiveCamera(fx=310.0, fy=312.0, cx=370.0, cy=245.0,
                            distortion=np.array([-0.22, 0.04, 0.001, -0.002, 0.003]),
                            height=0.52, pitch=0.4, roll=0.01)
    path = save_calib(cam, tmp_path / "calib.yaml")
    d = yaml.safe_load(path.read_text())
    assert d["kind"] == "perspective"
    assert set(d) >= {"image_size", "intrinsics", "distortion", "height", "pitch", "roll"}
    back = load_calib(path)
    assert isinstance(back, PerspectiveCamera)
    assert back == cam
    assert np.array_equal(back.distortion, cam.distortion)  # exact same-run: written and read back


def _good() -> dict:
    return PerspectiveCamera().to_dict()


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda d: d.pop("intrinsics"), "misses key 'intrinsics'"),
        (lambda d: d["intrinsics"].pop("fy"), "misses key 'fy'"),
        (lambda d: d.pop("height"), "misses key 'height'"),
        (lambda d: d.update(height="tall"), "'height' must be a number, got 'tall'"),
        (lambda d: d.update(height=-0.5), "'height' must be >= 0.001"),
        (lambda d: d.update(distortion=[0.1, 0.2]), "4 or 5 values"),
        (lambda d: d.update(image_size=[752]), r"'image_size' must be \[width, height\]"),
        (lambda d: d.update(intrinsics=[1, 2, 3, 4]), "'intrinsics' must be a mapping"),
        (lambda d: d["intrinsics"].update(fx=0.0), "fx, fy must be > 0"),
        (lambda d: d.update(pitch=float("nan")), "'pitch' must be a finite number"),
        (lambda d: d.update(distortion=[-0.6, 0.0, 0.0, 0.0, 0.0]), "folds back"),
    ],
)
def test_malformed_calib_is_a_clear_error(tmp_path, change, message):
    d = _good()
    change(d)
    path = tmp_path / "calib.yaml"
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(DatasetError, match=message) as err:
        load_calib(path)
    assert str(path) in str(err.value)


def test_position_and_pose_of_a_frame(tmp_path):
    """An optical centre over (x, y) of the robot frame moves the floor points by it;
    with_pose gives the same lens at a frame's pose; calib.yaml keeps the position."""
    cam = PerspectiveCamera(distortion=np.zeros(5))
    moved = cam.with_pose(position=(0.08, -0.02), yaw=0.3, height=0.45)
    # exact same-run: a copy
    assert moved.fx == cam.fx and np.array_equal(moved.distortion, cam.distortion)
    assert (moved.yaw, moved.height, cam.yaw, cam.height) == (0.3, 0.45, 0.0, 0.55)
    uv = np.array([[376.0, 400.0], [100.0, 450.0]])
    floor = moved.pixel_to_floor(uv)
    turned = cam.with_pose(yaw=0.3, height=0.45).pixel_to_floor(uv)
    assert np.allclose(floor - turned, [0.08, -0.02])
    assert np.allclose(moved.floor_to_pixel(floor), uv)
    back = load_calib(save_calib(moved, tmp_path / "calib.yaml"))
    assert back == moved and back.position == (0.08, -0.02)
    assert "position" not in cam.to_dict()  # only written where it is not the origin
    d = cam.to_dict()
    d["position"] = [0.1]
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(DatasetError, match="'position' must be"):
        load_calib(path)
