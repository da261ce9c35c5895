"""`fieldloc calibrate perspective --from-hulks`: HULKs camera-matrix JSON -> calib.yaml, or a
folder of captures -> a dataset with each frame's camera pose in head.csv (stages.calibrate.hulks),
on generated files with known poses."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.calibrate import hulks
from stages.common.camera import load_calib
from stages.common.dataset import open_dataset, read_csv
from stages.common.perspective_camera import head_rotation


def quaternion(rot: np.ndarray) -> list[float]:
    """[x, y, z, w] of a rotation matrix (w > 0 branch; the test's rotations are small)."""
    w = math.sqrt(max(1.0 + np.trace(rot), 0.0)) / 2
    return [(rot[2, 1] - rot[1, 2]) / (4 * w), (rot[0, 2] - rot[2, 0]) / (4 * w),
            (rot[1, 0] - rot[0, 1]) / (4 * w), w]


def capture(yaw, pitch, roll, xyz, position="Top") -> dict:
    """A HULKs capture's JSON for a camera at yaw/pitch/roll (HULKs' camera axes: x forward,
    y left, z up, i.e. fieldloc's camera axes turned by the model's _CAMERA_AXES)."""
    from stages.common.perspective_camera import _CAMERA_AXES

    rot = head_rotation(yaw, pitch, roll) @ _CAMERA_AXES.T
    c2g = {"rotation": quaternion(rot), "translation": list(map(float, xyz))}
    return {"camera_matrix": {"focal_length": [608.0, 609.6], "optical_center": [320.0, 240.0],
                              "camera_to_ground": c2g},
            "crossings": {}, "position": position}


def test_camera_from_a_capture_projects_like_hulks(tmp_path):
    d = capture(0.4, 0.3, -0.05, [0.06, -0.02, 0.48])
    path = tmp_path / "1687000000.json"
    path.write_text(json.dumps(d))
    cam = hulks.read_frame(path).camera
    assert (cam.yaw, cam.pitch, cam.roll) == pytest.approx((0.4, 0.3, -0.05))
    assert cam.height == pytest.approx(0.48) and cam.position == pytest.approx((0.06, -0.02))
    assert (cam.cx, cam.cy) == (319.5, 239.5)  # corner origin -> centre origin
    # HULKs' own projection of a pixel (u, v) in its coordinates
    c2g = d["camera_matrix"]["camera_to_ground"]
    rot, t = hulks.quaternion_matrix(c2g["rotation"]), np.array(c2g["translation"])
    for u, v in [(100.0, 400.0), (320.0, 300.0), (600.0, 470.0)]:
        ray = rot @ np.array([1.0, (320.0 - u) / 608.0, (240.0 - v) / 609.6])
        p = t + ray * (-t[2] / ray[2])
        assert np.allclose(cam.pixel_to_floor(np.array([[u - 0.5, v - 0.5]]))[0], p[:2])


def test_cli_writes_calib_yaml_and_a_dataset_from_a_folder(tmp_path):
    src = tmp_path / "measurements"
    src.mkdir()
    poses = [(0.0, 0.2, 0.0, [0.05, 0.0, 0.47]), (-0.6, 0.35, 0.02, [0.07, -0.03, 0.44])]
    for k, (yaw, pitch, roll, xyz) in enumerate(poses):
        (src / f"{1687000000 + k}.json").write_text(json.dumps(capture(yaw, pitch, roll, xyz)))
        cv2.imwrite(str(src / f"{1687000000 + k}.jpg"), np.full((480, 640, 3), 90, np.uint8))
    runner = CliRunner()
    res = runner.invoke(cli, ["calibrate", "perspective", "--from-hulks",
                              str(src / "1687000001.json"), "-o", str(tmp_path / "c.yaml")])
    assert res.exit_code == 0, res.output
    cam = load_calib(tmp_path / "c.yaml")
    assert cam.pitch == pytest.approx(0.35) and cam.yaw == pytest.approx(-0.6)
    res = runner.invoke(cli, ["calibrate", "perspective", "--from-hulks", str(src), "-o",
                              str(tmp_path / "data")])
    assert res.exit_code == 0, res.output
    ds = open_dataset(tmp_path / "data")
    assert ds.names == ["1687000000", "1687000001"]
    head = read_csv(tmp_path / "data" / "head.csv", "head")
    assert set(head) == {"stamp", "pitch", "roll", "yaw", "height", "x", "y"}
    assert np.allclose(head["stamp"], ds.stamps)
    assert np.allclose(head["yaw"], [0.0, -0.6], atol=1e-6)
    assert np.allclose(head["height"], [0.47, 0.44], atol=1e-6)
    nominal = load_calib(tmp_path / "data" / "calib.yaml")
    assert nominal.pitch == pytest.approx(0.275) and nominal.yaw == 0.0
    # fieldloc extract reads each frame's own pose from head.csv
    res = runner.invoke(cli, ["-q", "extract", str(tmp_path / "data")])
    assert res.exit_code == 0, res.output
    # refused: the folder exists
    res = runner.invoke(cli, ["calibrate", "perspective", "--from-hulks", str(src), "-o",
                              str(tmp_path / "data")])
    assert res.exit_code == 1 and "exists" in res.output


@pytest.mark.parametrize("change,message", [
    (lambda d: d.pop("camera_matrix"), "no 'camera_matrix'"),
    (lambda d: d["camera_matrix"].pop("focal_length"), "misses 'focal_length'"),
    (lambda d: d["camera_matrix"]["camera_to_ground"].update(rotation=[0, 0, 0, 2]),
     "not a unit quaternion"),
    (lambda d: d["camera_matrix"]["camera_to_ground"].update(translation=[0, 0, -0.4]),
     "above the floor"),
    (lambda d: d["camera_matrix"].update(camera_to_ground=quaternion(np.eye(3))),
     "'camera_to_ground' needs"),
    # trial M5, M6: named as the input's field, refused before numpy's maths could warn
    (lambda d: d["camera_matrix"].update(focal_length=[True, 609.6]),
     "1687000000.json: focal_length[0] must be a number, got True"),
    (lambda d: d["camera_matrix"]["camera_to_ground"].update(rotation=[1e308, 1e308, 0, 1]),
     "'camera_to_ground' rotation is not a unit quaternion"),
    (lambda d: d["camera_matrix"]["camera_to_ground"].update(translation=[1e308, 0, 0.4]),
     "'camera_to_ground' translation [1e+308, 0.0, 0.4] is beyond 1e+06 m"),
    (lambda d: d["camera_matrix"].update(optical_center=[1e20, 240]),
     "optical_center (1e+20, 240) must lie in the 640 x 480 px image"),
    (lambda d: d["camera_matrix"].update(focal_length=[1e300, 1e300]),
     "focal_length (1e+300, 1e+300) must lie between 0.05 and 100 times"),
])
@pytest.mark.filterwarnings("error")  # a numpy RuntimeWarning is an extra line on stderr
def test_bad_files_are_one_clear_error(tmp_path, change, message):
    d = capture(0.0, 0.2, 0.0, [0.0, 0.0, 0.45])
    change(d)
    path = tmp_path / "1687000000.json"
    path.write_text(json.dumps(d))
    res = CliRunner().invoke(cli, ["calibrate", "perspective", "--from-hulks", str(path), "-o",
                                   str(tmp_path / "c.yaml")])
    assert res.exit_code == 1 and message in res.output, res.output
    assert "Traceback" not in res.output and len(res.stderr.splitlines()) == 1, res.output


def test_a_camera_looking_up_is_refused(tmp_path):
    path = tmp_path / "1687000000.json"
    path.write_text(json.dumps(capture(0.0, -1.2, 0.0, [0.0, 0.0, 0.45])))
    with pytest.raises(hulks.HulksImportError, match="no floor in view"):
        hulks.read_frame(path)
