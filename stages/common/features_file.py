"""The features artifact (schema ``fieldloc.features``): per-frame features from ``extract``.

Root attributes: the common ones (see artifacts.root_attrs) plus ``camera_kind`` (omni or
perspective), ``dataset`` (folder), ``calib_hash``, ``scanlines`` (JSON of the scan-line
definition, omni only).

    /frames/<name>/           one group per frame, named by the image's file stem
        @stamp                seconds
        <dataset>             any of FRAME_DATASETS below, with a ``units`` attribute
    /failures                 (F,) strings "name: reason" of frames that were skipped

A frame with no group was not processed (or failed); re-running extract skips frames that
already have a group unless asked to overwrite.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from .artifacts import open_artifact, read_json_attr, write_artifact

SCHEMA = "fieldloc.features"
VERSION = 1

# name -> (units, dtype, description). Shapes are per frame.
FRAME_DATASETS = {
    # omnidirectional (seed 002)
    "radial": ("m", np.float32, "(72, 4) white-line crossings per radial scan line, NaN = none"),
    "spiral": ("m", np.float32, "(2, 72) first crossing radius per spiral (ccw, cw), NaN = none"),
    "points": ("m", np.float32, "(N, 2) line points in the robot frame (x forward, y left)"),
    "points_px": ("px", np.float32, "(N, 2) the same line points in the image (u, v)"),
    # perspective (seed 000); robot frame on the floor, bearings counter-clockwise from +x
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
}


class FeaturesWriter:
    """Adds frames to a features file being written (atomically, see write_artifact)."""

    def __init__(self, h5: h5py.File):
        self.h5 = h5
        self.frames = h5.require_group("frames")
        self._failures = [
            s.decode() if isinstance(s, bytes) else s for s in h5.get("failures", [])
        ]

    def has(self, name: str) -> bool:
        return name in self.frames

    def add_frame(self, name: str, stamp: float, arrays: dict[str, np.ndarray], attrs=None):
        if name in self.frames:
            del self.frames[name]
        g = self.frames.create_group(name)
        g.attrs["stamp"] = float(stamp)
        for k, v in (attrs or {}).items():
            g.attrs[k] = v
        for key, value in arrays.items():
            if key not in FRAME_DATASETS:
                raise KeyError(f"features schema has no dataset '{key}'")
            units, dtype, _ = FRAME_DATASETS[key]
            ds = g.create_dataset(key, data=np.asarray(value, dtype=dtype))
            ds.attrs["units"] = units

    def add_failure(self, name: str, reason: str):
        self._failures = [f for f in self._failures if not f.startswith(f"{name}:")]
        self._failures.append(f"{name}: {reason}")

    def clear_failure(self, name: str):
        """Forget an earlier failure of a frame that has now been extracted (resumed runs)."""
        self._failures = [f for f in self._failures if not f.startswith(f"{name}:")]

    def close(self):
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


class FeaturesFile:
    """Read access to a features file."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.h5 = open_artifact(self.path, SCHEMA, VERSION)
        frames = self.h5.get("frames")
        self.names = sorted(frames.keys()) if frames is not None else []
        self.stamps = np.array([frames[n].attrs["stamp"] for n in self.names], dtype=float)
        order = np.argsort(self.stamps, kind="stable")
        self.names = [self.names[i] for i in order]
        self.stamps = self.stamps[order]

    @property
    def camera_kind(self) -> str:
        v = self.h5.attrs.get("camera_kind", "")
        return v.decode() if isinstance(v, bytes) else v

    @property
    def conf(self) -> dict:
        return read_json_attr(self.h5, "conf")

    def attr_json(self, key: str):
        return read_json_attr(self.h5, key)

    @property
    def failures(self) -> list[str]:
        return [s.decode() if isinstance(s, bytes) else s for s in self.h5.get("failures", [])]

    def frame(self, name: str) -> dict[str, np.ndarray]:
        g = self.h5["frames"][name]
        out = {k: g[k][()] for k in g.keys()}
        out["stamp"] = float(g.attrs["stamp"])
        return out

    def __len__(self):
        return len(self.names)

    def close(self):
        self.h5.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
