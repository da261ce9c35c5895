"""Writing small ROS bags with ``rosbags`` itself: what a robot would have recorded, for the
tests and the bench of stages.ingest.rosbag (no ROS install).

    write_bag(path, fmt, *, image_topic, frames, odometry=None, imu=None, ...) -> Path

``fmt``: ``ros1`` (a .bag file), ``ros2-sqlite3`` or ``ros2-mcap`` (a bag folder). ``frames``: a
list of (stamp s, payload): a raw frame is (image array, encoding) and is stored as
sensor_msgs/Image with that encoding (the array already laid out in it: (h, w) for mono and
Bayer, (h, w, 3) for bgr8/rgb8, (h, w, 2) for yuv422); a compressed one is (bytes, format) and
is stored as sensor_msgs/CompressedImage. ``odometry``: rows (stamp, x, y, yaw) as
nav_msgs/Odometry; ``imu``: rows (stamp, yaw) as sensor_msgs/Imu. Messages are written at their
stamps (the bag's receive time equals the header stamp unless ``receive_delay`` s is given;
``zero_image_stamps``: the frames' header stamps are 0, as from a driver that never fills
them; ``header_stamps``: {"images" | "odometry" | "imu": one header stamp per message} for
messages written at their stamps but stamped otherwise, as by a clock that went back).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

FORMATS = ("ros1", "ros2-sqlite3", "ros2-mcap")


def _typestore(fmt):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)


def _time(ts, stamp: float):
    sec = int(math.floor(stamp))
    return ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((stamp - sec) * 1e9)))


def _header(ts, fmt, stamp, frame_id=""):
    Header = ts.types["std_msgs/msg/Header"]
    if fmt == "ros1":
        return Header(seq=0, stamp=_time(ts, stamp), frame_id=frame_id)
    return Header(stamp=_time(ts, stamp), frame_id=frame_id)


def _quaternion(ts, yaw):
    return ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                    w=math.cos(yaw / 2))


def _image(ts, fmt, stamp, payload):
    data, enc = payload
    if isinstance(data, (bytes, bytearray)):
        return "sensor_msgs/msg/CompressedImage", ts.types["sensor_msgs/msg/CompressedImage"](
            header=_header(ts, fmt, stamp, "camera"), format=enc,
            data=np.frombuffer(bytes(data), np.uint8))
    arr = np.ascontiguousarray(data)
    h, w = arr.shape[:2]
    step = arr.strides[0]
    return "sensor_msgs/msg/Image", ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, fmt, stamp, "camera"), height=h, width=w, encoding=enc,
        is_bigendian=0, step=step, data=arr.reshape(-1).view(np.uint8))


def _odometry(ts, fmt, stamp, x, y, yaw):
    T = ts.types
    cov = np.zeros(36)
    pose = T["geometry_msgs/msg/PoseWithCovariance"](
        pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                                         orientation=_quaternion(ts, yaw)), covariance=cov)
    zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    twist = T["geometry_msgs/msg/TwistWithCovariance"](
        twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=cov)
    return T["nav_msgs/msg/Odometry"](header=_header(ts, fmt, stamp, "odom"),
                                      child_frame_id="base_link", pose=pose, twist=twist)


def _imu(ts, fmt, stamp, yaw, has_orientation=True):
    T = ts.types
    zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    cov = np.zeros(9)
    ocov = cov.copy()
    if not has_orientation:
        ocov[0] = -1.0
    return T["sensor_msgs/msg/Imu"](header=_header(ts, fmt, stamp, "imu"),
                                    orientation=_quaternion(ts, yaw),
                                    orientation_covariance=ocov, angular_velocity=zero,
                                    angular_velocity_covariance=cov, linear_acceleration=zero,
                                    linear_acceleration_covariance=cov)


def write_bag(path, fmt: str, *, image_topic: str = "/camera/image", frames=(),
              odometry=None, imu=None, odom_topic: str = "/odom", imu_topic: str = "/imu",
              imu_has_orientation: bool = True, receive_delay: float = 0.0,
              zero_image_stamps: bool = False, header_stamps: dict | None = None) -> Path:
    """Write a bag (see the module doc); returns its path (a .bag file or a bag folder)."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown bag format {fmt!r} ({', '.join(FORMATS)})")
    ts = _typestore(fmt)
    path = Path(path)
    header_stamps = header_stamps or {}

    def header(kind: str, i: int, stamp) -> float:
        return float(header_stamps[kind][i]) if kind in header_stamps else float(stamp)

    rows = []  # (stamp, topic, msgtype, msg)
    for i, (stamp, payload) in enumerate(frames):
        typ, msg = _image(ts, fmt, 0.0 if zero_image_stamps else header("images", i, stamp),
                          payload)
        rows.append((float(stamp), image_topic, typ, msg))
    for i, (stamp, x, y, yaw) in enumerate(odometry if odometry is not None else ()):
        rows.append((float(stamp), odom_topic, "nav_msgs/msg/Odometry",
                     _odometry(ts, fmt, header("odometry", i, stamp), float(x), float(y),
                               float(yaw))))
    for i, (stamp, yaw) in enumerate(imu if imu is not None else ()):
        rows.append((float(stamp), imu_topic, "sensor_msgs/msg/Imu",
                     _imu(ts, fmt, header("imu", i, stamp), float(yaw), imu_has_orientation)))
    rows.sort(key=lambda r: r[0])
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        serialize = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if fmt == "ros2-mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
        serialize = ts.serialize_cdr
    with writer:
        conns = {}
        for _stamp, topic, typ, _msg in rows:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, typ, typestore=ts)
        # a series given empty ([], not None) is a topic without a message, as a driver that
        # advertised it and never published leaves one
        for given, topic, typ in ((odometry, odom_topic, "nav_msgs/msg/Odometry"),
                                  (imu, imu_topic, "sensor_msgs/msg/Imu")):
            if given is not None and not len(given) and topic not in conns:
                conns[topic] = writer.add_connection(topic, typ, typestore=ts)
        for stamp, topic, typ, msg in rows:
            writer.write(conns[topic], int(round((stamp + receive_delay) * 1e9)),
                         serialize(msg, typ))
    return path
