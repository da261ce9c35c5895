"""What the case table of test_faults cannot express. import rosbag
--overwrite refuses its own folder whose import.yaml has no written_files table, which vouches
for none of its files, and keeps every file (the refusals of a user's file there are cases of
test_faults); a JPEG followed by data of its own
(a vendor's trailer, an MPO file's second image) is read, a JPEG cut short is still refused;
import rosbag keeps the most frames in stamp order when one frame is stamped far ahead."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.common.dataset import decode_image_bytes, image_damage, open_dataset

SEED = 1860


@pytest.mark.parametrize("table", ["del", [1], "a"])
def test_import_rosbag_overwrite_of_its_folder_without_a_table_keeps_it(tmp_path, table):
    """A folder whose import.yaml has no written_files table (an older record's) or a damaged
    one: --overwrite cannot tell the importer's files from ones a user edited since (a
    frames.csv changed in a text editor), so the folder is refused in one line and every file
    is kept, even where it holds only the importer's own names."""
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
    frames_csv = tmp_path / "ds" / "frames.csv"
    frames_csv.write_text(frames_csv.read_text() + "# my note\n")
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "ds").rglob("*")}
    res = CliRunner().invoke(cli, [*args, "--overwrite"])
    assert res.exit_code == 1
    assert "lists no written_files" in res.output and len(res.output.splitlines()) == 1
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "ds").rglob("*")} == before


def _jpeg(seed: int = SEED, **params) -> bytes:
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    flags = [cv2.IMWRITE_JPEG_PROGRESSIVE, 1] if params.get("progressive") else []
    ok, data = cv2.imencode(".jpg", img, flags)
    assert ok
    return data.tobytes()


def _with_exif_thumbnail(main: bytes, thumb: bytes) -> bytes:
    """``main`` with an APP1 segment holding the whole JPEG ``thumb`` (its own SOS and EOI)."""
    payload = b"Exif\0\0" + thumb
    return main[:2] + b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload + main[2:]


@pytest.mark.parametrize("progressive", [False, True])
def test_a_jpeg_with_data_after_its_end_is_read(progressive):
    """A JPEG whose trailing data held the bytes FF DA (an SOS marker's) was refused as cut
    short: the last SOS of the file was compared with its last EOI. The image ends at the
    first EOI after its first scan; what follows is the file's business."""
    j = _jpeg(progressive=progressive)
    trailer = j + b"SAMSUNG_TRAILER\xff\xda\x00\x0cmeta" + bytes(50)
    mpo = j + _jpeg(SEED + 1)[: len(j) // 2]  # a second image, cut short
    for data in (j, trailer, mpo, _with_exif_thumbnail(j, _jpeg(SEED + 2))):
        assert image_damage(data) is None
        img = decode_image_bytes(data)[0]
        assert img is not None and img.shape == (48, 64, 3)


@pytest.mark.parametrize("progressive", [False, True])
def test_a_jpeg_cut_short_is_still_refused(progressive):
    """A JPEG without an EOI after its first scan is cut short, whether or not an EXIF
    thumbnail's whole JPEG (its own SOS and EOI) comes before the scan."""
    j = _jpeg(progressive=progressive)
    with_thumb = _with_exif_thumbnail(j, _jpeg(SEED + 2))
    for data in (j[: len(j) // 2], j[:-2], with_thumb[: len(with_thumb) - len(j) // 2]):
        assert image_damage(data) == "a JPEG file cut short: no end marker"
        assert decode_image_bytes(data)[0] is None

def test_import_rosbag_keeps_the_good_frames_after_one_stamped_far_ahead(tmp_path, caplog):
    """One frame whose header stamp jumped ahead (a clock glitch) was kept and every good
    frame after it dropped as stamped before it. The frames kept are the most whose stamps
    rise in bag order: the glitch's frame is dropped, named in import.yaml."""
    pytest.importorskip("rosbags")
    from stages.ingest.bag_writer import write_bag

    rng = np.random.default_rng(SEED + 3)
    received = 0.1 * np.arange(1, 7)
    frames = [(t, (rng.integers(0, 256, (8, 8, 3), dtype=np.uint8), "bgr8")) for t in received]
    for glitch in (0, 2):
        headers = received.copy()
        headers[glitch] = 1000.0
        odo = [(0.05 * i, 0.1 * i, 0.0, 0.0) for i in range(14)]
        bag = write_bag(tmp_path / f"g{glitch}.bag", "ros1", frames=frames, odometry=odo,
                        header_stamps={"images": headers})
        out = tmp_path / f"ds{glitch}"
        caplog.clear()
        res = CliRunner().invoke(cli, ["import", "rosbag", str(bag), "-o", str(out),
                                       "--image-topic", "/camera/image", "--odom-topic",
                                       "/odom"])
        assert res.exit_code == 0, res.output
        assert "1 frame(s) stamped out of order with the others" in caplog.text
        assert "frame intervals" not in caplog.text  # the odometry covers every interval
        ds = open_dataset(out)
        want = [f"{i:06d}.png" for i in range(6) if i != glitch]
        assert [p.name for p in ds.images] == want
        np.testing.assert_allclose(ds.stamps, np.delete(received, glitch))
        rec = yaml.safe_load((out / "import.yaml").read_text())
        assert rec["backward_stamps"] == [f"{glitch:06d}.png"]
        assert rec["repeated_stamps"] == [] and rec["frames"] == 5
        assert not (out / "images" / f"{glitch:06d}.png").exists()
