"""What the case table of test_faults cannot express. A bag whose frame
stamps go backwards imports into a dataset its readers accept; a warning quoting a file name
with a line break is one line; an image file cut short is one line of fieldloc's, nothing of
OpenCV's or its codecs' (run as a user runs fieldloc, in a subprocess: libpng and libjpeg
write to the process's stderr, which the in-process runner does not see)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
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
    assert "1 frame(s) stamped out of order with the others" in caplog.text
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


REALDATA = ROOT.parent / "shared" / "realdata"


def _cut(image: np.ndarray, kind: str) -> bytes:
    """The first half of ``image`` encoded as a ``kind`` file: a file cut short."""
    import cv2

    ok, data = cv2.imencode("." + kind, image)
    assert ok
    return data.tobytes()[:len(data) // 2]


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """Two-frame omni and perspective datasets (SPL field)."""
    from stages import simulate

    root = tmp_path_factory.mktemp("sim")
    out = {}
    for camera, preset in (("omni", "omni-clean"), ("perspective", "perspective-clean")):
        simulate.main(dict(simulate.confs[preset], frames=2), "spl", root / camera)
        out[camera] = root / camera
    return out


@pytest.mark.parametrize("camera,kind", [("omni", "png"), ("omni", "jpg"),
                                         ("perspective", "jpg")])
def test_extract_of_a_frame_cut_short_prints_one_line_of_its_own(simulated, tmp_path, camera,
                                                                   kind):
    """A frame file cut short printed a line of libpng's ("libpng error: PNG input buffer is
    incomplete") or of libjpeg's ("Premature end of JPEG file") beside fieldloc's warning, and
    a JPEG cut in half was even taken as a frame, grey below the cut. Now the frame is skipped
    with one warning line saying why, and nothing of OpenCV's is printed (whatever its
    version's wording: the test counts lines)."""
    import cv2

    ds = tmp_path / "ds"
    shutil.copytree(simulated[camera], ds)
    first = ds / "images" / "000000.png"
    image = cv2.imread(str(first))
    first.unlink()
    (ds / "images" / f"000000.{kind}").write_bytes(_cut(image, kind))
    frames = ds / "frames.csv"
    frames.write_text(frames.read_text().replace("000000.png", f"000000.{kind}"))
    r = _fieldloc("-q", "extract", ds, "-o", tmp_path / "f.h5", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and "frame 000000 skipped: unreadable image" in lines[0], r.stderr


@pytest.mark.parametrize("kind", ["png", "jpg"])
def test_inspect_of_an_image_cut_short_prints_nothing_of_opencv(tmp_path, kind):
    """`inspect` of a PNG or JPEG cut short says it cannot be decoded, and OpenCV's or the
    codec's own line ("[ERROR:0@0.016] global grfmt_png.cpp:296 readHeader ...") is gone."""
    rng = np.random.default_rng(1)
    (tmp_path / f"x.{kind}").write_bytes(_cut(rng.integers(0, 256, (60, 80, 3), np.uint8),
                                              kind))
    (tmp_path / "y.png").write_bytes(b"\x89PNG\r\n\x1a\nxxxx")
    for name in (f"x.{kind}", "y.png"):
        r = _fieldloc("inspect", name, cwd=tmp_path)
        assert r.returncode == 0 and r.stderr == "", r.stderr
        assert "cannot be decoded" in r.stdout


@pytest.mark.realdata
def test_calibrate_from_nubot_with_a_bmp_cut_short_is_one_line(tmp_path):
    """A NuBot calibration picture (BMP) cut short printed OpenCV's "[ERROR:0@0.266] global
    loadsave.cpp:621 imread_ ... can't read data" before fieldloc's one line."""
    source = REALDATA / "nwpu-nubot-omni-centre" / "2019-08"
    if not source.is_dir():
        pytest.skip("no real data")
    shutil.copytree(source, tmp_path / "nb")
    with open(tmp_path / "nb" / "pic_save0.bmp", "r+b") as f:
        f.truncate(100)
    r = _fieldloc("calibrate", "omni", "--from-nubot", "nb", "-o", "c.yaml", cwd=tmp_path)
    assert r.returncode == 1
    assert r.stderr.splitlines() == ["fieldloc: error: unreadable image: nb/pic_save0.bmp"]


@pytest.mark.realdata
def test_cnc_calibration_picture_cut_short_is_one_line(tmp_path):
    """The --from-cnc picture (PNG) cut short: one line, libpng's own line gone."""
    source = REALDATA / "cnc-calibration"
    if not source.is_dir():
        pytest.skip("no real data")
    shutil.copytree(source, tmp_path / "cn")
    picture = tmp_path / "cn" / "CarpetCalibImage.png"
    picture.write_bytes(picture.read_bytes()[:5000])
    r = _fieldloc("calibrate", "omni", "--from-cnc", "cn/CarpetCalibrator.conf", "--rings",
                  "detected", "-o", "c.yaml", cwd=tmp_path)
    assert r.returncode == 1
    assert r.stderr.splitlines() == ["fieldloc: error: unreadable image:"
                                     " cn/CarpetCalibImage.png (a PNG file cut short or"
                                     " damaged)"]


def test_an_interrupt_while_the_cluster_starts_waits_until_it_is_made():
    """A SIGTERM while LocalCluster started was raised inside it, and the half-made cluster
    was left for distributed's atexit hook: its INFO lines and a traceback after fieldloc's
    "terminated". batch holds the signal until the cluster is made (and stopped by its
    ExitStack), then raises it, once."""
    from stages.pipelines.batch import _interrupts_held

    seen = []
    with pytest.raises(KeyboardInterrupt):
        with _interrupts_held():
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # the handler has run (and only held the signal)
            seen.append("made")
    assert seen == ["made"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def _batch_signalled(simulated, folder, delay: float, signum: int, group: bool,
                     after: str = ""):
    """(exit code, stderr) of `fieldloc -q batch SPEC --workers 2` (lut and lut-no-fusion on
    the 2-frame omni dataset) sent ``signum`` ``delay`` s after it made its output folder (its
    plan made, its handlers in place: a fixed time from the start was, on a loaded machine,
    Python's start-up, which a signal ends before fieldloc runs), or the file ``after`` in
    it: to its whole process group with ``group``, as a terminal's Ctrl-C goes."""
    folder.mkdir(exist_ok=True)
    spec = folder / "spec.yaml"
    spec.write_text(yaml.safe_dump({
        "field": "spl", "build_map": {"resolution": 0.5},
        "datasets": [{"path": str(simulated["omni"])}],
        "methods": ["lut", "lut-no-fusion"], "runs": "all"}))
    p = subprocess.Popen([sys.executable, "-m", "fieldloc_cli.main", "-q", "batch", spec, "-o",
                          folder / "res", "--workers", "2"], cwd=folder,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=group)
    end = time.monotonic() + 120
    while not (folder / "res" / after).exists() and p.poll() is None and time.monotonic() < end:
        time.sleep(0.05)
    time.sleep(delay)
    if group:
        os.killpg(p.pid, signum)
    else:
        p.send_signal(signum)
    _out, err = p.communicate(timeout=120)
    return p.returncode, err


def test_sigterm_to_a_two_worker_batch_is_one_line_and_143(simulated, tmp_path):
    """SIGTERM to `batch -q --workers 2` printed Dask's "INFO distributed.nanny: Nanny at ...
    closed." (or a traceback of its atexit hook) after fieldloc's one "terminated" line. The
    moment decides what is running (before the cluster, while it starts, while runs run):
    not deterministic, so three moments, each of which must give exactly one line and 143."""
    for delay in (1.5, 3.5, 8.0):  # s: the cluster starts about 1 s after, and takes about 5
        rc, err = _batch_signalled(simulated, tmp_path / f"t{delay:g}", delay, signal.SIGTERM,
                                   group=False)
        if rc == 0:  # finished before the signal: nothing to check at this moment
            continue
        assert rc == 143, err
        assert err.splitlines() == ["fieldloc: terminated (finished runs were kept; a rerun"
                                    " resumes with the others)"], (delay, err)


def test_sigterm_to_a_two_worker_batch_stopping_its_cluster_is_one_line_and_143(simulated,
                                                                                tmp_path):
    """SIGTERM as the batch stops its cluster, its runs done (its last picture, drawn by a
    worker, written): the signal breaks off the stop, which Dask cancels in its event loop
    thread, whose nannies each logged "INFO distributed.nanny: Nanny at ... closed." before or
    after fieldloc's "terminated" line (5 of 8 SIGTERMs 0-0.6 s after the picture)."""
    # 0.1 s: the stop takes about 0.5 s (on the fix's parent the lines came in about 1 of 4
    # runs of this test with two delays; one keeps its cost at one batch)
    rc, err = _batch_signalled(simulated, tmp_path / "s", 0.1, signal.SIGTERM, group=False,
                               after="plots/cdf-omni.png")
    if rc != 0:  # 0: finished before the signal, nothing to check at this moment
        assert rc == 143, err
        assert err.splitlines() == ["fieldloc: terminated (finished runs were kept; a rerun"
                                    " resumes with the others)"], err


def test_ctrl_c_to_a_two_worker_batch_starting_up_is_one_line(simulated, tmp_path):
    """Ctrl-C in a terminal goes to the whole process group. Sent while the cluster's worker
    processes were starting (before they ignore SIGINT), each worker died of it with its own
    KeyboardInterrupt traceback, beside Dask's INFO lines (the rerun of trial A, A11: 79-109
    lines at 2.4-2.6 s). The workers now start with SIGINT blocked; whatever the moment, the
    batch ends in fieldloc's one line (or finishes)."""
    for delay in (1.0, 2.0, 3.0):  # s: the cluster starts about 1 s after, and takes about 5
        rc, err = _batch_signalled(simulated, tmp_path / f"i{delay:g}", delay, signal.SIGINT,
                                   group=True)
        if rc == 0:  # finished before the signal
            continue
        assert rc == 130, err
        assert "Traceback" not in err, (delay, err)
        assert len(err.splitlines()) == 1 and err.startswith("fieldloc: interrupted"), (
            delay, err)


@pytest.mark.parametrize("camera,progressive", [("omni", False), ("perspective", True)])
def test_a_jpeg_frame_whose_scan_is_damaged_prints_one_line_of_its_own(simulated, tmp_path,
                                                                        camera, progressive):
    """A JPEG frame whose scan data is damaged made OpenCV's libjpeg print "Corrupt JPEG data:
    2974 extraneous bytes before marker 0xd9" on stderr, and the frame was used, garbage
    pixels and all. Decoded by simplejpeg (the TurboJPEG API returns libjpeg's warnings),
    extract skips it with one warning line and show points refuses it in one line; nothing
    of libjpeg's is printed. (The progressive file's damage reaches a Huffman table between
    its scans: an error of libjpeg's, before which OpenCV's printed a warning.)"""
    import cv2
    from test_jpeg_and_image_headers import damaged_scan

    pytest.importorskip("simplejpeg")  # without it, OpenCV reads JPEG files (stages.common.jpeg)

    ds = tmp_path / "ds"
    shutil.copytree(simulated[camera], ds)
    first = ds / "images" / "000000.png"
    flags = [cv2.IMWRITE_JPEG_PROGRESSIVE, 1] if progressive else []
    ok, data = cv2.imencode(".jpg", cv2.imread(str(first)), flags)
    first.unlink()
    (ds / "images" / "000000.jpg").write_bytes(damaged_scan(data.tobytes()))
    frames = ds / "frames.csv"
    frames.write_text(frames.read_text().replace("000000.png", "000000.jpg"))
    r = _fieldloc("-q", "extract", ds, "-o", tmp_path / "f.h5", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and "frame 000000 skipped: unreadable image" in lines[0], r.stderr
    assert "(a damaged JPEG file: " in lines[0]
    r = _fieldloc("show", "points", ds, "--frame", "0", "-o", tmp_path / "b.png", cwd=tmp_path)
    assert r.returncode == 1
    assert len(r.stderr.splitlines()) == 1 and "(a damaged JPEG file: " in r.stderr, r.stderr


# ---- s57 group K: JPEG kinds that went to OpenCV whole (trial F's J1, J2, J4)


def test_damaged_cmyk_and_header_warning_jpegs_print_only_fieldlocs_lines(simulated, tmp_path):
    """A damaged CMYK JPEG frame (J1), a frame cut short behind a JFIF version libjpeg warns
    of (J2) and one with an unknown marker in its scan (J4) went to OpenCV's libjpeg, which
    printed "Corrupt JPEG data: ..." or the header's warning on stderr and decoded made-up
    pixels; extract counted them good frames. Now each is skipped in fieldloc's one line,
    and nothing of libjpeg's is printed."""
    import cv2
    from test_jpeg_and_image_headers import (
        as_cmyk,
        damaged_scan,
        with_header_warning,
        with_marker_in_scan,
    )

    pytest.importorskip("simplejpeg")  # without it, OpenCV reads JPEG files (stages.common.jpeg)

    ds = tmp_path / "ds"
    shutil.copytree(simulated["omni"], ds)
    frames = ds / "frames.csv"
    names = sorted(p.name for p in (ds / "images").glob("*.png"))
    first = cv2.imread(str(ds / "images" / names[0]))
    bad = [damaged_scan(as_cmyk(first)),
           with_header_warning(cv2.imencode(".jpg", first)[1].tobytes(), "jfif"),
           with_marker_in_scan(cv2.imencode(".jpg", first)[1].tobytes())]
    bad[1] = bad[1][:len(bad[1]) // 2] + b"\xff\xd9"
    table = frames.read_text()
    for i, data in enumerate(bad):
        name = f"bad{i}.jpg"
        (ds / "images" / name).write_bytes(data)
        table += f"{name},{10.0 + i:.6f}\n"
    frames.write_text(table)
    r = _fieldloc("-q", "extract", ds, "-o", tmp_path / "f.h5", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 3, r.stderr
    assert all("skipped: unreadable image" in line and "(a damaged JPEG file: " in line
               for line in lines), r.stderr
    r = _fieldloc("inspect", ds / "images" / "bad0.jpg", cwd=tmp_path)  # describes, on stdout
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert "a damaged JPEG file: Corrupt JPEG data: " in r.stdout
