"""sensor_msgs/Image and sensor_msgs/CompressedImage payloads as image files.

Raw images (sensor_msgs/Image) by ``encoding``, as ROS names them (sensor_msgs image_encodings):

- ``mono8``, ``8UC1``: grey; ``mono16``, ``16UC1``: 16-bit grey (written as a 16-bit PNG);
- ``bgr8``, ``rgb8``, ``bgra8``, ``rgba8``, ``8UC3`` (taken as bgr8), ``8UC4`` (bgra8): colour;
- ``yuv422`` / ``uyvy`` (byte order U Y0 V Y1, the ROS meaning of yuv422) and ``yuv422_yuy2``
  / ``yuyv`` (Y0 U Y1 V): colour through OpenCV;
- ``bayer_rggb8``, ``bayer_bggr8``, ``bayer_gbrg8``, ``bayer_grbg8`` and their ``16``
  variants: demosaiced by OpenCV. OpenCV names a pattern by the second row's first two
  pixels, so ROS ``bayer_rggb`` is OpenCV ``BayerBG`` (as cv_bridge maps it).

Rows may be padded (``step`` > width x pixel size); 16-bit data honours ``is_bigendian``.

An image of more than stages.common.dataset.MAX_IMAGE_PIXELS (a raw message's height x width,
a compressed one's header) is refused before it is converted or written: the readers refuse
such a file (a 6.6 MB LZ4 bag held a 40000 x 40000 frame, written as a 1.6-gigapixel PNG).

Compressed images (sensor_msgs/CompressedImage): the container is told by its first bytes (JPEG
or PNG), whatever ``format`` says. When ``format`` names a colour or grey source (``jpeg``,
``png``, ``bgr8; jpeg compressed bgr8``, ``rgb8; jpeg compressed bgr8``, ...) the bytes are
written unchanged: decoding and encoding again would only cost time and, for JPEG, quality. A
compressed Bayer mosaic (``bayer_rggb8; png compressed ...``) is decoded, demosaiced and
written as PNG. Depth images (``compressedDepth``) are refused.
"""

from __future__ import annotations

import numpy as np

from ..common.dataset import decode_image_bytes, too_many_pixels
from ..common.errors import FieldlocError
from ..common.image_header import image_size

JPEG_MAGIC = b"\xff\xd8"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class ImageMessageError(FieldlocError):
    """An image message that cannot be turned into an image file."""


def _cv2():
    import cv2

    return cv2


def _bayer_codes():
    cv2 = _cv2()
    return {
        "rggb": cv2.COLOR_BayerBG2BGR,
        "bggr": cv2.COLOR_BayerRG2BGR,
        "gbrg": cv2.COLOR_BayerGR2BGR,
        "grbg": cv2.COLOR_BayerGB2BGR,
    }


# encoding -> (channels, bytes per channel)
_LAYOUT = {
    "mono8": (1, 1), "8uc1": (1, 1), "mono16": (1, 2), "16uc1": (1, 2),
    "bgr8": (3, 1), "rgb8": (3, 1), "8uc3": (3, 1), "bgra8": (4, 1), "rgba8": (4, 1),
    "8uc4": (4, 1), "yuv422": (2, 1), "uyvy": (2, 1), "yuv422_yuy2": (2, 1), "yuyv": (2, 1),
}
for _p in ("rggb", "bggr", "gbrg", "grbg"):
    _LAYOUT[f"bayer_{_p}8"] = (1, 1)
    _LAYOUT[f"bayer_{_p}16"] = (1, 2)

ENCODINGS = tuple(sorted(_LAYOUT))


def raw_pixels(height: int, width: int, encoding: str, step: int, data, is_bigendian=False):
    """The pixel array (h, w[, c]) of a sensor_msgs/Image payload, rows unpadded, 16-bit data in
    native byte order. ``data``: bytes or a uint8 array."""
    enc = encoding.lower()
    if enc not in _LAYOUT:
        raise ImageMessageError(
            f"image encoding '{encoding}' is not supported (supported: {', '.join(ENCODINGS)})")
    channels, size = _LAYOUT[enc]
    h, w, step = int(height), int(width), int(step)
    if h > 0 and w > 0 and (why := too_many_pixels(w, h)):
        raise ImageMessageError(f"image of {why}")
    row = w * channels * size
    buf = (data.reshape(-1).view(np.uint8) if isinstance(data, np.ndarray)
           else np.frombuffer(data, dtype=np.uint8))
    if h <= 0 or w <= 0 or step < row or buf.size < h * step - (step - row):
        raise ImageMessageError(
            f"image message of {w} x {h} px, {encoding}, step {step}: {buf.size} bytes of data"
            " do not fill it")
    if buf.size < h * step:  # the last row's padding may be missing
        buf = np.concatenate([buf, np.zeros(h * step - buf.size, np.uint8)])
    rows = buf[: h * step].reshape(h, step)[:, :row]
    if size == 2:
        px = np.ascontiguousarray(rows).view(">u2" if is_bigendian else "<u2").astype(np.uint16)
    else:
        px = rows
    shape = (h, w) if channels == 1 else (h, w, channels)
    return px.reshape(shape)


def raw_to_image(height, width, encoding, step, data, is_bigendian=False) -> np.ndarray:
    """A sensor_msgs/Image payload as an OpenCV image: BGR uint8 for colour encodings, grey
    (uint8 or uint16) for mono ones."""
    cv2 = _cv2()
    enc = encoding.lower()
    px = raw_pixels(height, width, encoding, step, data, is_bigendian)
    if enc in ("mono8", "8uc1", "mono16", "16uc1", "bgr8", "8uc3"):
        return px
    if enc == "rgb8":
        return cv2.cvtColor(px, cv2.COLOR_RGB2BGR)
    if enc in ("bgra8", "8uc4"):
        return cv2.cvtColor(px, cv2.COLOR_BGRA2BGR)
    if enc == "rgba8":
        return cv2.cvtColor(px, cv2.COLOR_RGBA2BGR)
    if enc in ("yuv422", "uyvy"):
        return cv2.cvtColor(np.ascontiguousarray(px), cv2.COLOR_YUV2BGR_UYVY)
    if enc in ("yuv422_yuy2", "yuyv"):
        return cv2.cvtColor(np.ascontiguousarray(px), cv2.COLOR_YUV2BGR_YUY2)
    pattern = enc[len("bayer_"):len("bayer_") + 4]
    return cv2.cvtColor(np.ascontiguousarray(px), _bayer_codes()[pattern])


def compressed_container(data) -> str:
    """'jpeg' or 'png' from a compressed payload's first bytes."""
    head = bytes(data[:8])
    if head.startswith(JPEG_MAGIC):
        return "jpeg"
    if head.startswith(PNG_MAGIC):
        return "png"
    raise ImageMessageError("compressed image is neither JPEG nor PNG (its first bytes:"
                            f" {head.hex()})")


def compressed_source_encoding(fmt: str) -> str:
    """The source encoding a CompressedImage ``format`` names ('' when it names none):
    'bgr8; jpeg compressed bgr8' -> 'bgr8', 'jpeg' -> ''."""
    fmt = (fmt or "").strip().lower()
    if "compresseddepth" in fmt:
        raise ImageMessageError(f"compressed depth images are not camera frames (format '{fmt}')")
    if ";" in fmt:
        return fmt.split(";", 1)[0].strip()
    return "" if fmt in ("jpeg", "jpg", "png", "") else fmt


def compressed_to_file(fmt: str, data) -> tuple[str, bytes | np.ndarray]:
    """(suffix, content) for a CompressedImage: the bytes unchanged with '.jpg' or '.png', or
    for a Bayer mosaic ('.png', the demosaiced BGR image as an array to encode)."""
    container = compressed_container(data)
    source = compressed_source_encoding(fmt)
    size = image_size(bytes(data))
    if size is not None and (why := too_many_pixels(*size)):
        raise ImageMessageError(f"compressed image of {why}")
    if source.startswith("bayer_"):
        cv2 = _cv2()
        pattern = source[len("bayer_"):len("bayer_") + 4]
        if pattern not in _bayer_codes():
            raise ImageMessageError(f"unknown Bayer pattern in compressed format '{fmt}'")
        mosaic, why = decode_image_bytes(bytes(data), unchanged=True)
        if mosaic is None:
            raise ImageMessageError(f"compressed Bayer image ('{fmt}') cannot be decoded"
                                    + (f": {why}" if why else ""))
        if mosaic.ndim != 2:
            raise ImageMessageError(f"compressed Bayer image ('{fmt}') is not a one-channel"
                                    " mosaic")
        return ".png", cv2.cvtColor(mosaic, _bayer_codes()[pattern])
    if source and source not in _LAYOUT:
        raise ImageMessageError(f"compressed image format '{fmt}' is not supported")
    return (".jpg" if container == "jpeg" else ".png"), bytes(data)
