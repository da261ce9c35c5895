"""The features artifact (schema ``fieldloc.features``): per-frame features from ``extract``.

Root attributes: the common ones (see artifacts.root_attrs) plus ``camera_kind`` (omni or
perspective), ``dataset`` (folder), ``calib_hash``, ``scanlines`` (JSON of the scan-line
definition, omni only). Version 2 stores the frames as columns, each dataset of the schema as
one table of all frames' rows:

    /index/name               (N,) str   each frame's name (the image's file stem)
    /index/stamp              (N,) f8    its stamp, seconds (finite: a file with a NaN or
                                         infinite stamp is refused, as frames.csv is)
    /index/image              (N,) str   what identifies the image file the frame was
                                         extracted from, "<bytes>:<crc32>"
                                         (dataset.image_identity); "" where not recorded
                                         (files of fieldloc before it, simulated features
                                         without images). Optional.
    /rows/<dataset>           (N,) i8    the frame's rows of <dataset>; -1: the frame has none
    /data/<dataset>           (sum of rows, ...) the frames' rows one after the other, in
                              the order of /index, with a ``units`` attribute
    /failures                 (F,) strings "name: reason" of frames that were skipped

<dataset> is any of FRAME_DATASETS below; a frame's value of it is 2-D (rows, ...): its
(72, 4) ``radial`` is 72 rows of 4. A name stored twice counts with its last rows. Version
1 (still read; a resumed extract rewrites it as version 2) had a group per frame,
``/frames/<name>`` with a ``stamp`` attribute and the frame's datasets.

A frame that is not stored was not processed (or failed); re-running extract skips frames
already stored unless asked to overwrite.

Resume after an interruption (``FrameParts``): while extract runs, the finished frames are
committed every ``CHUNK_SECONDS`` as one small file in ``.<features name>.parts/`` beside the
target (written to a temporary name and renamed, so a chunk file is complete or absent), with
``run.json`` holding what the frames depend on (camera kind, calibration and mask hashes, conf,
the parts' format). A run killed at any moment (kill -9, power loss) keeps every frame but those
of its last ``CHUNK_SECONDS``, and one interrupted by Ctrl-C or an error keeps them all; the
next run with the same inputs takes them over and extracts only the rest, and one with other
inputs discards them with a warning. At the end the frames are merged into the features file
(atomically, see write_artifact) and the parts folder is removed; the target never holds a
half file.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import tempfile
import time
import zipfile
from pathlib import Path

import h5py
import numpy as np

from .artifacts import (
    MAX_FRAMES,
    MAX_ITEM_BYTES,
    PART_TAG,
    open_artifact,
    part_name,
    read_json_attr,
    stored_dataset,
    write_artifact,
    writing,
)
from .dataset import MAX_STAMP, file_identity, file_size_identity, stamp_error
from .errors import FieldlocError, SchemaError
from .scanlines import MAX_SCAN_ANGLES, MAX_SCAN_CROSSINGS
from .stops import raise_deferred_stop

log = logging.getLogger(__name__)

SCHEMA = "fieldloc.features"
VERSION = 2

# the type column of "crossings"
CROSSING_CODES = {"L": 0, "T": 1, "X": 2}

# name -> (units, dtype, description). Shapes are per frame.
FRAME_DATASETS = {
    # omnidirectional (Ribeiro et al. 2015)
    "radial": ("m", np.float32, "(72, 4) white-line crossings per radial scan line, NaN = none"),
    "spiral": ("m", np.float32, "(2, 72) first crossing radius per spiral (ccw, cw), NaN = none"),
    "points": ("m", np.float32, "(N, 2) line points in the robot frame (x forward, y left)"),
    "points_px": ("px", np.float32, "(N, 2) the same line points in the image (u, v)"),
    # perspective (Schulz et al. 2011); robot frame on the floor, bearings counter-clockwise from +x
    "boundary": ("px", np.float32, "(K, 2) field boundary polyline in the image (u, v)"),
    "line_ends": ("m", np.float32, "(L, 4) line end points on the floor x0, y0, x1, y1"),
    "line_ends_px": ("px", np.float32, "(L, 4) line end points in the image u0, v0, u1, v1"),
    "lines": ("m, rad, m, 1", np.float32,
              "(L, 4) perpendicular distance, angle of the perpendicular, length, confidence"),
    "crossings": ("1, m, rad, rad, 1", np.float32,
                  "(C, 5) type (0 L, 1 T, 2 X), distance, bearing, orientation, confidence"),
    "crossings_px": ("px", np.float32, "(C, 2) crossing positions in the image (u, v)"),
    "posts": ("m, rad, 1", np.float32, "(P, 3) goal post foot: distance, bearing, confidence"),
    "posts_px": ("px", np.float32, "(P, 2) goal post foot points in the image (u, v)"),
    "view": ("m", np.float32,
             "(V, 2) the floor the image sees below the field boundary, a polygon in the "
             "robot frame"),
}


# m: the farthest a scan line's crossing may lie (radial, spiral: distances from the robot,
# NaN = none). extract's scan lines reach at most 50 m (its bound on scanlines.max_range and
# spiral_end_radius), so a distance beyond twice that, or below 0, is damage, and was matched
# against the map's tables as if seen (every frame placed at one pose, no word said)
MAX_SCAN_DISTANCE = 100.0
SCAN_DISTANCES = ("radial", "spiral")
# the line points, in the robot frame and in the image: finite numbers, as extract writes them
POINT_DATASETS = ("points", "points_px")

CAMERA_KINDS = ("omni", "perspective")
# what every frame of a camera kind holds (extract writes these; an absent one is damage, not
# "nothing seen": an empty observation is stored as an empty array)
REQUIRED = {"omni": ("radial", "spiral", "points"),
            "perspective": ("lines", "crossings", "posts")}
# the trailing shape of each dataset (None: any length); radial and spiral from the scan lines
TRAILING = {"points": (2,), "points_px": (2,), "boundary": (2,), "line_ends": (4,),
            "line_ends_px": (4,), "lines": (4,), "crossings": (5,), "crossings_px": (2,),
            "posts": (3,), "posts_px": (2,), "view": (2,)}


# Frames are written and read in blocks of this many, in the order they were stored: one
# resize and write per dataset and block when writing, one read per dataset and block when
# reading, so a reader holds one block of features in memory however long the recording. A
# group per frame (version 1) cost HDF5 a few object headers per frame: about 0.8 ms to write
# and 0.35 ms to read an omni frame, more than localising it.
BLOCK_FRAMES = 256
# bytes of a column's storage chunk: a column's last chunk is partly empty, so small chunks
# keep small files small (200 omni frames: 836 kB, 947 kB in version 1, 1263 kB with 64 kB
# chunks; 200 KidSize frames 531 kB against 825 kB) and still read a block in a few reads
_CHUNK_BYTES = 16 << 10


def _check_datasets(arrays: dict) -> None:
    """A KeyError naming the first of ``arrays``' keys that is no dataset of the schema."""
    for key in arrays:
        if key not in FRAME_DATASETS:
            raise KeyError(f"features schema has no dataset '{key}'")


def _frame_rows(arrays: dict) -> dict[str, np.ndarray]:
    """A frame's ``arrays`` checked against the schema (_check_datasets) and as rows."""
    _check_datasets(arrays)
    return {k: _as_rows(k, v) for k, v in arrays.items()}


def _as_rows(key: str, value) -> np.ndarray:
    """``value`` as rows of column ``key``: 2-D, contiguous, in the schema's dtype (an empty
    array of any shape is no rows)."""
    dtype = FRAME_DATASETS[key][1]
    data = np.ascontiguousarray(value, dtype=dtype)
    if data.ndim == 2:
        return data
    if data.size == 0 and key in TRAILING:
        return np.zeros((0, *TRAILING[key]), dtype)
    raise ValueError(f"features dataset '{key}' of a frame must be 2-D, got shape {data.shape}")


def _columns(frames: list[dict[str, np.ndarray]], keys) -> dict[str, tuple]:
    """Per key of ``keys``, the frames' rows (``_as_rows``) as one column: (their rows one
    after the other, or None where no frame has the key; each frame's row count, -1 where it
    has none). The layout of the file's columns and of FrameParts' chunks."""
    out = {}
    for key in keys:
        rows = np.array([len(a[key]) if key in a else -1 for a in frames], np.int64)
        parts = [a[key] for a in frames if key in a]
        out[key] = (np.concatenate(parts) if parts else None, rows)
    return out


def _starts(rows: np.ndarray) -> np.ndarray:
    """Where each frame's rows start in its column, and (last) the column's length."""
    return np.concatenate([[0], np.cumsum(np.maximum(rows, 0), dtype=np.int64)])


def _append(h5: h5py.File, path: str, data: np.ndarray, units: str | None = None) -> None:
    """Append ``data``'s rows to the growable dataset ``path`` (made on first use)."""
    if path not in h5:
        row = max(1, data.dtype.itemsize * int(np.prod(data.shape[1:], dtype=np.int64)))
        chunk = (max(64, _CHUNK_BYTES // row), *data.shape[1:])
        d = h5.create_dataset(path, data=data, maxshape=(None, *data.shape[1:]), chunks=chunk,
                              track_times=False)
        if units is not None:
            d.attrs["units"] = units
        return
    d = h5[path]
    if d.shape[1:] != data.shape[1:]:
        raise ValueError(f"features column {path}: rows of shape {data.shape[1:]} where the"
                         f" file's are {d.shape[1:]}")
    n = d.shape[0]
    if len(data):
        d.resize(n + len(data), axis=0)
        d[n:] = data


def _text(values) -> list[str]:
    return [v.decode() if isinstance(v, bytes) else str(v) for v in values]


class FeaturesWriter:
    """Adds frames to a features file being written (atomically, see write_artifact), in the
    columns of the module doc. A file being resumed keeps its frames; one of version 1 has
    them moved into the columns."""

    def __init__(self, h5: h5py.File):
        self.h5 = h5
        self._failures = _text(h5.get("failures", []))
        self._names = set(_text(h5["index/name"][()])) if "index" in h5 else set()
        self._pending: list[tuple[str, float, dict[str, np.ndarray], str]] = []
        if "frames" in h5:
            old = _GroupPerFrame(h5)
            for name, stamp in zip(old.names, old.stamps):
                self.add_frame(name, float(stamp), old.read(name)[0])
            self._flush()
            del h5["frames"]

    def has(self, name: str) -> bool:
        return name in self._names

    def add_frame(self, name: str, stamp: float, arrays: dict[str, np.ndarray],
                  image: str = ""):
        """Frame ``name``: its ``stamp`` and each of ``arrays`` (the schema's datasets, 2-D)
        as its rows of that column, ``image`` the identity of the image it was extracted from
        ("" none); written with the next block. A name added again replaces the frame (its
        last rows are the ones read)."""
        self._pending.append((name, float(stamp), _frame_rows(arrays), image))
        self._names.add(name)
        if len(self._pending) >= BLOCK_FRAMES:
            self._flush()

    def _flush(self) -> None:
        if not self._pending:
            return
        pending, self._pending = self._pending, []
        stored = len(self.h5["index/name"]) if "index" in self.h5 else 0
        _append(self.h5, "index/name", np.array([n for n, _s, _a, _i in pending],
                                                dtype=h5py.string_dtype()))
        _append(self.h5, "index/stamp", np.array([s for _n, s, _a, _i in pending],
                                                 np.float64))
        images = [i for _n, _s, _a, i in pending]
        if "index/image" not in self.h5:  # frames stored by a fieldloc before the record
            images = [""] * stored + images
        _append(self.h5, "index/image", np.array(images, dtype=h5py.string_dtype()))
        keys = set(self.h5["rows"]) if "rows" in self.h5 else set()
        columns = _columns([a for _n, _s, a, _i in pending],
                           sorted(keys | {k for _n, _s, a, _i in pending for k in a}))
        for key, (data, rows) in columns.items():
            if key not in keys:  # the first frames that hold it: the stored ones do not
                rows = np.concatenate([np.full(stored, -1, np.int64), rows])
            _append(self.h5, f"rows/{key}", rows)
            if data is not None:
                _append(self.h5, f"data/{key}", data, units=FRAME_DATASETS[key][0])

    def add_failure(self, name: str, reason: str):
        self._failures = [f for f in self._failures if not f.startswith(f"{name}:")]
        self._failures.append(f"{name}: {reason}")

    def clear_failure(self, name: str):
        """Forget an earlier failure of a frame that has now been extracted (resumed runs)."""
        self._failures = [f for f in self._failures if not f.startswith(f"{name}:")]

    def close(self):
        self._flush()
        if "failures" in self.h5:
            del self.h5["failures"]
        self.h5.create_dataset(
            "failures", data=np.array(self._failures, dtype=h5py.string_dtype())
        )


def write_features(path: str | Path, attrs: dict, *, resume: bool = False):
    """Context manager yielding a FeaturesWriter; the file appears under ``path`` only when the
    block completes. With ``resume`` an existing file's frames are kept."""
    import contextlib

    @contextlib.contextmanager
    def _cm():
        with write_artifact(path, attrs, resume=resume) as h5:
            w = FeaturesWriter(h5)
            yield w
            w.close()

    return _cm()


class _Columns:
    """The frames of a version 2 file (the module doc's columns), read a block of BLOCK_FRAMES
    stored frames at a time. Each column is checked before it is read (stored_dataset: in the
    file, of numbers or short text; a frame index of at most MAX_FRAMES, a data column of
    the rows ``trailing`` gives); anything else inconsistent raises ValueError or KeyError."""

    def __init__(self, h5: h5py.File, trailing: dict[str, tuple]):
        def column(name: str) -> h5py.Dataset:
            d = stored_dataset(h5, name, "features file")
            if d.ndim != 1 or d.shape[0] > MAX_FRAMES:
                raise ValueError(f"{name} has shape {d.shape}; expected (N,) for N <="
                                 f" {MAX_FRAMES:,} frames")
            return d

        names = _text(column("index/name")[()])
        stamps = np.asarray(column("index/stamp")[()], dtype=float)
        n = len(names)
        if stamps.shape != (n,):
            raise ValueError(f"{n} frame names but {stamps.shape[0]} stamps")
        images = _text(column("index/image")[()]) if "index/image" in h5 else [""] * n
        if len(images) != n:
            raise ValueError(f"{n} frame names but {len(images)} image identities")
        self._rows, self._start, self._data = {}, {}, {}
        rows_g = h5.get("rows")
        for key in rows_g if rows_g is not None else ():
            if key not in FRAME_DATASETS:
                raise ValueError(f"no dataset '{key[:40]}' in the schema")
            rows = np.asarray(column(f"rows/{key}")[()])
            if rows.shape != (n,) or rows.dtype.kind not in "iu" or (rows < -1).any():
                raise ValueError(f"rows/{key} does not give one row count per frame")
            start = _starts(rows)
            data = stored_dataset(h5, f"data/{key}", "features file")
            if data.ndim < 1 or data.shape[0] != start[-1]:
                raise ValueError(f"data/{key} holds {data.shape[0] if data.ndim else 0} rows,"
                                 f" its frames {start[-1]}")
            want = trailing.get(key)
            if want is None:
                raise ValueError(f"its camera's frames hold no '{key}'")
            if data.shape[1:] != want or data.dtype.kind not in "fiu":
                raise ValueError(f"data/{key} is {str(data.shape)[:40]} {str(data.dtype)[:20]};"
                                 f" expected rows of {want} numbers")
            self._rows[key], self._start[key], self._data[key] = rows, start, data
        self._pos = {name: i for i, name in enumerate(names)}  # a name stored twice: the last
        keep = sorted(self._pos.values())
        self.names = [names[i] for i in keep]
        self.stamps = stamps[keep]
        self.images = [images[i] for i in keep]
        self._all_stamps = stamps
        self._block: tuple[int, dict[str, np.ndarray]] = (-1, {})

    def read(self, name: str) -> tuple[dict[str, np.ndarray], float]:
        i = self._pos[name]
        b, first = i // BLOCK_FRAMES, i - i % BLOCK_FRAMES
        if self._block[0] != b:
            last = min(first + BLOCK_FRAMES, len(self._all_stamps))
            self._block = (b, {k: d[self._start[k][first]:self._start[k][last]]
                               for k, d in self._data.items()})
        out = {}
        for key, rows in self._rows.items():
            if rows[i] >= 0:
                s = self._start[key][i] - self._start[key][first]
                out[key] = self._block[1][key][s:s + rows[i]].copy()
        return out, float(self._all_stamps[i])


class _GroupPerFrame:
    """The frames of a version 1 file: a group per frame under ``/frames``, each with its
    ``stamp`` and datasets (still read; extract's resume moves them into columns)."""

    def __init__(self, h5: h5py.File):
        frames = self._frames = h5["frames"]
        self.names = sorted(frames.keys())
        self.stamps = np.array([frames[n].attrs["stamp"] for n in self.names], dtype=float)
        self.images = [""] * len(self.names)  # version 1 recorded no image identities

    def read(self, name: str) -> tuple[dict[str, np.ndarray], float]:
        """Every dataset of frame ``name`` read whole, and its stamp (numeric ones through
        h5py's low-level calls, a third of the time of its high-level objects). A missing
        frame or stamp raises KeyError."""
        frames = self._frames
        group = h5py.h5g.open(frames.id, name.encode())
        out = {}
        for key in group:
            d = h5py.h5d.open(group, key)
            k = key.decode()
            if d.dtype.subdtype is not None or d.dtype.itemsize > MAX_ITEM_BYTES:
                raise SchemaError(f"{frames.file.filename}: damaged features file (frame"
                                  f" {name[:40]}: '{k[:40]}' holds elements of"
                                  f" {d.dtype.itemsize:,} bytes; fieldloc writes numbers)")
            if d.dtype.kind not in "fiu":
                out[k] = frames[name][k][()]
                continue
            out[k] = np.empty(d.shape, d.dtype)
            if out[k].size:
                d.read(h5py.h5s.ALL, h5py.h5s.ALL, out[k])
        attr = h5py.h5a.open(group, b"stamp")
        stamp = np.empty(attr.shape, attr.dtype)
        attr.read(stamp)
        return out, float(stamp)


class _NoFrames:
    names: list[str] = []
    stamps = np.zeros(0)
    images: list[str] = []

    def read(self, name: str):
        raise KeyError(f"no frame {name!r}: the file has no frames")


# a features frame is a dataset's frame when their names and stamps agree; extract copies the
# dataset's stamp, so only float formatting separates them: far below a frame interval (33 ms
# at 30 Hz)
SAME_STAMP_S = 1e-3


class FeaturesFile:
    """Read access to a features file (version 2, or 1)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.h5 = open_artifact(self.path, SCHEMA, VERSION)
        self._failures: list[str] | None = None  # read on first use (``failures``)
        _small_metadata_cache(self.h5)
        # the camera kind, read once (a FeaturesFile only reads: each frame's check asks it)
        v = self.h5.attrs.get("camera_kind", "")
        kind = self._kind = v.decode(errors="replace") if isinstance(v, bytes) else v
        if not isinstance(kind, str) or kind not in CAMERA_KINDS:
            self.h5.close()
            raise SchemaError(f"{self.path}: damaged features file (camera_kind"
                              f" {str(kind)[:40]!r} is not one of {', '.join(CAMERA_KINDS)})")
        self._shapes = dict(TRAILING)
        if "radial" in REQUIRED[kind]:  # read along scan lines: their layout shapes them
            try:
                sl = read_json_attr(self.h5, "scanlines") or {}
                if not isinstance(sl, dict):
                    raise ValueError(f"{str(sl)[:40]} is no JSON object")
                n, k = int(sl.get("n_angles", 72)), int(sl.get("max_crossings", 4))
                if not (1 <= n <= MAX_SCAN_ANGLES and 1 <= k <= MAX_SCAN_CROSSINGS):
                    raise ValueError(f"n_angles {str(n)[:20]}, max_crossings {str(k)[:20]};"
                                     f" expected 1 to {MAX_SCAN_ANGLES} and 1 to"
                                     f" {MAX_SCAN_CROSSINGS}")
            except (ValueError, TypeError, AttributeError, OverflowError) as e:
                self.h5.close()
                raise SchemaError(f"{self.path}: damaged features file (scanlines: {e})"
                                  ) from None
            self._shapes.update(radial=(n, k), spiral=(2, n))
        # a column's rows: a frame's radial (n, k) is n rows of k, its spiral (2, n) 2 rows of n
        trailing = {k: v[1:] if k in SCAN_DISTANCES else v for k, v in self._shapes.items()}
        try:
            self._layout = (_Columns(self.h5, trailing) if "index" in self.h5
                            else _GroupPerFrame(self.h5) if "frames" in self.h5
                            else _NoFrames())
        except SchemaError:
            self.h5.close()
            raise
        except (KeyError, ValueError, TypeError, OSError, AttributeError) as e:
            self.h5.close()
            raise SchemaError(f"{self.path}: damaged features file ({str(e)[:200]})") from None
        # by stamp, frames of one stamp by name
        names, stamps = self._layout.names, np.asarray(self._layout.stamps, dtype=float)
        bad = np.flatnonzero(~(np.abs(stamps) <= MAX_STAMP))
        if len(bad):  # as frames.csv's: a frame without a finite stamp cannot be placed
            self.h5.close()
            raise SchemaError(f"{self.path}: damaged features file (frame"
                              f" {str(names[bad[0]])[:40]}: {stamp_error(stamps[bad[0]])})")
        order = np.lexsort((np.array(names, dtype=str), stamps)) if names else []
        self.names = [names[i] for i in order]
        self.stamps = stamps[order]
        self._images = dict(zip(names, self._layout.images))
    @property
    def camera_kind(self) -> str:
        return self._kind

    @property
    def conf(self) -> dict:
        conf = self.attr_json("conf")
        if not isinstance(conf, dict):  # [1, 2] or null: no conf (trial X1-6)
            raise SchemaError(f"{self.path}: damaged features file (attribute 'conf' is"
                              f" {str(conf)[:40]}; expected a JSON object)")
        return conf

    def attr_json(self, key: str):
        """The JSON root attribute ``key``; SchemaError where it is no JSON text."""
        try:
            return read_json_attr(self.h5, key)
        except ValueError as e:
            raise SchemaError(f"{self.path}: damaged features file ({e})") from None

    @property
    def failures(self) -> list[str]:
        """'name: reason' of each frame extract left out (text not UTF-8 escaped: A2-6), read
        once; a ``/failures`` that is no 1-D text dataset of at most MAX_FRAMES rows is
        SchemaError (a scalar, a 50-million-row float or a group ended in a traceback or ran
        past a minute, trial B1)."""
        if self._failures is None:
            if "failures" not in self.h5:
                self._failures = []
            else:
                d = stored_dataset(self.h5, "failures", "features file")
                if d.ndim != 1 or d.shape[0] > MAX_FRAMES or d.dtype.kind not in "OS":
                    raise SchemaError(f"{self.path}: damaged features file (/failures is"
                                      f" {str(d.shape)[:30]} {str(d.dtype)[:20]}; expected"
                                      f" one text a frame left out, at most {MAX_FRAMES:,})")
                self._failures = [v.decode(errors="backslashreplace") if isinstance(v, bytes)
                                  else str(v) for v in d[()]]
        return self._failures

    def frame(self, name: str) -> dict[str, np.ndarray]:
        """The datasets of frame ``name`` and its ``stamp``; a frame missing a dataset its
        camera kind always has, holding one of another shape, or scan-line distances below 0
        or beyond MAX_SCAN_DISTANCE, is refused (SchemaError)."""
        try:
            out, stamp = self._layout.read(name)
        except OSError as e:  # a damaged block: the file, not the frame (trial V1-4)
            raise SchemaError(f"{self.path}: damaged features file (frame {name[:40]}:"
                              f" {str(e)[:120]})") from None
        for k, v in out.items():
            want = self._shapes.get(k)
            if want is not None and (np.ndim(v) != 2 or v.dtype.kind not in "fiu" or (
                    v.shape[-len(want):] != want if k in ("radial", "spiral")
                    else v.shape[1:] != want)):
                expect = (f"({', '.join(map(str, want))})" if k in ("radial", "spiral")
                          else f"(N, {', '.join(map(str, want))})")
                raise SchemaError(f"{self.path}: damaged features file (frame {name}: '{k}'"
                                  f" has shape {np.shape(v)}, expected {expect})")
        for k in POINT_DATASETS:  # extract writes finite points only (trial X1-1: inf
            v = out.get(k)        # points placed every frame at one pose, rc 0)
            if v is not None and v.dtype.kind == "f" and not np.isfinite(v).all():
                raise SchemaError(f"{self.path}: damaged features file (frame {name}: '{k}'"
                                  f" holds {v[~np.isfinite(v)].flat[0]} where finite numbers"
                                  " belong)")
        for k in SCAN_DISTANCES:
            v = out.get(k)
            if v is not None and ((v < 0) | (v > MAX_SCAN_DISTANCE)).any():
                d = v[(v < 0) | (v > MAX_SCAN_DISTANCE)].flat[0]
                raise SchemaError(f"{self.path}: damaged features file (frame {name}: '{k}'"
                                  f" holds the distance {float(d):.6g} m; expected 0 to"
                                  f" {MAX_SCAN_DISTANCE:g} m, or NaN for none)")
        missing = [k for k in REQUIRED[self._kind] if k not in out]
        if missing:
            raise SchemaError(f"{self.path}: damaged features file (frame {name} has no"
                              f" '{missing[0]}' dataset)")
        out["stamp"] = stamp
        return out

    def check_of(self, dataset) -> None:
        """Refuse (FieldlocError, one line) features that are not the dataset's own: of
        another camera kind than its calib.yaml's, naming none of its frames, placing one
        of its frames at another stamp (another recording's, whose frames are other names
        or other times), or extracted from another image file than one of its frames' (the
        recorded ``image_identity``: every simulated dataset names and stamps its frames
        alike, and a frame re-encoded since its extraction is another image). Frames of the
        file that the dataset does not have (a dataset cut after its extraction) are then
        left out of ``names`` and ``stamps``: a reader uses the dataset's frames only.
        The one check every reader of a dataset's frames from a features file applies
        (localize, show belief, show points). A file of failures only is judged by its kind;
        frames without a recorded identity (features of a fieldloc before the record) by
        their names and stamps alone, with no word: they were right until now, and
        re-extracting a recording only to be told nothing new is a cost without a gain.
        Every shared frame's image file has its size compared (a stat), and a sample of
        IDENTITY_SAMPLE of them, spread over the recording, its CRC-32 too: an image replaced
        or re-encoded is of another size but by chance, and reading every image would cost a
        cold recording its whole size in reads (4 GB for 10,000 omni frames) before a
        localisation that reads none."""
        # a dataset given its features may lack a calib.yaml (localize reads none then)
        kind = dataset.camera().kind if dataset.calib_path.is_file() else self._kind
        if self._kind != kind:
            raise FieldlocError(
                f"{self.path}: features of a '{self._kind}' camera, {dataset.root} was recorded by"
                f" a '{kind}' camera: are they another dataset's?")
        if not (self.names and dataset.names):
            return
        stamp_of = dict(zip(dataset.names, (float(s) for s in dataset.stamps)))
        shared = [(n, float(s)) for n, s in zip(self.names, self.stamps) if n in stamp_of]
        if not shared:
            raise FieldlocError(
                f"{self.path}: no frame of {dataset.root} is in the features file (its frames"
                f" are like '{str(self.names[0])[:40]}'): are they another dataset's?")
        other = next(((n, s) for n, s in shared if not abs(stamp_of[n] - s) <= SAME_STAMP_S),
                     None)
        if other is not None:
            raise FieldlocError(
                f"{self.path}: frame {str(other[0])[:40]} is at {other[1]:.6g} s, in"
                f" {dataset.root} at {stamp_of[other[0]]:.6g} s: are they another dataset's"
                " (or of its earlier frames.csv)? Extract the dataset again")
        for name, path, want, have in self.changed_images(dataset, first=True):
            raise FieldlocError(
                f"{self.path}: frame {str(name)[:40]} was extracted from another image"
                f" than {path} (size:CRC-32 {want[:40]}, now {have}): are they"
                " another dataset's features, or was the image changed? Extract the"
                " dataset again")
        if len(shared) < len(self.names):  # the dataset's frames only
            keep = [i for i, n in enumerate(self.names) if n in stamp_of]
            log.info("%s: %d of its frames are not in %s; left out", self.path,
                     len(self.names) - len(keep), dataset.root)
            self.names = [self.names[i] for i in keep]
            self.stamps = self.stamps[keep]

    def changed_images(self, dataset, *, first: bool = False):
        """(name, image path, recorded identity, identity now) of each frame of the file that
        the dataset has, whose recorded ``image_identity`` its image file no longer has
        (``first``: the first such frame only). Every such frame's image file has its size
        compared (a stat), and a sample of IDENTITY_SAMPLE of them, spread over the
        recording, its CRC-32 too: check_of's doc says why. A frame without a recorded
        identity, or whose image cannot be read now (its reader says so), is not listed."""
        path_of = dict(zip(dataset.names, dataset.images))
        shared = [n for n in self.names if n in path_of]
        sample = {int(i) for i in np.linspace(0, len(shared) - 1, IDENTITY_SAMPLE)}
        out = []
        for k, name in enumerate(shared):
            want = self._images.get(name)
            if not want:
                continue
            if k in sample:
                have = file_identity(path_of[name])
            else:  # the size alone, from a stat
                have = file_size_identity(path_of[name], want)
            if have is not None and have != want:
                out.append((name, path_of[name], want, have))
                if first:
                    break
        return out

    def image(self, name: str) -> str:
        """The recorded ``image_identity`` of frame ``name``'s image ("" none)."""
        return self._images.get(name, "")

    def __len__(self):
        return len(self.names)

    def close(self):
        self.h5.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# frames whose image file check_of reads for its CRC-32 (the others: their size): spread
# over the recording, so that a dataset of which a stretch of frames was replaced meets one
IDENTITY_SAMPLE = 32


# HDF5's metadata cache of a features file being read (bytes). A version 1 reader visits each
# frame's group and datasets about once, in order, so a cache of a few frames' object headers
# serves it as well as HDF5's default of 2 MB (about 10,000 entries, which take 30-45 MB of
# memory once a long recording's frames have passed through it: a lut process's resident set
# grew by 20 kB a frame). Reading is no slower with it (0.55-0.69 against 0.60-0.71 ms a
# frame). Version 2's few column objects fit in it.
READ_CACHE_BYTES = 256 << 10


def _small_metadata_cache(h5: h5py.File) -> None:
    """Hold the metadata cache of the open file ``h5`` to READ_CACHE_BYTES."""
    cfg = h5.id.get_mdc_config()
    cfg.set_initial_size = True
    cfg.initial_size = cfg.max_size = READ_CACHE_BYTES
    cfg.min_size = READ_CACHE_BYTES // 2
    h5.id.set_mdc_config(cfg)


# ---------------------------------------------------------------------------- resume parts

# what frames depend on (head_hash since parts format 5); the keys of every format's run.json
# mark a parts folder as extract's (``_parts_run``)
RUN_KEYS = ("camera_kind", "calib_hash", "mask_hash", "head_hash", "conf", "scanlines")
MARK_KEYS = ("camera_kind", "calib_hash", "mask_hash", "conf", "scanlines")
# The parts' layout, in run.json beside RUN_KEYS: a folder of another layout (one file per
# frame, format 1; one entry per frame and dataset, format 2; each frame's shape, format 3;
# no head_hash, format 4) is discarded like one of other inputs.
PARTS_FORMAT = 5
# Finished frames are committed together at most this often (s): a commit (a temporary file,
# written and renamed) costs about 1-1.7 ms, as much as extracting an omni frame, so committing
# every frame spent a fifth of extract's time on it; a run killed by kill -9 loses at most this
# much work. CHUNK_FRAMES bounds the frames held uncommitted (their memory) on a slow disk.
CHUNK_SECONDS = 0.5
CHUNK_FRAMES = 256


# HDF5's own structure of a features file beside its columns' storage chunks (superblock,
# groups, object headers, attributes): 14.6 kB of a 4-frame omni file of 197 kB, of which
# 182 kB are chunks. A lower bound, so that no run that fits is refused for it.
FILE_HEAD_BYTES = 8 << 10
_NAME_BYTES = 16  # an entry of /index/name or /index/image as stored (a variable-length
# string's)


def _chunked(rows: int, chunk_row: int, stored_row: int | None = None) -> int:
    """The bytes ``rows`` rows of a column take in whole storage chunks (``_append``'s
    chunks of rows of ``chunk_row`` bytes in memory, ``stored_row`` on disk if other): HDF5
    allocates a chunk whole once any row of it is written."""
    per_chunk = max(64, _CHUNK_BYTES // max(1, chunk_row))
    return -(-rows // per_chunk) * per_chunk * (stored_row or chunk_row)


def file_bytes(columns: dict[str, tuple[int, int]], frames: int) -> int:
    """The storage of a features file of ``frames`` frames whose columns are ``columns``
    (key -> (rows of all frames, bytes per row)): each column's rows and row counts in whole
    chunks, the index (names, stamps, images), and FILE_HEAD_BYTES. What extract checks the disk
    for: before its first frame is committed, with that frame's columns (the least the run
    writes: later frames only add rows), and before the frames are merged, with them all."""
    size = FILE_HEAD_BYTES + 2 * _chunked(frames, 8, _NAME_BYTES) + _chunked(frames, 8)
    for rows, row in columns.values():
        size += _chunked(frames, 8) + _chunked(rows, row)
    return size


def frame_columns(arrays: dict[str, np.ndarray]) -> dict[str, tuple[int, int]]:
    """A frame's columns as ``file_bytes`` takes them: key -> (its rows, bytes per row)."""
    return {k: (len(a), a.dtype.itemsize * int(np.prod(a.shape[1:], dtype=np.int64)))
            for k, a in _frame_rows(arrays).items()}


# What extract writes in its parts folder, and all it ever removes there: run.json, chunks
# "<first frame>+<count>.npz", failed frames "<name>.failed", and a file being committed (a
# temporary part, ".<file>.fieldloc-<pid>-<random>.part")
_CHUNK_NAME = re.compile(r"[^.][^/]*\+\d+\.npz")
_COMMIT_PART = re.compile(rf"\..+\.{PART_TAG}-\d+-[^/]*\.part")  # artifacts.part_name


def kept_frames(target: str | Path) -> bool:
    """Whether an extraction into ``target`` that stopped kept finished frames for a rerun to
    resume: a chunk in its parts folder (FrameParts)."""
    folder = Path(target).with_name(f".{Path(target).name}.parts")
    try:
        return any(_CHUNK_NAME.fullmatch(p.name) for p in folder.iterdir())
    except OSError:
        return False


def _parts_file(name: str) -> bool:
    """Whether ``name`` is the name of a file FrameParts writes in its folder."""
    return (name == "run.json" or bool(_CHUNK_NAME.fullmatch(name))
            or (name.endswith(".failed") and not name.startswith("."))
            or bool(_COMMIT_PART.fullmatch(name)))


def _parts_run(run) -> bool:
    """Whether ``run`` (a parts folder's run.json, or None where it is absent or unreadable)
    is one extract wrote, in any layout: a mapping holding MARK_KEYS."""
    return isinstance(run, dict) and all(k in run for k in MARK_KEYS)


class FrameParts:
    """Frames of an unfinished extraction, committed in chunks of at most CHUNK_SECONDS (see the
    module doc): ``<first frame>+<count>.npz`` holds the chunk's ``names``, ``stamps``,
    ``images`` (their image identities; absent in chunks of a fieldloc before them) and, per
    dataset, its frames as the file's columns hold them (``_columns``: ``<dataset>:data`` the
    rows one after the other, ``<dataset>:rows`` each frame's row count, -1 where it has no
    such dataset); a failed frame is ``<name>.failed``. A few entries per chunk, not one per
    frame and dataset: zip entries cost about 0.1 ms each to write and read, as much as an omni
    frame's features.

    ``attrs``: the run's root attributes; frames in an existing parts folder are taken over only
    if its ``run.json`` has the same values under RUN_KEYS and PARTS_FORMAT."""

    def __init__(self, target: str | Path, attrs: dict):
        self.target = Path(target)
        self.dir = self.target.with_name(f".{self.target.name}.parts")
        self.run = {k: _plain_attr(attrs.get(k, "")) for k in RUN_KEYS}
        self.run["parts_format"] = PARTS_FORMAT
        self._frames: dict[str, tuple[Path, int]] = {}  # name -> (chunk file, index in it)
        self._failures: dict[str, str] = {}
        self._pending: list[tuple[str, float, dict, str]] = []
        self._since = time.monotonic()
        self._cached: tuple[Path, tuple] | None = None  # the chunk frame() read last

    # -------------------------------------------------------------- open / discard
    def open(self) -> int:
        """Take over the frames of an interrupted run with the same inputs (returns how many),
        or start an empty parts folder."""
        if self.dir.is_symlink():
            raise FieldlocError(f"{self.dir} is a link where extract keeps its resume folder;"
                                " move it")
        if self.dir.is_dir():
            foreign = next((p for p in sorted(self.dir.iterdir())
                            if not _parts_file(p.name) or p.is_symlink() or not p.is_file()),
                           None)
            if foreign is not None:  # a user's file in it: the folder is never removed then
                raise FieldlocError(f"{self.dir} holds {str(foreign.name)[:40]!r}, which extract"
                                    " did not write; move it out of the folder")
            old = self._read_run()
            if not _parts_run(old) and any(self.dir.iterdir()):
                # a folder of the user's at the parts' name: never removed (an empty one is
                # what a run killed between its mkdir and its run.json leaves)
                raise FieldlocError(f"{self.dir} is in the way of extract's resume folder (it"
                                    " holds no run.json of extract's); move it")
            if old == self.run:
                self._scan()
                n = len(self._frames) + len(self._failures)
                if n:
                    log.warning("extract: resuming %d frames finished by an interrupted run"
                                " (%s)", n, self.dir)
                return n
            self.discard(f"they were extracted with other inputs ({self._what_differs(old)})")
        elif self.dir.exists():
            raise FieldlocError(f"{self.dir} is in the way of extract's resume folder; remove it")
        self.dir.mkdir()
        try:
            with writing(self.target):
                self._write_json(self.dir / "run.json", self.run)
        except BaseException:  # a full disk: no parts folder without its run.json
            self.remove()
            raise
        return 0

    @property
    def began_ns(self) -> int:
        """When the run that started the parts folder began (its run.json's modification time,
        ns; an open() folder has one): a file this run writes beside the frames (extract's
        debug overlays) that is newer was written by it or by the interrupted runs it
        resumes."""
        return (self.dir / "run.json").stat().st_mtime_ns

    def discard(self, why: str) -> None:
        """Remove the frames of an interrupted run that cannot be used, saying why."""
        if self.dir.is_dir():
            n = sum(1 for p in self.dir.iterdir() if p.suffix in (".npz", ".failed"))
            if n:
                log.warning("extract: discarded %d frames of an interrupted run in %s: %s", n,
                            self.dir, why)
        self.remove()

    def remove(self) -> None:
        """Remove the parts folder (its frames are in the features file, or not wanted): the
        files extract writes there, then the folder if that emptied it (never a user's file,
        nor through a link)."""
        if self.dir.is_dir() and not self.dir.is_symlink():
            for p in self.dir.iterdir():
                if _parts_file(p.name) and p.is_file() and not p.is_symlink():
                    p.unlink(missing_ok=True)
            with contextlib.suppress(OSError):  # not empty: a file that is not extract's
                self.dir.rmdir()
        self._frames.clear()
        self._failures.clear()
        self._pending.clear()
        self._cached = None

    def _read_run(self):
        try:
            return json.loads((self.dir / "run.json").read_text())
        except (OSError, ValueError):
            return None

    def _what_differs(self, old) -> str:
        if not isinstance(old, dict):
            return "no readable run.json"
        return ", ".join(k.replace("_", " ") for k in self.run if old.get(k) != self.run[k])

    def _scan(self):
        for p in sorted(self.dir.iterdir()):
            if _COMMIT_PART.fullmatch(p.name):  # a chunk being written when the run was killed
                p.unlink(missing_ok=True)
            elif _CHUNK_NAME.fullmatch(p.name):
                try:
                    with np.load(p, allow_pickle=False) as z:
                        names = [str(n) for n in z["names"]]
                except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile):
                    # a chunk a crash (a full disk, a lost power) left unreadable: its
                    # frames are extracted again
                    log.warning("extract: a damaged chunk of an interrupted run, %s, is"
                                " discarded", p)
                    p.unlink(missing_ok=True)
                    continue
                for k, name in enumerate(names):
                    self._frames[name] = (p, k)
            elif p.name.endswith(".failed"):
                try:
                    self._failures[p.stem] = p.read_text()
                except (OSError, UnicodeDecodeError):
                    p.unlink(missing_ok=True)

    # -------------------------------------------------------------- frames
    def has(self, name: str) -> bool:
        return (name in self._frames or name in self._failures
                or any(n == name for n, _s, _a, _i in self._pending))

    @property
    def frame_names(self) -> list[str]:
        """The committed frames (flush() commits the pending ones)."""
        return sorted(self._frames)

    @property
    def failures(self) -> dict[str, str]:
        return dict(self._failures)

    def add_frame(self, name: str, stamp: float, arrays: dict[str, np.ndarray],
                  image: str = "") -> None:
        """Take one finished frame (``image``: the identity of its image file, as
        FeaturesWriter.add_frame); it is committed with the others of its chunk
        (CHUNK_SECONDS, CHUNK_FRAMES), or by flush()."""
        rows = _frame_rows(arrays)
        if not self._pending:
            self._since = time.monotonic()
        self._pending.append((name, float(stamp), rows, image))
        if (len(self._pending) >= CHUNK_FRAMES
                or time.monotonic() - self._since >= CHUNK_SECONDS):
            self.flush()

    def flush(self) -> None:
        """Commit the frames taken since the last commit as one chunk file (complete or absent
        after any interruption)."""
        if not self._pending:
            return
        pending, self._pending = self._pending, []
        names = [n for n, _s, _a, _i in pending]
        content = {"names": np.array(names), "stamps": np.array([s for _n, s, _a, _i in pending]),
                   "images": np.array([i for _n, _s, _a, i in pending], dtype=str)}
        content.update(_packed([a for _n, _s, a, _i in pending]))
        path = self.dir / f"{names[0]}+{len(names)}.npz"
        try:
            self._commit(path, lambda f: np.savez(f, **content))
        except BaseException:  # Ctrl-C mid-commit: still pending, for the next flush
            self._pending = pending + self._pending
            raise
        for k, name in enumerate(names):
            if name in self._failures:
                (self.dir / f"{name}.failed").unlink(missing_ok=True)
                self._failures.pop(name)
            self._frames[name] = (path, k)

    def add_failure(self, name: str, reason: str) -> None:
        path = self.dir / f"{name}.failed"
        self._commit(path, lambda f: f.write(reason.encode()))
        self._failures[name] = reason

    def frame(self, name: str) -> tuple[float, dict[str, np.ndarray]]:
        """A committed frame's (stamp, arrays)."""
        stamps, frames, _images, k = self._chunk_of(name)
        return float(stamps[k]), frames[k]

    def image(self, name: str) -> str:
        """A committed frame's image identity ("" where its chunk records none)."""
        _stamps, _frames, images, k = self._chunk_of(name)
        return str(images[k])

    def _chunk_of(self, name: str) -> tuple:
        """(stamps, frames, images, index of ``name``) of the chunk holding ``name``."""
        path, k = self._frames[name]
        if self._cached is None or self._cached[0] != path:
            with np.load(path, allow_pickle=False) as z:
                stamps = z["stamps"]
                frames = _unpacked(z, len(stamps))
                images = z["images"] if "images" in z.files else [""] * len(stamps)
            self._cached = (path, (stamps, frames, images))
        return (*self._cached[1], k)

    def _commit(self, path: Path, write) -> None:
        raise_deferred_stop()  # a stop a callback dropped: no frame committed after it
        prefix, suffix = part_name(path)
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=self.dir)
        try:
            with writing(self.target), os.fdopen(fd, "wb") as f:
                write(f)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)

    @staticmethod
    def _write_json(path: Path, obj) -> None:
        path.write_text(json.dumps(obj, sort_keys=True))

    def bytes_needed(self) -> int:
        """What merging the committed frames into a new features file writes
        (``file_bytes`` of their columns; the shapes are read from the chunks' array headers,
        not their data)."""
        columns: dict[str, tuple[int, int]] = {}
        for p in {p for p, _k in self._frames.values()}:
            for key, (rows, row) in _chunk_columns(p).items():
                columns[key] = (columns.get(key, (0, row))[0] + rows, row)
        return file_bytes(columns, len(self._frames))

    def merge_into(self, writer: FeaturesWriter) -> int:
        """Add every committed frame and failure to ``writer`` (chunk by chunk, each read
        once); returns the frames added."""
        for name in sorted(self._frames, key=lambda n: (str(self._frames[n][0]),
                                                        self._frames[n][1])):
            stamp, arrays = self.frame(name)
            writer.add_frame(name, stamp, arrays, self.image(name))
            writer.clear_failure(name)
        for name, reason in sorted(self._failures.items()):
            writer.add_failure(name, reason)
        return len(self._frames)


def _chunk_columns(path: Path) -> dict[str, tuple[int, int]]:
    """The columns of a parts chunk (``_packed``) as ``file_bytes`` takes them, from the
    headers of its arrays ({} for a chunk that cannot be read: the merge then says so)."""
    import zipfile

    out = {}
    try:
        with zipfile.ZipFile(path) as z:
            for member in z.namelist():
                key, _sep, part = member.removesuffix(".npy").partition(":")
                if part != "data":
                    continue
                with z.open(member) as f:
                    version = np.lib.format.read_magic(f)
                    read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                            else np.lib.format.read_array_header_2_0)
                    shape, _order, dtype = read(f)
                if shape:
                    out[key] = (int(shape[0]),
                                dtype.itemsize * int(np.prod(shape[1:], dtype=np.int64)))
    except (OSError, ValueError, zipfile.BadZipFile):
        return {}
    return out


def _packed(frames: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The arrays of ``frames`` (their rows, ``_as_rows``) as FrameParts stores a chunk."""
    out = {}
    for key, (data, rows) in _columns(frames, sorted({k for a in frames for k in a})).items():
        out[f"{key}:data"], out[f"{key}:rows"] = data, rows
    return out


def _unpacked(z, n: int) -> list[dict[str, np.ndarray]]:
    """The frames' arrays of a chunk (``z``: its entries, ``n`` frames), as _packed had them."""
    frames: list[dict] = [{} for _ in range(n)]
    for entry in z.files:
        key, _sep, part = entry.partition(":")
        if part != "data":
            continue
        data, rows = z[entry], z[f"{key}:rows"]
        for i, start in enumerate(_starts(rows)[:-1]):
            if rows[i] >= 0:
                frames[i][key] = data[start:start + rows[i]]
    return frames


def _plain_attr(v):
    if isinstance(v, bytes):
        v = v.decode()
    if isinstance(v, str):
        try:  # JSON attributes compare by content, not by formatting
            return json.loads(v)
        except ValueError:
            return v
    return v

