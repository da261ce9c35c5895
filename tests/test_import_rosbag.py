"""`fieldloc import rosbag`: small bags written with rosbags itself (ROS 1, ROS 2 sqlite3 and
mcap), imported and compared with the frames, stamps and increments they were made from."""

import math

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.common.dataset import open_dataset, read_csv
from stages.common.geometry import between
from stages.ingest import ros_images, rosbag
from stages.ingest.bag_writer import write_bag

pytest.importorskip("rosbags")


# a calibration fieldloc reads (import rosbag --calib checks it before copying it)
CALIB = """kind: omni
image_size: [480, 480]
centre: [244.0, 236.5]
polynomial: [-2.12375, 0.150314, -0.00356398, 4.06874e-05, -2.15966e-07, 4.39107e-10]
valid_radius: [40.0, 228.0]
forward_angle: 1.5708
mirrored: false
"""


def _frames(n=5, h=24, w=32, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]


def _trajectory(t):
    """A robot driving a curve: pose (x, y, yaw) at time t (s)."""
    return 0.8 * t, 0.3 * np.sin(t), 0.4 * t + 0.1 * np.sin(2 * t)


def _bag_name(tmp_path, fmt):
    return tmp_path / ("run.bag" if fmt == "ros1" else f"run_{fmt}")


@pytest.mark.parametrize("fmt", ["ros1", "ros2-sqlite3", "ros2-mcap"])
def test_import_frames_stamps_odometry_imu(tmp_path, fmt):
    imgs = _frames()
    stamps = 1700000000.0 + np.array([0.0, 0.1, 0.23, 0.31, 0.5])
    # odometry at 100 Hz over [t0 + 0.05, end]: the first frame lies outside its span
    t_odo = stamps[0] + 0.05 + np.arange(0, 46) * 0.01
    odo = [(t, *_trajectory(t - stamps[0])) for t in t_odo]
    t_imu = stamps[0] - 0.01 + np.arange(0, 40) * 0.0125
    imu = [(t, _trajectory(t - stamps[0])[2] + 1.0) for t in t_imu]
    bag = write_bag(_bag_name(tmp_path, fmt), fmt,
                    frames=[(s, (im, "bgr8")) for s, im in zip(stamps, imgs)],
                    odometry=odo, imu=imu, receive_delay=0.02)
    calib = tmp_path / "calib.yaml"
    calib.write_text(CALIB)
    out = rosbag.main(rosbag.confs["default"], bag, tmp_path / "ds", image_topic="/camera/image",
                      odom_topic="/odom", imu_topic="/imu", calib=calib)
    ds = open_dataset(out)
    assert [p.name for p in ds.images] == [f"{i:06d}.png" for i in range(5)]
    np.testing.assert_allclose(ds.stamps, stamps, atol=1e-6)  # header stamps, not bag times
    for p, im in zip(ds.images, imgs):
        assert np.array_equal(cv2.imread(str(p)), im)  # exact integers: uint8 images
    assert (out / "calib.yaml").read_text() == CALIB  # copied byte for byte

    odo_csv = read_csv(out / "odometry.csv", "odometry")
    # frame 0 is outside the odometry span and frame 1 needs frame 0: rows from frame 2 on
    np.testing.assert_allclose(odo_csv["stamp"], stamps[2:], atol=1e-6)
    truth = np.array([_trajectory(s - stamps[0]) for s in stamps])
    for k, row in zip(range(2, 5), zip(odo_csv["dx"], odo_csv["dy"], odo_csv["dtheta"])):
        expected = between(truth[k - 1], truth[k])
        # linear interpolation between 10 ms samples of a smooth curve: sub-millimetre
        np.testing.assert_allclose(row, expected, atol=2e-3)
    imu_csv = read_csv(out / "imu.csv", "imu")
    inside = (stamps >= t_imu[0]) & (stamps <= t_imu[-1])
    np.testing.assert_allclose(imu_csv["stamp"], stamps[inside], atol=1e-6)
    want = np.array([_trajectory(s - stamps[0])[2] + 1.0 for s in stamps[inside]])
    err = np.abs(np.angle(np.exp(1j * (imu_csv["yaw"] - want))))
    assert err.max() < 2e-3
    assert np.all(imu_csv["collision"] == 0)
    rec = rosbag.describe(out)
    assert rec["bag_format"] == fmt and rec["frames"] == 5 and rec["odometry_rows"] == 3


def test_every_and_compressed_passthrough(tmp_path):
    imgs = _frames(7)
    jpgs = [cv2.imencode(".jpg", im)[1].tobytes() for im in imgs]
    stamps = 10.0 + np.arange(7) * 0.1
    frames = [(s, (j, "bgr8; jpeg compressed bgr8")) for s, j in zip(stamps, jpgs)]
    odo = [(t, *_trajectory(t)) for t in np.arange(9.9, 10.8, 0.02)]
    bag = write_bag(tmp_path / "c.bag", "ros1", image_topic="/cam/compressed", frames=frames,
                    odometry=odo)
    out = rosbag.main(rosbag.confs["default"], bag, tmp_path / "ds",
                      image_topic="/cam/compressed", odom_topic="/odom", every=3)
    ds = open_dataset(out)
    assert [p.name for p in ds.images] == ["000000.jpg", "000001.jpg", "000002.jpg"]
    assert [p.read_bytes() for p in ds.images] == [jpgs[0], jpgs[3], jpgs[6]]  # unchanged
    np.testing.assert_allclose(ds.stamps, stamps[[0, 3, 6]], atol=1e-6)
    odo_csv = read_csv(out / "odometry.csv", "odometry")
    truth = np.array([_trajectory(s) for s in stamps[[0, 3, 6]]])
    # increments between the kept frames, not between consecutive messages
    np.testing.assert_allclose(np.c_[odo_csv["dx"], odo_csv["dy"], odo_csv["dtheta"]],
                               [between(truth[0], truth[1]), between(truth[1], truth[2])],
                               atol=2e-3)


def _bgr_flat(colours, h=8, w=8):
    """An image of four flat quadrants (BGR)."""
    img = np.zeros((2 * h, 2 * w, 3), np.uint8)
    img[:h, :w], img[:h, w:], img[h:, :w], img[h:, w:] = colours
    return img


def _mosaic(bgr, pattern):
    """A Bayer mosaic of a BGR image: ``pattern`` names the 2 x 2 cell's colours in reading
    order (ROS naming, e.g. 'rggb')."""
    idx = {"b": 0, "g": 1, "r": 2}
    out = np.zeros(bgr.shape[:2], bgr.dtype)
    for k, c in enumerate(pattern):
        dy, dx = divmod(k, 2)
        out[dy::2, dx::2] = bgr[dy::2, dx::2, idx[c]]
    return out


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_demosaic_gives_the_colours(pattern):
    img = _bgr_flat([(200, 30, 40), (20, 180, 60), (40, 50, 220), (120, 120, 120)], 16, 16)
    mosaic = _mosaic(img, pattern)
    out = ros_images.raw_to_image(*mosaic.shape, f"bayer_{pattern}8", mosaic.strides[0], mosaic)
    # away from the quadrant borders, the demosaiced colour is the flat colour
    for (v, u), want in zip([(8, 8), (8, 24), (24, 8), (24, 24)], img[[8, 8, 24, 24],
                                                                      [8, 24, 8, 24]]):
        assert np.abs(out[v, u].astype(int) - want.astype(int)).max() <= 2, (pattern, v, u)


def test_rgb_yuv422_mono_and_padding():
    img = _bgr_flat([(200, 30, 40), (20, 180, 60), (40, 50, 220), (10, 240, 10)])
    rgb = img[..., ::-1].copy()
    padded = np.zeros((rgb.shape[0], rgb.shape[1] * 3 + 6), np.uint8)  # rows padded by 6 bytes
    padded[:, :rgb.shape[1] * 3] = rgb.reshape(rgb.shape[0], -1)
    out = ros_images.raw_to_image(16, 16, "rgb8", padded.shape[1], padded)
    assert np.array_equal(out, img)  # exact integers: uint8 images
    # UYVY of the image (BT.601 video range, what cameras and OpenCV's UYVY decoder use)
    b, g, r = (img[..., k].astype(float) for k in range(3))
    yuv = np.clip(np.rint(np.stack([0.257 * r + 0.504 * g + 0.098 * b + 16,
                                    -0.148 * r - 0.291 * g + 0.439 * b + 128,
                                    0.439 * r - 0.368 * g - 0.071 * b + 128], -1)), 0, 255
                  ).astype(np.uint8)
    uyvy = np.zeros((16, 16, 2), np.uint8)
    uyvy[:, :, 1] = yuv[:, :, 0]
    uyvy[:, 0::2, 0] = yuv[:, 0::2, 1]
    uyvy[:, 1::2, 0] = yuv[:, 0::2, 2]
    out = ros_images.raw_to_image(16, 16, "yuv422", 32, uyvy)
    assert np.abs(out.astype(int) - img.astype(int)).max() <= 6
    yuyv = uyvy[:, :, ::-1].copy()
    out2 = ros_images.raw_to_image(16, 16, "yuv422_yuy2", 32, yuyv)
    assert np.abs(out2.astype(int) - img.astype(int)).max() <= 6
    grey16 = (np.arange(16 * 16) * 200).astype(">u2").reshape(16, 16)
    out = ros_images.raw_to_image(16, 16, "mono16", 32, grey16.view(np.uint8), True)
    # exact integers: uint16 images
    assert out.dtype == np.uint16 and np.array_equal(out, grey16.astype(np.uint16))
    with pytest.raises(ros_images.ImageMessageError, match="not supported"):
        ros_images.raw_to_image(16, 16, "32FC1", 64, np.zeros(1024, np.uint8))


def test_bad_frames_skipped_and_user_errors(tmp_path):
    ok = _frames(2)
    frames = [(1.0, (ok[0], "bgr8")), (1.1, (np.zeros((4, 4), np.float32), "32FC1")),
              (1.2, (ok[1], "bgr8"))]
    bag = write_bag(tmp_path / "b.bag", "ros1", frames=frames, imu=[(1.0, 0.0), (1.2, 0.1)],
                    imu_has_orientation=False)
    runner = CliRunner()
    res = runner.invoke(cli, ["import", "rosbag", str(bag), "-o", str(tmp_path / "ds"),
                              "--image-topic", "/camera/image"])
    assert res.exit_code == 0, res.output
    assert "2 frames of 3 image messages" in res.output and "1 frame(s) skipped" in res.output
    assert len(open_dataset(tmp_path / "ds").images) == 2
    # the same folder again without --overwrite, an unknown topic, an IMU without orientation,
    # a folder that is no bag: one line each, no traceback
    for args, msg in [([], "exists and is not empty"),
                      (["--overwrite", "--odom-topic", "/nope"], "no topic /nope"),
                      (["--overwrite", "--imu-topic", "/imu"], "publishes no orientation"),
                      (["--overwrite", "--image-topic", "/imu"], "must be sensor_msgs/msg/Image")]:
        res = runner.invoke(cli, ["import", "rosbag", str(bag), "-o", str(tmp_path / "ds"),
                                  "--image-topic", "/camera/image", *args])
        assert res.exit_code == 1 and msg in res.output, (args, res.output)
        assert "Traceback" not in res.output
    assert len(open_dataset(tmp_path / "ds").images) == 2  # the earlier import is intact
    res = runner.invoke(cli, ["import", "rosbag", str(tmp_path), "-o", str(tmp_path / "x"),
                              "--image-topic", "/a"])
    assert res.exit_code == 1 and "not a ROS bag" in res.output


def test_a_bag_of_only_skipped_frames_is_refused_in_one_line(tmp_path, caplog):
    """A bag none of whose frames can be written was refused after a warning per skipped
    message (trial U2-10: two lines for one message): the refusal alone names the first
    reason and the count, and a bag whose later frames are written says each skip, in order."""
    import logging

    bad = np.zeros((4, 4), np.float32)
    ok = _frames(1)[0]
    runner = CliRunner()
    for n in (1, 3):
        bag = write_bag(tmp_path / f"b{n}.bag", "ros1",
                        frames=[(1.0 + 0.1 * i, (bad, "32FC1")) for i in range(n)])
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            res = runner.invoke(cli, ["import", "rosbag", str(bag), "-o", str(tmp_path / "ds"),
                                      "--image-topic", "/camera/image"])
        assert res.exit_code == 1 and not caplog.records, caplog.text
        lines = res.stderr.strip().splitlines()
        first = "image encoding '32FC1' is not supported"
        assert len(lines) == 1 and (first in lines[0] if n == 1 else
                                    f"(3 image messages skipped; the first: {first}" in lines[0])
        assert not (tmp_path / "ds").exists()
    payloads = [(bad, "32FC1"), (bad, "32FC1"), (ok, "bgr8"), (bad, "32FC1")]
    bag = write_bag(tmp_path / "c.bag", "ros1",
                    frames=[(1.0 + 0.1 * i, f) for i, f in enumerate(payloads)])
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        res = runner.invoke(cli, ["import", "rosbag", str(bag), "-o", str(tmp_path / "ds"),
                                  "--image-topic", "/camera/image"])
    assert res.exit_code == 0, res.output
    assert [r.getMessage()[:23] for r in caplog.records] == [
        f"image message {i} skipped" for i in (0, 1, 3)], caplog.text


def test_zero_header_stamps_fall_back_to_receive_times(tmp_path, caplog):
    imgs = _frames(3)
    stamps = 5.0 + np.arange(3) * 0.2
    bag = write_bag(tmp_path / "z.bag", "ros1", frames=[(s, (im, "bgr8"))
                                                        for s, im in zip(stamps, imgs)],
                    zero_image_stamps=True, receive_delay=0.01)
    out = rosbag.main(rosbag.confs["default"], bag, tmp_path / "ds", image_topic="/camera/image")
    np.testing.assert_allclose(open_dataset(out).stamps, stamps + 0.01, atol=1e-6)
    assert rosbag.describe(out)["stamps"]["images"] == "bag"
    assert "zero header stamp" in caplog.text


def test_pose_interpolation_unwraps_heading():
    t = np.array([0.0, 1.0, 2.0])
    yaw = np.array([3.0, -3.0, -2.9])  # crossing +-pi: +0.28 rad, not -6 rad
    poses, inside = rosbag.pose_at(t, [0, 1, 2], [0, 0, 0], yaw, [0.25, 1.5, 2.5])
    assert list(inside) == [True, True, False]
    assert abs(poses[0, 2] - (3.0 + (2 * math.pi - 6.0) / 4)) < 1e-9
    assert abs(poses[1, 2] - (-2.95)) < 1e-9
    inc, ok = rosbag.increments_between(poses, inside)
    assert list(ok) == [False, True, False]
    np.testing.assert_allclose(inc[1], between(poses[0], poses[1]))


def test_message_problem_names_what_no_robot_sends():
    """An odometry or IMU message of a value that is not finite, a position beyond
    MAX_ODOMETRY_POSITION, or a quaternion of no length (a driver's "not set", read as a yaw
    of 0) is one the import drops; a unit or nearly unit quaternion is taken."""
    assert rosbag.message_problem((1.0, 2.0), (0.0, 0.0, 0.0, 1.0)) is None
    assert rosbag.message_problem((), (0.0, 0.0, 0.3, 0.95)) is None
    assert "not a rotation" in rosbag.message_problem((0.0, 0.0), (0.0, 0.0, 0.0, 0.0))
    assert "lies beyond" in rosbag.message_problem((1e308, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert "not all finite" in rosbag.message_problem((), (0.0, 0.0, math.nan, 1.0))
    # a quaternion far from unit length overflowed the yaw's products (90 deg read as 135)
    assert "not a rotation" in rosbag.message_problem((), (0.0, 0.0, 1e308, 1e308))


def test_frames_of_another_size_than_the_first_are_said(tmp_path, caplog):
    """Frames of two sizes were written without a word (trial V2-4), though a dataset's
    frames share one calib.yaml and extract leaves the others out: one warning names the
    first frame of another size and both sizes; every frame is written (a first frame whose
    header lies would otherwise have the good ones dropped, trial W2-2)."""
    import logging

    small, large = np.zeros((48, 64), np.uint8), np.zeros((96, 128), np.uint8)
    payloads = [(small, "mono8"), (large, "mono8"), (small, "mono8"), (large, "mono8")]
    bag = write_bag(tmp_path / "s.bag", "ros1",
                    frames=[(1.0 + 0.1 * i, f) for i, f in enumerate(payloads)])
    with caplog.at_level(logging.WARNING):
        res = CliRunner().invoke(cli, ["import", "rosbag", str(bag), "-o", str(tmp_path / "ds"),
                                       "--image-topic", "/camera/image"])
    assert res.exit_code == 0, res.output
    assert [r.getMessage() for r in caplog.records] == [
        "image message 1 is of 128 x 96 px, the first frame's 64 x 48: a dataset's frames"
        " share one calib.yaml, and extract leaves out those of another size than it gives"
    ], caplog.text
    assert len(list((tmp_path / "ds" / "images").iterdir())) == 4
