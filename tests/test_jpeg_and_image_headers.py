"""JPEG frames decoded by libjpeg-turbo through simplejpeg (stages.common.jpeg): the image
OpenCV decodes (within a grey level or so: the two may bundle different builds of
libjpeg-turbo), EXIF orientation applied as OpenCV applies it, CMYK files still read (by
OpenCV), a damaged scan unreadable in fieldloc's words; and the size every kind of image
header claims (stages.common.image_header), refused beyond MAX_IMAGE_PIXELS before decoding.
The one-line output of a command given such a frame is in tests/test_faults.py (group J) and
tests/test_cut_images_bags_and_signals.py (stderr of a real process)."""

from __future__ import annotations

import importlib.util
import io
import struct

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.common.dataset import MAX_IMAGE_PIXELS, decode_image_bytes
from stages.common.image_header import image_size
from stages.common.jpeg import DamagedJPEG, decode_jpeg

SEED = 57
# simplejpeg has wheels for CPython 3.9-3.13 only (pyproject.toml); without it OpenCV reads
# every JPEG file, and the tests of its decoding skip
needs_simplejpeg = pytest.mark.skipif(importlib.util.find_spec("simplejpeg") is None,
                                      reason="simplejpeg is not installed")


def smooth_image(rng: np.random.Generator, h: int, w: int, channels: int) -> np.ndarray:
    """A camera-like image: random levels blurred (noise alone is the worst case of JPEG,
    where rounding differences of the inverse DCT show most)."""
    img = rng.integers(0, 256, (h, w, channels), dtype=np.uint8)
    img = cv2.GaussianBlur(img, (0, 0), 2.0)
    return img if channels == 3 else img.reshape(h, w)


def encode(img: np.ndarray, quality: int = 90, **params) -> bytes:
    flags = [cv2.IMWRITE_JPEG_QUALITY, quality]
    if params.get("progressive"):
        flags += [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]
    ok, data = cv2.imencode(".jpg", img, flags)
    assert ok
    return data.tobytes()


def opencv(data: bytes, flag: int = cv2.IMREAD_COLOR) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), flag)


def assert_close(got: np.ndarray, want: np.ndarray) -> None:
    """Within a grey level on average and a few at most: what two builds of libjpeg-turbo
    may differ by (SIMD or not, versions); not bit-exact."""
    assert got.shape == want.shape and got.dtype == np.uint8
    diff = np.abs(got.astype(int) - want.astype(int))
    assert diff.mean() < 1.0 and diff.max() <= 4, (diff.mean(), diff.max())


def damaged_scan(data: bytes) -> bytes:
    """The JPEG file ``data`` with every 97th byte of the last two thirds of its coded data
    changed, never into 0xFF (no marker is made): libjpeg decodes it to garbage and says
    "Corrupt JPEG data: 4682 extraneous bytes before marker 0xd9"."""
    b = bytearray(data)
    start = data.find(b"\xff\xda") + 20
    for i in range(start + (len(b) - start) // 3, len(b) - 2, 97):
        if b[i] != 0xFF and b[i - 1] != 0xFF:
            b[i] = b[i] ^ 0x55 if b[i] ^ 0x55 != 0xFF else 0x00
    return bytes(b)


def with_exif_orientation(img: np.ndarray, orientation: int) -> bytes:
    """``img`` (BGR) as a JPEG file whose EXIF gives ``orientation`` (Pillow writes it)."""
    from PIL import Image

    pil = Image.fromarray(img[..., ::-1])
    exif = pil.getexif()
    exif[0x0112] = orientation
    out = io.BytesIO()
    pil.save(out, "JPEG", quality=90, exif=exif.tobytes())
    return out.getvalue()


@needs_simplejpeg
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), quality=st.integers(30, 100),
       h=st.integers(8, 120), w=st.integers(8, 120), grey=st.booleans(),
       progressive=st.booleans())
def test_a_jpeg_decodes_to_what_opencv_decodes(seed, quality, h, w, grey, progressive):
    """Colour and grey JPEG files of any size and quality decode to OpenCV's image, as
    IMREAD_COLOR (grey replicated into BGR) and as IMREAD_UNCHANGED (grey: one channel)."""
    img = smooth_image(np.random.default_rng(seed), h, w, 1 if grey else 3)
    data = encode(img, quality, progressive=progressive)
    assert_close(decode_image_bytes(data)[0], opencv(data))
    assert_close(decode_image_bytes(data, unchanged=True)[0],
                 opencv(data, cv2.IMREAD_UNCHANGED))
    assert decode_jpeg(data) is not None  # simplejpeg's path, not OpenCV's


@needs_simplejpeg
@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_is_applied_as_opencv_applies_it(orientation):
    """OpenCV's IMREAD_COLOR turns a JPEG upright by its EXIF Orientation (a quarter turn
    for 6 and 8): fieldloc's frames were read so, and still are; IMREAD_UNCHANGED does not."""
    img = smooth_image(np.random.default_rng(SEED), 48, 64, 3)
    data = with_exif_orientation(img, orientation)
    got = decode_image_bytes(data)[0]
    assert got.shape == ((64, 48, 3) if orientation >= 5 else (48, 64, 3))
    assert_close(got, opencv(data))
    assert_close(decode_image_bytes(data, unchanged=True)[0],
                 opencv(data, cv2.IMREAD_UNCHANGED))


def test_a_cmyk_jpeg_is_read_by_opencv():
    """simplejpeg converts CMYK with its own formula: such a file goes to OpenCV, as before."""
    from PIL import Image

    out = io.BytesIO()
    Image.new("CMYK", (64, 48), (10, 200, 30, 40)).save(out, "JPEG")
    data = out.getvalue()
    assert decode_jpeg(data) is None
    got, why = decode_image_bytes(data)
    assert why is None and np.array_equal(got, opencv(data))


@needs_simplejpeg
@pytest.mark.parametrize("progressive", [False, True])
def test_a_jpeg_whose_scan_is_damaged_is_unreadable(progressive):
    """libjpeg decoded a damaged scan to garbage and printed "Corrupt JPEG data: ..." on
    stderr; the TurboJPEG API returns it, and the frame is unreadable, saying why. (In the
    progressive file the damage reaches a Huffman table between scans: libjpeg's error,
    "Bogus Huffman table definition", after OpenCV's libjpeg printed a warning.)"""
    img = smooth_image(np.random.default_rng(SEED), 240, 320, 3)
    data = damaged_scan(encode(img, progressive=progressive))
    said = "Bogus Huffman table definition" if progressive else "Corrupt JPEG data: "
    with pytest.raises(DamagedJPEG, match=said):
        decode_jpeg(data)
    got, why = decode_image_bytes(data)
    assert got is None and why.startswith("a damaged JPEG file: " + said), why
    assert len(why) < 100


def claiming(kind: str, width: int, height: int) -> bytes:
    """A small image file of ``kind`` (as OpenCV writes it) whose header is made to claim
    ``width`` x ``height`` pixels; the rest of the file is left as written."""
    ok, buf = cv2.imencode("." + kind, smooth_image(np.random.default_rng(SEED), 16, 24, 3))
    data = bytearray(buf.tobytes())
    if kind == "jpg":  # the frame header (SOF0): precision, height, width
        sof = data.find(b"\xff\xc0")
        struct.pack_into(">HH", data, sof + 5, height, width)
    elif kind == "bmp":
        struct.pack_into("<ii", data, 18, width, height)
    elif kind == "webp":  # OpenCV's is lossless (VP8L): 14 bits each, less one
        assert data[12:16] == b"VP8L"
        bits = int.from_bytes(data[21:25], "little") & ~((1 << 28) - 1)
        data[21:25] = (bits | (width - 1) | (height - 1) << 14).to_bytes(4, "little")
    elif kind == "tiff":  # tags 256 and 257 of IFD0
        order = "<" if data[:2] == b"II" else ">"
        ifd = struct.unpack_from(order + "I", data, 4)[0]
        for i in range(struct.unpack_from(order + "H", data, ifd)[0]):
            entry = ifd + 2 + 12 * i
            tag, kind_ = struct.unpack_from(order + "HH", data, entry)
            if tag in (256, 257):
                fmt = order + ("H" if kind_ == 3 else "I")
                struct.pack_into(fmt, data, entry + 8, width if tag == 256 else height)
    return bytes(data)


@pytest.mark.parametrize("kind", ["jpg", "bmp", "webp", "tiff", "png"])
def test_the_size_every_header_claims_is_read(kind):
    """The size read from the header of each kind of frame is the image's."""
    img = smooth_image(np.random.default_rng(SEED), 37, 53, 3)
    ok, buf = cv2.imencode("." + kind, img)
    assert image_size(buf.tobytes()) == (53, 37)


@pytest.mark.parametrize("mode", ["RGB", "RGBA"])
@pytest.mark.parametrize("lossless", [False, True])
def test_the_size_of_every_kind_of_webp_is_read(mode, lossless):
    """WebP's three layouts: lossy (VP8), lossless (VP8L), extended (VP8X, with alpha)."""
    from PIL import Image

    out = io.BytesIO()
    Image.new(mode, (53, 37)).save(out, "WEBP", lossless=lossless)
    assert image_size(out.getvalue()) == (53, 37)


@pytest.mark.parametrize("kind,width,height", [("jpg", 65000, 65000), ("bmp", 30000, 30000),
                                               ("webp", 16383, 16383),
                                               ("tiff", 20000, 20000)])
def test_a_header_claiming_too_many_pixels_says_how_many(kind, width, height):
    """A TIFF or WebP claiming 20000 x 20000 px was refused by OpenCV's pixel limit in a line
    without a reason; a JPEG claiming 65000 x 65000 px would have made simplejpeg reserve
    12 GB. Each is refused from its header, in a line saying the size."""
    assert width * height > MAX_IMAGE_PIXELS
    got, why = decode_image_bytes(claiming(kind, width, height))
    assert got is None
    assert why == (f"its header claims {width} x {height} px, more than the"
                   f" {MAX_IMAGE_PIXELS:,} pixels fieldloc reads")
