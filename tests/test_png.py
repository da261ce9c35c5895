"""stages.common.png: the fast PNG decoder gives what OpenCV's IMREAD_COLOR gives, to the bit
(PNG is lossless: there is one right answer), on every row filter and on files written by
OpenCV and Pillow; it declines what it does not read (and read_image then asks OpenCV), and
never decodes a file libpng refuses.

The PNG writer here is a reference for the tests (PNG specification, ISO/IEC 15948:2004): it
lets a test choose each row's filter type and split the data into several IDAT chunks, which
no library's writer exposes."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from stages.common import png
from stages.common.dataset import read_image
from stages.common.errors import DatasetError


def _chunk(kind: bytes, body: bytes, crc: int | None = None) -> bytes:
    crc = zlib.crc32(kind + body) if crc is None else crc
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def _filter_row(row: np.ndarray, above: np.ndarray, kind: int, bpp: int) -> np.ndarray:
    """Row ``row`` (int, file order) filtered with ``kind`` (specification, section 9.2)."""
    left = np.concatenate([np.zeros(bpp, int), row[:-bpp]])
    corner = np.concatenate([np.zeros(bpp, int), above[:-bpp]])
    if kind == 0:
        pred = np.zeros_like(row)
    elif kind == 1:
        pred = left
    elif kind == 2:
        pred = above
    elif kind == 3:
        pred = (left + above) // 2
    else:
        p = left + above - corner
        pa, pb, pc = np.abs(p - left), np.abs(p - above), np.abs(p - corner)
        pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, above, corner))
    return (row - pred) % 256


def encode(img: np.ndarray, filters, parts: int = 1, level: int = 6, extra=(),
           header: dict | None = None) -> bytes:
    """A PNG of ``img`` (h, w, 3 RGB or h, w grey, uint8) with row i filtered by
    ``filters[i % len(filters)]``, its zlib stream cut into ``parts`` IDAT chunks, ``extra``
    chunks (kind, body) before the data, and IHDR fields overridden by ``header``."""
    h, w = img.shape[:2]
    bpp = 1 if img.ndim == 2 else 3
    rows = img.reshape(h, w * bpp).astype(int)
    above = np.zeros(w * bpp, int)
    raw = bytearray()
    for i in range(h):
        kind = filters[i % len(filters)]
        raw.append(kind)
        raw += _filter_row(rows[i], above, kind, bpp).astype(np.uint8).tobytes()
        above = rows[i]
    data = zlib.compress(bytes(raw), level)
    fields = dict(width=w, height=h, depth=8, colour=0 if bpp == 1 else 2, interlace=0)
    fields.update(header or {})
    ihdr = struct.pack(">IIBBBBB", fields["width"], fields["height"], fields["depth"],
                       fields["colour"], 0, 0, fields["interlace"])
    cut = np.linspace(0, len(data), parts + 1).astype(int)
    out = png.SIGNATURE + _chunk(b"IHDR", ihdr)
    out += b"".join(_chunk(k, b) for k, b in extra)
    out += b"".join(_chunk(b"IDAT", data[a:b]) for a, b in zip(cut[:-1], cut[1:]))
    return out + _chunk(b"IEND", b"")


def _same_pixels(got: np.ndarray | None, want: np.ndarray | None) -> None:
    """Two decodes of one image agree pixel for pixel (PNG is lossless)."""
    assert got is not None and want is not None
    assert got.dtype == want.dtype == np.uint8
    # PNG is lossless and decoding is integer arithmetic on every CPU: the one right image is
    # the property, and a tolerance would pass a row filter off by one grey level
    np.testing.assert_array_equal(got, want)  # exact integers: uint8 pixels, lossless decodes


def _bgr(img: np.ndarray) -> np.ndarray:
    return np.repeat(img[..., None], 3, axis=2) if img.ndim == 2 else img[..., ::-1]


def _opencv(data: bytes) -> np.ndarray | None:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def _image(draw_or_rng, h, w, grey, smooth):
    rng = draw_or_rng
    shape = (h, w) if grey else (h, w, 3)
    if smooth:  # gradients, where the predictive filters matter
        yy, xx = np.mgrid[:h, :w]
        base = (3 * yy + 5 * xx) % 256
        img = base if grey else np.stack([base, (base * 7) % 256, 255 - base], axis=2)
        return (img + rng.integers(0, 3, shape)).astype(np.uint8)
    return rng.integers(0, 256, shape, dtype=np.uint8)


@settings(max_examples=60, deadline=None)
@given(h=st.integers(1, 12), w=st.integers(1, 12), grey=st.booleans(), smooth=st.booleans(),
       filters=st.lists(st.integers(0, 4), min_size=1, max_size=5), parts=st.integers(1, 3),
       seed=st.integers(0, 2**16))
def test_every_row_filter_decodes_as_opencv_reads_it(h, w, grey, smooth, filters, parts, seed):
    img = _image(np.random.default_rng(seed), h, w, grey, smooth)
    data = encode(img, filters, parts)
    got = png.decode_png(data)
    assert got is not None
    assert got.dtype == np.uint8 and got.shape == (h, w, 3)
    _same_pixels(got, _bgr(img))
    _same_pixels(got, _opencv(data))


@pytest.mark.parametrize("grey", [False, True])
def test_files_written_by_opencv_and_pillow_decode_as_opencv_reads_them(tmp_path, grey):
    rng = np.random.default_rng(3)
    img = _image(rng, 37, 53, grey, smooth=True)
    files = []
    for level in (0, 1, 9):
        p = tmp_path / f"cv{level}.png"
        cv2.imwrite(str(p), _bgr(img) if not grey else img, [cv2.IMWRITE_PNG_COMPRESSION, level])
        files.append(p)
    for optimize in (False, True):  # Pillow's adaptive filters use every filter type
        p = tmp_path / f"pil{optimize}.png"
        Image.fromarray(img).save(p, optimize=optimize)
        files.append(p)
    for p in files:
        got = png.decode_png(p.read_bytes())
        assert got is not None, p.name
        _same_pixels(got, cv2.imread(str(p), cv2.IMREAD_COLOR))
        _same_pixels(read_image(p), got)


def test_ancillary_chunks_are_skipped_and_a_bad_one_does_not_stop_the_image():
    img = _image(np.random.default_rng(4), 9, 11, False, True)
    extra = [(b"tEXt", b"Software\x00fieldloc"), (b"gAMA", struct.pack(">I", 45455)),
             (b"PLTE", bytes(range(6)))]
    data = encode(img, [1, 4], extra=extra)
    _same_pixels(png.decode_png(data), _opencv(data))
    # an ancillary chunk with a wrong CRC: libpng warns and drops it, the image reads
    bad = encode(img, [1], extra=[(b"tEXt", b"a\x00b")])
    at = bad.index(b"tEXt") + 4 + len(b"a\x00b")
    bad = bad[:at] + bytes([bad[at] ^ 1]) + bad[at + 1:]
    _same_pixels(png.decode_png(bad), _opencv(bad))


@pytest.mark.parametrize("header", [dict(depth=16), dict(colour=3), dict(colour=6),
                                    dict(interlace=1)])
def test_kinds_it_does_not_read_are_declined(header):
    img = _image(np.random.default_rng(5), 6, 7, False, False)
    assert png.decode_png(encode(img, [0], header=header)) is None


def test_other_kinds_read_by_read_image_as_opencv_reads_them(tmp_path):
    """Alpha channels and 16-bit samples are decoded here (png._decode_other), as OpenCV
    reads them."""
    rgba = np.random.default_rng(6).integers(0, 256, (8, 9, 4), dtype=np.uint8)
    wide = np.random.default_rng(7).integers(0, 65536, (8, 9), dtype=np.uint16)
    for name, arr in (("rgba.png", rgba), ("deep.png", wide)):
        p = tmp_path / name
        cv2.imwrite(str(p), arr)
        _same_pixels(png.decode_png(p.read_bytes()), cv2.imread(str(p), cv2.IMREAD_COLOR))
        _same_pixels(read_image(p), cv2.imread(str(p), cv2.IMREAD_COLOR))


def _damaged(data: bytes, how: str) -> bytes:
    at = data.index(b"IDAT") + 4
    if how == "idat crc":
        end = data.index(b"IEND") - 8  # the IDAT's CRC, just before IEND's length
        return data[:end] + bytes([data[end] ^ 1]) + data[end + 1:]
    if how == "idat byte":  # the byte and its chunk's CRC changed together: zlib must notice
        body = bytearray(data[at:data.index(b"IEND") - 8])
        body[len(body) // 2] ^= 0x40
        return data[:at - 8] + _chunk(b"IDAT", bytes(body)) + _chunk(b"IEND", b"")
    if how == "truncated":
        return data[:len(data) * 2 // 3]
    if how == "no iend":
        return data[:data.index(b"IEND") - 4]
    if how == "unknown critical chunk":
        return data[:at - 8] + _chunk(b"ABCD", b"x") + data[at - 8:]
    if how == "bad filter type":
        return _bad_filter()
    raise ValueError(how)


def _bad_filter() -> bytes:
    raw = zlib.compress(bytes([5, 0, 0, 0]))
    return (png.SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", 3, 1, 8, 0, 0, 0, 0))
            + _chunk(b"IDAT", raw) + _chunk(b"IEND", b""))


@pytest.mark.parametrize("how", ["idat crc", "idat byte", "truncated", "no iend",
                                 "unknown critical chunk", "bad filter type"])
def test_a_damaged_file_is_left_to_opencv(tmp_path, how):
    """The fast path never decodes what the specification calls an error: it declines, and
    read_image does what OpenCV does with the file (an image, or one clear error)."""
    img = _image(np.random.default_rng(8), 40, 30, False, False)
    data = _damaged(encode(img, [1, 2, 3, 4], parts=2), how)
    assert png.decode_png(data) is None
    p = tmp_path / "damaged.png"
    p.write_bytes(data)
    want = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if want is None:
        with pytest.raises(DatasetError, match="unreadable image"):
            read_image(p)
    else:
        _same_pixels(read_image(p), want)


def test_a_header_claiming_a_huge_image_reserves_nothing():
    data = encode(np.zeros((2, 2), np.uint8), [0], header=dict(width=60000, height=60000))
    assert png.decode_png(data) is None  # declined before any allocation (MAX_RAW_BYTES)


def test_a_file_that_is_not_a_png_is_declined():
    assert png.decode_png(b"") is None
    assert png.decode_png(b"\xff\xd8\xff\xe0 not a png") is None
    assert png.decode_png(png.SIGNATURE) is None
