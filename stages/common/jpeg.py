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
levels replicated into three channels) or IMREAD_UNCHANGED (BGR, or one channel (h, w) for a
grey JPEG), its pixels as stored: an EXIF Orientation is not applied (stages.common.dataset's
decode_image_bytes says why). Every kind of file libjpeg
could print a warning about is decoded here, strictly, never by OpenCV (whose libjpeg prints
the first warning only: a damaged scan behind a harmless warning went unsaid and was used):

- CMYK and YCCK files: decoded to CMYK (TurboJPEG turns YCCK into CMYK as libjpeg does for
  OpenCV) and converted to BGR by ``cmyk_to_bgr``, OpenCV's own formula for libjpeg's
  (Adobe's inverted) CMYK: the same pixels, to the bit.
- A header's warning about metadata only (BENIGN): libjpeg then decodes the image as if the
  field held the value it assumes. That field is set so in a copy of the bytes, and the copy
  is decoded strictly, so that damage behind the warning is still found: a JFIF APP0 whose
  major version is not 1 ("Warning: unknown JFIF revision number 3.01"; the version changes
  nothing in decoding), an Adobe APP14 transform code libjpeg does not know ("Unknown Adobe
  color transform code 9": read as YCbCr for 3 components, YCCK for 4, as libjpeg assumes),
  and a sequential file's scan header whose spectral selection or approximation is not 0-63,
  0 ("Invalid SOS parameters for sequential JPEG": old encoders wrote zeros there; libjpeg's
  sequential decoder does not use them).

It declines (None: the caller asks OpenCV, as before) only the files of OPENCV_READS, kinds
TurboJPEG's 8-bit decoder does not read at all (12-bit samples, lossless or hierarchical
processes); OpenCV reads none of them either, and says so without a line on stderr (an
error, not a warning). Every other message of libjpeg-turbo's is damage (DamagedJPEG), and so
is "Unsupported marker type 0x1c": a marker code that exists in no JPEG file, met in the
middle of a scan whose bytes were changed.

A header claims at most 65535 x 65535 px; the reader (stages.common.dataset) refuses more than
its MAX_IMAGE_PIXELS from the header before any decoding. A small file may still claim many
pixels (a 1 kB progressive CMYK file claiming 8191 x 8191 px: libjpeg reserves its
coefficients, 0.9 GB and 3 s, before finding the data short; the file is then refused as
damaged): JPEG sets no
least number of bytes per pixel (an arithmetic-coded flat image takes almost none), so no
bound is put on it beyond the pixel limit.
"""

from __future__ import annotations

import re

import numpy as np

# the exact starts of libjpeg's messages (jerror.h) about a file that is not damaged but that
# TurboJPEG's 8-bit decoder does not read: 12-bit samples, a lossless or hierarchical process
# (SOF3, SOF5-7, SOF11, SOF13-15; its colour conversion then fails). OpenCV reads none of them
# either and fails without a line on stderr: libjpeg's errors reach OpenCV's handler, only its
# warnings are printed. ("Unsupported marker type 0x1c" is not here: damage.)
OPENCV_READS = ("Unsupported JPEG data precision ", "Unsupported JPEG process: ",
                "Unsupported color conversion request")
# libjpeg's warnings about a header's metadata, which it decodes past (module doc)
JFIF_VERSION = "Warning: unknown JFIF revision number "
ADOBE_TRANSFORM = "Unknown Adobe color transform code "
SOS_PARAMETERS = "Invalid SOS parameters for sequential JPEG"
BENIGN = (JFIF_VERSION, ADOBE_TRANSFORM, SOS_PARAMETERS)
APP0, APP14, SOS, EOI = 0xE0, 0xEE, 0xDA, 0xD9
# the frame headers (SOF0-3, 5-7, 9-11, 13-15): not DHT (C4), JPG (C8), DAC (CC)
SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# how long the quoted libjpeg-turbo message may be in fieldloc's line
MESSAGE_CHARS = 70
# the most marker segments read: a camera's JPEG file has a few dozen (APPn metadata, DQT, SOF,
# DHT; an ICC profile in at most 255 APP2 chunks; a progressive file's ten scans and their
# tables). Each costs a step of Python here (libjpeg's are in C): a file of 30 MB can hold
# 7.5 M empty segments, 10 s to walk, and is refused instead
MAX_SEGMENTS = 4096
# fill bytes (any number of 0xFF) and the marker code they end in, found at C speed
_MARKER = re.compile(rb"\xff+([^\xff])")
# the first marker after a scan's coded data, where 0xFF is followed by 0x00 (a stuffed
# byte), a restart marker (0xD0-0xD7) or more fill bytes
_AFTER_SCAN = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")


class DamagedJPEG(ValueError):
    """A JPEG file whose coded image libjpeg-turbo found damaged (the message says how)."""


class UnreadJPEG(ValueError):
    """A JPEG file fieldloc does not read, for the reason its message gives in full."""


def decode_jpeg(data: bytes, *, unchanged: bool = False) -> np.ndarray | None:
    """The image of the JPEG file ``data`` as ``cv2.imdecode`` gives it (module doc), or None
    where only OpenCV might read it (OPENCV_READS: the caller asks OpenCV). Raises DamagedJPEG
    where libjpeg-turbo finds the file damaged, UnreadJPEG for too many segments. Where
    simplejpeg is not installed (a Python it has no wheel for: pyproject.toml), None: OpenCV
    decodes every JPEG file, and a damaged one's libjpeg line is printed as before."""
    try:
        import simplejpeg
    except ImportError:
        return None

    try:
        _, _, colorspace, _ = simplejpeg.decode_jpeg_header(data, strict=False)
    except KeyError:  # a colour space simplejpeg has no name for (a header cut short)
        return None
    except ValueError as e:
        if str(e).startswith(OPENCV_READS):
            return None
        raise DamagedJPEG(str(e)[:MESSAGE_CHARS]) from None
    cmyk = colorspace in ("CMYK", "YCCK")
    space = "CMYK" if cmyk else "GRAY" if unchanged and colorspace == "Gray" else "BGR"
    img = _decode_strictly(simplejpeg, data, space)
    if img is None:
        return None
    if cmyk:
        img = cmyk_to_bgr(img)
    elif space == "GRAY":
        img = img[..., 0]
    return img


def _decode_strictly(simplejpeg, data: bytes, space: str) -> np.ndarray | None:
    """simplejpeg's strict decoding of ``data`` to ``space``; a BENIGN warning's field set to
    what libjpeg assumes (``_without_warning``) in a copy decoded in its stead; None for the
    kinds of OPENCV_READS; DamagedJPEG for every other message."""
    mended: set[str] = set()
    while True:
        try:
            return simplejpeg.decode_jpeg(data, colorspace=space)
        except ValueError as e:
            said = str(e)
        if said.startswith(OPENCV_READS):
            return None
        kind = next((k for k in BENIGN if said.startswith(k)), None)
        if kind is None or kind in mended:
            raise DamagedJPEG(said[:MESSAGE_CHARS])
        mended.add(kind)
        data = _without_warning(data, kind)


def _without_warning(data: bytes, kind: str) -> bytes:
    """A copy of the JPEG file ``data`` whose fields that draw libjpeg's warning ``kind`` (one
    of BENIGN) hold what libjpeg assumes in their stead (module doc): the same image."""
    out = bytearray(data)
    segments = list(marker_segments(data, whole=kind == SOS_PARAMETERS))
    components = next((data[start + 5] for marker, start, end in segments
                       if marker in SOF_MARKERS and end - start >= 6), 0)
    for marker, start, end in segments:
        payload = end - start
        if kind == JFIF_VERSION and marker == APP0 and payload >= 14 \
                and data.startswith(b"JFIF\x00", start):
            out[start + 5] = 1
        elif kind == ADOBE_TRANSFORM and marker == APP14 and payload >= 12 \
                and data.startswith(b"Adobe", start):
            known = {3: (0, 1), 4: (0, 2)}.get(components)
            if known and data[start + 11] not in known:
                out[start + 11] = known[1]  # YCbCr for 3 components, YCCK for 4
        elif kind == SOS_PARAMETERS and marker == SOS and payload >= 4:
            out[end - 3:end] = b"\x00\x3f\x00"  # Ss 0, Se 63, Ah and Al 0
    return bytes(out)


def cmyk_to_bgr(cmyk: np.ndarray) -> np.ndarray:
    """The BGR uint8 image (h, w, 3) of libjpeg's CMYK samples (h, w, 4), by OpenCV's formula
    (imgcodecs' icvCvt_CMYK2BGR_8u_C4C3R: each of C, M, Y is Adobe's inverted ink, scaled by
    K): c' = k - ((255 - c) * k >> 8), and so for m and y; the same pixels as
    ``cv2.imdecode`` (tests/test_jpeg_and_image_headers.py)."""
    out = np.empty(cmyk.shape[:2] + (3,), np.uint8)
    k = cmyk[..., 3].astype(np.uint16)  # (255 - c) * k < 2**16, and k - (... >> 8) >= 0
    for channel in range(3):  # B from Y, G from M, R from C
        out[..., channel] = k - (((255 - cmyk[..., 2 - channel]).astype(np.uint16) * k) >> 8)
    return out


def marker_segments(data: bytes, *, whole: bool = False):
    """(marker code, payload start, payload end) of each marker segment of the JPEG file
    ``data`` from SOI on, up to and with its first scan's SOS (``whole``: every segment up to
    its end marker, EOI; the scans' coded data skipped), markers without a payload left out.
    The walk stops where the segments do not follow each other (a damaged header) or the file
    ends. Fill bytes and coded data are skipped at C speed (``re``); raises UnreadJPEG after
    MAX_SEGMENTS segments."""
    pos, n, count = 2, len(data), 0
    while pos < n:
        found = _MARKER.match(data, pos)
        if found is None:
            return
        marker, pos = found.group(1)[0], found.end()
        if marker == EOI:
            return
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # markers without a length
            continue
        count += 1
        if count > MAX_SEGMENTS:
            raise UnreadJPEG(f"a JPEG file of more than {MAX_SEGMENTS:,} marker segments")
        if pos + 2 > n:
            return
        length = int.from_bytes(data[pos:pos + 2], "big")
        if length < 2:
            return
        yield marker, pos + 2, min(pos + length, n)
        pos += length
        if marker == SOS:
            if not whole:
                return
            after = _AFTER_SCAN.search(data, pos)
            if after is None:
                return
            pos = after.start()


def first_scan(data: bytes) -> int:
    """Where the first scan (SOS marker) of the JPEG ``data`` begins, or -1 where it has none:
    found by walking the marker segments from SOI, so that the bytes FF DA inside a segment
    (an EXIF thumbnail's own scan in APP1, a vendor's metadata) are not taken for it. Where the
    segments do not follow each other (a damaged header), the first FF DA after the last one
    read. Raises UnreadJPEG as ``marker_segments``."""
    last = 2
    for marker, start, end in marker_segments(data):
        if marker == SOS:
            return start - 4
        last = end
    return data.find(b"\xff\xda", last)
