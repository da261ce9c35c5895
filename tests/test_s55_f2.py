"""Stop 55, group F2: what the case table of test_faults cannot express. A bag whose frame
stamps go backwards imports into a dataset its readers accept; a warning quoting a file name
with a line break is one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.common.dataset import open_dataset, read_csv
from stages.ingest.bag_writer import write_bag

ROOT = Path(__file__).resolve().parents[1]


def test_a_bag_whose_frame_stamps_go_backwards_imports_in_stamp_order(tmp_path, caplog):
    """Frames stamped before an earlier frame (a clock that went back) were kept with a
    warning, and the odometry and IMU rows written at their stamps were out of time order:
    a dataset its own readers refused. Frames are the camera's messages in stamp order now:
    those stamped before an earlier kept frame are dropped, named in import.yaml, and the
    odometry and IMU messages (stamped out of bag order too) are read in stamp order."""
    pytest.importorskip("rosbags")
    rng = np.random.default_rng(0)
    received = 100.0 + 0.1 * np.arange(7)
    headers = 100.0 + np.array([0.0, 0.1, 0.2, 0.15, 0.3, 0.3, 0.5])  # back once, then a repeat
    frames = [(t, (rng.integers(0, 256, (8, 8, 3), dtype=np.uint8), "bgr8")) for t in received]
    t_odo = 99.9 + 0.02 * np.arange(40)
    odo_headers = t_odo.copy()
    odo_headers[[10, 11]] = odo_headers[[11, 10]]  # two messages stamped out of bag order
    # driving straight ahead at 0.5 m/s: the pose each message holds is the one at its stamp
    odo = [(t, 0.5 * (h - 99.9), 0.0, 0.0) for t, h in zip(t_odo, odo_headers)]
    imu = [(t, 0.1 * (h - 99.9)) for t, h in zip(t_odo, odo_headers)]
    bag = write_bag(tmp_path / "b.bag", "ros1", frames=frames, odometry=odo, imu=imu,
                    header_stamps={"images": headers, "odometry": odo_headers,
                                   "imu": odo_headers})
    res = CliRunner().invoke(cli, ["import", "rosbag", str(bag), "-o", str(tmp_path / "ds"),
                                   "--image-topic", "/camera/image", "--odom-topic", "/odom",
                                   "--imu-topic", "/imu"])
    assert res.exit_code == 0, res.output
    assert "1 frame(s) stamped before an earlier frame" in caplog.text
    ds = open_dataset(tmp_path / "ds")
    assert [p.name for p in ds.images] == ["000000.png", "000001.png", "000002.png",
                                           "000004.png", "000006.png"]
    np.testing.assert_allclose(ds.stamps, 100.0 + np.array([0.0, 0.1, 0.2, 0.3, 0.5]))
    odometry = read_csv(tmp_path / "ds" / "odometry.csv", "odometry")  # in time order
    assert np.all(np.diff(odometry["stamp"]) > 0) and len(odometry["stamp"]) == 4
    np.testing.assert_allclose(odometry["dx"], 0.5 * np.diff(ds.stamps), atol=1e-6)
    imu_rows = read_csv(tmp_path / "ds" / "imu.csv", "imu")
    assert np.all(np.diff(imu_rows["stamp"]) > 0) and len(imu_rows["stamp"]) == 5
    np.testing.assert_allclose(imu_rows["yaw"], 0.1 * (ds.stamps - 99.9), atol=1e-6)
    rec = yaml.safe_load((tmp_path / "ds" / "import.yaml").read_text())
    assert rec["backward_stamps"] == ["000003.png"]
    assert rec["repeated_stamps"] == ["000005.png"]
    assert rec["frames"] == 5 and rec["image_messages"] == 7


def _fieldloc(*args, cwd, timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    """The fieldloc of this tree run as a user runs it: its own process, its own stderr (the
    log's lines formatted by the CLI, not by pytest's capture)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "fieldloc_cli.main", *map(str, args)],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout,
                          **kw)


def test_a_warning_quoting_a_file_name_with_a_line_break_is_one_line(tmp_path):
    """A WARNING line quoting a file called "17\\n0.json" took two lines; the CLI's log
    formatter shows the line break as a space, as the error and summary lines do."""
    (tmp_path / "hk").mkdir()
    (tmp_path / "hk" / "17\n0.json").write_text("{}")
    r = _fieldloc("calibrate", "perspective", "--from-hulks", "hk", "-o", "c", cwd=tmp_path)
    assert r.returncode == 1
    assert r.stderr.splitlines() == [
        "WARNING stages.calibrate.hulks: hk/17 0.json: no image beside it, skipped",
        "fieldloc: error: hk: no HULKs capture (<stamp>.json with its image)"], r.stderr
