"""Dataset folders (GUIDE section 4): what users bring and what ``fieldloc simulate`` writes.

    DIR/images/        frames, sorted by name (png, jpg, bmp, tiff or webp)
    DIR/frames.csv     optional: name, stamp (s) per image; without it a numeric file stem is
                       the stamp, otherwise frame index / 30 Hz
    DIR/calib.yaml     camera model (see stages.common.camera)
    DIR/odometry.csv   optional: stamp, dx, dy, dtheta (robot frame, since previous frame)
    DIR/imu.csv        optional: stamp, yaw, collision
    DIR/truth.csv      optional: stamp, x, y, theta (field frame)
    DIR/head.csv       optional, perspective cameras: stamp, pitch, roll of the camera (rad),
                       optionally followed by any of yaw (rad), height (m), x, y (m: the
                       optical centre over the floor in the robot frame), for robots whose
                       head turns and whose camera height changes (imported team frames)

CSV files have a header line with exactly these column names (and, where listed in
``CSV_OPTIONAL_COLUMNS``, some of the optional ones after them); metres and radians. Every value
must be a finite number in ASCII decimal or scientific notation, of magnitude at most 1e6 except
stamps (a row without a value is left out; only truth.csv may hold NaN poses, where a motion
capture lost the robot), and the rows of
the time series (odometry, imu, truth, head) must be in time order with one row per stamp: a
file that breaks this is refused with its line number, because a NaN increment or a row out of
order cannot be placed without guessing (odometry rows are increments since the previous row).
Two images with the same stem (``000003.png`` and ``000003.jpg``) would be one frame name and
are refused too, and so is a frame frames.csv lists twice (``000003.png`` and ``000003``: which
stamp is it?) and an image whose file name is no UTF-8 (a frame's name is written as text into
every artifact). frames.csv stamps must not decrease in the frames' order (of their names),
and no row may lead out of the dataset (``..``): both refused naming the line. Which frame a
frames.csv row lists: ``_listed_frame``; frame positions: ``Dataset.frame_at``.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import os
import re
import stat
import unicodedata
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .conf import load_yaml, read_record, yaml_problem
from .dataset_layout import CSV_COLUMNS, CSV_OPTIONAL_COLUMNS, OWN_FILES, SIMULATION_RECORD
from .errors import DatasetError, file_problem, present
from .user_numbers import parse_number, user_numbers

# the image files that are frames: PNG and JPEG (what import and simulate write), and the
# other kinds OpenCV reads that teams' own tools save frames as (a robot's camera tool may
# write BMP; TIFF and WebP from image tools). Any other file in images/ is not a frame; one
# that frames.csv names is said (open_dataset)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
IMAGE_KINDS = "png, jpg, bmp, tiff or webp"
DEFAULT_RATE_HZ = 30.0

log = logging.getLogger(__name__)


TIME_SERIES = ("odometry", "imu", "truth", "head")  # rows in time order, one per stamp
# columns that may hold NaN: a motion capture that lost the robot writes a truth row without a
# pose, and a frame at that stamp is then unmatched (stages.evaluate)
NAN_ALLOWED = {"truth": ("x", "y", "theta")}


# the largest magnitude of a value other than a stamp (metres: positions, increments, heights;
# radians: angles; imu's collision is 0 or 1): a field is at most tens of metres, so 1e6 is
# far beyond any robot's, and a value such as 1e300 would overflow the arithmetic that places
# it (grid cells of a map, sums of increments) instead of meaning anything
MAX_VALUE = 1e6
# the largest magnitude of a stamp, in seconds: Unix time reaches 1e10 s in the year 2286, so a
# larger stamp is in other units (ms, ns: a ROS stamp in ns is 1.7e18) or damaged; beyond it
# the gaps between frames overflow the motion model's noise (1e299 s ended in tracebacks)
MAX_STAMP = 1e11
# rows a CSV may hold (a dataset's, --points, calibration points), counted before any is
# read (a row costs 5-15 us of checks: a 117 MB frames.csv of 5 million rows ran past a
# minute only to refuse its first row, trial P2; 4.9 million truth rows took evaluate past a
# minute, trial Q3): a rendered dataset's most frames (simulate's MAX_FRAMES, a day at 10
# Hz), a time series of 2.8 hours at 100 Hz, 5,000 frames of 200 line points
MAX_CSV_ROWS = 1_000_000
# bytes a CSV may weigh, told from its size before a byte is read: MAX_CSV_ROWS rows of 256
# bytes (a frames.csv row holds a stamp and a file name of at most 255 bytes; a truth or
# odometry row about 60); a 4 GB file was read and decoded whole for 24 s, a 40 GB one said
# "out of memory" (trial U1)
MAX_CSV_BYTES = MAX_CSV_ROWS * 256


def stamp_error(stamp: float) -> str | None:
    """Why ``stamp`` (seconds) cannot be a frame's or a row's stamp, or None: not finite, or
    beyond ``MAX_STAMP``."""
    if not math.isfinite(stamp):
        return f"stamp {stamp} is not a finite number"
    if abs(stamp) > MAX_STAMP:
        return (f"stamp {stamp:.4g} s is beyond {MAX_STAMP:g} s (the year 5000); stamps are"
                " seconds, not ms or ns")
    return None


def read_csv(path: str | Path, kind: str) -> dict[str, np.ndarray]:
    """Read one of the dataset CSVs, checking its header, that every value is a finite number
    (names excepted) and, for time series, that the stamps increase from row to row. Returns
    column -> array (frames.csv: also "line", each row's line number). Every problem is a
    DatasetError naming the file and line; frames.csv's rows are matched with the images by
    open_dataset."""
    path = Path(path)
    cols = CSV_COLUMNS[kind]
    if not present(path):
        raise DatasetError(f"file not found: {path}")
    lines = csv_rows(path)
    if not lines:
        raise DatasetError(f"{path}: empty; expected a header '{','.join(cols)}'")
    header = [h.strip() for h in lines[0][1]]
    extra = header[len(cols):]
    optional = CSV_OPTIONAL_COLUMNS.get(kind, ())
    if header[:len(cols)] != list(cols) or extra != [c for c in optional if c in extra]:
        more = f" (then any of '{','.join(optional)}')" if optional else ""
        raise DatasetError(
            f"{path}: expected columns '{','.join(cols)}'{more}, found"
            f" '{','.join(header)[:80]}'"
        )
    cols = tuple(header)
    body = lines[1:]
    if not body:
        raise DatasetError(f"{path}: no rows after the header '{','.join(cols)}'")
    values: dict[str, list] = {c: [] for c in cols}
    for line_no, row in body:
        if len(row) != len(cols):
            raise DatasetError(
                f"{path}: line {line_no}: expected {len(cols)} values ({','.join(cols)}),"
                f" found {len(row)}")
        for name, cell in zip(cols, row):
            cell = cell.strip()
            if name == "name":
                if not cell:
                    raise DatasetError(f"{path}: line {line_no}: empty name")
                values[name].append(cell)
                continue
            try:
                v = parse_number(cell)
            except ValueError:
                raise DatasetError(
                    f"{path}: line {line_no}: '{name}' is not a number ({cell[:20]!r})"
                ) from None
            if not math.isfinite(v) and not (math.isnan(v)
                                             and name in NAN_ALLOWED.get(kind, ())):
                raise DatasetError(
                    f"{path}: line {line_no}: '{name}' is {cell}; every value must be a finite"
                    " number (leave a row without a value out)")
            if name != "stamp" and abs(v) > MAX_VALUE:
                raise DatasetError(
                    f"{path}: line {line_no}: '{name}' is {cell[:20]}; no robot's value is"
                    f" larger than {MAX_VALUE:g} (metres or radians)")
            if name == "stamp" and math.isfinite(v) and (why := stamp_error(v)):
                raise DatasetError(f"{path}: line {line_no}: {why}")
            values[name].append(v)
    out = {name: (np.array(v, dtype=object) if name == "name" else np.array(v, dtype=float))
           for name, v in values.items()}
    if kind == "frames":  # the line of each row: open_dataset's messages name it
        out["line"] = np.array([line_no for line_no, _ in body], dtype=int)
    if kind in TIME_SERIES:
        st = out["stamp"]
        bad = np.flatnonzero(np.diff(st) <= 0)
        if len(bad):
            i = int(bad[0])
            what = "repeats" if st[i + 1] == st[i] else "is before"
            raise DatasetError(
                f"{path}: line {body[i + 1][0]}: stamp {float(st[i + 1])!r} {what} line"
                f" {body[i][0]}'s stamp {float(st[i])!r}; rows must be in time order, one per"
                " stamp")
    if kind == "frames":
        for line_no, nm in zip(out["line"], out["name"]):
            file = row_file_name(nm)
            if file in ("", ".", ".."):
                # a folder (images/, a/b/, ., ..) is no frame: taken for a deleted one, it
                # sorted first and shifted every position (trial H)
                raise folder_row(path, line_no, nm)
            if OTHER_KIND_SUFFIX.fullmatch(file):
                # a file name of a suffix only (.png: a hidden file, which is no frame) has
                # no stem to be a frame's name: it was a deleted frame ".png" at position 0,
                # "images/.png.png cannot be read" (trial I)
                raise DatasetError(f"{path}: line {line_no}: '{nm[:40]}' names no frame: its"
                                   " file name has no stem before its suffix")
            if file.startswith("."):
                # a hidden file (..png, .thumb.png) is never a frame (the images' listing
                # skips them): taken for a deleted frame ".thumb", it sorted first and
                # shifted every position (trial J)
                raise DatasetError(f"{path}: line {line_no}: '{nm[:40]}' names a hidden file,"
                                   " which is no frame")
    return out


def folder_row(path: Path, line_no: int, row: str) -> DatasetError:
    """The error of frames.csv (``path``)'s row ``row`` on line ``line_no`` that names a
    folder, not a frame's image: taken for a deleted frame, it would take a frame position."""
    return DatasetError(f"{path}: line {line_no}: '{row[:40]}' names a folder, not a frame's"
                        " image")


def _refuse_many_rows(path: Path, data: bytes, most: int = MAX_CSV_ROWS) -> None:
    """DatasetError where the CSV bytes ``data`` of ``path`` hold more than ``most`` rows past
    the header, counted before any is parsed (MAX_CSV_ROWS): as the CSV reader ends rows, at
    a line feed, a carriage return or the two together (counted once; trial R: rows ending
    alternately in LF and CR passed twice the cap as the larger count of either)."""
    ends = data.count(b"\n") + data.count(b"\r") - data.count(b"\r\n")
    lines = ends + (data[-1:] not in (b"", b"\n", b"\r"))  # the last row without its end
    if lines > most + 1:
        raise DatasetError(f"{path}: more than {most:,} rows; a CSV fieldloc reads holds at"
                           " most that many")


def csv_rows(path: Path) -> list[tuple[int, list[str]]]:
    """(line number, cells) of the non-empty, non-comment rows of a text CSV file of at most
    MAX_CSV_ROWS rows and MAX_CSV_BYTES bytes."""
    try:
        size = os.stat(path).st_size
        with open(path, "rb") as f:
            data = f.read(MAX_CSV_BYTES + 1)  # a file that grew since its stat: no further
        if max(size, len(data)) > MAX_CSV_BYTES:
            raise DatasetError(f"{path}: {size / 1e6:,.0f} MB, more than the"
                               f" {MAX_CSV_BYTES / 1e6:,.0f} MB a CSV fieldloc reads may weigh")
        _refuse_many_rows(path, data)
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DatasetError(
            f"{path}: not a text CSV file (binary content; is it the file you meant?)"
        ) from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot be read ({e.strerror or e})") from None
    if "\0" in text:
        raise DatasetError(f"{path}: not a text CSV file (it holds NUL bytes)")
    reader = csv.reader(io.StringIO(text, newline=""))
    out = []
    try:
        for row in reader:
            if row and any(c.strip() for c in row) and not row[0].lstrip().startswith("#"):
                out.append((reader.line_num, row))
    except csv.Error as e:
        raise DatasetError(f"{path}: line {reader.line_num}: not valid CSV ({e})") from None
    return out


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def write_csv(path: str | Path, kind: str, columns: dict) -> Path:
    from .artifacts import atomic_path

    path = Path(path)
    cols = CSV_COLUMNS[kind] + tuple(c for c in CSV_OPTIONAL_COLUMNS.get(kind, ()) if c in columns)
    n = len(columns[cols[0]])
    with atomic_path(path, suffix=".csv") as tmp:
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(cols)
            for i in range(n):
                row = []
                for c in cols:
                    v = columns[c][i]
                    row.append(v if isinstance(v, str) else f"{float(v):.6f}")
                w.writerow(row)
    return path


STAMP_SOURCES = {
    "frames.csv": "from frames.csv",
    "file names": "from the image file names (000005.png = 5 s; there is no frames.csv)",
    "frame order": f"from the frame order at {DEFAULT_RATE_HZ:g} Hz (there is no frames.csv"
                   " and the file names are not numbers)",
}


def read_simulation_record(folder: str | Path):
    """The parsed simulation.yaml of ``folder`` (what ``fieldloc simulate`` records), read only
    where it is a regular file (a FIFO blocks a read) of at most conf.MAX_RECORD_BYTES (a 2 GB
    one was read for 16 s, trial U1) as UTF-8 YAML; OSError (``strerror`` the reason),
    UnicodeDecodeError or yaml.YAMLError (an alias bomb included) otherwise."""
    p = Path(folder) / SIMULATION_RECORD
    why = file_problem(p)
    if why is not None:
        raise OSError(0, why)
    return load_yaml(read_record(p).decode())


@dataclass
class Dataset:
    root: Path
    images: list[Path]
    stamps: np.ndarray
    stamp_source: str = "frames.csv"  # a key of STAMP_SOURCES: where the frame stamps come from
    # the camera's calib.yaml when it is not the folder's own (one learnt from a recording,
    # stages.pipelines.images_to_poses); None: root/calib.yaml
    calib: Path | None = None
    # the names frames.csv lists whose image is not in images/ (deleted since): not frames,
    # but they keep their places when a frame is given by its position (``frame_at``)
    missing: tuple[str, ...] = ()

    @property
    def names(self) -> list[str]:
        return [p.stem for p in self.images]

    def frame_at(self, frame: str | int) -> int:
        """The index in ``names`` of a frame given by its name or its position (0-based), as
        ``frame_index``: the one reading of a user's ``--frame`` (show points, show belief).
        A frame's position is its place in the order of the frames' file names (the order
        of features.h5's and poses.h5's rows), the frames frames.csv lists whose image is
        missing counted in their places (by their file names, whatever folder a row
        names; listed by its stem, as a file of the images' suffix), so that a frame keeps
        its position when another's image is deleted (the rows of the artifacts made
        before); a row naming a file of another kind
        (``_listed_frame``: x.txt, a .gif) is no frame and takes no place. A missing frame is
        refused in one line: with 000000.png deleted, "--frame 0" drew frame 000001 (and
        "--frame 000000", read as position 0, too) without a word."""
        if not self.missing:
            return frame_index(self.names, frame, str(self.root))
        order = [(p.name, p.stem, None) for p in self.images]
        suffix = self.images[0].suffix if self.images else ""
        for listed in self.missing:  # each frame once (open_dataset refuses one twice)
            # sorted by its file name, whatever folder the row names (images/ has none)
            name, file = row_frame_name(listed), row_file_name(listed)
            order.append((file if name != file else file + suffix, name, listed))
        order.sort()
        names = [name for _file, name, _listed in order]
        i = frame_index(names, frame, str(self.root))
        file, name, listed = order[i]
        if listed is None:
            return self.names.index(name)
        # the file looked for is in images/, whatever folder the row names: the path built
        # from the row (images/../../etc/000001.png) was not where fieldloc looked (trial I)
        row = "" if listed == file else f" as '{listed[:40]}'"
        raise DatasetError(f"{self.root}: frame {name[:40]}'s image"
                           f" {self.root / 'images' / file[:40]} cannot be read: there"
                           f" is no such file (frames.csv lists it{row})")

    @property
    def calib_path(self) -> Path:
        return self.calib if self.calib is not None else self.root / "calib.yaml"

    def camera(self):
        from .camera import load_calib

        return load_calib(self.calib_path)

    def optional(self, kind: str) -> dict[str, np.ndarray] | None:
        p = self.root / f"{kind}.csv"
        return read_csv(p, kind) if present(p) else None

    def field_record(self) -> dict:
        """The field the dataset was recorded on, where the dataset says so: the ``field``
        (name) and ``field_size`` ([length, width], m; newer datasets) of simulation.yaml, the
        record ``fieldloc simulate`` writes. {} when the dataset does not say; a size that is
        not two finite numbers > 0 is refused (DatasetError). A record that cannot be read
        (no regular file, not YAML, an alias bomb) is {} with one warning naming it and why:
        the record only names the field, the run needs it not."""
        p = self.root / SIMULATION_RECORD
        if file_problem(p) == "not found":
            return {}
        import yaml

        try:
            d = read_simulation_record(self.root)
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
            if isinstance(e, yaml.YAMLError):
                reason = f"not YAML: {yaml_problem(e, read_record(p).decode())}"
            else:
                reason = "not UTF-8 text" if isinstance(e, UnicodeDecodeError) else \
                    e.strerror or str(e)
            log.warning("%s: ignored, the field it records is not read (%s)", p, reason[:100])
            return {}
        if not isinstance(d, dict) or not isinstance(d.get("field"), str):
            return {}
        out = {"name": d["field"]}
        size = d.get("field_size")
        if size is not None:
            size = user_numbers(size, f"{p}: field_size", count=2, finite=False,
                                error=DatasetError)
            if not all(math.isfinite(v) and v > 0 for v in size):
                # recorded with the features, it would be taken for the field's size
                raise DatasetError(f"{p}: field_size {str(size)[:40]} must be two finite"
                                   " numbers > 0 (m)")
            out["size"] = size
        return out

    def files(self) -> dict[str, list[Path]]:
        """The dataset's own files that exist (role -> paths): what no command may write over."""
        out = {"images": list(self.images)}
        for name in OWN_FILES:
            if (self.root / name).exists():
                out[name] = [self.root / name]
        return out


def open_dataset(root: str | Path, *, need_images: bool = True) -> Dataset:
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"dataset folder not found: {root}")
    img_dir = root / "images"
    try:
        images = (
            sorted(p for p in img_dir.iterdir()
                   if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))
            if img_dir.is_dir()
            else []
        )
    except OSError as e:
        raise DatasetError(f"{img_dir}: cannot be listed ({e.strerror or e})") from None
    if need_images and not images:
        raise DatasetError(f"{root}: no images ({IMAGE_KINDS}) in {img_dir}")
    from .artifacts import storable_text

    by_stem: dict[str, Path] = {}  # by the stem's NFC form (``nfc``)
    for p in images:
        if storable_text(p.name) != p.name:
            raise DatasetError(
                f"{img_dir}: image file name {storable_text(p.name)[:40]} is not UTF-8 text;"
                " frame names are written as text into every artifact: rename it")
        # two stems that differ only in Unicode normalisation (café NFC and NFD) print alike:
        # two frames "café" in every table could not be told apart (trial J)
        other = by_stem.get(nfc(p.stem))
        if other is not None:
            alike = "" if other.stem == p.stem else " (their names differ only in Unicode form)"
            raise DatasetError(
                f"{img_dir}: {other.name[:40]} and {p.name[:40]} would both be frame"
                f" '{p.stem[:40]}'{alike}; rename or remove one")
        by_stem[nfc(p.stem)] = p
    frames = root / "frames.csv"
    gone: tuple[str, ...] = ()
    if present(frames):
        stamps, gone, other = _listed_frames(frames, read_csv(frames, "frames"), images)
        source = "frames.csv"
        if other and str(frames) not in _SAID_OTHER_KINDS:  # a frame the user listed, left
            _SAID_OTHER_KINDS.add(str(frames))  # out: said once, however often it is opened
            log.warning("%s: %d frames are files of a kind fieldloc does not read or none of"
                        " the images is (first: %s; it reads %s); left out", frames,
                        len(other), str(other[0])[:40], IMAGE_KINDS)
    elif images and all(_is_float(p.stem) and stamp_error(float(p.stem)) is None
                        for p in images):
        stamps = np.array([float(p.stem) for p in images])
        source = "file names"
    else:
        stamps = np.arange(len(images)) / DEFAULT_RATE_HZ
        source = "frame order"
    return Dataset(root=root, images=images, stamps=stamps, stamp_source=source, missing=gone)


# the frames.csv files whose frames of other image kinds were said (open_dataset): a command
# opens its dataset more than once
_SAID_OTHER_KINDS: set[str] = set()


def nfc(text: str) -> str:
    """``text`` in Unicode's composed form (NFC): names that print alike compare alike."""
    return unicodedata.normalize("NFC", text)


# the folder part of a frames.csv row: all up to its last / or \\, or a leading Windows drive
# letter (C:000001.png is 000001.png in drive C's current folder)
ROW_FOLDER = re.compile(r"^(?:.*[/\\]|[A-Za-z]:)", re.DOTALL)


def row_file_name(row: str) -> str:
    """The file name a frames.csv row gives: all after its folder part (``ROW_FOLDER``), which
    is no part of it (the frames are the files in images/). A backslash is a folder
    separator too, of a frames.csv written on Windows (``images\\000001.png``): Path(row).name
    does not split at it on Linux, and a deleted ``cam\\000001.png`` became a missing frame
    named ``cam\\000001`` that sorted last, so that ``--frame 1`` drew frame 000002 (trial
    I). So is a leading drive letter without a separator (``C:000001.png``, Windows' name of
    a file in drive C's current folder): read whole, it was a deleted frame ``C:000001``, and
    the image 000001.png had "no stamp" naming no line (trial J)."""
    return ROW_FOLDER.sub("", row, count=1)


def row_frame_name(file_name: str) -> str:
    """The frame name of an image file name as frames.csv gives it (its stem; a name given
    without an image suffix is the frame name itself: 1687078170.100, f1.v2); a folder it
    names is no part of it (``row_file_name``)."""
    name = row_file_name(file_name)
    return Path(name).stem if Path(name).suffix.lower() in IMAGE_SUFFIXES else name


# image suffixes of one kind: a deleted frame 000001.jpeg among .jpg frames is a JPEG frame
SAME_KIND = {".jpeg": ".jpg", ".tif": ".tiff"}


def _image_kind(suffix: str) -> str:
    """The kind of image a suffix (of IMAGE_SUFFIXES, any case) is: .jpg for .JPEG too."""
    suffix = suffix.lower()
    return SAME_KIND.get(suffix, suffix)


# the suffix of a file of another kind than an image: a dot and letters only (notes.txt,
# x.gif, a.yaml). A dot followed by anything else is part of a frame's name as frames.csv
# lists it by its stem (a timestamp 1687078170.100, a version f1.v2: trial H, whose deleted
# f1.v2 was taken for a file of kind "v2" and took no frame position)
OTHER_KIND_SUFFIX = re.compile(r"\.[A-Za-z]+")


def _listed_frame(row: str, images: dict[str, str], kinds: set[str]) -> str | None:
    """The frame a frames.csv row lists, or None for a row of another kind, which is no frame
    and takes no frame position (``Dataset.frame_at``). A row is read by its file name,
    whatever folder it names: the frame of an image in images/ of that file name or stem
    (``images``: file name and stem -> stem); else a frame whose image is missing (deleted
    since) if it is a file of one of the dataset's image kinds (``kinds``, as
    ``_image_kind``: in a folder of PNG and JPG frames, both) or a stem (no suffix of letters
    only); else (x.txt, a .gif, a .jpg among PNG frames) of another kind."""
    name = row_file_name(row)
    if name in images:
        return images[name]
    stem, suffix = os.path.splitext(name)  # Path's, at a fifth of its cost a row
    if suffix.lower() in IMAGE_SUFFIXES:
        return stem if _image_kind(suffix) in kinds else None
    return None if OTHER_KIND_SUFFIX.fullmatch(suffix) else name


def _listed_frames(path: Path, tab: dict[str, np.ndarray],
                   images: list[Path]) -> tuple[np.ndarray, tuple[str, ...], list[str]]:
    """The stamps of ``images`` from frames.csv (``path``, read as ``tab``), the rows that
    list frames whose image is missing (``Dataset.missing``) and the rows of another kind
    (``_listed_frame``). A frame listed twice (by its file name and its stem: which stamp
    is it?) is refused naming both lines, and so is an image no row lists, naming the row
    that lists its frame by another file name (000001.PNG, 000001.jpg beside JPG frames)
    or as a file of another kind (000001.jpg among PNG frames), or by its stem in another
    letter case or Unicode normalisation (``_refuse_near_name``)."""
    by_file = {p.name: p.stem for p in images} | {p.stem: p.stem for p in images}
    # the image kinds of the frames (any, for a dataset given without its images)
    kinds = {_image_kind(p.suffix) for p in images} or set(map(_image_kind, IMAGE_SUFFIXES))
    listed: dict[str, tuple[int, str, float]] = {}  # frame -> its row's line, text, stamp
    other: list[tuple[int, str]] = []  # the rows of another kind: line, text
    for line_no, row, stamp in zip(tab["line"], tab["name"], tab["stamp"]):
        if ".." in row and ".." in re.split(r"[/\\]", row)[:-1]:  # its file name was read
            raise DatasetError(f"{path}: line {line_no}: '{row[:40]}' leads out of the dataset"
                               " (..); a row names an image in images/")
        # a root path (/data/D/images/000002.png) was matched by its file name alone (O9);
        # a Windows drive's (D:\rec\000002.png) is a recording's own list, read so (trial J)
        if row.startswith(("/", "\\")):
            raise DatasetError(f"{path}: line {line_no}: '{row[:40]}' is an absolute path; a"
                               " row names an image in images/")
        frame = _listed_frame(row, by_file, kinds)
        if frame is None:
            other.append((int(line_no), row))
        elif frame in listed:
            first_line, first, _ = listed[frame]
            also = "" if first == row else f" as '{first[:40]}'"
            raise DatasetError(f"{path}: line {line_no}: frame '{frame[:40]}' is given twice"
                               f" (line {first_line}{also})")
        else:
            listed[frame] = int(line_no), row, float(stamp)
    stamps = []
    have = {p.stem for p in images}
    before = None  # (line, frame, stamp) of the frame before
    for p in images:
        if p.stem not in listed:
            _refuse_near_name(path, p, {f: v for f, v in listed.items() if f not in have})
            # a row of another kind of its stem (000001.jpg among PNG frames) is said
            near = next((f" (line {ln}'s '{r[:40]}' is a file of another kind)"
                         for ln, r in other if row_frame_name(r) == p.stem), "")
            # else a row of another kind holding its name (000000.png:Zone.Identifier, an
            # NTFS stream's name, is a file of kind .Identifier): it named no line (trial L)
            near = near or _unmatched_row(listed, have, p.stem) or next(
                (f" (no row lists it; line {ln}'s '{r[:40]}' is read as a file of another"
                 " kind)" for ln, r in other if p.stem in r), "")
            raise DatasetError(f"{path}: no stamp for image {p.name}{near}")
        line_no, row, stamp = listed[p.stem]
        if row_file_name(row) not in (p.name, p.stem):
            raise DatasetError(f"{path}: line {line_no}: '{row[:40]}' is no image in images/;"
                               f" frame {p.stem[:40]}'s image is {p.name[:40]}")
        if before is not None and stamp < before[2]:  # a frame is placed by its name
            raise DatasetError(
                f"{path}: line {line_no}: frame {p.stem[:40]}'s stamp {stamp!r} is before frame"
                f" {before[1][:40]}'s {before[2]!r} (line {before[0]}); stamps must not"
                " decrease in the order of the frames' names")
        before = line_no, p.stem, stamp
        stamps.append(stamp)
    gone = []
    # the folders of the dataset and of images/, and the files in images/, listed once (a
    # stat a row took 13 s of a million rows, trial W2-1)
    folders = {e.name for e in _entries(path.parent) if e.is_dir()}
    in_images = {e.name: e.is_dir() for e in _entries(path.parent / "images")}
    for frame, (line_no, row, _) in listed.items():
        if frame in have:
            continue
        # a missing frame listed by a stem that is a folder's name (images, or a folder in
        # the dataset) is that folder: a row "images" was a deleted frame "images" (trial I)
        if frame == row_file_name(row) and (
                frame == "images" or frame in folders or in_images.get(frame)):
            raise folder_row(path, line_no, row)
        if in_images.get(row_file_name(row)) is False:
            # its file is in images/, of a kind not read (000002.jp2: a stem with a suffix
            # of digits, trial V2-3): no deleted frame, a row of another kind (said once)
            other.append((int(line_no), row))
        else:
            gone.append(row)
    return np.array(stamps, float), tuple(gone), [row for _, row in other]


def _entries(folder: Path) -> list[os.DirEntry]:
    """The entries of ``folder`` (none where it is no folder one may list)."""
    try:
        with os.scandir(folder) as it:
            return list(it)
    except OSError:
        return []


def _unmatched_row(listed: dict[str, tuple[int, str, float]], have: set[str],
                   stem: str) -> str:
    """What the message of an image no frames.csv row lists (stem ``stem``) says of the rows
    that name no image (``listed``: frame -> line, row, stamp; ``have``: the images' stems):
    the line of one, the first whose frame's name holds ``stem`` (cam0-000001.png for
    000001.png) or else the first, since it may be the row meant for the image; nothing where
    every row names an image. A row read as a deleted frame that no image matched ended in
    "no stamp for image ..." naming no line (trial J: C:000000.png)."""
    rows = sorted((stem not in frame, line_no, row) for frame, (line_no, row, _)
                  in listed.items() if frame not in have)
    if not rows:
        return ""
    _, line_no, row = rows[0]
    return (f" (no row lists it; line {line_no}'s '{row[:40]}' names no image in images/, a"
            " deleted frame)")


def _refuse_near_name(path: Path, image: Path,
                      missing: dict[str, tuple[int, str, float]]) -> None:
    """Refuse, naming its line, the frames.csv (``path``) row of a missing frame (``missing``:
    frame -> line, row, stamp) whose name is ``image``'s stem but for letter case or Unicode
    normalisation (A0.png for a0.png; café written NFD for an NFC file name): the image had
    "no stamp" without a line (trial I), where the row was meant for it."""
    for frame, (line_no, row, _) in missing.items():
        if nfc(frame).casefold() != nfc(image.stem).casefold():
            continue
        how = ("Unicode normalisation (NFC, NFD)" if nfc(frame) == nfc(image.stem) else
               "letter case" if frame.casefold() == image.stem.casefold() else
               "letter case and Unicode normalisation")
        raise DatasetError(f"{path}: line {line_no}: '{row[:40]}' is no image in images/;"
                           f" image {image.name[:40]} differs from it only in {how}")


# a frame position as a user writes it: a whole number without leading zeros (a negative one
# is refused as out of range). A zero-padded number is a frame's name: with 000001.png deleted,
# `--frame 000001` was read as position 1 and drew frame 000002 (trial H)
POSITION = re.compile(r"-?(0|[1-9][0-9]*)")


def frame_index(names: list[str], frame: str | int, where: str) -> int:
    """The index of a frame given by its name, or else by its position in ``names`` (0-based,
    written as ``POSITION``). An unknown name or a position out of range is a user error
    naming ``where``; so is a negative position (Python's "from the end" would draw another
    frame than the one asked for, silently, where a mistyped number is likelier than a wish
    for the last frame)."""
    frame = str(frame)
    if frame in names:
        return names.index(frame)
    # typed in another Unicode form than the file's (café NFC for an NFD file name, as macOS
    # writes them): the name every listing prints, not found (trial J)
    alike = [k for k, n in enumerate(names) if nfc(n) == nfc(frame)]
    if len(alike) == 1:
        return alike[0]
    if not POSITION.fullmatch(frame):  # 000001, +1, " 1": a name, never a position
        raise DatasetError(f"{where}: no frame named '{frame[:40]}'")
    i = int(frame)
    if not 0 <= i < len(names):
        raise DatasetError(f"{where}: frame index {str(i)[:40]} out of range"
                           f" (0..{len(names) - 1})")
    return i


TRUTH_TOLERANCE = 0.05  # s: the largest stamp difference of a frame and its truth row


def truth_at(truth: dict[str, np.ndarray] | None, stamp: float,
             tolerance: float = TRUTH_TOLERANCE) -> np.ndarray | None:
    """The true pose (x, y, theta) of the ``truth`` row (truth.csv columns) nearest to
    ``stamp``, or None when there is no truth or no row within ``tolerance`` s."""
    if truth is None or len(truth["stamp"]) == 0:
        return None
    i = int(np.argmin(np.abs(truth["stamp"] - stamp)))
    if abs(truth["stamp"][i] - stamp) > tolerance:
        return None
    return np.array([truth["x"][i], truth["y"][i], truth["theta"][i]], dtype=float)


def readable_truth(dataset_dir) -> dict[str, np.ndarray] | None:
    """truth.csv of the dataset folder ``dataset_dir``, or None when there is no folder, no
    truth.csv, or one that cannot be read (a picture then goes without the truth)."""
    if not dataset_dir:
        return None
    p = Path(dataset_dir) / "truth.csv"
    if not p.is_file():
        return None
    try:
        return read_csv(p, "truth")
    except DatasetError:
        return None


# the most pixels an image may have: 64 M (an 8K frame has 33 M). A PNG's header can claim up
# to 4 G x 4 G pixels in 33 bytes (a JPEG's 65535 x 65535, a TIFF's or a WebP's in a few
# hundred kilobytes 20000 x 20000), and the decoder would reserve the memory for it before
# finding the data short (or stop at its own assertion); a camera frame is far smaller. Also
# OpenCV's own limit (stages/__init__.py), for a header stages.common.image_header cannot read
MAX_IMAGE_PIXELS = 1 << 26


def too_many_pixels(width: int, height: int) -> str | None:
    """Why an image of ``width`` x ``height`` px is not read (more than MAX_IMAGE_PIXELS), or
    None: the one wording of the bound, for the readers and for the importers that would
    otherwise write a frame the readers refuse."""
    if width * height > MAX_IMAGE_PIXELS:
        return f"{width} x {height} px, more than the {MAX_IMAGE_PIXELS:,} pixels fieldloc reads"
    return None


def read_image(path: Path) -> np.ndarray:
    """Read an image as BGR uint8, its pixels as stored (``decode_image_bytes``); raises
    DatasetError if unreadable (callers skip the frame). Decoded by ``decode_image_bytes``."""
    return _decode_image(path, "image")[0]


def read_frame(path: Path) -> tuple[np.ndarray, str]:
    """The image of a frame (as ``read_image``) and what identifies its file's content
    (``image_identity``), from one read of the file: extract records it with the frame's
    features, so that features are never taken for another recording's frames."""
    return _decode_image(path, "image")


def image_identity(data: bytes) -> str:
    """What identifies the content of an image file ``data``: "<size in bytes>:<CRC-32 of the
    bytes, 8 hex digits>". Two datasets' frames of one name and stamp (every simulated
    dataset's, 000000.png at 0 s) differ in it, and so does a frame re-encoded after its
    features were extracted (other images: other features). CRC-32 by ISA-L: 0.03 ms for a
    400 kB frame, nothing next to decoding it."""
    from isal import isal_zlib

    return f"{len(data)}:{isal_zlib.crc32(data):08x}"


def file_size_identity(path: Path, recorded: str) -> str | None:
    """``recorded`` (an ``image_identity``) where the file at ``path`` has its size, else
    the file's size with no CRC, or None where it cannot be read: what ``image_identity``
    tells without reading the file."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    if not stat.S_ISREG(st.st_mode):
        return "(not a regular file)"
    size = st.st_size
    return recorded if recorded.partition(":")[0] == str(size) else f"{size}:(not read)"


def file_identity(path: Path) -> str | None:
    """``image_identity`` of the file at ``path``, "(not a regular file)" where something
    else stands at its name (a FIFO, whose read would block forever; a folder), or None
    where nothing is there or it cannot be read."""
    path = Path(path)
    if not path.is_file():
        return "(not a regular file)" if os.path.lexists(path) else None
    try:
        return image_identity(path.read_bytes())
    except OSError:
        return None


def _decode_image(path: Path, what: str) -> tuple[np.ndarray, str]:
    """The one reader of every image a user gives (frames, masks, calibration pictures): the
    BGR uint8 image at ``path`` and its ``image_identity``, or a DatasetError "unreadable
    ``what``: path (why)" for a file that is not a regular file, empty, or that
    ``decode_image_bytes`` cannot decode."""
    path = Path(path)
    if not path.is_file():  # a FIFO would block the read forever
        raise DatasetError(f"unreadable {what}: {path} (not a regular file)")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise DatasetError(f"unreadable {what}: {path} ({e.strerror or e})") from None
    if not data:
        raise DatasetError(f"unreadable {what}: {path} (empty file)")
    img, why = decode_image_bytes(data)
    if img is None:
        raise DatasetError(f"unreadable {what}: {path}" + (f" ({why})" if why else ""))
    return img, image_identity(data)


def decode_image_bytes(data: bytes, *,
                       unchanged: bool = False) -> tuple[np.ndarray | None, str | None]:
    """(image, None): the image decoded from the bytes of an image file, BGR uint8 as OpenCV's
    IMREAD_COLOR | IMREAD_IGNORE_ORIENTATION gives it (its depth and channels as stored,
    OpenCV's IMREAD_UNCHANGED, with ``unchanged``); or
    (None, why it cannot be decoded), the why None where all that is known is that OpenCV
    cannot decode it; callers turn that into their own one-line error. Nothing is
    printed on stderr but by OpenCV for what only it reads (quiet_opencv): a header claiming
    more than MAX_IMAGE_PIXELS is refused before decoding (stages.common.image_header); PNG
    frames of 8-bit grey or RGB are decoded by stages.common.png in about half of OpenCV's
    time, JPEG files by libjpeg-turbo through simplejpeg, which returns libjpeg's warnings
    instead of printing them (stages.common.jpeg: a damaged scan is unreadable); a PNG or JPEG
    file that libpng or libjpeg would complain of on stderr is not given to OpenCV
    (image_damage); every other file goes to OpenCV. The one decoder of every image read.

    The pixels are the file's as stored: an EXIF Orientation (a JPEG's APP1, a PNG's eXIf, a
    TIFF's or WebP's) is not applied, as OpenCV's IMREAD_COLOR alone would apply it. A robot
    camera's frames are its sensor's pixels, which its calibration (image size, mirror
    centre, intrinsics) describes; a frame turned upright by a tag some tool wrote would be
    another image of another size, its mirror centre moved (trial U2, U2-4)."""
    from .image_header import image_size
    from .jpeg import DamagedJPEG, UnreadJPEG, decode_jpeg
    from .png import SIGNATURE, decode_png, png_for_opencv

    if data.startswith(JPEG_SOI):
        # walked before libjpeg reads the header (image_size), which keeps each of millions of
        # empty segments (0.7 GB, 1 s): image_damage refuses more than a camera's file has
        why = image_damage(data)
        if why is not None:
            return None, why
    size = image_size(data)
    if size is not None and (why := too_many_pixels(*size)):
        return None, f"its header claims {why}"
    if data.startswith(SIGNATURE):
        img = None if unchanged else decode_png(data)
        if img is not None:
            return img, None
        data = png_for_opencv(data)  # checked, given to libpng without ancillary chunks
        if data is None:
            return None, "a PNG file cut short or damaged"
        return _opencv_decode(data, unchanged), None
    if data.startswith(JPEG_SOI):
        try:
            img = decode_jpeg(data, unchanged=unchanged)
        except DamagedJPEG as e:
            return None, f"a damaged JPEG file: {e}"
        except UnreadJPEG as e:
            return None, str(e)
        if img is not None:
            return img, None
    return _opencv_decode(data, unchanged), None


def _opencv_decode(data: bytes, unchanged: bool) -> np.ndarray | None:
    """OpenCV's image of the file ``data`` (IMREAD_UNCHANGED, or IMREAD_COLOR with
    IMREAD_IGNORE_ORIENTATION: pixels as stored), or None."""
    cv2 = quiet_opencv()
    flags = (cv2.IMREAD_UNCHANGED if unchanged
             else cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    try:
        return cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error:  # its assertions, e.g. more than OPENCV_IO_MAX_IMAGE_PIXELS
        return None


def quiet_opencv():
    """The cv2 module, its own logging silenced for the process: a file it cannot decode makes
    OpenCV print a line of its own on stderr ("[ERROR:0@0.266] global loadsave.cpp:621
    imread_ ... can't read data"), before fieldloc's one line saying the same. Set once rather
    than around each read: frames are read by several threads at once, and a level put back by
    one would let another's line through; fieldloc shows none of OpenCV's log lines."""
    import cv2

    global _OPENCV_SILENCED
    if not _OPENCV_SILENCED:
        logging_api = getattr(getattr(cv2, "utils", None), "logging", None)
        if logging_api is not None and hasattr(logging_api, "setLogLevel"):
            logging_api.setLogLevel(logging_api.LOG_LEVEL_SILENT)
        elif hasattr(cv2, "setLogLevel"):  # OpenCV builds without cv2.utils.logging
            cv2.setLogLevel(0)  # 0: silent
        _OPENCV_SILENCED = True
    return cv2


_OPENCV_SILENCED = False


JPEG_SOI, JPEG_SOS, JPEG_EOI = b"\xff\xd8", b"\xff\xda", b"\xff\xd9"


def image_damage(data: bytes) -> str | None:
    """Why the bytes of an image file are not given to a decoder, in a message's words, or None:
    a JPEG file cut short (it starts as one, SOI, and holds no end marker, EOI, after its
    first scan, SOS: an EOI cannot occur inside a scan's coded data, where a 0xff byte is
    followed by 0x00 or a restart marker; what follows the image's EOI, a vendor's trailer
    or an MPO file's second image, is not the image's and is not looked at), or a PNG file
    libpng refuses (stages.common.png.png_damaged). libjpeg and libpng report these on stderr
    themselves, not through OpenCV's logging ("Premature end of JPEG file", "libpng error:
    PNG input buffer is incomplete"): a line beside fieldloc's own (and libjpeg decodes the
    cut file, grey below the cut). (simplejpeg, which decodes JPEG files, would say
    "Premature end of JPEG file".) The first scan is found by stages.common.jpeg.first_scan,
    which refuses a file of more segments than a camera's file has (jpeg.MAX_SEGMENTS)."""
    from .jpeg import UnreadJPEG, first_scan
    from .png import png_damaged

    if data.startswith(JPEG_SOI):
        try:
            scan = first_scan(data)
        except UnreadJPEG as e:
            return str(e)
        if scan >= 0 and data.find(JPEG_EOI, scan) < 0:
            return "a JPEG file cut short: no end marker"
    if png_damaged(data):
        return "a PNG file cut short or damaged"
    return None


def read_mask(path: str | Path, image_size: tuple[int, int]) -> np.ndarray:
    """A dataset's mask image -> bool (h, w), True where the floor may be used. Pixels painted
    pure red (R >= 200, G and B <= 60; the MINHO team's convention) are excluded; a mask without
    red is read as grey levels and its dark pixels (< 128) are excluded."""
    import cv2

    path = Path(path)
    img = _decode_image(path, "mask image")[0]
    w, h = image_size
    if img.shape[:2] != (h, w):
        raise DatasetError(
            f"{path}: mask is {img.shape[1]} x {img.shape[0]} px, the images are {w} x {h}")
    red = (img[..., 2] >= 200) & (img[..., 1] <= 60) & (img[..., 0] <= 60)
    if red.any():
        return ~red
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) >= 128
