"""Decoding the PNG frames that fieldloc renders and most teams log, in about half of
OpenCV's time: 8-bit grey or RGB, not interlaced.

Reading a frame is the largest single cost of taking images to poses: OpenCV (libpng and zlib)
spends about 4 ms on a 480 x 480 omni frame and 7 ms on a 752 x 480 perspective one, more than
extracting the features from it. Nearly all of it is inflating the compressed rows with zlib;
ISA-L's inflate (Intel's Intelligent Storage Acceleration Library, through the ``isal``
package; it picks SSE, AVX2 or AVX-512 code for the CPU it runs on) does the same about three
times faster. The rest of decoding is undoing the PNG row filters (PNG specification, ISO/IEC
15948:2004, section 9), a short compiled loop here.

``decode_png`` reads the common case and declines everything else (returns None): palette
images, 16-bit samples, alpha channels, interlacing, and any file that is damaged in a way
the PNG specification makes an error (a critical chunk's CRC, the zlib stream, the length of
the rows, an unknown filter type). The caller then asks OpenCV, so those files decode, or fail,
exactly as before. What it returns is what ``cv2.imread(path, cv2.IMREAD_COLOR)`` returns for
the same file (BGR, grey replicated into the three channels), which the tests hold to the bit:
PNG is lossless, so there is one right answer.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from isal import isal_zlib

from .errors import FieldlocError
from .jit import njit

SIGNATURE = b"\x89PNG\r\n\x1a\n"
# colour type -> samples per pixel, for the types decoded here (0: grey, 2: RGB)
CHANNELS = {0: 1, 2: 3}
# rows of more than this many bytes in all are left to OpenCV, so that a header claiming a
# huge image cannot make this decoder reserve memory for it (a 16k x 16k RGB frame is 768 MB)
MAX_RAW_BYTES = 1 << 28


def write_png(path: str | Path, image: np.ndarray, params: Sequence[int] = ()) -> None:
    """Write ``image`` as the PNG file ``path``: OpenCV's encoder (``params``: its
    IMWRITE_PNG_* flags), then a plain write, so that a full disk or a refused write raises
    the OSError that says which (``cv2.imwrite`` only returns False, and the caller could only
    say that it "could not write")."""
    import cv2

    ok, buf = cv2.imencode(".png", image, list(params))
    if not ok:
        raise FieldlocError(f"could not encode {Path(path).name} as PNG")
    with open(path, "wb") as f:
        f.write(buf)


def decode_png(data: bytes) -> np.ndarray | None:
    """The BGR uint8 image (h, w, 3) of the PNG file ``data``, as OpenCV's IMREAD_COLOR reads
    it, or None if it is not an 8-bit grey or RGB, non-interlaced PNG that decodes without
    error (module doc: the caller then reads it with OpenCV)."""
    if not data.startswith(SIGNATURE):
        return None
    chunks = _chunks(data)
    if chunks is None:
        return None
    header, idat = chunks
    width, height, depth, colour, compression, filtering, interlace = header
    channels = CHANNELS.get(colour)
    if (channels is None or depth != 8 or compression or filtering or interlace
            or width == 0 or height == 0):
        return None
    row_bytes = width * channels + 1  # each row starts with its filter type
    expected = height * row_bytes
    if expected > MAX_RAW_BYTES:
        return None
    try:
        raw = isal_zlib.decompress(idat, 15, expected)
    except Exception:  # isal's own error class: a damaged stream, left to OpenCV to report
        return None
    if len(raw) != expected:
        return None
    out = np.empty((height, width, 3), np.uint8)
    if not unfilter_rows(np.frombuffer(raw, np.uint8), channels, out):
        return None
    return out


def png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) that the header of the PNG file ``data`` claims, or None if ``data`` does
    not start as a PNG file does (signature, then the IHDR chunk): read before decoding, so
    that a header claiming a huge image is refused before any memory is reserved for it."""
    if not data.startswith(SIGNATURE) or data[12:16] != b"IHDR" or len(data) < 24:
        return None
    return struct.unpack_from(">II", data, 16)


def png_damaged(data: bytes) -> bool:
    """Whether ``data`` starts as a PNG file and breaks a rule that makes libpng refuse it
    (cut short, a chunk running past the end, no IEND, a critical chunk's CRC: ``_chunks``).
    libpng says so on stderr itself ("libpng error: PNG input buffer is incomplete"), a line
    beside fieldloc's own: such a file is not given to OpenCV."""
    return data.startswith(SIGNATURE) and _chunks(data) is None


def _chunks(data: bytes):
    """(IHDR fields, the concatenated IDAT data) of a PNG file, or None where it breaks a rule
    that makes libpng refuse the file: a critical chunk whose CRC is wrong, an unknown
    critical chunk, IDAT chunks that are not consecutive, a missing IHDR, IDAT or IEND, or a
    chunk running past the end. Ancillary chunks (text, gamma, physical size, ...) are skipped,
    as OpenCV's IMREAD_COLOR applies none of them."""
    view = memoryview(data)  # slices without copies
    pos, n = len(SIGNATURE), len(data)
    header, idat, idat_done, ended = None, [], False, False
    while pos + 8 <= n:
        length, kind = struct.unpack_from(">I4s", data, pos)
        end = pos + 12 + length
        if end > n:
            return None
        critical = not kind[0] & 0x20  # bit 5 of the first letter: 0 for critical chunks
        if critical and isal_zlib.crc32(view[pos + 4:pos + 8 + length]) != \
                struct.unpack_from(">I", data, end - 4)[0]:
            return None
        body = view[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            if header is not None or length != 13:
                return None
            header = struct.unpack(">IIBBBBB", body.tobytes())
        elif kind == b"IDAT":
            if header is None or idat_done:
                return None
            idat.append(body)
        elif kind == b"IEND":
            ended = True
            break
        elif critical and kind != b"PLTE":  # PLTE in an RGB file is a suggestion, unused
            return None
        if idat and kind != b"IDAT":
            idat_done = True
        pos = end
    if header is None or not idat or not ended:
        return None
    return header, idat[0] if len(idat) == 1 else b"".join(idat)


@njit(cache=True, nogil=True)
def unfilter_rows(raw, channels, out):
    """Undo the PNG row filters of the inflated rows ``raw`` (each a filter-type byte, then
    width x ``channels`` samples) into ``out`` (h, w, 3) as BGR (grey into all three). The
    filters (PNG specification, section 9.2) add to each byte, modulo 256: nothing (0), the
    byte one pixel to the left (1, Sub), the byte above (2, Up), the floor of their mean (3,
    Average), or whichever of left, above and upper-left is nearest to left + above -
    upper-left (4, Paeth; ties to left, then above). Bytes left of the first pixel and above
    the first row are 0. Returns False at an unknown filter type."""
    h, w = out.shape[0], out.shape[1]
    stride = w * channels
    prev = np.zeros(stride, np.uint8)  # the row above, unfiltered, in the file's order
    cur = np.zeros(stride, np.uint8)
    above_in_out = False  # the row above was written to ``out`` only (not to ``prev``)
    for y in range(h):
        row = raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)]
        kind = raw[y * (stride + 1)]
        if above_in_out and kind >= 2:  # this filter reads the row above: back to file order
            for j in range(w):
                prev[3 * j], prev[3 * j + 1], prev[3 * j + 2] = \
                    out[y - 1, j, 2], out[y - 1, j, 1], out[y - 1, j, 0]
        above_in_out = False
        if kind == 0:
            cur[:] = row
        elif kind == 1 and channels == 3:
            # the renders' filter: the left sums kept in registers, the row written to ``out``
            # alone (the next row's filter may read it back from there)
            r = g = b = np.uint8(0)
            for j in range(w):
                r += row[3 * j]  # uint8 arithmetic wraps modulo 256
                g += row[3 * j + 1]
                b += row[3 * j + 2]
                out[y, j, 0], out[y, j, 1], out[y, j, 2] = b, g, r
            above_in_out = True
            continue
        elif kind == 1:
            cur[:channels] = row[:channels]
            for i in range(channels, stride):
                cur[i] = row[i] + cur[i - channels]
        elif kind == 2:
            for i in range(stride):
                cur[i] = row[i] + prev[i]
        elif kind == 3:
            for i in range(channels):
                cur[i] = row[i] + (prev[i] >> 1)
            for i in range(channels, stride):
                cur[i] = row[i] + np.uint8((np.int32(cur[i - channels]) + prev[i]) >> 1)
        elif kind == 4 and channels == 3:  # left and upper-left kept in registers
            l0 = l1 = l2 = c0 = c1 = c2 = np.int32(0)
            for j in range(w):
                k = 3 * j
                a0, a1, a2 = np.int32(prev[k]), np.int32(prev[k + 1]), np.int32(prev[k + 2])
                l0 = np.int32(np.uint8(row[k] + _paeth(l0, a0, c0)))
                l1 = np.int32(np.uint8(row[k + 1] + _paeth(l1, a1, c1)))
                l2 = np.int32(np.uint8(row[k + 2] + _paeth(l2, a2, c2)))
                cur[k], cur[k + 1], cur[k + 2] = l0, l1, l2
                c0, c1, c2 = a0, a1, a2
        elif kind == 4:
            for i in range(channels):
                cur[i] = row[i] + prev[i]  # left and corner are 0: Paeth picks above
            for i in range(channels, stride):
                cur[i] = row[i] + _paeth(np.int32(cur[i - channels]), np.int32(prev[i]),
                                         np.int32(prev[i - channels]))
        else:
            return False
        if channels == 3:
            for j in range(w):
                out[y, j, 0] = cur[3 * j + 2]
                out[y, j, 1] = cur[3 * j + 1]
                out[y, j, 2] = cur[3 * j]
        else:
            for j in range(w):
                out[y, j, 0] = cur[j]
                out[y, j, 1] = cur[j]
                out[y, j, 2] = cur[j]
        prev, cur = cur, prev
    return True


@njit(cache=True, nogil=True, inline="always")
def _paeth(left, above, corner):
    """The Paeth predictor of one byte (PNG specification, section 9.4) as uint8: of the
    bytes left, above and upper-left, the one nearest to left + above - upper-left."""
    pa, pb, pc = abs(above - corner), abs(left - corner), abs(left + above - 2 * corner)
    near = above if pb <= pc else corner
    return np.uint8(left if (pa <= pb) & (pa <= pc) else near)


def with_mark(data: bytes) -> bytes:
    """The PNG ``data`` (as OpenCV encodes it) with a text chunk ``Software: WRITTEN_MARK``
    before its end chunk: how --overwrite tells a picture fieldloc drew (artifacts'
    ``fieldloc_wrote``) from a user's of the same name, as matplotlib's pictures carry it."""
    import zlib

    from .artifacts import WRITTEN_MARK

    body = b"tEXt" + b"Software\0" + WRITTEN_MARK.encode("latin-1")
    chunk = (len(body) - 4).to_bytes(4, "big") + body + zlib.crc32(body).to_bytes(4, "big")
    end = data.rfind(b"IEND") - 4  # the end chunk: length, type, crc
    return data[:end] + chunk + data[end:]
