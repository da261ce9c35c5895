"""What a features file records of the images it was extracted from (their identity, checked
by every reader against the dataset's frames), and the images a dataset reads: the PNG files
libpng would print lines of its own about, other kinds of frames (.bmp, .tiff, .webp).

The images are written here with numpy, OpenCV and Pillow, and damaged here."""

from __future__ import annotations

import io
import logging
import os
import re
import struct
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from stages.common import png
from stages.common.artifacts import root_attrs
from stages.common.dataset import Dataset, frame_index, open_dataset, read_frame, read_image
from stages.common.errors import DatasetError, FieldlocError
from stages.common.features_file import SCHEMA, VERSION, FeaturesFile, write_features

ATTRS = {**root_attrs(SCHEMA, VERSION), "camera_kind": "omni", "calib_hash": ""}


def _chunk(kind: bytes, body: bytes, crc: int | None = None) -> bytes:
    crc = zlib.crc32(kind + body) if crc is None else crc
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def _rgb(seed: int, h: int = 24, w: int = 31) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _quantized(img: np.ndarray, colours: int) -> Image.Image:
    """``img`` (its channels read as RGB) as a palette image of ``colours`` (Pillow's)."""
    return Image.fromarray(img).quantize(colours)


def _bgr(image: Image.Image) -> np.ndarray:
    """The pixels of a Pillow image as an image reader returns them: BGR, uint8."""
    return np.asarray(image.convert("RGB"))[..., ::-1]


def _palette_png(extra: bytes = b"") -> bytes:
    """An 8-bit palette PNG (Pillow's) with ``extra`` chunks before its end chunk."""
    b = io.BytesIO()
    _quantized(_rgb(1), 40).save(b, "PNG")
    data = b.getvalue()
    end = data.rindex(b"IEND") - 4
    return data[:end] + extra + data[end:]


def _idat_damaged_crc_right(data: bytes) -> bytes:
    """``data`` with bytes of its IDAT data changed and the chunk's CRC made right again (what
    libpng answers with "bad adaptive filter value")."""
    at = data.index(b"IDAT")
    length = struct.unpack(">I", data[at - 4:at])[0]
    raw = bytearray(zlib.decompress(data[at + 4:at + 4 + length]))
    raw[0] = 9  # the first row's filter type: none of 0..4
    return data[:at - 4] + _chunk(b"IDAT", zlib.compress(bytes(raw))) + data[at + 8 + length:]


def _interlaced(img: np.ndarray, filters: int = 0) -> bytes:
    """An Adam7-interlaced 8-bit RGB PNG of ``img`` (every row unfiltered; the first row's
    filter type ``filters``)."""
    h, w = img.shape[:2]
    raw = bytearray()
    for x0, y0, dx, dy in png.ADAM7:
        sub = img[y0::dy, x0::dx]
        if sub.size:
            for row in sub:
                raw.append(0)
                raw += row.tobytes()
    raw[0] = filters
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 1)
    return (png.SIGNATURE + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(bytes(raw)))
            + _chunk(b"IEND", b""))


# ---------------------------------------------------------------- I2: libpng's own lines


@pytest.mark.parametrize("kind", ["rgb", "palette", "interlaced"])
def test_idat_damaged_under_right_crcs_is_refused_without_libpng_lines(tmp_path, capfd, kind):
    """A PNG whose IDAT data is damaged but whose CRCs are right made libpng print "libpng
    error: bad adaptive filter value" beside fieldloc's one line: refused before libpng."""
    if kind == "rgb":
        data = png.SIGNATURE + cv2.imencode(".png", _rgb(2))[1].tobytes()[8:]
        data = _idat_damaged_crc_right(data)
    elif kind == "palette":
        data = _idat_damaged_crc_right(_palette_png())
    else:
        data = _interlaced(_rgb(3), filters=9)
    p = tmp_path / "f.png"
    p.write_bytes(data)
    capfd.readouterr()
    with pytest.raises(DatasetError, match="unreadable image: .*damaged"):
        read_image(p)
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize("chunk", [
    _chunk(b"tEXt", b"Comment\x00a user's note", crc=0),  # "libpng warning: tEXt: CRC error"
    _chunk(b"iCCP", b"x\x00\x00ab"),  # "libpng warning: iCCP: too short"
])
def test_a_bad_ancillary_chunk_reads_the_image_without_libpng_lines(tmp_path, capfd, chunk):
    """libpng warned of a bad ancillary chunk and then decoded the image: it is read, the
    pixels that were written (PNG is lossless; alpha left out), without a line."""
    for data, written in ((_palette_png(chunk), _bgr(_quantized(_rgb(1), 40))),
                          (png.SIGNATURE + cv2.imencode(".png", cv2.cvtColor(
                              _rgb(4), cv2.COLOR_BGR2BGRA))[1].tobytes()[8:], _rgb(4))):
        end = data.rindex(b"IEND") - 4
        data = data if chunk in data else data[:end] + chunk + data[end:]
        p = tmp_path / "f.png"
        p.write_bytes(data)
        capfd.readouterr()
        got = read_image(p)
        assert capfd.readouterr().err == ""
        assert got.shape == written.shape and _max_step(got, written) == 0


def test_an_interlaced_png_is_read_as_opencv_reads_it(tmp_path):
    img = _rgb(5, 13, 11)
    data = _interlaced(img)
    assert png.decode_png(data) is None  # left to OpenCV, checked first
    assert png.png_for_opencv(data) is not None
    p = tmp_path / "f.png"
    p.write_bytes(data)
    assert _max_step(read_image(p), img[..., ::-1]) == 0  # the pixels written (lossless)


@pytest.mark.parametrize("kind", ["palette", "grey+alpha", "rgba", "grey16", "rgb16",
                                  "rgba16", "palette+trns"])
def test_other_png_kinds_decode_to_the_pixels_written(kind):
    """Decoded here (png._decode_other), not by libpng: the pixels written, as an image
    reader returns them (BGR; grey in all three channels; alpha left out). PNG is lossless,
    so 8-bit samples come back as written; a 16-bit sample comes back within one level of
    its value in 8 bits (v / 257: its high byte, or a rounded scaling, as readers differ)."""
    rng = np.random.default_rng(6)
    img = _rgb(7, 20, 17)
    b = io.BytesIO()
    if kind in ("palette", "palette+trns"):
        q = _quantized(img, 60)
        q.save(b, "PNG", **({"transparency": 3} if kind == "palette+trns" else {}))
        written, levels = _bgr(q), 0
    elif kind == "grey+alpha":
        Image.fromarray(img[..., 0]).convert("LA").save(b, "PNG")
        written, levels = np.repeat(img[..., :1], 3, axis=2), 0
    elif kind == "rgba":
        b.write(cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_BGR2BGRA))[1].tobytes())
        written, levels = img, 0
    else:
        arr = rng.integers(0, 65536, {"grey16": (20, 17), "rgb16": (20, 17, 3),
                                      "rgba16": (20, 17, 4)}[kind], dtype=np.uint16)
        b.write(cv2.imencode(".png", arr)[1].tobytes())  # BGR(A) order, as OpenCV writes
        bgr = np.repeat(arr[..., None], 3, axis=2) if arr.ndim == 2 else arr[..., :3]
        written, levels = bgr / 257.0, 1
    got = png.decode_png(b.getvalue())
    assert got is not None and got.shape == written.shape and got.dtype == np.uint8
    assert _max_step(got, written) <= levels


def _max_step(got: np.ndarray, want: np.ndarray) -> float:
    """The largest difference, in grey levels, between a decoded image and the pixels
    written."""
    return float(np.max(np.abs(got.astype(np.float64) - want)))


# ---------------------------------------------------------------- I3: other kinds of frames


def _dataset(root: Path, n: int = 3, suffix: str = ".png") -> Path:
    (root / "images").mkdir(parents=True)
    rows = ["name,stamp"]
    for i in range(n):
        name = f"{i:06d}{suffix if i == 1 else '.png'}"
        cv2.imwrite(str(root / "images" / name), _rgb(10 + i))
        rows.append(f"{name},{i / 10:.6f}")
    (root / "frames.csv").write_text("\n".join(rows) + "\n")
    return root


@pytest.mark.parametrize("suffix", [".bmp", ".tiff", ".tif", ".webp", ".jpeg"])
def test_frames_of_other_image_kinds_are_read(tmp_path, suffix):
    """A team's frames saved as BMP (or TIFF, WebP) are frames, read as OpenCV reads them."""
    ds = open_dataset(_dataset(tmp_path / "ds", suffix=suffix))
    assert ds.names == ["000000", "000001", "000002"]
    assert ds.images[1].suffix == suffix
    img = read_image(ds.images[1])
    if suffix in (".bmp", ".tiff", ".tif"):  # lossless: the pixels written
        assert img.shape == _rgb(11).shape and _max_step(img, _rgb(11)) == 0


def test_a_listed_frame_of_a_kind_not_read_is_said(tmp_path, caplog):
    root = _dataset(tmp_path / "ds")
    Image.fromarray(_rgb(20)).save(root / "images" / "000003.gif")
    with open(root / "frames.csv", "a") as f:
        f.write("000003.gif,0.3\n")
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(root)
    assert len(ds.names) == 3
    assert ("1 frames are files of a kind fieldloc does not read or none of the images is"
            " (first: 000003.gif") in caplog.text


# ---------------------------------------------------------------- F1: the images' identity


def _features(path: Path, ds: Dataset, identities: bool = True) -> Path:
    with write_features(path, ATTRS) as w:
        for p, name, stamp in zip(ds.images, ds.names, ds.stamps):
            _img, identity = read_frame(p)
            w.add_frame(name, float(stamp), {"radial": np.full((72, 4), np.nan, np.float32),
                                             "spiral": np.full((2, 72), np.nan, np.float32),
                                             "points": np.zeros((0, 2), np.float32)},
                        identity if identities else "")
    return path


def test_features_of_another_dataset_with_the_same_names_and_stamps_are_refused(tmp_path):
    mine = open_dataset(_dataset(tmp_path / "mine"))
    other = open_dataset(_dataset(tmp_path / "other"))
    cv2.imwrite(str(other.images[2]), _rgb(99))  # the other recording's frame 2
    f = _features(tmp_path / "f.h5", mine)
    with FeaturesFile(f) as ff:
        ff.check_of(mine)
        with pytest.raises(FieldlocError, match="frame 000002 was extracted from another image"
                                                " than .*other/images/000002.png"):
            ff.check_of(other)


def test_a_frame_re_encoded_since_its_extraction_is_another_image(tmp_path):
    ds = open_dataset(_dataset(tmp_path / "ds"))
    f = _features(tmp_path / "f.h5", ds)
    cv2.imwrite(str(ds.images[0]), cv2.imread(str(ds.images[0])),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])  # the same pixels, other bytes
    with FeaturesFile(f) as ff, pytest.raises(FieldlocError, match="frame 000000 was"):
        ff.check_of(ds)


def test_features_without_the_record_are_judged_by_names_and_stamps(tmp_path, caplog):
    """Features of a fieldloc before the record (no /index/image) are taken without a word."""
    mine = open_dataset(_dataset(tmp_path / "mine"))
    other = open_dataset(_dataset(tmp_path / "other"))
    cv2.imwrite(str(other.images[2]), _rgb(99))
    f = _features(tmp_path / "f.h5", mine)
    with h5py.File(f, "a") as h5:
        del h5["index/image"]
    with caplog.at_level(logging.WARNING), FeaturesFile(f) as ff:
        ff.check_of(other)
    assert caplog.text == ""
    g = _features(tmp_path / "g.h5", mine, identities=False)
    with FeaturesFile(g) as ff:
        ff.check_of(other)


def test_frames_the_dataset_does_not_have_are_left_out(tmp_path):
    """A dataset cut after its extraction: its readers see its frames only."""
    root = _dataset(tmp_path / "ds")
    f = _features(tmp_path / "f.h5", open_dataset(root))
    (root / "images" / "000002.png").unlink()
    ds = open_dataset(root)
    with FeaturesFile(f) as ff:
        assert len(ff.names) == 3
        ff.check_of(ds)
        assert ff.names == ["000000", "000001"] and len(ff.stamps) == 2


def test_the_identity_is_kept_through_a_resumed_file(tmp_path):
    """A file resumed by extract keeps the identities of its frames, and frames stored before
    the record have none ("")."""
    ds = open_dataset(_dataset(tmp_path / "ds"))
    f = _features(tmp_path / "f.h5", ds)
    with h5py.File(f, "a") as h5:
        del h5["index/image"]
    with write_features(f, ATTRS, resume=True) as w:
        _img, identity = read_frame(ds.images[0])
        w.add_frame("000009", 0.9, {"radial": np.full((72, 4), np.nan, np.float32),
                                    "spiral": np.full((2, 72), np.nan, np.float32),
                                    "points": np.zeros((0, 2), np.float32)}, identity)
    with h5py.File(f) as h5:
        got = [v.decode() for v in h5["index/image"][()]]
    assert got == ["", "", "", identity]


def test_a_png_whose_stream_inflates_far_beyond_its_rows_is_refused_without_inflating_it():
    """A "zlib bomb": a PNG of 37 x 23 px whose IDAT stream inflates to 64 MB (a few hundred
    kilobytes of zeros compressed) is refused, and the reader never holds more than its rows
    and a byte: a 3 MB file of this kind made the reader inflate 3 GB."""
    import tracemalloc

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(
            ">I", zlib.crc32(kind + body))

    bomb = zlib.compress(bytes(64 << 20), 9)
    for colour, depth in ((2, 8), (6, 8), (2, 16)):  # the fast path and the other kinds
        data = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 37, 23, depth,
                                                                      colour, 0, 0, 0))
                + chunk(b"IDAT", bomb) + chunk(b"IEND", b""))
        path = Path(tempfile.mkdtemp()) / "bomb.png"
        path.write_bytes(data)
        tracemalloc.start()
        with pytest.raises(DatasetError, match="unreadable image"):
            read_image(path)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak < len(data) + (8 << 20), peak  # the file, not what it inflates to


def test_opencv_refuses_an_image_whose_header_claims_more_than_the_pixel_limit():
    """Importing stages sets OpenCV's pixel limit (OPENCV_IO_MAX_IMAGE_PIXELS) to
    MAX_IMAGE_PIXELS before OpenCV loads: a BMP header claiming 9000 x 8000 px (72 M: under
    OpenCV's own 1 G) is refused at its header, before OpenCV reserves its memory (a TIFF or
    WebP of a few hundred kilobytes claiming 20000 x 20000 px took 1.6-2.4 GB)."""
    code = (
        "import struct, numpy as np, stages, cv2\n"
        "info = struct.pack('<IiiHHIIiiII', 40, 9000, 8000, 1, 24, 0, 0, 2835, 2835, 0, 0)\n"
        "data = b'BM' + struct.pack('<IHHI', 118, 0, 0, 54) + info + bytes(64)\n"
        "try:\n"
        "    cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)\n"
        "except cv2.error as e:\n"
        "    print('refused' if 'MAX_IMAGE_PIXELS' in str(e) else 'other')\n")
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_IO_MAX_IMAGE_PIXELS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, cwd=str(Path(__file__).resolve().parents[1]), timeout=120)
    assert out.stdout.strip() == "refused", out.stdout + out.stderr


def test_a_frame_whose_image_became_a_fifo_is_refused(tmp_path):
    """localize with a features file reads no image: a frame whose image was replaced by a
    FIFO (or a folder) since its extraction was localised from the old image's features,
    without a word; now refused, as another image is. A frame whose image was deleted
    (features kept, images thrown away to save room) is still localised."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages import extract, simulate

    ds = simulate.main(dict(simulate.confs["omni-clean"], frames=2, seed=1896), "spl",
                       tmp_path / "ds")
    feats = extract.main(None, ds, tmp_path / "f.h5")
    img = ds / "images" / "000001.png"
    img.unlink()
    os.mkfifo(img)
    res = CliRunner().invoke(cli, ["localize", str(ds), "--map", _spl_map(tmp_path),
                                   "--features", str(feats), "--method", "lut", "-o",
                                   str(tmp_path / "p.h5")])
    assert res.exit_code == 1 and "not a regular file" in res.output, res.output
    img.unlink()
    res = CliRunner().invoke(cli, ["-q", "localize", str(ds), "--map", _spl_map(tmp_path),
                                   "--features", str(feats), "--method", "lut", "-o",
                                   str(tmp_path / "p.h5")])
    assert res.exit_code == 0, res.output


def _spl_map(tmp_path) -> str:
    """A coarse map of the spl field, built once in ``tmp_path``."""
    from stages import build_map

    path = tmp_path / "spl.map.h5"
    if not path.exists():
        build_map.main({"resolution": 0.5}, "spl", path)
    return str(path)


def test_a_frame_given_by_position_keeps_its_place_when_its_image_is_deleted(tmp_path):
    """With 000000.png deleted (frames.csv still listing it), `show points --frame 0` drew
    frame 000001 without a word, and so did `--frame 000000` (not a name any more, read as
    position 0). Positions count the frames frames.csv lists; such a frame is refused."""
    (tmp_path / "images").mkdir()
    for name in ("000001", "000002"):
        cv2.imwrite(str(tmp_path / "images" / f"{name}.png"), np.zeros((4, 4, 3), np.uint8))
    (tmp_path / "frames.csv").write_text(
        "name,stamp\n000000.png,0.0\n000001.png,0.1\n000002.png,0.2\n")
    ds = open_dataset(tmp_path)
    assert ds.names == ["000001", "000002"] and ds.missing == ("000000.png",)
    for frame in (0, "0", "000000"):
        with pytest.raises(DatasetError, match="frame 000000's image .*000000.png cannot be"
                                               r" read: there is no such file \(frames.csv"):
            ds.frame_at(frame)
    assert [ds.frame_at(f) for f in (1, "2", "000001", "000002")] == [0, 1, 0, 1]
    with pytest.raises(DatasetError, match=r"frame index 3 out of range \(0..2\)"):
        ds.frame_at(3)
    (tmp_path / "frames.csv").unlink()  # no list: the images are the frames
    assert open_dataset(tmp_path).frame_at(0) == 0


def test_rows_of_no_frame_take_no_position_and_deleted_frames_keep_theirs(tmp_path):
    """Trial G: (G2) rows naming a text file, a .gif or a .jpg among PNG frames (no such
    files) shifted every later frame's position (`--frame 2` drew 000001), and (G6) a
    deleted frame named in a folder (sub/000000.png) sorted after the frames. A frame's
    position is its place among the frames' file names, a deleted frame's in its place
    whatever its folder; a row of no frame takes none."""
    root = _dataset(tmp_path / "ds", n=4)
    (root / "images" / "000000.png").unlink()
    (root / "frames.csv").write_text(
        "name,stamp\n000001.png,0.1\n0000001.txt,0.11\n000001a.gif,0.12\n000001b.jpg,0.13\n"
        "sub/000000.png,0.0\n000002.png,0.2\n000003.png,0.3\n")
    ds = open_dataset(root)
    assert ds.names == ["000001", "000002", "000003"]
    # the positions of the frames there: their places among the four frames listed
    assert [ds.names[ds.frame_at(i)] for i in (1, 2, 3)] == ds.names
    for frame in (0, "000000"):
        # trial I (I4): the path looked for, not one built from the row's folder
        with pytest.raises(DatasetError, match=re.escape(
                "images/000000.png cannot be read: there is no such file (frames.csv lists it"
                " as 'sub/000000.png')")):
            ds.frame_at(frame)
    with pytest.raises(DatasetError, match=r"frame index 4 out of range \(0..3\)"):
        ds.frame_at(4)


@pytest.mark.parametrize("second", ["000001", "000001.png", "sub/000001.png"])
def test_a_frame_listed_twice_is_refused(tmp_path, second):
    """Trial G (G3): 000001.png and 000001 listed at two stamps were accepted (one stamp
    kept, silently); a frame listed twice is refused, as a name listed twice is."""
    root = _dataset(tmp_path / "ds")
    with open(root / "frames.csv", "a") as f:
        f.write(f"{second},0.15\n")
    with pytest.raises(DatasetError, match="frames.csv: line 5: frame '000001' is given twice"
                                           r" \(line 3"):
        open_dataset(root)


def _positions(ds) -> list[str]:
    """What each frame position of ``ds`` is: a frame's name, or "-" where the frame's
    image is missing (refused)."""
    out = []
    for i in range(len(ds.names) + len(ds.missing)):
        try:
            out.append(ds.names[ds.frame_at(i)])
        except DatasetError as e:
            assert "cannot be read: there is no such file (frames.csv lists it" in str(e)
            out.append("-")
    return out


@pytest.mark.parametrize("stems, deleted, listed", [
    # trial H (H4): a stem with a dot and letters in its last part (f1.v2), listed by it
    (["f0.v2", "f1.v2", "f2.v2"], "f1.v2.png", "f1.v2"),
    (["f0.v2", "f1.v2", "f2.v2"], "f1.v2.png", "f1.v2.png"),
    # a deleted JPG frame among PNG and JPG frames; a .jpeg is a JPG frame
    (["000000", "000001.jpg", "000002.jpg"], "000001.jpg", "000001.jpg"),
    (["000000", "000001.jpeg", "000002.jpg"], "000001.jpeg", "000001.jpeg"),
    (["000000", "000001.TIF", "000002.tiff"], "000001.TIF", "000001.TIF"),
    # trial I (I2): listed in a folder written with a backslash (a Windows frames.csv): it was
    # a missing frame named cam\000001 that sorted last
    (["000000", "000001", "000002"], "000001.png", "cam\\000001.png"),
])
def test_a_deleted_frame_of_the_datasets_kinds_keeps_its_position(tmp_path, caplog, stems,
                                                                   deleted, listed):
    """Trial H (H4): a deleted frame listed as f1.v2 (a dot in its stem), or a deleted .jpg
    frame of a folder of PNG and JPG frames, was taken for a row of another kind and took
    no position: every later frame moved one position back, without a word. A frame of one
    of the kinds of the dataset's images (.jpg and .jpeg one kind), or listed by a stem,
    keeps its place; only the missing frame itself is refused."""
    (tmp_path / "images").mkdir()
    rows = ["name,stamp"]
    for i, stem in enumerate(stems):
        name = stem if Path(stem).suffix.lower() in (".jpg", ".jpeg", ".tif", ".tiff") \
            else stem + ".png"
        cv2.imwrite(str(tmp_path / "images" / name), _rgb(10 + i))
        rows.append(f"{listed if name == deleted else name},{i / 10}")
    (tmp_path / "frames.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "images" / deleted).unlink()
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(tmp_path)
    assert ds.missing == (listed,) and caplog.text == ""
    assert _positions(ds) == [ds.names[0], "-", ds.names[1]]


def test_a_row_of_another_kind_beside_a_frame_of_its_stem_takes_no_position(tmp_path, caplog):
    """Trial H (H8): rows 000001.png and 000001.jpg in a folder of PNG frames were refused
    as a frame listed twice, where a .jpg among PNG frames is no frame (a row of another
    kind: said in a warning naming it, left out); so are notes.txt and a .gif."""
    root = _dataset(tmp_path / "ds", n=3)
    with open(root / "frames.csv", "a") as f:
        f.write("000001.jpg,0.15\nnotes.txt,0.16\n000001.gif,0.17\n")
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(root)
    assert ds.missing == () and list(ds.stamps) == [0.0, 0.1, 0.2]
    assert "3 frames are files of a kind" in caplog.text and "first: 000001.jpg" in caplog.text
    assert _positions(ds) == ds.names


@pytest.mark.parametrize("row, said", [
    ("images/000001.png", None), ("sub/000001.png", None), ("images/000001", None),
    ("images\\000001.png", None), ("a/b\\000001", None),  # trial I: a Windows folder
    ("C:000001.png", None), ("c:000001", None),  # trial J: a Windows drive, no separator
    ("C:images\\000001.png", None), ("D:\\rec\\000001.png", None),
    ("000001.PNG", "line 3: '000001.PNG' is no image in images/; frame 000001's image is"
                   " 000001.png"),
    ("images/000001.jpg", "no stamp for image 000001.png (line 3's 'images/000001.jpg' is a"
                          " file of another kind)"),
    # trial J: a row that names no image is named with the image no row lists
    ("000009.png", "no stamp for image 000001.png (no row lists it; line 3's '000009.png'"
                   " names no image in images/, a deleted frame)"),
    ("C|000001.png", "no stamp for image 000001.png (no row lists it; line 3's"
                     " 'C|000001.png' names no image"),
])
def test_a_frame_is_listed_by_its_file_name_or_stem_in_any_folder(tmp_path, row, said):
    """Trial H (H7): a row images/000000.png for an existing image gave "no stamp for image
    000000.png", naming neither the line nor the row. A row names a frame by its file name
    or stem whatever folder it names (as a deleted frame's row keeps its place by its file
    name, trial G); a row naming the frame by another file name is refused naming its line."""
    root = _dataset(tmp_path / "ds", n=3)
    text = (root / "frames.csv").read_text().replace("000001.png", row)
    (root / "frames.csv").write_text(text)
    if said is None:
        assert list(open_dataset(root).stamps) == [0.0, 0.1, 0.2]
    else:
        with pytest.raises(DatasetError, match=re.escape(said)):
            open_dataset(root)


def test_an_image_no_row_lists_names_the_row_that_names_its_stem(tmp_path):
    """Trial J (J6): of the rows that name no image, the message of an image no row lists
    names the one whose frame holds the image's stem, not merely the first: with deleted
    frames listed before it, that is the row meant for the image."""
    root = _dataset(tmp_path / "ds", n=3)
    text = (root / "frames.csv").read_text().replace("000001.png", "cam0|000001.png")
    (root / "frames.csv").write_text(text.replace("000000.png,", "000009.png,0.01\n000000.png,"))
    with pytest.raises(DatasetError, match=re.escape(
            "no stamp for image 000001.png (no row lists it; line 4's 'cam0|000001.png'")):
        open_dataset(root)


@pytest.mark.parametrize("row, said", [
    ("images", "names a folder, not a frame's image"),
    ("sub", "names a folder, not a frame's image"),
    ("cam\\inner", "names a folder, not a frame's image"),
    ("C:", "names a folder, not a frame's image"),
    (".png", "names no frame: its file name has no stem before its suffix"),
    ("images\\.PNG", "names no frame: its file name has no stem before its suffix"),
    (".txt", "names no frame: its file name has no stem before its suffix"),
    ("..png", "names a hidden file, which is no frame"),
    (".thumb.png", "names a hidden file, which is no frame"),
    ("images\\.x.png", "names a hidden file, which is no frame"),
])
def test_a_row_naming_a_folder_or_no_stem_is_refused_naming_its_line(tmp_path, row, said):
    """Trial I (I3, I5): a row "images" (the images folder's name, without a slash) was a
    deleted frame "images", and a row ".png" (a hidden file images/.png beside it) a deleted
    frame ".png" at position 0: each took a frame position. A row whose stem is the images
    folder's name or a folder's in the dataset or in images/, or whose file name has no stem
    before its suffix, is refused naming its line; so is a row naming a hidden file with a
    stem (trial J: ".thumb.png" was a deleted frame ".thumb" that sorted first)."""
    root = _dataset(tmp_path / "ds", n=3)
    (root / "sub").mkdir()
    (root / "images" / "inner").mkdir()
    (root / "images" / ".png").write_bytes((root / "images" / "000000.png").read_bytes())
    with open(root / "frames.csv", "a") as f:
        f.write(f"{row},0.15\n")
    with pytest.raises(DatasetError, match=re.escape(f"frames.csv: line 5: '{row}' {said}")):
        open_dataset(root)


@pytest.mark.parametrize("image, row, how", [
    ("a0.png", "A0.png", "letter case"),
    ("a0.png", "images/A0", "letter case"),
    ("caf\u00e9.png", "cafe\u0301.png", "Unicode normalisation (NFC, NFD)"),
    ("caf\u00e9.png", "CAFE\u0301.png", "letter case and Unicode normalisation"),
])
def test_a_row_naming_an_image_but_for_case_or_normalisation_is_refused_naming_its_line(
        tmp_path, image, row, how):
    """Trial I (I6): a row A0.png for image a0.png, or café.png written NFD (as macOS
    writes file names) for an NFC file name, was refused as "no stamp for image a0.png",
    naming neither the line nor the row; as a row 000001.PNG for 000001.png is, it is refused
    naming its line, its row and how the names differ."""
    root = _dataset(tmp_path / "ds", n=2)
    (root / "images" / image).write_bytes(cv2.imencode(".png", _rgb(3))[1].tobytes())
    with open(root / "frames.csv", "a", encoding="utf-8") as f:
        f.write(f"{row},0.2\n")
    with pytest.raises(DatasetError, match=re.escape(
            f"frames.csv: line 4: '{row}' is no image in images/; image {image} differs from"
            f" it only in {how}")):
        open_dataset(root)


def test_a_dataset_given_without_its_images_keeps_its_listed_frames(tmp_path, caplog):
    """A dataset folder of frames.csv and no images (show belief given a features file):
    its listed frames are frames whose image is missing, not rows of another kind."""
    (tmp_path / "frames.csv").write_text("name,stamp\n000000.png,0.0\n000001.jpg,0.1\n")
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(tmp_path, need_images=False)
    assert ds.missing == ("000000.png", "000001.jpg") and caplog.text == ""


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 50), st.integers(1, 4))
def test_a_zero_padded_number_is_a_name_never_a_position(n, pad):
    """Trial H: with 000001.png deleted, `--frame 000001` was read as position 1 and drew
    frame 000002 with exit 0. A position is a plain whole number; a zero-padded one (or one
    with a sign or spaces) that names no frame is refused as a name, whatever it would count
    to."""
    names = [f"{i:06d}" for i in range(0, 60, 2)]  # the odd frames deleted
    padded = "0" * pad + str(n)
    if padded in names:
        assert frame_index(names, padded, "d") == names.index(padded)
    else:
        with pytest.raises(DatasetError, match="no frame named"):
            frame_index(names, padded, "d")
    for written in (f"+{n}", f" {n}", f"{n} "):
        with pytest.raises(DatasetError, match="no frame named"):
            frame_index(names, written, "d")
    if n < len(names):
        assert frame_index(names, str(n), "d") == n  # a plain number is a position


def test_two_images_whose_names_differ_only_in_unicode_form_are_refused(tmp_path):
    """Trial J (J3): café.png written NFC and NFD (two files on Linux) were two frames
    "café" in every table, which no one could tell apart: refused as two images of one
    frame, saying how their names differ."""
    root = tmp_path / "ds"
    (root / "images").mkdir(parents=True)
    for name in ("caf\u00e9.png", "cafe\u0301.png"):
        cv2.imwrite(str(root / "images" / name), _rgb(3))
    with pytest.raises(DatasetError, match=r"differ only in Unicode form\); rename or remove one"):
        open_dataset(root)


@pytest.mark.parametrize("file, typed", [("cafe\u0301", "caf\u00e9"), ("caf\u00e9", "cafe\u0301")])
def test_a_frame_typed_in_another_unicode_form_is_found(tmp_path, file, typed):
    """Trial J (J4): `--frame café` typed NFC for a file whose name is NFD (as macOS writes
    them) said "no frame named 'café'" though every listing printed café: the frame a user's
    --frame names (Dataset.frame_at, show points and show belief's reading) is found by the
    name's composed form."""
    root = tmp_path / "ds"
    (root / "images").mkdir(parents=True)
    for name in (file, "z0"):
        cv2.imwrite(str(root / "images" / f"{name}.png"), _rgb(3))
    ds = open_dataset(root)
    assert ds.names[ds.frame_at(typed)] == file
    with pytest.raises(DatasetError, match="no frame named"):
        ds.frame_at("cafe")
