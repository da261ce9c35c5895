"""``fieldloc bench`` rows of `fieldloc import rosbag`: a 1000-frame bag (ROS 1 with JPEG
frames, ROS 2 MCAP with raw ones) against reading and deserialising the same messages."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .harness import Row, msec
from .inputs import INPUTS, work_dir


def _import_bag(fmt: str, kind: str, frames: int = 1000, size: int = 480) -> Path:
    """A bag of ``frames`` rendered-looking frames (``kind`` jpeg: CompressedImage, raw:
    Image bgr8) with odometry and IMU at 100 Hz, written once per bench run."""
    key = ("bag", fmt, kind, frames, size)
    if key not in INPUTS:
        import cv2

        from ...ingest.bag_writer import write_bag

        rng = np.random.default_rng(11)
        base = cv2.GaussianBlur(rng.integers(0, 256, (size, size, 3), dtype=np.uint8), (9, 9), 3)
        stamps = 1700000000.0 + np.arange(frames) / 30.0
        imgs = (np.roll(base, 3 * k, axis=1) for k in range(frames))
        payload = ([(cv2.imencode(".jpg", im)[1].tobytes(), "jpeg") for im in imgs]
                   if kind == "jpeg" else [(im, "bgr8") for im in imgs])
        t = stamps[0] + np.arange(int(frames / 30.0 * 100) + 2) / 100.0
        odo = np.c_[t, 0.5 * (t - t[0]), np.zeros_like(t), 0.2 * (t - t[0])]
        path = work_dir() / (f"{fmt}-{kind}-{frames}" + (".bag" if fmt == "ros1" else ""))
        write_bag(path, fmt, frames=list(zip(stamps, payload)), odometry=odo,
                  imu=np.c_[t, 0.2 * (t - t[0])])
        INPUTS[key] = path
    return INPUTS[key]


def bench_import_rosbag(repeat: int) -> list[Row]:
    import shutil

    from ...ingest import rosbag

    topics = ["/camera/image", "/odom", "/imu"]
    rows = []
    for fmt, kind, preset, n_rep in (("ros1", "jpeg", "default", repeat),
                                     ("ros2-mcap", "raw", "fast", max(2, repeat // 2)),
                                     ("ros2-mcap", "raw", "default", max(2, repeat // 2))):
        bag = _import_bag(fmt, kind)
        out_root = work_dir() / f"import-{fmt}-{kind}-{preset}"
        out_root.mkdir(exist_ok=True)
        a, b, floor, cpu_a, cpu_b, encode = [], [], [], [], [], []
        for k in range(n_rep + 1):  # the first round warms up (imports, page cache)
            out = out_root / f"run{k}"
            t, c = time.perf_counter(), time.process_time()
            rosbag.main(rosbag.confs[preset], bag, out, image_topic="/camera/image",
                        odom_topic="/odom", imu_topic="/imu")
            t_import, c_import = time.perf_counter() - t, time.process_time() - c
            t, c = time.perf_counter(), time.process_time()
            rosbag.read_messages(bag, topics)
            t_read, c_read = time.perf_counter() - t, time.process_time() - c
            # the disk's share: writing the same files again, nothing else
            files = [(p.name, p.read_bytes()) for p in sorted((out / "images").iterdir())]
            again = out_root / f"again{k}"
            again.mkdir()
            t = time.perf_counter()
            for name, data in files:
                (again / name).write_bytes(data)
            t_floor = time.perf_counter() - t
            t_encode = _png_encode_time(out / "images", rosbag, preset) if kind == "raw" else 0
            # not timed: a folder full of earlier runs' files makes new ones slower to create
            shutil.rmtree(out, ignore_errors=True)
            shutil.rmtree(again, ignore_errors=True)
            if k:
                a.append(t_import)
                b.append(t_read)
                floor.append(t_floor)
                cpu_a.append(c_import)
                cpu_b.append(c_read)
                encode.append(t_encode)
        shutil.rmtree(out_root, ignore_errors=True)
        ratio = msec(a) / msec(b)
        what = ("CompressedImage JPEG, copied" if kind == "jpeg"
                else "Image bgr8 480 x 480 -> PNG level {png_compression}, {png_strategy}"
                     " strategy, {png_filter} filter".format(**rosbag.confs[preset]))
        rows.append(Row(
            name=f"import rosbag {fmt}, 1000 frames ({kind}, preset {preset})",
            median_ms=msec(a), baseline="rosbags reading + deserialising the same messages",
            baseline_ms=msec(b), ratio=ratio, goal="<= 1.5 x reading",
            meets_goal=ratio <= 1.5, repeats=len(a),
            note=f"{what}; + odometry and IMU at 100 Hz; writing the same image files alone"
                 f" took {msec(floor):.0f} ms"
                 + (f", encoding the same frames alone (one thread) {msec(encode):.0f} ms"
                    if kind == "raw" else "")
                 + f"; CPU time {msec(cpu_a):.0f} ms against {msec(cpu_b):.0f} ms reading"
                   f" ({msec(cpu_a) / msec(cpu_b):.2f} x)"))
    return rows


def _png_encode_time(folder, rosbag, preset: str) -> float:
    """Seconds to encode the frames of ``folder`` again with the preset's PNG parameters in
    one thread, in memory: the encoder's share of a raw import."""
    import cv2

    params = rosbag.png_params(rosbag.confs[preset])
    frames = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(folder.iterdir())]
    t = time.perf_counter()
    for im in frames:
        cv2.imencode(".png", im, params)
    return time.perf_counter() - t
