"""Decoding the PNG frames that fieldloc renders and most teams log, in about half of
OpenCV's time: 8-bit grey or RGB, not interlaced.

Reading a frame is the largest single cost of taking images to poses: OpenCV (libpng and zlib)
spends about 4 ms on a 480 x 480 omni frame and 7 ms on a 752 x 480 perspective one, more than
extracting the features from it. Nearly all of it is inflating the compressed rows with zlib;
ISA-L's inflate (Intel's Intelligent Storage Acceleration Library, through the ``isal``
package; it picks SSE, AVX2 or AVX-512 code for the CPU it runs on) does the same about three
times faster. The rest of decoding is undoing the PNG row filters (PNG specification, ISO/IEC
15948:2004, section 9), a short compiled loop here.

``decode_png`` reads the common case, and (``_decode_other``) 8-bit palette images, alpha
channels and 16-bit samples; it declines everything else (returns None): interlacing, palette
or grey samples of fewer than 8 bits, and any file that is damaged in a way the PNG
specification makes an error (a critical chunk's CRC, the zlib stream, the length of the rows,
an unknown filter type). The caller then asks OpenCV, through ``png_for_opencv``: a damaged
file is not given to libpng, which would print lines of its own on stderr about it.
What it returns is what ``cv2.imread(path, cv2.IMREAD_COLOR)`` returns for
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
from .image_header import PNG_SIGNATURE as SIGNATURE
from .jit import njit

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
    it, or None if it is not a non-interlaced PNG of 8-bit grey or RGB (or of the kinds
    ``_decode_other`` reads) that decodes without error (module doc: the caller then reads it
    with OpenCV)."""
    if not data.startswith(SIGNATURE):
        return None
    chunks = _chunks(data, keep=(b"PLTE",))
    if chunks is None:
        return None
    header, idat, extra = chunks
    width, height, depth, colour, compression, filtering, interlace = header
    if compression or filtering or interlace or width == 0 or height == 0:
        return None
    channels = CHANNELS.get(colour)
    if channels is None or depth != 8:
        return _decode_other(header, idat, extra.get(b"PLTE"))
    row_bytes = width * channels + 1  # each row starts with its filter type
    expected = height * row_bytes
    if expected > MAX_RAW_BYTES:
        return None
    raw = _inflated(idat, expected)
    if raw is None:  # a damaged stream, left to OpenCV (png_for_opencv) to report
        return None
    out = np.empty((height, width, 3), np.uint8)
    if not unfilter_rows(np.frombuffer(raw, np.uint8), channels, out):
        return None
    return out


def _inflated(idat, expected: int) -> bytes | None:
    """The rows ``expected`` bytes long that the zlib stream ``idat`` inflates to, or None
    where it is damaged or inflates to any other length. Inflated to at most one byte more
    than ``expected``: a stream of a few megabytes can inflate to gigabytes (a "zlib bomb"),
    which the header's row count says nothing of."""
    try:
        raw = isal_zlib.decompressobj().decompress(idat, expected + 1)
    except Exception:  # isal's own error class: a damaged stream
        return None
    return raw if len(raw) == expected else None


def png_damaged(data: bytes) -> bool:
    """Whether ``data`` starts as a PNG file that ``png_for_opencv`` does not pass on: one
    libpng would refuse or complain of on stderr itself ("libpng error: PNG input buffer is
    incomplete", "libpng error: bad adaptive filter value"), a line beside fieldloc's own."""
    return data.startswith(SIGNATURE) and png_for_opencv(data) is None


# colour type -> samples per pixel and the bit depths the PNG specification allows for it
# (table 11.1): grey, RGB, palette, grey + alpha, RGB + alpha
SAMPLES = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}
# Adam7 interlacing (section 8.2): each pass's first column and row, and its steps
ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
         (0, 1, 1, 2))
# the largest valid filter type (0 None .. 4 Paeth; section 9.2)
MAX_FILTER = 4


def png_for_opencv(data: bytes) -> bytes | None:
    """The PNG file ``data`` as given to OpenCV (libpng): its critical chunks (IHDR, PLTE of a
    palette image, IDAT, IEND) and a sound tRNS (IMREAD_UNCHANGED reads it as alpha), or None
    where libpng would refuse the file or print a line of its own on stderr about it. Checked
    here, as libpng checks while decoding: the chunks (``_chunks``: cut short, a critical
    chunk's CRC, ...), the header's values, the palette's length, the zlib stream (complete,
    its checksum right, nothing after it, exactly the rows the header gives) and every row's
    filter type ("libpng error: bad adaptive filter value": IDAT data damaged under a right
    CRC). Ancillary chunks are left out, not checked: libpng warns of a bad one ("libpng
    warning: tEXt: CRC error", "iCCP: too short") and then decodes the same pixels, as
    IMREAD_COLOR applies none of them. Costs one inflate by ISA-L: a third of libpng's."""
    chunks = _chunks(data, keep=(b"PLTE", b"tRNS"))
    if chunks is None:
        return None
    header, idat, extra = chunks
    width, height, depth, colour, compression, filtering, interlace = header
    if (colour not in SAMPLES or depth not in DEPTHS[colour] or compression or filtering
            or interlace not in (0, 1) or not 0 < width < 1 << 31 or not 0 < height < 1 << 31):
        return None
    plte = extra.get(b"PLTE")
    if colour == 3 and (plte is None or not 0 < len(plte) <= 3 * 256 or len(plte) % 3):
        return None
    trns = extra.get(b"tRNS")
    if trns is not None and not (0 < len(trns) <= len(plte) // 3 if colour == 3 else
                                 len(trns) == {0: 2, 2: 6}.get(colour, -1)):
        trns = None  # libpng would warn of it and ignore it
    bits = depth * SAMPLES[colour]
    passes = [(width, height)] if not interlace else [
        ((width - x0 + dx - 1) // dx, (height - y0 + dy - 1) // dy) for x0, y0, dx, dy in ADAM7]
    starts, pos = [], 0  # where each row (its filter type byte) starts in the inflated rows
    for w, h in passes:
        if w and h:
            row = (w * bits + 7) // 8 + 1
            starts.append(pos + row * np.arange(h, dtype=np.int64))
            pos += row * h
    if pos > MAX_IMAGE_BYTES:
        return None
    try:
        inflate = isal_zlib.decompressobj()
        raw = inflate.decompress(idat, pos + 1)
    except Exception:  # isal's own error class: a damaged stream
        return None
    if len(raw) != pos or not inflate.eof or inflate.unused_data or inflate.unconsumed_tail:
        return None
    if (np.frombuffer(raw, np.uint8)[np.concatenate(starts)] > MAX_FILTER).any():
        return None
    out = [SIGNATURE, _chunk(b"IHDR", struct.pack(">IIBBBBB", *header))]
    if colour == 3:
        out.append(_chunk(b"PLTE", plte))
    if trns is not None:
        out.append(_chunk(b"tRNS", trns))
    out += [_chunk(b"IDAT", idat), _chunk(b"IEND", b"")]
    return b"".join(out)


# the most bytes of inflated rows png_for_opencv checks: a 64 M pixel (dataset's
# MAX_IMAGE_PIXELS) RGBA image of 16-bit samples and its filter bytes
MAX_IMAGE_BYTES = (1 << 26) * 8 + (1 << 26)


def _chunk(kind: bytes, body) -> bytes:
    """One PNG chunk: length, type, ``body``, CRC of type and body."""
    body = bytes(body)
    return (struct.pack(">I", len(body)) + kind + body
            + struct.pack(">I", isal_zlib.crc32(kind + body)))


def _chunks(data: bytes, keep: tuple[bytes, ...] = ()):
    """(IHDR fields, the concatenated IDAT data, {kind: body} of the chunks of ``keep`` the
    file holds once each, those ancillary only with a right CRC) of a PNG file, or None where
    it breaks a rule that makes libpng refuse the file: a critical chunk whose CRC is wrong,
    an unknown critical chunk, IDAT chunks that are not consecutive, a missing IHDR, IDAT or
    IEND, or a chunk running past the end. Other ancillary chunks (text, gamma, physical size,
    ...) are skipped, as OpenCV's IMREAD_COLOR applies none of them."""
    view = memoryview(data)  # slices without copies
    pos, n = len(SIGNATURE), len(data)
    header, idat, idat_done, ended = None, [], False, False
    kept: dict[bytes, bytes] = {}
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
        if kind in keep and kind not in kept and (critical or isal_zlib.crc32(
                view[pos + 4:pos + 8 + length]) == struct.unpack_from(">I", data, end - 4)[0]):
            kept[kind] = body.tobytes()
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
    return header, idat[0] if len(idat) == 1 else b"".join(idat), kept


def _decode_other(header, idat, plte: bytes | None) -> np.ndarray | None:
    """The BGR uint8 image of a non-interlaced PNG of palette indices (8-bit), grey + alpha
    or RGB + alpha (8- or 16-bit), or 16-bit grey or RGB, as OpenCV's IMREAD_COLOR reads it
    (alpha left out, 16-bit samples cut to their high byte, libpng's strip_16), or None where
    it is of another kind or damaged. Decoded here, not by libpng, as checking such a file
    for what makes libpng print lines of its own (``png_for_opencv``) costs an inflate, as
    much as decoding it: 2.6 ms for a 480 x 480 palette frame and 4.5 ms for an RGBA one,
    where OpenCV takes 2.0 and 5.3 ms."""
    width, height, depth, colour = header[:4]
    samples = SAMPLES.get(colour)
    if samples is None or depth not in ((8,) if colour == 3 else (8, 16)):
        return None
    bpp = samples * depth // 8  # bytes per pixel
    expected = height * (width * bpp + 1)
    if expected > MAX_RAW_BYTES:
        return None
    raw = _inflated(idat, expected)
    if raw is None:
        return None
    rows = np.empty((height, width * bpp), np.uint8)
    if not unfilter_bytes(np.frombuffer(raw, np.uint8), bpp, rows):
        return None
    pixels = rows.reshape(height, width, samples, depth // 8)[..., 0]  # the high bytes
    if colour == 3:
        if plte is None or len(plte) % 3 or not 0 < len(plte) <= 3 * 256:
            return None
        palette = np.frombuffer(plte, np.uint8).reshape(-1, 3)[:, ::-1]  # as BGR
        index = pixels[..., 0]
        if int(index.max()) >= len(palette):  # libpng warns of it on stderr
            return None
        return np.take(palette, index, axis=0)
    if samples <= 2:  # grey (+ alpha): grey in all three channels
        return np.repeat(pixels[..., :1], 3, axis=2)
    return np.ascontiguousarray(pixels[..., 2::-1])  # RGB (+ alpha) as BGR


@njit(cache=True, nogil=True)
def unfilter_bytes(raw, bpp, out):
    """Undo the PNG row filters of the inflated rows ``raw`` (each a filter-type byte, then
    a row of ``out``'s width in bytes) into ``out`` (h, row bytes), ``bpp`` bytes a pixel (the
    filters' "left" is the byte one pixel to the left): the rules of ``unfilter_rows`` for
    any pixel size. Returns False at an unknown filter type."""
    h, stride = out.shape[0], out.shape[1]
    zero = np.zeros(stride, np.uint8)
    for y in range(h):
        base = y * (stride + 1) + 1
        kind = raw[base - 1]
        row = out[y]
        up = out[y - 1] if y > 0 else zero
        if kind == 0:
            for i in range(stride):
                row[i] = raw[base + i]
        elif kind == 1:
            for i in range(stride):
                row[i] = raw[base + i] + (row[i - bpp] if i >= bpp else np.uint8(0))
        elif kind == 2:
            for i in range(stride):
                row[i] = raw[base + i] + up[i]
        elif kind == 3:
            for i in range(stride):
                left = np.int32(row[i - bpp]) if i >= bpp else np.int32(0)
                row[i] = raw[base + i] + np.uint8((left + np.int32(up[i])) >> 1)
        elif kind == 4:
            for i in range(stride):
                if i >= bpp:
                    row[i] = raw[base + i] + _paeth(np.int32(row[i - bpp]), np.int32(up[i]),
                                                    np.int32(up[i - bpp]))
                else:
                    row[i] = raw[base + i] + up[i]  # left and corner 0: Paeth picks above
        else:
            return False
    return True


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
