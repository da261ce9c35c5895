"""The poses artifact (schema ``fieldloc.poses``) written by ``localize``, and its TUM twin.

Root attributes: the common ones plus ``method`` (lut, mcl, templates), ``field`` (name),
``dataset``.

    /poses/name        (N,) str    frame name
    /poses/stamp       (N,) f8     s
    /poses/x, /y       (N,) f8     m, field frame; NaN where the frame failed
    /poses/theta       (N,) f8     rad
    /poses/failed      (N,) bool   the method could not localise this frame (never a fallback)
    /poses/error       (N,) f4     method's own error term (lut: weighted matching error)
    /poses/confidence  (N,) f4     0..1
    /poses/mode        (N,) str    how the pose was found: global, local, tracking, ...
    /poses/runtime     (N,) f4     s, time the method spent on the frame
    /poses/covariance  (N, 3, 3) f4  optional, m^2 / rad^2
    /poses/flags       (N,) str    optional notes per frame (e.g. "mirror-ambiguous")

``poses.tum`` beside it holds "stamp x y z qx qy qz qw" rows of the frames that did not fail,
readable by evo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from .artifacts import atomic_path, open_artifact, read_json_attr, write_artifact

SCHEMA = "fieldloc.poses"
VERSION = 1

COLUMNS = {
    # name: (dtype, units)
    "stamp": ("f8", "s"),
    "x": ("f8", "m"),
    "y": ("f8", "m"),
    "theta": ("f8", "rad"),
    "failed": ("bool", ""),
    "error": ("f4", ""),
    "confidence": ("f4", ""),
    "runtime": ("f4", "s"),
}


@dataclass
class PoseTrack:
    """Per-frame localisation results, in memory."""

    name: list = field(default_factory=list)
    stamp: list = field(default_factory=list)
    x: list = field(default_factory=list)
    y: list = field(default_factory=list)
    theta: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    error: list = field(default_factory=list)
    confidence: list = field(default_factory=list)
    mode: list = field(default_factory=list)
    runtime: list = field(default_factory=list)
    covariance: list = field(default_factory=list)
    flags: list = field(default_factory=list)

    def add(self, name, stamp, pose=None, *, error=math.nan, confidence=0.0, mode="",
            runtime=0.0, covariance=None, flags=""):
        """Record one frame; ``pose=None`` records a failure (NaN pose, failed=True)."""
        failed = pose is None
        x, y, th = (math.nan, math.nan, math.nan) if failed else (float(v) for v in pose)
        self.name.append(str(name))
        self.stamp.append(float(stamp))
        self.x.append(x)
        self.y.append(y)
        self.theta.append(th)
        self.failed.append(failed)
        self.error.append(float(error))
        self.confidence.append(float(confidence))
        self.mode.append(str(mode))
        self.runtime.append(float(runtime))
        self.covariance.append(
            np.full((3, 3), np.nan) if covariance is None else np.asarray(covariance, float)
        )
        self.flags.append(str(flags))

    def __len__(self):
        return len(self.name)

    def arrays(self) -> dict[str, np.ndarray]:
        out = {k: np.asarray(getattr(self, k), dtype=COLUMNS[k][0]) for k in COLUMNS}
        out["name"] = np.asarray(self.name, dtype=object)
        out["mode"] = np.asarray(self.mode, dtype=object)
        out["flags"] = np.asarray(self.flags, dtype=object)
        out["covariance"] = np.asarray(self.covariance, dtype=np.float32).reshape(-1, 3, 3)
        return out


def write_poses(path: str | Path, track: PoseTrack, attrs: dict, *, tum: bool = True) -> Path:
    """Write poses.h5 (atomically) and, with ``tum``, poses.tum beside it."""
    path = Path(path)
    arr = track.arrays()
    with write_artifact(path, attrs) as h5:
        g = h5.create_group("poses")
        for k, (_dtype, units) in COLUMNS.items():
            ds = g.create_dataset(k, data=arr[k])
            if units:
                ds.attrs["units"] = units
        s = h5py.string_dtype()
        for k in ("name", "mode", "flags"):
            g.create_dataset(k, data=np.array(arr[k], dtype=s))
        ds = g.create_dataset("covariance", data=arr["covariance"])
        ds.attrs["units"] = "m^2, rad^2"
    if tum:
        write_tum(path.with_suffix(".tum"), arr)
    return path


def write_tum(path: str | Path, arr: dict) -> Path:
    """TUM trajectory rows 'stamp x y z qx qy qz qw' (z = 0, yaw-only quaternion)."""
    ok = ~arr["failed"]
    th = arr["theta"][ok]
    rows = np.stack(
        [arr["stamp"][ok], arr["x"][ok], arr["y"][ok], np.zeros(ok.sum()),
         np.zeros(ok.sum()), np.zeros(ok.sum()), np.sin(th / 2), np.cos(th / 2)],
        axis=1,
    )
    with atomic_path(Path(path), suffix=".tum") as tmp:
        np.savetxt(tmp, rows, fmt="%.6f", header="stamp x y z qx qy qz qw")
    return Path(path)


def read_poses(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """Columns and root attributes (with ``conf`` and ``inputs`` decoded) of a poses file."""
    with open_artifact(path, SCHEMA, VERSION) as h5:
        g = h5["poses"]
        out = {}
        for k in g.keys():
            v = g[k][()]
            if v.dtype.kind in ("O", "S"):
                v = np.array([s.decode() if isinstance(s, bytes) else s for s in v], dtype=object)
            out[k] = v
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()}
        attrs["conf"] = read_json_attr(h5, "conf")
        attrs["inputs"] = read_json_attr(h5, "inputs")
    return out, attrs
