"""Stage localize: poses of a dataset's frames from their features and a map.

    from stages import localize
    localize.main({"method": "lut"}, "data/run1", "msl-2015.map.h5", "data/run1/poses.h5")

``conf["method"]`` picks the method module (``METHODS``, imported when used); each exposes
``confs`` (named presets, at least "default") and
``run(conf, dataset, features, map_file, progress) -> PoseTrack``. The conf given to ``main``
is ``{"method": name, "preset": preset name (optional, default "default"), **overrides}``;
the overrides are merged into the method's preset (unknown keys are errors), and the resolved
conf is stored in poses.h5.

Features come from a features file (``features``), from line points of a team's own detector
(``points``: CSV with columns frame, x, y in the robot frame, binned into the scan lines by
stages.extract.omni.bin_points_to_scanlines), or, with neither, from running extract on the
dataset on the fly into ``<output stem>.features.h5`` beside the output (resumed if present).
"""

from __future__ import annotations

import csv
import importlib
import json
import logging
from pathlib import Path

import numpy as np

from ..common.artifacts import file_hash, root_attrs
from ..common.conf import registered_module, resolve_conf
from ..common.dataset import open_dataset
from ..common.errors import DatasetError, FieldlocError
from ..common.features_file import FeaturesFile
from ..common.map_file import MapFile
from ..common.poses_file import SCHEMA, VERSION, write_poses

log = logging.getLogger(__name__)

METHODS = {
    "lut": "stages.localize.lut",
    "mcl": "stages.localize.mcl",
}
DEFAULT_METHOD = "lut"


def method_module(method: str):
    """The module of a localisation method (imported on first use)."""
    return registered_module(METHODS, method, "method")


def method_confs(method: str) -> dict:
    """The named presets of a method."""
    return method_module(method).confs


def available_methods() -> list[str]:
    return [m for m, mod in METHODS.items() if importlib.util.find_spec(mod) is not None]


# presets of the default method (the others: method_confs(name))
confs = {name: {"method": DEFAULT_METHOD, **c} for name, c in method_confs(DEFAULT_METHOD).items()}


def resolve_localize_conf(conf: dict | str | None) -> dict:
    """The full conf of a run: the method's preset with the overrides merged, plus ``method``."""
    if conf is None:
        conf = {}
    if isinstance(conf, str):
        conf = {"preset": conf}
    conf = dict(conf)
    method = conf.pop("method", DEFAULT_METHOD)
    preset = conf.pop("preset", "default")
    out = resolve_conf(method_confs(method), preset, conf)
    out["method"] = method
    return out


# ---------------------------------------------------------------------------- points input


class PointFrames:
    """Per-frame scan-line features from a CSV of line points (frame, x, y; robot frame, m),
    with the interface of FeaturesFile that the methods use (names, stamps, frame(name))."""

    camera_kind = "omni"

    def __init__(self, path: str | Path, dataset, scanlines):
        from ..extract.omni import bin_points_to_scanlines

        self.path = Path(path)
        rows = _read_points_csv(self.path)
        names = list(dict.fromkeys(r[0] for r in rows))
        self.names = names
        by_name: dict[str, list] = {nm: [] for nm in names}
        for nm, x, y in rows:
            by_name[nm].append((x, y))
        self.stamps = _stamps_for(names, dataset)
        order = np.argsort(self.stamps, kind="stable")
        self.names = [names[i] for i in order]
        self.stamps = self.stamps[order]
        self._frames = {}
        for nm, pts in by_name.items():
            p = np.asarray(pts, dtype=float).reshape(-1, 2)
            radial, spiral = bin_points_to_scanlines(p, scanlines)
            self._frames[nm] = {"radial": radial, "spiral": spiral,
                                "points": p.astype(np.float32)}

    def frame(self, name: str) -> dict:
        out = dict(self._frames[name])
        out["stamp"] = float(self.stamps[self.names.index(name)])
        return out

    def __len__(self):
        return len(self.names)

    def close(self):
        pass


def _read_points_csv(path: Path) -> list[tuple[str, float, float]]:
    if not path.is_file():
        raise DatasetError(f"points file not found: {path}")
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    if not rows or [h.strip() for h in rows[0]] != ["frame", "x", "y"]:
        found = ",".join(h.strip() for h in rows[0]) if rows else "nothing"
        raise DatasetError(f"{path}: expected columns 'frame,x,y', found '{found}'")
    out = []
    for n, r in enumerate(rows[1:], start=2):
        try:
            out.append((r[0].strip(), float(r[1]), float(r[2])))
        except (ValueError, IndexError):
            raise DatasetError(f"{path}: line {n}: x and y must be numbers") from None
    if not out:
        raise DatasetError(f"{path}: no points")
    return out


def _stamps_for(names: list[str], dataset) -> np.ndarray:
    """Stamps of point frames: the dataset's image/frame stamps by name, else the numeric
    frame name, else frame order at 30 Hz."""
    known = {}
    if dataset is not None:
        known.update({nm: float(s) for nm, s in zip(dataset.names, dataset.stamps)})
        frames = dataset.optional("frames")
        if frames is not None:
            for nm, s in zip(frames["name"], frames["stamp"]):
                known[str(nm)] = float(s)
                known[Path(str(nm)).stem] = float(s)
    if all(nm in known for nm in names):
        return np.array([known[nm] for nm in names])
    try:
        return np.array([float(nm) for nm in names])
    except ValueError:
        from ..common.dataset import DEFAULT_RATE_HZ

        log.warning("points: frame names are not dataset frames nor numbers; stamps from the"
                    " frame order at %.0f Hz", DEFAULT_RATE_HZ)
        return np.arange(len(names)) / DEFAULT_RATE_HZ


# ---------------------------------------------------------------------------- main


def default_features_path(output: Path) -> Path:
    return output.with_name(output.stem + ".features.h5")


def main(conf: dict | str | None, dataset_dir: str | Path, map_path: str | Path,
         output: str | Path, *, features: str | Path | None = None,
         points: str | Path | None = None, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Localise the frames of ``dataset_dir`` on ``map_path`` into ``output`` (poses.h5 and
    poses.tum beside it) and return its path."""
    conf = resolve_localize_conf(conf)
    output = Path(output)
    if output.exists() and not overwrite:
        raise FieldlocError(f"{output} exists (use --overwrite to replace it)")
    if features is not None and points is not None:
        raise FieldlocError("give either a features file or a points file, not both")
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise DatasetError(f"dataset folder not found: {dataset_dir}")
    dataset = open_dataset(dataset_dir, need_images=False)
    module = method_module(conf["method"])
    map_file = MapFile(map_path)
    inputs = {"dataset": str(dataset_dir), "map": str(map_path), "map_hash": file_hash(map_path)}
    try:
        if points is not None:
            feats = PointFrames(points, dataset, map_file.scanlines)
            inputs.update(points=str(points), points_hash=file_hash(points))
        else:
            if features is None:
                from .. import extract

                features = default_features_path(output)
                log.info("no features given: extracting %s into %s", dataset_dir, features)
                extract.main(None, dataset_dir, features, progress=progress)
            feats = FeaturesFile(features)
            inputs.update(features=str(features), features_hash=file_hash(features))
        if len(feats.names) == 0:
            raise FieldlocError(f"{features or points}: no frames to localise")
        try:
            track = module.run(conf, dataset, feats, map_file, progress)
        finally:
            feats.close()
    finally:
        map_file.close()
    attrs = root_attrs(SCHEMA, VERSION, conf, inputs)
    attrs.update(method=conf["method"], field=map_file.field.name, dataset=str(dataset_dir),
                 method_report=json.dumps(track.meta, sort_keys=True))
    path = write_poses(output, track, attrs)
    n_failed = int(np.sum(track.failed))
    log.info("localize %s: %d frames, %d failed -> %s", conf["method"], len(track), n_failed,
             path)
    return path
