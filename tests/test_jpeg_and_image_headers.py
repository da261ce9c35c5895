"""JPEG frames decoded by libjpeg-turbo through simplejpeg (stages.common.jpeg): the image
OpenCV decodes (within a grey level or so: the two may bundle different builds of
libjpeg-turbo), its pixels as stored (an EXIF orientation, a PNG's eXIf too, not applied), CMYK and
YCCK files and files with a harmless header warning decoded strictly too, a damaged scan
unreadable in fieldloc's words; and the size every kind of image
header claims (stages.common.image_header), refused beyond MAX_IMAGE_PIXELS before decoding.
The one-line output of a command given such a frame is in tests/test_faults.py (groups J and K) and
tests/test_cut_images_bags_and_signals.py (stderr of a real process)."""

from __future__ import annotations

import importlib.util
import io
import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.common.dataset import MAX_IMAGE_PIXELS, decode_image_bytes
from stages.common.image_header import image_size
from stages.common.jpeg import DamagedJPEG, decode_jpeg
from stages.common.png import decode_png

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


# OpenCV's colour image of a file, its pixels as stored (fieldloc applies no EXIF orientation)
AS_STORED = cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION


def opencv(data: bytes, flag: int = AS_STORED) -> np.ndarray:
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
def test_exif_orientation_is_not_applied(orientation):
    """OpenCV's IMREAD_COLOR turns a JPEG upright by its EXIF Orientation (a quarter turn
    for 6 and 8), and fieldloc's frames were read so: a frame of 3 was extracted upside down,
    its mirror centre moved (trial U2, U2-4). A camera's frame is its sensor's pixels: the
    file's size and pixels whatever the tag, the same as without it."""
    img = smooth_image(np.random.default_rng(SEED), 48, 64, 3)
    data = with_exif_orientation(img, orientation)
    got = decode_image_bytes(data)[0]
    assert got.shape == (48, 64, 3)
    assert_close(got, opencv(data))
    assert_close(got, decode_image_bytes(with_exif_orientation(img, 1))[0])
    assert_close(decode_image_bytes(data, unchanged=True)[0],
                 opencv(data, cv2.IMREAD_UNCHANGED))


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
    data = cv2.imencode("." + kind, img)[1].tobytes()
    assert image_size(data) == (53, 37)


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


# ---- s57 group K: every JPEG decoded strictly (CMYK, YCCK, a header's harmless warning), the
# EXIF APP1 OpenCV reads, a PNG's eXIf, the marker walk at C speed


def as_cmyk(img: np.ndarray, ycck: bool = False) -> bytes:
    """``img`` (BGR) as a CMYK JPEG file as Pillow writes it (Adobe's inverted CMYK, transform
    0), or as a YCCK one (TurboJPEG's encoder, Adobe transform 2)."""
    from PIL import Image

    pil = Image.fromarray(np.ascontiguousarray(img[..., ::-1])).convert("CMYK")
    if not ycck:
        out = io.BytesIO()
        pil.save(out, "JPEG", quality=90)
        return out.getvalue()
    import simplejpeg

    return simplejpeg.encode_jpeg(np.asarray(pil), quality=90, colorspace="CMYK")


def segment(marker: int, payload: bytes) -> bytes:
    """A JPEG marker segment: 0xFF, ``marker``, its length, ``payload``."""
    return bytes((0xFF, marker)) + (len(payload) + 2).to_bytes(2, "big") + payload


def with_header_warning(data: bytes, kind: str) -> bytes:
    """The JPEG file ``data`` (OpenCV's: a JFIF APP0 first, one baseline scan) changed so that
    libjpeg warns of its header ("jfif": major version 3; "adobe": the JFIF APP0 replaced by an
    Adobe APP14 of transform code 9; "sos": the scan's spectral selection starting at 1), the
    image left as it was."""
    b = bytearray(data)
    app0 = data.find(b"JFIF\x00") - 4
    if kind == "jfif":
        b[app0 + 4 + 5] = 3
    elif kind == "adobe":
        length = int.from_bytes(data[app0 + 2:app0 + 4], "big")
        adobe = segment(0xEE, b"Adobe" + bytes((0, 100, 0, 0, 0, 0, 9)))
        b[app0:app0 + 2 + length] = adobe
    else:
        sos = data.find(b"\xff\xda")
        length = int.from_bytes(data[sos + 2:sos + 4], "big")
        b[sos + 2 + length - 3] = 1  # Ss
    return bytes(b)


def with_marker_in_scan(data: bytes) -> bytes:
    """The JPEG file ``data`` with the bytes FF 1C (a marker code no JPEG file holds) in the
    middle of its coded data: libjpeg says "Unsupported marker type 0x1c"."""
    middle = (data.find(b"\xff\xda") + len(data)) // 2
    while data[middle - 1] == 0xFF:
        middle += 1
    return data[:middle] + b"\xff\x1c" + data[middle:]


@needs_simplejpeg
@pytest.mark.parametrize("ycck", [False, True])
@pytest.mark.parametrize("unchanged", [False, True])
def test_a_cmyk_or_ycck_jpeg_decodes_to_what_opencv_decodes(ycck, unchanged):
    """A CMYK or YCCK file went to OpenCV whole, and a damaged one's libjpeg lines with it
    (J1): decoded by simplejpeg to CMYK and converted by OpenCV's formula, to OpenCV's BGR
    image (IMREAD_UNCHANGED gives BGR too)."""
    data = as_cmyk(smooth_image(np.random.default_rng(SEED), 48, 64, 3), ycck)
    assert decode_jpeg(data) is not None
    flag = cv2.IMREAD_UNCHANGED if unchanged else cv2.IMREAD_COLOR
    assert_close(decode_image_bytes(data, unchanged=unchanged)[0], opencv(data, flag))


@needs_simplejpeg
@pytest.mark.parametrize("ycck", [False, True])
def test_a_cmyk_jpeg_whose_scan_is_damaged_is_unreadable(ycck):
    """OpenCV printed "Corrupt JPEG data: ..." for a damaged CMYK file and decoded it (J1)."""
    img = smooth_image(np.random.default_rng(SEED), 240, 320, 3)
    data = damaged_scan(as_cmyk(img, ycck))
    with pytest.raises(DamagedJPEG, match="Corrupt JPEG data: "):
        decode_jpeg(data)
    got, why = decode_image_bytes(data)
    assert got is None and why.startswith("a damaged JPEG file: Corrupt JPEG data: "), why


@needs_simplejpeg
@pytest.mark.parametrize("kind", ["jfif", "adobe", "sos"])
def test_a_header_warning_decodes_as_opencv_and_damage_behind_it_is_found(kind):
    """A header libjpeg warns of (an unknown JFIF version, Adobe transform, a sequential scan's
    spectral selection) sent the file to OpenCV, which printed the warning and, printing only
    its first, decoded a damaged scan behind it without a word (J2). The field is set to
    what libjpeg assumes in a copy, decoded strictly: OpenCV's image, or the damage said."""
    img = smooth_image(np.random.default_rng(SEED), 240, 320, 3)
    data = with_header_warning(encode(img), kind)
    assert decode_jpeg(data) is not None
    assert_close(decode_image_bytes(data)[0], opencv(data))
    for damaged in (damaged_scan(data), data[:len(data) // 2] + b"\xff\xd9"):
        with pytest.raises(DamagedJPEG, match="Corrupt JPEG data: "):
            decode_jpeg(damaged)


@needs_simplejpeg
def test_an_unknown_marker_in_a_scan_is_damage():
    """"Unsupported marker type 0x1c" sent the file to OpenCV, which printed "Corrupt JPEG
    data: premature end of data segment" and made up the lower half (J4)."""
    data = with_marker_in_scan(encode(smooth_image(np.random.default_rng(SEED), 240, 320, 3)))
    got, why = decode_image_bytes(data)
    assert got is None and why == "a damaged JPEG file: Unsupported marker type 0x1c"


def exif_tiff(orientation: int | None) -> bytes:
    """A big-endian TIFF structure whose IFD0 holds Orientation ``orientation`` (None: another
    tag, 0x0110, in its stead)."""
    tag = 0x0110 if orientation is None else 0x0112
    entry = struct.pack(">HHIHH", tag, 3, 1, orientation or 1, 0)
    return b"MM\x00*\x00\x00\x00\x08\x00\x01" + entry + bytes(4)


EXIF_LAYOUTS = {  # APP1 payloads before the frame (OpenCV 5 would turn the first and third)
    "xmp then exif 6": [b"http://ns.adobe.com/xap/1.0/\x00<x:xmpmeta/>",
                        b"Exif\x00\x00" + exif_tiff(6)],
    "no exif header": [b"Junk\x00\x00" + exif_tiff(6)],
    "exif without orientation then exif 6": [b"Exif\x00\x00" + exif_tiff(None),
                                             b"Exif\x00\x00" + exif_tiff(6)],
}


@needs_simplejpeg
@pytest.mark.parametrize("layout", EXIF_LAYOUTS)
def test_a_frame_behind_any_exif_segments_is_read_as_stored(layout):
    """Whatever APP1 segments come before the frame (an XMP one, an EXIF one with or without
    an Orientation), its pixels are the file's, as without them."""
    img = smooth_image(np.random.default_rng(SEED), 48, 64, 3)
    plain = encode(img)
    data = plain[:2] + b"".join(segment(0xE1, p) for p in EXIF_LAYOUTS[layout]) + plain[2:]
    got = decode_image_bytes(data)[0]
    assert got.shape == (48, 64, 3)
    assert_close(got, decode_image_bytes(plain)[0])


def with_exif_chunk(png: bytes, orientation: int, after_image: bool = False) -> bytes:
    """The PNG file ``png`` with an eXIf chunk giving ``orientation``, before its image data
    (IDAT) or after it."""
    body = exif_tiff(orientation)
    chunk = (struct.pack(">I", len(body)) + b"eXIf" + body
             + struct.pack(">I", zlib.crc32(b"eXIf" + body)))
    at = png.find(b"IEND" if after_image else b"IDAT") - 4
    return png[:at] + chunk + png[at:]


@pytest.mark.parametrize("orientation", [3, 6, 8])
@pytest.mark.parametrize("kind", ["rgb", "grey", "16-bit", "1-bit"])
@pytest.mark.parametrize("after_image", [False, True])
def test_a_png_is_not_turned_by_its_exif(orientation, kind, after_image):
    """OpenCV's IMREAD_COLOR turns a PNG by its eXIf chunk (J5); fieldloc reads its pixels as
    stored, by its own PNG decoder or by OpenCV (a 1-bit or 16-bit file), as a JPEG's."""
    from PIL import Image

    img = smooth_image(np.random.default_rng(SEED), 48, 64, 1 if kind == "grey" else 3)
    if kind == "16-bit":
        img = img.astype(np.uint16) * 257
    if kind == "1-bit":  # decoded by OpenCV (stages.common.png declines it)
        out = io.BytesIO()
        Image.fromarray(img[..., 1] > 128).save(out, "PNG")
        png = out.getvalue()
        assert png[24] == 1 and decode_png(png) is None  # its bit depth
    else:
        png = cv2.imencode(".png", img)[1].tobytes()
    data = with_exif_chunk(png, orientation, after_image)
    got = decode_image_bytes(data)[0]
    want = opencv(data)
    assert got.shape == (48, 64, 3)
    # PNG is lossless: the same pixels, but for a 16-bit sample, which libpng takes by its
    # high byte and libspng (another OpenCV build) rounds: one level at most. A turn moves
    # every pixel, by far more
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1
    assert decode_image_bytes(data, unchanged=True)[0].shape[:2] == (48, 64)


@needs_simplejpeg
def test_fill_bytes_are_skipped_and_millions_of_segments_refused():
    """The marker walks went byte by byte and segment by segment in Python: 30 MB of fill
    bytes or of 7.5 M empty segments before the frame cost 10-18 s (P1). Fill bytes are
    skipped at C speed; more segments than a camera's file has (MAX_SEGMENTS) are refused
    before libjpeg reads them (it keeps each: 0.7 GB)."""
    import time

    from stages.common.jpeg import MAX_SEGMENTS

    data = with_exif_orientation(smooth_image(np.random.default_rng(SEED), 48, 64, 3), 6)
    filled = data[:2] + b"\xff" * 30_000_000 + data[2:]
    start = time.perf_counter()
    got = decode_image_bytes(filled)[0]
    assert time.perf_counter() - start < 5.0  # 0.3 s; 10 s and more when walked in Python
    assert_close(got, decode_image_bytes(data)[0])  # fill bytes change no pixel
    many = data[:2] + segment(0xE2, b"") * (MAX_SEGMENTS + 1) + data[2:]
    assert decode_image_bytes(many) == (
        None, f"a JPEG file of more than {MAX_SEGMENTS:,} marker segments")
    fewer = data[:2] + segment(0xE2, b"") * (MAX_SEGMENTS - 20) + data[2:]
    assert decode_image_bytes(fewer)[0].shape == (48, 64, 3)
