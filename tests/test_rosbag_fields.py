"""stages.ingest.rosbag_fields reads the import's fields from serialised messages: for any
message rosbags serialises (ROS 1 and CDR, frame ids of every length, so every alignment), the
fields equal what rosbags' own deserialisation gives; and what it cannot read it declines."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.ingest.rosbag_fields import ImageFields, MessageFields

pytest.importorskip("rosbags")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

STORES = {"ros1": get_typestore(Stores.ROS1_NOETIC), "ros2": get_typestore(Stores.ROS2_HUMBLE)}
names = st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=11)
floats = st.floats(-1e6, 1e6, allow_nan=False)
stamps = st.tuples(st.integers(0, 2**31 - 1), st.integers(0, 999_999_999))


def _header(ts, wire, stamp, frame_id):
    t = ts.types["builtin_interfaces/msg/Time"](sec=stamp[0], nanosec=stamp[1])
    if wire == "ros1":
        return ts.types["std_msgs/msg/Header"](seq=7, stamp=t, frame_id=frame_id)
    return ts.types["std_msgs/msg/Header"](stamp=t, frame_id=frame_id)


def _serialise(ts, wire, msg, typ):
    return bytes(ts.serialize_ros1(msg, typ) if wire == "ros1" else ts.serialize_cdr(msg, typ))


def _deserialise(ts, wire, raw, typ):
    return ts.deserialize_ros1(raw, typ) if wire == "ros1" else ts.deserialize_cdr(raw, typ)


def _seconds(m):
    return m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec


@settings(max_examples=60, deadline=None)
@given(wire=st.sampled_from(["ros1", "ros2"]), stamp=stamps, frame_id=names, fmt=names,
       data=st.binary(max_size=40))
def test_compressed_image_fields(wire, stamp, frame_id, fmt, data):
    ts = STORES[wire]
    typ = "sensor_msgs/msg/CompressedImage"
    msg = ts.types[typ](header=_header(ts, wire, stamp, frame_id), format=fmt,
                        data=np.frombuffer(data, np.uint8))
    raw = _serialise(ts, wire, msg, typ)
    got = MessageFields(cdr=wire == "ros2").image(raw, typ)
    ref = _deserialise(ts, wire, raw, typ)
    assert isinstance(got, ImageFields)
    assert got.stamp_s == _seconds(ref) and got.format == ref.format
    assert bytes(got.data) == bytes(ref.data)


@settings(max_examples=60, deadline=None)
@given(wire=st.sampled_from(["ros1", "ros2"]), stamp=stamps, frame_id=names,
       encoding=st.sampled_from(["bgr8", "mono8", "mono16", "yuv422", "bayer_rggb8"]),
       h=st.integers(1, 4), w=st.integers(1, 5), pad=st.integers(0, 3),
       big=st.booleans())
def test_raw_image_fields(wire, stamp, frame_id, encoding, h, w, pad, big):
    ts = STORES[wire]
    typ = "sensor_msgs/msg/Image"
    step = w * 3 + pad
    data = np.arange(h * step, dtype=np.uint8)
    msg = ts.types[typ](header=_header(ts, wire, stamp, frame_id), height=h, width=w,
                        encoding=encoding, is_bigendian=int(big), step=step, data=data)
    raw = _serialise(ts, wire, msg, typ)
    got = MessageFields(cdr=wire == "ros2").image(raw, typ)
    ref = _deserialise(ts, wire, raw, typ)
    assert got.stamp_s == _seconds(ref)
    assert (got.height, got.width, got.encoding, got.is_bigendian, got.step) == (
        ref.height, ref.width, ref.encoding, bool(ref.is_bigendian), ref.step)
    assert bytes(got.data) == bytes(ref.data)


@settings(max_examples=60, deadline=None)
@given(wire=st.sampled_from(["ros1", "ros2"]), stamp=stamps, frame_id=names, child=names,
       pose=st.tuples(floats, floats, floats, floats, floats, floats, floats))
def test_odometry_fields(wire, stamp, frame_id, child, pose):
    ts = STORES[wire]
    T = ts.types
    typ = "nav_msgs/msg/Odometry"
    cov = np.arange(36, dtype=float)
    zero = T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=3.0)
    msg = T[typ](
        header=_header(ts, wire, stamp, frame_id), child_frame_id=child,
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=pose[0], y=pose[1], z=pose[2]),
                orientation=T["geometry_msgs/msg/Quaternion"](x=pose[3], y=pose[4], z=pose[5],
                                                              w=pose[6])),
            covariance=cov),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=cov))
    raw = _serialise(ts, wire, msg, typ)
    got = MessageFields(cdr=wire == "ros2").odometry(raw)
    ref = _deserialise(ts, wire, raw, typ)
    p, q = ref.pose.pose.position, ref.pose.pose.orientation
    assert got == (_seconds(ref), p.x, p.y, q.x, q.y, q.z, q.w)


@settings(max_examples=60, deadline=None)
@given(wire=st.sampled_from(["ros1", "ros2"]), stamp=stamps, frame_id=names,
       q=st.tuples(floats, floats, floats, floats), cov0=st.sampled_from([0.0, -1.0, 0.5]))
def test_imu_fields(wire, stamp, frame_id, q, cov0):
    ts = STORES[wire]
    T = ts.types
    typ = "sensor_msgs/msg/Imu"
    v = T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=3.0)
    ocov = np.full(9, 0.25)
    ocov[0] = cov0
    msg = T[typ](header=_header(ts, wire, stamp, frame_id),
                 orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                 orientation_covariance=ocov, angular_velocity=v,
                 angular_velocity_covariance=np.zeros(9), linear_acceleration=v,
                 linear_acceleration_covariance=np.zeros(9))
    raw = _serialise(ts, wire, msg, typ)
    got = MessageFields(cdr=wire == "ros2").imu(raw)
    ref = _deserialise(ts, wire, raw, typ)
    o = ref.orientation
    assert got == (_seconds(ref), o.x, o.y, o.z, o.w, float(ref.orientation_covariance[0]))


def test_what_it_cannot_read_it_declines():
    ts = STORES["ros2"]
    typ = "sensor_msgs/msg/CompressedImage"
    msg = ts.types[typ](header=_header(ts, "ros2", (1, 2), "cam"), format="jpeg",
                        data=np.zeros(10, np.uint8))
    raw = bytearray(_serialise(ts, "ros2", msg, typ))
    fields = MessageFields(cdr=True)
    assert fields.image(bytes(raw), typ) is not None
    assert fields.image(bytes(raw), "sensor_msgs/msg/PointCloud2") is None
    big = bytearray(raw)
    big[1] = 0  # big-endian CDR: left to rosbags
    assert fields.image(bytes(big), typ) is None
    assert fields.image(bytes(raw[:-4]), typ) is None  # data runs past the message
    assert fields.image(bytes(raw[:10]), typ) is None
    assert fields.odometry(bytes(raw[:12])) is None and fields.imu(b"") is None
    assert math.isclose(fields.image(bytes(raw), typ).stamp_s, 1 + 2e-9)
