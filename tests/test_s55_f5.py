"""Stop 55, group F5: what the case table of test_faults cannot express. import rosbag
--overwrite still replaces its own folder whose import.yaml has no written_files table (the
refusals of a user's file there are cases of test_faults); a JPEG followed by data of its own
(a vendor's trailer, an MPO file's second image) is read, a JPEG cut short is still refused;
import rosbag keeps the most frames in stamp order when one frame is stamped far ahead."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from fieldloc_cli.main import cli

SEED = 1860


@pytest.mark.parametrize("table", ["del", [1], "a"])
def test_import_rosbag_overwrite_of_its_folder_without_a_table_replaces_it(tmp_path, table):
    """A folder whose import.yaml has no written_files table (an older record's) or a damaged
    one is still replaced by --overwrite where it holds only the importer's own files (the
    case table holds those that also hold a user's file: refused)."""
    pytest.importorskip("rosbags")
    from stages.ingest.bag_writer import write_bag

    rng = np.random.default_rng(SEED + 4)
    frames = [(0.1 * i, (rng.integers(0, 256, (8, 8, 3), dtype=np.uint8), "bgr8"))
              for i in range(1, 4)]
    odo = [(0.05 * i, 0.1 * i, 0.0, 0.0) for i in range(10)]
    bag = write_bag(tmp_path / "b.bag", "ros1", frames=frames, odometry=odo, imu=[
        (0.05 * i, 0.01 * i) for i in range(10)])
    args = ["import", "rosbag", str(bag), "-o", str(tmp_path / "ds"), "--image-topic",
            "/camera/image", "--odom-topic", "/odom", "--imu-topic", "/imu"]
    assert CliRunner().invoke(cli, args).exit_code == 0
    rec_path = tmp_path / "ds" / "import.yaml"
    rec = yaml.safe_load(rec_path.read_text())
    assert {"frames.csv", "odometry.csv", "imu.csv", "images/000000.png"} <= set(
        rec["written_files"])
    if table == "del":
        del rec["written_files"]
    else:
        rec["written_files"] = table
    rec_path.write_text(yaml.safe_dump(rec, sort_keys=False))
    res = CliRunner().invoke(cli, [*args, "--overwrite"])
    assert res.exit_code == 0, res.output
    assert isinstance(yaml.safe_load(rec_path.read_text())["written_files"], dict)
