"""Decoding JPEG frames without a line of libjpeg's on stderr.

OpenCV's libjpeg prints its warnings on the process's stderr itself ("Corrupt JPEG data: 2974
extraneous bytes before marker 0xd9" for a frame whose scan data is damaged), a line beside
fieldloc's own, and decodes such a frame to garbage pixels without a sign to its caller.
simplejpeg decodes with libjpeg-turbo's TurboJPEG API, which returns the warning instead of
printing it (``strict``: as a ValueError): a damaged frame is then unreadable, in fieldloc's
one line. It gives the pixels ``cv2.imdecode`` gives (both are libjpeg-turbo with its
default, accurate DCT and upsampling; tests/test_jpeg_and_image_headers.py) in no more time
(0.8-1.3 ms for a 480 x 480 or 752 x 480 frame).

``decode_jpeg`` returns what ``cv2.imdecode`` returns with IMREAD_COLOR (BGR, a grey JPEG's
levels replicated into three channels, EXIF orientation applied) or IMREAD_UNCHANGED (BGR,
or one channel (h, w) for a grey JPEG; orientation not applied). It declines (None: the
caller asks OpenCV, as before) CMYK and YCCK files (OpenCV converts them to BGR its own
way), and the files of OPENCV_READS: 12-bit samples, which TurboJPEG's 8-bit decoder does
not read (nor does OpenCV), and a header's warning about its metadata only.
"""

from __future__ import annotations

import numpy as np

from .image_header import tiff_ifd0

# the starts of libjpeg's messages (jerror.h) about a file that is not damaged but that
# simplejpeg does not decode: a kind TurboJPEG's 8-bit decoder does not read ("Unsupported JPEG
# data precision 12"; OpenCV reads none either), or a warning about a header's metadata
# ("Warning: unknown JFIF revision number 3.01"; simplejpeg refuses it even when not strict)
# that OpenCV reads, printing the warning as it did before simplejpeg. Every other message
# says that the file is damaged: a warning about the coded data ("Corrupt JPEG data: ...",
# where libjpeg goes on with made-up pixels), or an error ("Bogus Huffman table definition",
# where OpenCV's libjpeg prints the warnings it met before it)
OPENCV_READS = ("Unsupported", "Warning:", "Unknown Adobe color transform",
                "Invalid SOS parameters for sequential JPEG")
APP1 = 0xE1
EXIF_ORIENTATION_TAG = 0x0112
# how long the quoted libjpeg-turbo message may be in fieldloc's line
MESSAGE_CHARS = 70


class DamagedJPEG(ValueError):
    """A JPEG file whose coded image libjpeg-turbo found damaged (the message says how)."""


def decode_jpeg(data: bytes, *, unchanged: bool = False) -> np.ndarray | None:
    """The image of the JPEG file ``data`` as ``cv2.imdecode`` gives it (module doc), or None
    where simplejpeg does not read it as OpenCV does (CMYK, YCCK, OPENCV_READS: the caller
    asks OpenCV). Raises DamagedJPEG where libjpeg-turbo finds the file damaged. Where
    simplejpeg is not installed (a Python it has no wheel for: pyproject.toml), None: OpenCV
    decodes every JPEG file, and a damaged one's libjpeg line is printed as before."""
    try:
        import simplejpeg
    except ImportError:
        return None

    try:
        _, _, colorspace, _ = simplejpeg.decode_jpeg_header(data)
        if colorspace in ("CMYK", "YCCK"):
            return None
        space = "GRAY" if unchanged and colorspace == "Gray" else "BGR"
        img = simplejpeg.decode_jpeg(data, colorspace=space)
    except KeyError:  # a colour space simplejpeg has no name for (a header cut short)
        return None
    except ValueError as e:
        if str(e).startswith(OPENCV_READS):
            return None
        raise DamagedJPEG(str(e)[:MESSAGE_CHARS]) from None
    if space == "GRAY":
        img = img[..., 0]
    return img if unchanged else orient(img, exif_orientation(data))


def exif_orientation(data: bytes) -> int:
    """The EXIF Orientation (1-8) of the JPEG file ``data``, 1 where it gives none: read as
    OpenCV reads it (its JPEG decoder's ``ExifReader``), from the first APP1 segment before
    the first scan, its TIFF header after the 6 bytes of "Exif\\0\\0", tag 0x0112 of IFD0."""
    pos = 2
    while pos + 4 <= len(data) and data[pos] == 0xFF:
        marker = data[pos + 1]
        if marker == 0xFF:  # a fill byte before a marker
            pos += 1
            continue
        if marker == 0xDA or marker == 0xD9:  # the first scan, or the end: no APP1 before it
            return 1
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # markers without a length
            pos += 2
            continue
        length = int.from_bytes(data[pos + 2:pos + 4], "big")
        if marker == APP1:
            tiff = data[pos + 10:pos + 2 + length]
            value = tiff_ifd0(tiff, (EXIF_ORIENTATION_TAG,)).get(EXIF_ORIENTATION_TAG, 1)
            return value if 1 <= value <= 8 else 1
        pos += 2 + length
    return 1


def orient(img: np.ndarray, orientation: int) -> np.ndarray:
    """``img`` turned upright for its EXIF ``orientation`` as OpenCV's
    ``ApplyExifOrientation`` turns it (2: mirrored, 3: upside down, 6: a quarter turn
    clockwise to be upright, ...), a C-contiguous array."""
    if orientation == 1:
        return img
    if orientation >= 5:  # the rows are the picture's columns
        img = img.swapaxes(0, 1)
    flips = {2: (1,), 3: (0, 1), 4: (0,), 5: (), 6: (1,), 7: (0, 1), 8: (0,)}[orientation]
    for axis in flips:
        img = np.flip(img, axis)
    return np.ascontiguousarray(img)
