"""The size an image file's header claims, read from its first bytes before it is decoded.

A header of a few dozen bytes can claim an image of billions of pixels (a PNG's 4 G x 4 G, a
WebP's 16383 x 16383, a TIFF of a few hundred kilobytes claiming 20000 x 20000 px): the
decoder reserves the memory for it before finding the data short. ``image_size`` reads the
claim of every kind of frame fieldloc reads (stages.common.dataset.IMAGE_SUFFIXES), so that
the reader refuses it in a line that says how large, before decoding.
"""

from __future__ import annotations

import struct

TIFF_WIDTH_TAG, TIFF_HEIGHT_TAG = 256, 257


# the first bytes of every PNG file (PNG specification, 5.2)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) that the header of the image file ``data`` claims (PNG, JPEG, BMP,
    TIFF or WebP), or None where it is none of these or its header cannot be read (the
    decoder then says what is wrong)."""
    if data.startswith(b"\xff\xd8"):
        return jpeg_size(data)
    if data.startswith(b"BM") and len(data) >= 26:
        if struct.unpack_from("<I", data, 14)[0] == 12:  # OS/2's BITMAPCOREHEADER
            return struct.unpack_from("<HH", data, 18)
        width, height = struct.unpack_from("<ii", data, 18)
        return abs(width), abs(height)  # a negative height: rows stored top-down
    if data[:4] in (b"II*\0", b"MM\0*"):
        tags = tiff_ifd0(data, (TIFF_WIDTH_TAG, TIFF_HEIGHT_TAG))
        if len(tags) == 2:
            return tags[TIFF_WIDTH_TAG], tags[TIFF_HEIGHT_TAG]
        return None
    if data[:4] in (b"II+\0", b"MM\0+"):
        return _bigtiff_size(data)
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP" and len(data) >= 30:
        return _webp_size(data)
    return png_size(data)


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) that the frame header of the JPEG file ``data`` claims, or None where
    libjpeg-turbo cannot read its header: read before decoding, so that a header claiming a
    huge image (up to 65535 x 65535 px) is refused before memory is reserved for it."""
    import simplejpeg

    try:
        height, width, _, _ = simplejpeg.decode_jpeg_header(data, strict=False)
    except (ValueError, KeyError):  # KeyError: a colour space simplejpeg has no name for
        return None
    return width, height


def _webp_size(data: bytes) -> tuple[int, int] | None:
    """The canvas of a WebP file (Google's container specification): the extended header's
    (VP8X), or that of its one lossless (VP8L) or lossy (VP8) bitstream."""
    kind = data[12:16]
    if kind == b"VP8X":
        return (1 + int.from_bytes(data[24:27], "little"),
                1 + int.from_bytes(data[27:30], "little"))
    if kind == b"VP8L" and data[20] == 0x2F:
        bits = int.from_bytes(data[21:25], "little")
        return 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
    if kind == b"VP8 " and data[23:26] == b"\x9d\x01\x2a":
        width, height = struct.unpack_from("<HH", data, 26)
        return width & 0x3FFF, height & 0x3FFF
    return None


def _bigtiff_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) of the first image of a BigTIFF file (Adobe's TIFF with 64-bit offsets:
    an 8-byte IFD0 offset at byte 8, entries of 20 bytes: tag, type, an 8-byte count and
    value), or None where its first directory does not say (trial V2-5: a 79 kB BigTIFF
    claiming 9000 x 9000 px was refused without its reason)."""
    order = "<" if data[:2] == b"II" else ">"
    if len(data) < 16:
        return None
    ifd = struct.unpack_from(order + "Q", data, 8)[0]
    if ifd + 8 > len(data):
        return None
    found = {}
    for i in range(min(struct.unpack_from(order + "Q", data, ifd)[0], 4096)):
        entry = ifd + 8 + 20 * i
        if entry + 20 > len(data):
            break
        tag, kind, count = struct.unpack_from(order + "HHQ", data, entry)
        fmt = {3: "H", 4: "I", 16: "Q"}.get(kind)  # SHORT, LONG, LONG8
        if tag in (TIFF_WIDTH_TAG, TIFF_HEIGHT_TAG) and count == 1 and fmt:
            found[tag] = struct.unpack_from(order + fmt, data, entry + 12)[0]
    if len(found) != 2:
        return None
    return found[TIFF_WIDTH_TAG], found[TIFF_HEIGHT_TAG]


def _ifd0_entries(tiff: bytes):
    """(byte order, tag, type, count, offset of the entry) of each entry of the first image
    file directory (IFD0) of the TIFF structure ``tiff``, in their order; none where the
    structure is not TIFF, fewer where it is cut short."""
    order = {b"II": "<", b"MM": ">"}.get(tiff[:2])
    if order is None or len(tiff) < 8:
        return
    ifd = struct.unpack_from(order + "I", tiff, 4)[0]
    if ifd + 2 > len(tiff):
        return
    for i in range(struct.unpack_from(order + "H", tiff, ifd)[0]):
        entry = ifd + 2 + 12 * i
        if entry + 12 > len(tiff):
            return
        tag, kind, count = struct.unpack_from(order + "HHI", tiff, entry)
        yield order, tag, kind, count, entry


def tiff_ifd0(tiff: bytes, tags: tuple[int, ...]) -> dict[int, int]:
    """The values of those of ``tags`` that the first image file directory (IFD0) of the TIFF
    structure ``tiff`` holds as one SHORT or LONG (a TIFF file's, or EXIF's inside a JPEG);
    fewer where the structure is cut short or not TIFF."""
    found = {}
    for order, tag, kind, count, entry in _ifd0_entries(tiff):
        if tag in tags and count == 1 and kind in (3, 4):  # 3: SHORT, 4: LONG
            found[tag] = struct.unpack_from(order + ("H" if kind == 3 else "I"), tiff,
                                            entry + 8)[0]
    return found


def png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) that the header of the PNG file ``data`` claims, or None if ``data`` does
    not start as a PNG file does (signature, then the IHDR chunk): read before decoding, so
    that a header claiming a huge image is refused before any memory is reserved for it."""
    if not data.startswith(PNG_SIGNATURE) or data[12:16] != b"IHDR" or len(data) < 24:
        return None
    return struct.unpack_from(">II", data, 16)
