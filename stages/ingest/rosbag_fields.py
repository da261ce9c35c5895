"""The few fields ``import rosbag`` needs, read straight from a message's serialised bytes.

    MessageFields(cdr).image(raw, msgtype) -> ImageFields | None
    MessageFields(cdr).odometry(raw) -> (stamp, x, y, qx, qy, qz, qw) | None
    MessageFields(cdr).imu(raw) -> (stamp, qx, qy, qz, qw, orientation_covariance[0]) | None

rosbags deserialises every field of a message into Python objects: for nav_msgs/Odometry two
6 x 6 covariances and a twist, for sensor_msgs/Imu three covariances and two vectors the import
never reads, and those messages outnumber the frames 7 to 1 at 100 Hz. Here only the header
stamp, the pose or orientation, and an image's layout and a view of its bytes are read, at the
offsets the two wire formats give:

- ROS 1: little-endian, packed; std_msgs/Header is seq (uint32), stamp (uint32 sec, uint32
  nsec), frame_id (uint32 length + bytes); a string is a uint32 length and its bytes, a uint8[]
  a uint32 count and its bytes.
- ROS 2 (CDR, OMG DDS-XTypes): a 4-byte encapsulation header (``00 01``: little-endian CDR),
  then every primitive aligned to its own size counted from the end of that header; the stamp
  is int32 sec, uint32 nanosec; a string is a uint32 length that counts its terminating NUL.

Anything else (big-endian CDR, a length that runs past the message, a type not listed) gives
None, and the caller deserialises the message with rosbags, which also reports broken messages
the way it always did.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

_U32 = struct.Struct("<I")
_STAMP1 = struct.Struct("<II")  # ROS 1 time: sec, nsec (after seq)
_STAMP2 = struct.Struct("<iI")  # ROS 2 builtin_interfaces/Time
_F64x7 = struct.Struct("<7d")  # position x, y, z; orientation x, y, z, w
_F64x5 = struct.Struct("<5d")  # orientation x, y, z, w; orientation_covariance[0]

COMPRESSED = "sensor_msgs/msg/CompressedImage"
RAW = "sensor_msgs/msg/Image"


@dataclass
class ImageFields:
    """What ``_FrameWriter`` reads of an image message (the attribute names of the ROS
    message), and the header stamp in seconds."""

    stamp_s: float
    format: str = ""
    height: int = 0
    width: int = 0
    encoding: str = ""
    is_bigendian: bool = False
    step: int = 0
    data: memoryview | None = None


class _Cursor:
    """A read position in one message; ``base`` is where CDR alignment counts from."""

    __slots__ = ("buf", "pos", "base", "cdr")

    def __init__(self, buf, cdr: bool):
        self.buf = buf
        self.cdr = cdr
        self.base = 4 if cdr else 0
        self.pos = self.base

    def align(self, size: int):
        if self.cdr:
            self.pos += (-(self.pos - self.base)) % size

    def u32(self) -> int:
        self.align(4)
        v = _U32.unpack_from(self.buf, self.pos)[0]
        self.pos += 4
        return v

    def u8(self) -> int:
        v = self.buf[self.pos]
        self.pos += 1
        return v

    def string(self) -> str:
        n = self.u32()
        end = self.pos + n
        if end > len(self.buf):
            raise ValueError("string runs past the message")
        raw = bytes(self.buf[self.pos:end])
        self.pos = end
        if self.cdr:
            raw = raw[:-1] if raw.endswith(b"\x00") else raw
        return raw.decode()

    def skip_string(self):
        n = self.u32()
        self.pos += n
        if self.pos > len(self.buf):
            raise ValueError("string runs past the message")

    def stamp(self) -> float:
        if self.cdr:
            self.align(4)
            sec, nsec = _STAMP2.unpack_from(self.buf, self.pos)
            self.pos += 8
        else:
            sec, nsec = _STAMP1.unpack_from(self.buf, self.pos + 4)  # after seq
            self.pos += 12
        self.skip_string()  # frame_id
        return float(sec) + 1e-9 * float(nsec)

    def blob(self) -> memoryview:
        n = self.u32()
        end = self.pos + n
        if end > len(self.buf):
            raise ValueError("array runs past the message")
        view = memoryview(self.buf)[self.pos:end]
        self.pos = end
        return view


class MessageFields:
    """Field readers for one bag's wire format (``cdr``: a ROS 2 bag)."""

    def __init__(self, cdr: bool):
        self.cdr = bool(cdr)

    def _cursor(self, raw) -> _Cursor | None:
        if self.cdr and (len(raw) < 4 or raw[0] != 0 or raw[1] != 1):
            return None  # not little-endian plain CDR
        return _Cursor(raw, self.cdr)

    def image(self, raw, msgtype: str) -> ImageFields | None:
        c = self._cursor(raw)
        if c is None or msgtype not in (COMPRESSED, RAW):
            return None
        try:
            out = ImageFields(stamp_s=c.stamp())
            if msgtype == COMPRESSED:
                out.format = c.string()
            else:
                out.height, out.width = c.u32(), c.u32()
                out.encoding = c.string()
                out.is_bigendian = bool(c.u8())
                out.step = c.u32()
            out.data = c.blob()
        except (ValueError, struct.error, IndexError, UnicodeDecodeError):
            return None
        return out

    def odometry(self, raw):
        c = self._cursor(raw)
        if c is None:
            return None
        try:
            stamp = c.stamp()
            c.skip_string()  # child_frame_id
            c.align(8)
            x, y, _z, qx, qy, qz, qw = _F64x7.unpack_from(c.buf, c.pos)
        except (ValueError, struct.error, IndexError):
            return None
        return stamp, x, y, qx, qy, qz, qw

    def imu(self, raw):
        c = self._cursor(raw)
        if c is None:
            return None
        try:
            stamp = c.stamp()
            c.align(8)
            qx, qy, qz, qw, cov0 = _F64x5.unpack_from(c.buf, c.pos)
        except (ValueError, struct.error, IndexError):
            return None
        return stamp, qx, qy, qz, qw, cov0
