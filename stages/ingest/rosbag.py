"""A ROS bag into a dataset folder (GUIDE section 4), read with ``rosbags`` (no ROS install).

    main(conf, bag, output, *, image_topic, odom_topic=None, imu_topic=None, every=1,
         calib=None, overwrite=False, progress=False) -> Path

``bag``: a ROS 1 ``.bag`` file, or a ROS 2 bag folder (``metadata.yaml`` beside sqlite3
``.db3`` or ``.mcap`` files; the path of one of those files is taken as its folder).

What is written into ``output``:

- ``images/NNNNNN.png`` (or ``.jpg``): every ``every``-th message of ``image_topic``
  (sensor_msgs/Image or CompressedImage; encodings in stages.ingest.ros_images), numbered in
  bag order. Compressed JPEG/PNG frames are copied byte for byte; raw frames are written as
  PNG (``png_compression``: 0 stores them uncompressed, 1 is zlib's fastest level;
  ``png_strategy`` and ``png_filter``: zlib's matching strategy and PNG's row filter; preset
  ``default``: level 1, run-length matches after the "sub" filter, about half the size of the
  pixels; ``fast``: stored, about three times faster again). A frame that cannot be decoded is
  reported and skipped;
- ``frames.csv``: name, stamp: each frame's header stamp (s);
- ``odometry.csv`` (with ``odom_topic``, nav_msgs/Odometry): per frame the robot-frame
  increment (dx, dy, dtheta) since the previous frame, from the odometry pose interpolated at
  both frames' stamps (position linearly, heading linearly after unwrapping). Frames whose
  stamp or whose previous frame's stamp lies outside the odometry's time span get no row (the
  localiser then has no odometry for them) rather than an extrapolated one;
- ``imu.csv`` (with ``imu_topic``, sensor_msgs/Imu): the yaw of the IMU orientation
  interpolated at each frame's stamp (frames outside the IMU's time span get no row);
  collision 0 (a sensor_msgs/Imu message has no such flag). An IMU that publishes no
  orientation (``orientation_covariance[0] == -1``) is refused;
- ``calib.yaml``: a copy of ``calib`` when given (a bag holds no fieldloc calibration);
- ``import.yaml``: where the data came from (bag, topics, message types, counts, encodings,
  which stamps were used, skipped frames, dropped messages, frames dropped for a repeated or
  an out-of-order stamp, ``backward_stamps``).

Odometry and IMU messages no robot sends (a value that is not finite, a position beyond
``MAX_ODOMETRY_POSITION``, an orientation quaternion of no length) are dropped, with one
warning line per topic saying how many; a topic none of whose messages is usable is refused.
Frames are the most of the camera's messages whose stamps rise in bag order: a frame that
repeats a kept frame's stamp or is stamped out of order (a clock that went back, or one frame
stamped far ahead, which no longer drops the good frames after it) is dropped likewise, with
one warning line and its name in import.yaml (the dataset's odometry and IMU rows are
written at the frame stamps, and its readers take them only in time order, one per stamp).
Odometry and IMU messages are samples of a pose at their stamps: they are interpolated in
stamp order, whatever order the bag holds them in. The dataset written is one ``extract``
and ``localize`` read.

Stamps (conf ``stamp``): ``header`` uses each message's header stamp, except for a topic any of
whose messages has a zero header stamp (a driver that never fills it): that topic uses the
bag's receive times instead, with a warning. ``bag`` always uses the receive times.

Only the fields the import uses are read from each message's bytes (stages.ingest.rosbag_fields:
stamps, the pose, the orientation, an image's layout and a view of its data), with rosbags'
full deserialisation where that reader declines. The folder is written atomically
(stages.common.artifacts.atomic_dir). Frames to encode (raw,
Bayer) are encoded and written on ``workers`` threads while the bag is read (OpenCV releases
the GIL while encoding); compressed frames are copied in the reading thread, which is faster
than handing them to a thread that must win the GIL back after every system call.
"""

from __future__ import annotations

import bisect
import copy
import datetime as _dt
import logging
import math
import os
import shutil
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..common.artifacts import (
    WRITTEN_FILES,
    atomic_dir,
    cannot_read,
    check_importer_target,
    check_output,
    file_hash,
    record_text,
    tree_files,
    written_by,
    written_files,
)
from ..common.camera import load_calib
from ..common.conf import load_yaml, stage_conf
from ..common.dataset import MAX_VALUE, write_csv
from ..common.errors import FieldlocError, real_path
from ..common.geometry import wrap_angle
from ..common.image_header import image_size
from ..common.png import write_png
from . import ros_images
from .rosbag_fields import ImageFields, MessageFields

log = logging.getLogger(__name__)

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
ODOMETRY_TYPES = ("nav_msgs/msg/Odometry",)
IMU_TYPES = ("sensor_msgs/msg/Imu",)
STAMPS = ("header", "bag")
GENERATOR = "fieldloc import rosbag"  # import.yaml's generator: the marker of our folders

# zlib strategies and PNG row filters by name (OpenCV's IMWRITE_PNG_STRATEGY / _FILTER values)
PNG_STRATEGIES = {"default": 0, "filtered": 1, "huffman": 2, "rle": 3, "fixed": 4}
PNG_FILTERS = ("adaptive", "none", "sub", "up", "avg", "paeth")

confs = {
    "default": {
        "png_compression": 1,  # zlib level of raw frames written as PNG (0..9)
        # camera frames hold few long repeats: run-length matches after the "sub" row filter
        # (each byte less its left neighbour) give files within -6..+13 % of zlib's default
        # strategy with adaptive filters, 2-3 times faster (480 x 480 frames, 4 cameras)
        "png_strategy": "rle",
        "png_filter": "sub",
        "workers": 2,  # threads encoding and writing frames (0: in the reading thread)
        "max_in_flight": 8,  # frames read but not yet written, per worker
        "stamp": "header",  # header | bag (see the module doc)
    },
}
confs["fast"] = {**copy.deepcopy(confs["default"]), "png_compression": 0, "png_filter": "none"}


class BagError(FieldlocError):
    """A bag that cannot be read or does not hold what was asked for."""


@dataclass
class _Series:
    """Stamps (header and bag receive time, s) and values of one topic's messages."""

    header: list = field(default_factory=list)
    received: list = field(default_factory=list)
    values: list = field(default_factory=list)
    dropped: list = field(default_factory=list)  # why each message not imported was dropped

    def check_dropped(self, bag, topic: str | None, what: str) -> int:
        """One warning line for the messages of ``topic`` dropped as unusable (how many, the
        first's reason); BagError when none was usable, or when the topic named holds no
        message at all (an IMU or odometry asked for and not there). Returns how many were
        dropped."""
        if topic is not None and not self.dropped and not self.values:
            raise BagError(f"{bag}: the {what} topic {topic} holds no message")
        if not self.dropped:
            return 0
        n = len(self.dropped)
        if not self.values:
            raise BagError(f"{bag}: none of the {n} {what} message(s) on {topic} is usable"
                           f" (first: {self.dropped[0]})")
        log.warning("%s: %d of %d %s message(s) dropped as unusable (first: %s)", topic, n,
                    n + len(self.values), what, self.dropped[0])
        return n

    def stamps(self, mode: str, topic: str) -> tuple[np.ndarray, str]:
        header = np.asarray(self.header, float)
        if mode == "header" and len(header) and np.all(header > 0):
            return header, "header"
        if mode == "header" and len(header):
            log.warning("%s: %d message(s) have a zero header stamp; using the bag's receive"
                        " times for this topic", topic, int(np.sum(header <= 0)))
        return np.asarray(self.received, float), "bag"


# ---------------------------------------------------------------------------- reading


def bag_paths(bag) -> list[Path]:
    """The paths ``rosbags.highlevel.AnyReader`` takes for a bag given by the user."""
    p = Path(bag)
    if not p.exists():
        raise BagError(f"bag not found: {p}")
    if p.is_file() and p.suffix == ".bag":
        return [p]
    if p.is_file() and p.suffix in (".db3", ".mcap") and (p.parent / "metadata.yaml").is_file():
        return [p.parent]
    if p.is_dir() and (p / "metadata.yaml").is_file():
        return [p]
    if p.is_file() and p.suffix == ".mcap":
        raise BagError(f"{p}: an mcap file without metadata.yaml beside it; give the ROS 2 bag"
                       " folder (ros2 bag record writes one)")
    raise BagError(f"{p}: not a ROS bag (a ROS 1 .bag file, or a ROS 2 bag folder with"
                   " metadata.yaml)")


def _bag_problem(bag, e: BaseException) -> BagError:
    """One line for what rosbags (or the YAML and SQLite readers below it) raised on a
    foreign or damaged bag: the first line of its message, at most 120 characters; a bag
    fieldloc may not read is said to be that (``cannot_read``), not damaged."""
    cause = e
    while cause is not None and not isinstance(cause, PermissionError):
        cause = cause.__cause__ or cause.__context__
    if isinstance(cause, PermissionError):
        return BagError(str(cannot_read(cause.filename or bag, cause)))
    text = " ".join(str(e).split()) or type(e).__name__
    if len(text) > 120:
        text = text[:117] + "..."
    return BagError(f"{bag}: cannot read the bag, it is empty or damaged ({text})")


class _Reader:
    """rosbags' AnyReader with every failure of a foreign or damaged bag (empty, random
    bytes, truncated, metadata.yaml that is not YAML, a .db3 without tables) turned into a
    BagError, on opening and while its messages are read."""

    def __init__(self, bag):
        from rosbags.highlevel import AnyReader

        self.bag = bag
        try:
            self._reader = AnyReader(bag_paths(bag))
        except FieldlocError:
            raise
        except Exception as e:  # rosbags raises its own errors for foreign or broken files
            raise _bag_problem(bag, e) from None

    def __enter__(self):
        try:
            self._reader.open()
        except Exception as e:  # AnyReaderError, UnicodeDecodeError, YAML and SQLite errors
            raise _bag_problem(self.bag, e) from None
        return self

    def __exit__(self, *exc):
        try:
            self._reader.close()
        except Exception:  # closing a half-opened damaged bag: nothing more to report
            pass
        return False

    @property
    def connections(self):
        return self._reader.connections

    @property
    def is2(self) -> bool:
        """Whether the bag is ROS 2 (CDR messages) rather than ROS 1."""
        return bool(self._reader.is2)

    def deserialize(self, raw, msgtype):
        return self._reader.deserialize(raw, msgtype)

    def messages(self, connections):
        it = iter(self._reader.messages(connections=connections))
        while True:
            try:
                item = next(it)
            except StopIteration:
                return
            except Exception as e:  # a truncated chunk or a damaged database page
                raise _bag_problem(self.bag, e) from None
            yield item


def open_reader(bag) -> _Reader:
    """A reader on the bag, not yet opened (``with`` opens it); whatever a foreign or damaged
    bag makes rosbags raise is a BagError."""
    return _Reader(bag)


def _connections(reader, topic: str, types: tuple, what: str, bag) -> list:
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        have = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
        raise BagError(f"{bag}: no topic {topic} for the {what}; the bag has: "
                       + (", ".join(have) if have else "no topics"))
    bad = sorted({c.msgtype for c in conns if c.msgtype not in types})
    if bad:
        raise BagError(f"{bag}: topic {topic} carries {', '.join(bad)}; the {what} must be "
                       + " or ".join(types))
    return conns


def read_messages(bag, topics) -> int:
    """Read and deserialise every message of ``topics`` with rosbags and nothing else (what an
    import cannot do with less; the bench's baseline). Returns the number of messages."""
    reader = open_reader(bag)
    n = 0
    with reader:
        conns = [c for c in reader.connections if c.topic in set(topics)]
        for conn, _t, raw in reader.messages(connections=conns):
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n


def _stamp(msg) -> float:
    if isinstance(msg, ImageFields):
        return msg.stamp_s
    st = msg.header.stamp
    return float(st.sec) + 1e-9 * float(st.nanosec)


# m: the largest odometry position imported. The dataset holds increments between frames, each
# within dataset.MAX_VALUE (which extract and localize demand); two positions within a quarter
# of it give an increment within it. A position beyond is a damaged message (1e308 became an
# increment of 0, NaN one of NaN)
MAX_ODOMETRY_POSITION = MAX_VALUE / 4
# the norms of an orientation quaternion taken for a rotation: a unit quaternion has norm 1
# (drivers in float32 a few ulps off); an all-zero one is a driver's "not set", which atan2
# read as a yaw of 0, and one of norm 1e308 overflowed the yaw's products (90 deg read as 135)
MIN_QUATERNION_NORM = 0.1
MAX_QUATERNION_NORM = 10.0


def message_problem(position, quaternion) -> str | None:
    """Why an odometry (``position`` x, y) or IMU (``position`` empty) message cannot be
    imported, or None: a value that is not finite, a position beyond MAX_ODOMETRY_POSITION, an
    orientation quaternion of (nearly) no length."""
    values = [*position, *quaternion]
    if not all(math.isfinite(v) for v in values):
        return f"values {str(tuple(values))[:60]} are not all finite numbers"
    if any(abs(v) > MAX_ODOMETRY_POSITION for v in position):
        return (f"position {str(tuple(position))[:40]} lies beyond"
                f" {MAX_ODOMETRY_POSITION:g} m")
    if not MIN_QUATERNION_NORM <= math.hypot(*quaternion) <= MAX_QUATERNION_NORM:
        return f"orientation quaternion {str(tuple(quaternion))[:40]} is not a rotation"
    return None


def quaternion_yaw(x: float, y: float, z: float, w: float) -> float:
    """Rotation about z of a quaternion (rad)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


# ---------------------------------------------------------------------------- interpolation


def pose_at(stamps, x, y, yaw, at) -> tuple[np.ndarray, np.ndarray]:
    """Poses (F, 3) interpolated at the stamps ``at`` (x, y linearly, yaw linearly after
    unwrapping, wrapped back) and a (F,) bool: whether each stamp lies within the samples' span.
    Samples with equal stamps keep the last one."""
    t = np.asarray(stamps, float)
    at = np.asarray(at, float)
    if len(t) == 0:  # a topic without a message
        return np.full((len(at), 3), np.nan), np.zeros(len(at), bool)
    order = np.argsort(t, kind="stable")
    t = t[order]
    vals = np.stack([np.asarray(x, float)[order], np.asarray(y, float)[order],
                     np.unwrap(np.asarray(yaw, float)[order])], axis=1)
    keep = np.append(t[1:] != t[:-1], True)
    t, vals = t[keep], vals[keep]
    out = np.full((len(at), 3), np.nan)
    inside = (at >= t[0] - 1e-9) & (at <= t[-1] + 1e-9)
    for k in range(3):
        out[:, k] = np.interp(at, t, vals[:, k])
    out[:, 2] = wrap_angle(out[:, 2])
    out[~inside] = np.nan
    return out, inside


def increments_between(poses, inside) -> tuple[np.ndarray, np.ndarray]:
    """Robot-frame increments (F, 3) from frame k-1 to frame k of interpolated odometry poses,
    and a (F,) bool: defined (both frames inside the odometry's span; never for frame 0)."""
    poses = np.asarray(poses, float)
    inc = np.zeros_like(poses)
    ok = np.zeros(len(poses), bool)
    if len(poses) < 2:
        return inc, ok
    a, b = poses[:-1], poses[1:]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    inc[1:, 0] = c * dx + s * dy
    inc[1:, 1] = -s * dx + c * dy
    inc[1:, 2] = wrap_angle(b[:, 2] - a[:, 2])
    ok[1:] = inside[:-1] & inside[1:]
    inc[~ok] = 0.0
    return inc, ok


# ---------------------------------------------------------------------------- writing


def _check_conf(conf: dict, every):
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise FieldlocError(f"--every must be a whole number >= 1, got {every!r}")
    lvl = conf["png_compression"]
    if isinstance(lvl, bool) or not isinstance(lvl, int) or not 0 <= lvl <= 9:
        raise FieldlocError(f"png_compression must be 0..9, got {lvl!r}")
    w = conf["workers"]
    if isinstance(w, bool) or not isinstance(w, int) or w < 0:
        raise FieldlocError(f"workers must be a whole number >= 0, got {w!r}")
    if conf["png_strategy"] not in PNG_STRATEGIES:
        raise FieldlocError(f"png_strategy must be one of {', '.join(PNG_STRATEGIES)}, got"
                            f" {str(conf['png_strategy'])[:30]!r}")
    if conf["png_filter"] not in PNG_FILTERS:
        raise FieldlocError(f"png_filter must be one of {', '.join(PNG_FILTERS)}, got"
                            f" {str(conf['png_filter'])[:30]!r}")
    if conf["stamp"] not in STAMPS:
        raise FieldlocError(f"stamp must be one of {', '.join(STAMPS)}, got {conf['stamp']!r}")


def png_params(conf: dict) -> list:
    """OpenCV's imwrite parameters for raw frames written as PNG under ``conf``."""
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, int(conf["png_compression"]),
              cv2.IMWRITE_PNG_STRATEGY, PNG_STRATEGIES[conf["png_strategy"]]]
    if conf["png_filter"] != "adaptive":
        params += [cv2.IMWRITE_PNG_FILTER,
                   getattr(cv2, f"IMWRITE_PNG_FILTER_{conf['png_filter'].upper()}")]
    return params


class _FrameWriter:
    """Turns image messages into files, on worker threads when asked."""

    def __init__(self, folder: Path, conf: dict):
        self.folder = folder
        self.conf = conf
        self._png_params = None
        workers = int(conf["workers"])
        self.pool = ThreadPoolExecutor(max_workers=workers) if workers > 0 else None
        self.limit = max(1, workers) * int(conf["max_in_flight"])
        self.pending: list = []
        self.skipped: list[dict] = []
        self.encodings: dict[str, int] = {}
        self.size: tuple[int, int] | None = None  # (width, height) of the first frame
        self.sizes_said = False  # frames of another size than the first were warned of

    def add(self, index: int, name_stem: str, msgtype: str, msg) -> str | None:
        """Queue one frame; returns its file name, or None if it was skipped."""
        try:
            if msgtype.endswith("CompressedImage"):
                key = msg.format or "(none)"
                suffix, content = ros_images.compressed_to_file(msg.format, msg.data)
                job = (content, None)
                size = (image_size(content) if isinstance(content, bytes)
                        else content.shape[1::-1])
            else:
                key = msg.encoding
                ros_images.raw_pixels(msg.height, msg.width, msg.encoding, msg.step, msg.data,
                                      bool(msg.is_bigendian))  # checks the layout here
                suffix = ".png"
                job = (None, (msg.height, msg.width, msg.encoding, msg.step, msg.data,
                              bool(msg.is_bigendian)))
                size = (int(msg.width), int(msg.height))
            self._check_size(index, size)
        except ros_images.ImageMessageError as e:
            self._skip(index, str(e))
            return None
        if not self.encodings:  # the first frame: the skips before it are said now
            for s in self.skipped:
                log.warning("image message %d skipped: %s", s["message"], s["reason"])
        self.encodings[key] = self.encodings.get(key, 0) + 1
        name = name_stem + suffix
        if self.pool is None or isinstance(job[0], bytes):
            # bytes to copy are written at once: a worker thread would wait for the GIL
            # after each system call while this thread deserialises (slower, not faster)
            self._write(index, name, *job)
        else:
            if len(self.pending) >= self.limit:
                self._drain(self.limit // 2)
            self.pending.append(self.pool.submit(self._write, index, name, *job))
        return name

    def _check_size(self, index: int, size) -> None:
        """Warn once where a frame is of another size than the first (``size``: (width,
        height), None where its header does not say): a dataset's frames share one
        calib.yaml, and extract leaves out those of another size (trial V2-4: two sizes
        written without a word). Not skipped here: a first frame whose header lies (its
        pixels cut short, trial W2-2) would have every good frame after it dropped."""
        if size is None:
            return
        size = (int(size[0]), int(size[1]))
        if self.size is None:
            self.size = size
        elif size != self.size and not self.sizes_said:
            self.sizes_said = True
            log.warning("image message %d is of %d x %d px, the first frame's %d x %d: a"
                        " dataset's frames share one calib.yaml, and extract leaves out those"
                        " of another size than it gives", index, *size, *self.size)

    def _skip(self, index, reason):
        """Record a skipped message; said at once after the first frame, else when the first
        frame comes: a bag none of whose frames is written is refused in one line (main)."""
        if self.encodings:
            log.warning("image message %d skipped: %s", index, reason)
        self.skipped.append({"message": int(index), "reason": reason})

    def png_params(self) -> list:
        if self._png_params is None:
            self._png_params = png_params(self.conf)
        return self._png_params

    def _write(self, index, name, content, raw):
        if raw is not None:
            content = ros_images.raw_to_image(*raw)
        if isinstance(content, np.ndarray):
            # encoded and written without the GIL; a full disk raises its OSError, which
            # atomic_dir reports as the output's
            write_png(self.folder / name, content, self.png_params())
            return
        fd = os.open(self.folder / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            view = memoryview(content).cast("B")
            while view:
                view = view[os.write(fd, view):]
        finally:
            os.close(fd)

    def _drain(self, keep: int = 0):
        while len(self.pending) > keep:
            self.pending.pop(0).result()

    def close(self):
        try:
            self._drain(0)
        finally:
            if self.pool is not None:
                self.pool.shutdown(wait=True)


def main(conf: str | dict | None, bag, output, *, image_topic: str, odom_topic: str | None = None,
         imu_topic: str | None = None, every: int = 1, calib=None, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Import ``bag`` into the dataset folder ``output`` (see the module doc); ``conf``: a
    preset name, None or a dict of overrides on ``default``. Returns ``output``."""
    from tqdm import tqdm

    conf = stage_conf(confs, conf)
    _check_conf(conf, every)
    output = Path(output)
    _check_target(output, bag, calib, overwrite)
    if calib is not None:
        try:
            load_calib(calib)
        except FieldlocError as e:
            raise FieldlocError(f"--calib: {e}") from None
    reader = open_reader(bag)
    with reader:
        img_conns = _connections(reader, image_topic, IMAGE_TYPES, "images", bag)
        odo_conns = (_connections(reader, odom_topic, ODOMETRY_TYPES, "odometry", bag)
                     if odom_topic else [])
        imu_conns = _connections(reader, imu_topic, IMU_TYPES, "IMU", bag) if imu_topic else []
        role = {id(c): "image" for c in img_conns}
        role.update({id(c): "odometry" for c in odo_conns})
        role.update({id(c): "imu" for c in imu_conns})
        conns = img_conns + odo_conns + imu_conns
        total = sum(int(c.msgcount) for c in conns)
        frames, odo, imu = _Series(), _Series(), _Series()
        names: list[str] = []
        with atomic_dir(output, overwrite=overwrite) as tmp:
            (tmp / "images").mkdir()
            writer = _FrameWriter(tmp / "images", conf)
            fields = MessageFields(cdr=reader.is2)
            n_image = 0
            try:
                bar = tqdm(total=total, desc="import rosbag", unit="msg", disable=not progress)
                for conn, t_ns, raw in reader.messages(connections=conns):
                    bar.update(1)
                    kind = role[id(conn)]
                    if kind == "image":
                        index, n_image = n_image, n_image + 1
                        if index % every:
                            continue
                        msg = (fields.image(raw, conn.msgtype)
                               or _deserialize(reader, raw, conn, bag))
                        name = writer.add(index, f"{len(names):06d}", conn.msgtype, msg)
                        if name is None:
                            continue
                        names.append(name)
                        frames.header.append(_stamp(msg))
                        frames.received.append(t_ns * 1e-9)
                    elif kind == "odometry":
                        v = fields.odometry(raw)
                        if v is None:
                            msg = _deserialize(reader, raw, conn, bag)
                            p, q = msg.pose.pose.position, msg.pose.pose.orientation
                            v = (_stamp(msg), p.x, p.y, q.x, q.y, q.z, q.w)
                        if why := message_problem(v[1:3], v[3:7]):
                            odo.dropped.append(why)
                            continue
                        odo.header.append(v[0])
                        odo.received.append(t_ns * 1e-9)
                        odo.values.append((v[1], v[2], quaternion_yaw(*v[3:7])))
                    else:
                        v = fields.imu(raw)
                        if v is None:
                            msg = _deserialize(reader, raw, conn, bag)
                            q = msg.orientation
                            v = (_stamp(msg), q.x, q.y, q.z, q.w,
                                 float(msg.orientation_covariance[0]))
                        if v[5] == -1.0:
                            raise BagError(f"{bag}: topic {imu_topic} publishes no orientation"
                                           " (orientation_covariance[0] = -1): no yaw to import")
                        if why := message_problem((), v[1:5]):
                            imu.dropped.append(why)
                            continue
                        imu.header.append(v[0])
                        imu.received.append(t_ns * 1e-9)
                        imu.values.append(quaternion_yaw(*v[1:5]))
                bar.close()
            finally:
                writer.close()
            if not names:
                skipped = writer.skipped
                why = skipped[0]["reason"] if skipped else "the topic has no messages"
                if len(skipped) > 1:
                    why = f"{len(skipped)} image messages skipped; the first: {why}"
                raise BagError(f"{bag}: no frame written from {image_topic} ({why})")
            dropped = {topic: n for topic, n in (
                (odom_topic, odo.check_dropped(bag, odom_topic, "odometry")),
                (imu_topic, imu.check_dropped(bag, imu_topic, "IMU"))) if n}
            record = _write_tables(tmp, names, frames, odo, imu, conf["stamp"], image_topic,
                                   odom_topic, imu_topic)
            record["dropped_messages"] = dropped
            if calib is not None:
                shutil.copyfile(calib, tmp / "calib.yaml")
            record.update({
                "generator": GENERATOR,
                "fieldloc_version": __version__,
                "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                "bag": str(bag),
                "bag_format": _bag_format(bag),
                "every": int(every),
                "image_messages": int(n_image),
                "frames": (len(names) - len(record["repeated_stamps"])
                           - len(record["backward_stamps"])),
                "encodings": writer.encodings,
                "skipped": writer.skipped,
                "message_types": {c.topic: c.msgtype for c in conns},
                "conf": dict(conf),
            })
            if calib is not None:
                record["calib"] = {"source": str(calib), "hash": file_hash(calib)}
            record[WRITTEN_FILES] = written_files(tmp, tree_files(tmp))  # --overwrite's test
            (tmp / "import.yaml").write_bytes(record_text(record, "import.yaml").encode())
    log.info("imported %d frames from %s into %s", len(names), bag, output)
    return output


def is_imported_dataset(folder: Path) -> bool:
    """Whether ``folder`` was written by this importer (its import.yaml says so)."""
    return written_by(folder, "import.yaml", GENERATOR)


def _check_target(output: Path, bag, calib, overwrite: bool) -> None:
    """The dataset folder may be none of the inputs, hold none, nor lie inside a ROS 2 bag
    folder; ``overwrite`` replaces only a folder this importer wrote, never a user's own
    folder (the whole folder is replaced, so anything else in it would be lost)."""
    source = bag_paths(bag)[0]
    check_output(output, {"bag": [Path(bag), source], "calibration": calib}, overwrite=None,
                 kind="folder", recording=True)
    if source.is_dir() and real_path(output).is_relative_to(real_path(source)):
        raise FieldlocError(f"{output} lies inside the bag folder {source}: choose an output"
                            " outside it")
    check_importer_target(output, {}, overwrite, record="import.yaml", generator=GENERATOR)


def _deserialize(reader, raw, conn, bag):
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as e:  # a message that does not match its own definition
        raise BagError(f"{bag}: a {conn.msgtype} message on {conn.topic} cannot be"
                       f" deserialised ({e})") from None


def _bag_format(bag) -> str:
    p = bag_paths(bag)[0]
    if p.suffix == ".bag":
        return "ros1"
    storage = {f.suffix for f in p.iterdir()}
    return "ros2-mcap" if ".mcap" in storage else "ros2-sqlite3"


def _write_tables(folder, names, frames, odo, imu, stamp_mode, image_topic, odom_topic,
                  imu_topic) -> dict:
    stamps, frame_source = frames.stamps(stamp_mode, image_topic)
    names, stamps, repeated, backward = _frames_in_stamp_order(folder, names, stamps)
    if repeated:
        log.warning("%s: %d frame(s) repeat an earlier frame's stamp; dropped (one frame per"
                    " stamp: the odometry and IMU rows are one per stamp)", image_topic,
                    len(repeated))
    if backward:
        log.warning("%s: %d frame(s) stamped out of order with the others; dropped (frames"
                    " are the most of the camera's messages in stamp order; first: %s)",
                    image_topic, len(backward), backward[0])
    write_csv(folder / "frames.csv", "frames", {"name": names, "stamp": stamps})
    record = {"stamps": {"images": frame_source}, "topics": {"images": image_topic},
              "repeated_stamps": repeated, "backward_stamps": backward}
    if odom_topic:
        t, source = odo.stamps(stamp_mode, odom_topic)
        v = np.asarray(odo.values, float).reshape(-1, 3)
        poses, inside = pose_at(t, v[:, 0], v[:, 1], v[:, 2], stamps)
        inc, ok = increments_between(poses, inside)
        if ok.any():  # a file of no rows is one the dataset's readers refuse
            write_csv(folder / "odometry.csv", "odometry", {
                "stamp": stamps[ok], "dx": inc[ok, 0], "dy": inc[ok, 1], "dtheta": inc[ok, 2]})
        record["stamps"]["odometry"] = source
        record["topics"]["odometry"] = odom_topic
        record["odometry_messages"] = len(v)
        record["odometry_rows"] = int(ok.sum())
        if len(names) > 1 and ok.sum() < len(names) - 1:
            log.warning("%s covers %d of %d frame intervals; the others have no odometry row",
                        odom_topic, int(ok.sum()), len(names) - 1)
    if imu_topic:
        t, source = imu.stamps(stamp_mode, imu_topic)
        yaw = np.asarray(imu.values, float)
        poses, inside = pose_at(t, np.zeros_like(yaw), np.zeros_like(yaw), yaw, stamps)
        if inside.any():
            write_csv(folder / "imu.csv", "imu", {
                "stamp": stamps[inside], "yaw": poses[inside, 2],
                "collision": np.zeros(int(inside.sum()))})
        record["stamps"]["imu"] = source
        record["topics"]["imu"] = imu_topic
        record["imu_messages"] = len(yaw)
        record["imu_rows"] = int(inside.sum())
    return record


def _frames_in_stamp_order(folder, names, stamps) -> tuple[list, np.ndarray, list, list]:
    """The frames in stamp order: the most frames whose stamps rise strictly in bag order
    (a longest increasing subsequence; of several, the one keeping the earliest frames), and
    the images of the others are removed from ``folder``/images. Returns the names and stamps
    kept, the names dropped for repeating a kept frame's stamp (a driver that stamped several
    images alike) and those dropped for a stamp out of order (a clock that went back or
    jumped ahead, a message stamped late). Keeping only frames stamped after every earlier
    kept frame let one frame stamped far ahead drop every good frame after it. Frames are
    read in name order, which is bag order, and their odometry and IMU rows are written at
    their stamps: a stamp repeated or out of order would make rows of one stamp or out of
    time order, which the dataset's readers refuse (rows are in time order, one per stamp).
    Sorting the frames by stamp instead would keep a glitch's frame and put the names out of
    order."""
    stamps = np.asarray(stamps, float)
    keep = _longest_rising(stamps)
    kept = set(stamps[keep].tolist())
    repeated, backward = [], []
    for name, t, k in zip(names, stamps, keep):
        if not k:
            (repeated if t in kept else backward).append(name)
    for n in repeated + backward:
        (folder / "images" / n).unlink()
    return [n for n, k in zip(names, keep) if k], stamps[keep], repeated, backward


def _longest_rising(values: np.ndarray) -> np.ndarray:
    """A mask of the longest subsequence of ``values`` rising strictly (NaN never in it); of
    several, the one whose positions come first. O(n log n): the longest rising run starting
    at each position, found from the end (patience sorting of the negated values), then
    taken greedily from the start."""
    n = len(values)
    longest = np.zeros(n, int)  # the longest rising subsequence starting at each position
    tails: list[float] = []  # tails[k]: the largest -value starting a rise of k + 1
    for i in range(n - 1, -1, -1):
        if not np.isfinite(values[i]):
            continue
        k = bisect.bisect_left(tails, -values[i])
        longest[i] = k + 1
        if k == len(tails):
            tails.append(-values[i])
        else:
            tails[k] = -values[i]
    keep = np.zeros(n, bool)
    need, last = int(longest.max(initial=0)), -np.inf
    for i in range(n):
        if need and longest[i] == need and values[i] > last:
            keep[i], need, last = True, need - 1, values[i]
    return keep


def describe(output) -> dict:
    """The import record of a dataset folder written by this stage (for the CLI's report)."""
    p = Path(output) / "import.yaml"
    if not p.is_file():
        raise FieldlocError(f"{output}: no import.yaml (not written by fieldloc import rosbag)")
    return load_yaml(p.read_text())
