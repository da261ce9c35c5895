"""Stage localize: poses of a dataset's frames from their features and a map.

    from stages import localize
    localize.main({"method": "lut"}, "data/run1", "msl-2015.map.h5", "data/run1/poses.h5",
                  features="data/run1/features.h5")

``conf["method"]`` picks the method module (``METHODS``); each exposes ``confs`` (named
presets, at least "default") and ``run(conf, dataset, features, map_file, progress) ->
PoseTrack``, and may say which camera kinds' features it reads (``camera_kinds``, e.g.
``("omni",)``: batch runs pair it only with such datasets). ``confs`` here lists the presets of
every method as ``<method>-<preset>`` (``mcl-uniform``), each with its ``method``, and
"default" (``lut-default``). The conf given to ``main`` is a name of ``confs``, None
("default"), or a dict of overrides on the default preset of its method (``{"method": "mcl",
"init": "uniform"}``; the method "lut" when it names none); unknown keys are errors, and the
resolved conf is stored in poses.h5.

Method ``templates`` (the SURF template paper) reads no features: it matches the dataset's own
images against a template database (``templates``, from build-templates;
stages.common.templates), and the map is optional (it gives the field; without it, the field
the templates record). Its module says so with ``INPUT = "templates"``, and its ``run`` takes
the database in place of the features.

Features come from a features file (``features``) or from line points of a team's own
detector (``features=LinePoints(csv)``: columns frame, x, y in the robot frame, binned into
the scan lines by stages.common.scanlines.bin_points_to_scanlines). From a dataset's images
without a features file, stages.pipelines.images_to_poses reuses ``DIR/features.h5`` or runs
extract first (``fieldloc localize DIR`` without ``--features``).

Checked before any frame is localised (each a one-line error, or a warning where the run can
still mean something):
- the output and poses.tum beside it are none of the inputs (map, features, points, the
  dataset's files), and an existing output needs ``overwrite``; an existing poses.tum is
  replaced only where the poses file beside it is fieldloc's and records it as it is
  (stages.common.poses_file.check_tum_output), never an edited twin nor a user's trajectory
  of that name;
- odometry.csv, imu.csv and truth.csv are read once: a NaN or infinite value, a stamp out of
  order or repeated is refused with its line (stages.common.dataset.read_csv). Refused rather
  than skipped: an odometry row is an increment since the previous row, so dropping or
  reordering one moves every later pose, and no rule can tell what the robot did instead;
- the features were recorded on the map's field with the map's scan lines (features record the
  dataset's field, from simulation.yaml, and their scan lines): otherwise an error unless
  ``allow_field_mismatch``;
- lut and fit need omni features (scan-line distances, line points), mcl perspective ones;
- points files: frame ids are the dataset's frame names, or the same numbers (``3`` is frame
  ``000003``); ids that match no frame are skipped with a warning, a file matching none is
  refused;
- frames whose stamps have no imu/odometry row: a warning that says how many and where the
  frame stamps come from (frames.csv, the file names, the frame order).

Every dataset frame that extract could not read is recorded as failed ("unreadable-image", or
"extract-failed" for other reasons) with its dataset stamp, and a frame missing from the
features altogether as "not-extracted", so evaluate scores the dataset's frames, not only the
readable ones.
"""

from __future__ import annotations

import importlib
import json
import logging
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..common.artifacts import check_output, file_hash, root_attrs
from ..common.conf import KindPresets, check_bounds, registered_module, stage_conf
from ..common.dataset import (
    MAX_VALUE,
    STAMP_SOURCES,
    csv_rows,
    open_dataset,
    parse_number,
    row_frame_name,
)
from ..common.errors import DatasetError, FieldlocError, SchemaError, check_file, real_path
from ..common.features_file import FeaturesFile
from ..common.field import load_field
from ..common.map_file import MapFile
from ..common.poses_file import SCHEMA, VERSION, PoseTrack, check_tum_output, write_poses
from ..common.scanlines import bin_points_to_scanlines
from ..common.user_numbers import json_float
from .motion_model import accumulate_odometry
from .symmetry import set_up_to_mirror, start_half_warning

log = logging.getLogger(__name__)

METHODS = {
    "lut": "stages.localize.lut",
    "mcl": "stages.localize.mcl",
    "templates": "stages.localize.templates",
    "fit": "stages.localize.fit",
}
DEFAULT_METHOD = "lut"


def method_module(method: str):
    """The module of a localisation method (imported on first use)."""
    return registered_module(METHODS, method, "method")


def method_confs(method: str) -> dict:
    """The named presets of a method."""
    return method_module(method).confs


def method_camera_kinds(method: str) -> tuple[str, ...] | None:
    """The camera kinds whose features a method reads (its module's ``camera_kinds``), or
    None when the module does not say (then every kind is tried)."""
    kinds = getattr(method_module(method), "camera_kinds", None)
    return tuple(kinds) if kinds is not None else None


def available_methods() -> list[str]:
    return [m for m, mod in METHODS.items() if importlib.util.find_spec(mod) is not None]


# the presets of every method: "<method>-<preset>" -> conf with its "method"; "default" is the
# default method's. A method's module is imported when one of its presets is read.
confs = KindPresets(METHODS, method_confs, lambda m, c: {"method": m, **c},
                    aliases={"default": (DEFAULT_METHOD, "default")})


def preset_name(method: str, preset: str) -> str:
    """The name in ``confs`` of ``preset`` of ``method`` (lut, no-fusion -> lut-no-fusion)."""
    presets = method_confs(method)
    if preset not in presets:
        raise FieldlocError(f"unknown preset '{preset}' (presets: {', '.join(sorted(presets))})")
    return f"{method}-{preset}"


def resolve_localize_conf(conf: dict | str | None) -> dict:
    """The full conf of a run (module doc): a preset with the overrides merged, ``method``
    included."""
    if isinstance(conf, dict):
        method = conf.get("method", DEFAULT_METHOD)
        if not isinstance(method, str):
            raise FieldlocError(f"conf 'method' must be a method name, got {method!r}")
        method_module(method)  # an unknown method is refused as one, listing the known
        return stage_conf(confs, conf, default=f"{method}-default")
    return stage_conf(confs, conf)


# ---------------------------------------------------------------------------- points input


class LinePoints(NamedTuple):
    """A team's own line points given in place of a features file (``features=``): ``path``,
    a CSV of frame, x, y in the robot frame (m), read by PointFrames."""

    path: str | Path


def split_features(features) -> tuple[Path | None, Path | None]:
    """(features file, points CSV) of a ``features`` argument: a features file's path, a
    LinePoints, or None."""
    if features is None:
        return None, None
    if isinstance(features, LinePoints):
        return None, Path(features.path)
    return Path(features), None


class PointFrames:
    """Per-frame scan-line features from a CSV of line points (frame, x, y; robot frame, m),
    with the interface of FeaturesFile that the methods use (names, stamps, frame(name))."""

    camera_kind = "omni"

    def __init__(self, path: str | Path, dataset, scanlines):
        self.path = Path(path)
        rows = _read_points_csv(self.path)
        ids = list(dict.fromkeys(r[0] for r in rows))
        by_id: dict[str, list] = {i: [] for i in ids}
        for i, x, y in rows:
            by_id[i].append((x, y))
        rename, stamps = _point_frames_in_dataset(self.path, ids, dataset)
        names = [rename[i] for i in ids if i in rename]
        stamps = np.array([stamps[i] for i in ids if i in rename], dtype=float)
        order = np.argsort(stamps, kind="stable")
        self.names = [names[i] for i in order]
        self.stamps = stamps[order]
        self._index = {nm: k for k, nm in enumerate(self.names)}
        self._frames = {}
        for i, pts in by_id.items():
            if i not in rename:
                continue
            p = np.asarray(pts, dtype=float).reshape(-1, 2)
            radial, spiral = bin_points_to_scanlines(p, scanlines)
            self._frames[rename[i]] = {"radial": radial, "spiral": spiral,
                                       "points": p.astype(np.float32)}

    def frame(self, name: str) -> dict:
        out = dict(self._frames[name])
        out["stamp"] = float(self.stamps[self._index[name]])
        return out

    def __len__(self):
        return len(self.names)

    def close(self):
        pass


def _read_points_csv(path: Path) -> list[tuple[str, float, float]]:
    check_file(path, "points file", DatasetError)
    rows = csv_rows(path)
    if not rows or [h.strip() for h in rows[0][1]] != ["frame", "x", "y"]:
        found = ",".join(h.strip() for h in rows[0][1])[:80] if rows else "nothing"
        raise DatasetError(f"{path}: expected columns 'frame,x,y', found '{found}'")
    out = []
    for n, r in rows[1:]:
        if len(r) != 3:
            raise DatasetError(f"{path}: line {n}: expected 3 values (frame,x,y), found {len(r)}")
        name = r[0].strip()
        if not name:
            raise DatasetError(f"{path}: line {n}: empty frame id")
        try:
            x, y = parse_number(r[1]), parse_number(r[2])
        except ValueError:
            raise DatasetError(f"{path}: line {n}: x and y must be numbers") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise DatasetError(f"{path}: line {n}: x and y must be finite numbers")
        if max(abs(x), abs(y)) > MAX_VALUE:  # metres from the robot: 1e308 overflowed
            raise DatasetError(f"{path}: line {n}: x and y are metres from the robot, at most"
                               f" {MAX_VALUE:g}; got {x:g}, {y:g}")
        out.append((name, x, y))
    if not out:
        raise DatasetError(f"{path}: no points")
    return out


def _whole_number(s: str) -> int | None:
    try:
        v = float(s)
    except ValueError:
        return None
    return int(v) if math.isfinite(v) and v == int(v) else None


def _point_frames_in_dataset(path: Path, ids: list[str], dataset):
    """Which dataset frame each points-file frame id is, and its stamp: (id -> name, id ->
    stamp). Ids are frame names (image stems or frames.csv names) or the same whole numbers
    (``3`` for ``000003``). Ids matching no frame are left out with a warning; a file matching
    none is an error. A dataset without frames takes numeric ids as stamps (s), else the order
    at 30 Hz."""
    known: dict[str, float] = {}
    if dataset is not None:
        known.update({nm: float(s) for nm, s in zip(dataset.names, dataset.stamps)})
        frames = dataset.optional("frames")
        if frames is not None:
            for nm, s in zip(frames["name"], frames["stamp"]):
                # the frame's name as the dataset reads the row (a stem with a dot, f1.v2,
                # is a name, not f1 with a suffix; a folder before it is no part of it)
                known.setdefault(row_frame_name(str(nm)), float(s))
    if not known:
        try:
            stamps = {i: float(i) for i in ids}
            if not all(math.isfinite(v) for v in stamps.values()):
                raise ValueError
        except ValueError:
            from ..common.dataset import DEFAULT_RATE_HZ

            log.warning("points: the dataset has no frames and the frame ids are not numbers;"
                        " stamps from the frame order at %.0f Hz", DEFAULT_RATE_HZ)
            stamps = {i: k / DEFAULT_RATE_HZ for k, i in enumerate(ids)}
        return {i: i for i in ids}, stamps
    by_number: dict[int, str] = {}
    for nm in known:
        v = _whole_number(nm)
        if v is not None:
            by_number.setdefault(v, nm)
    rename = {}
    for i in ids:
        if i in known:
            rename[i] = i
        else:
            v = _whole_number(i)
            if v is not None and v in by_number:
                rename[i] = by_number[v]
    taken: dict[str, str] = {}
    for i, nm in rename.items():
        if nm in taken:
            raise DatasetError(
                f"{path}: frame ids '{taken[nm]}' and '{i}' are both frame '{nm}' of"
                f" {dataset.root}; give each frame one id")
        taken[nm] = i
    unknown = [i for i in ids if i not in rename]
    sample = ", ".join(sorted(known)[:3])
    if not rename:
        raise DatasetError(
            f"{path}: no frame id matches a frame of {dataset.root} (ids like '{ids[0]}';"
            f" the dataset's frames: {sample}, ...)")
    if unknown:
        log.warning("points: %d of %d frame ids of %s match no frame of %s and are skipped"
                    " (first: '%s'; the dataset's frames: %s, ...)", len(unknown), len(ids),
                    path, dataset.root, unknown[0], sample)
    return rename, {i: known[rename[i]] for i in rename}


# ---------------------------------------------------------------------------- main


def _abs(p) -> str:
    return os.path.abspath(p)


def uses_templates(method: str) -> bool:
    """Whether a method localises images against a template database (module doc)."""
    return getattr(method_module(method), "INPUT", "features") == "templates"


def check_run(conf: dict | str | None, dataset_dir: str | Path, map_path: str | Path | None,
              output: str | Path, *, features: str | Path | LinePoints | None = None,
              overwrite: bool = False, templates: str | Path | None = None):
    """What ``main`` refuses before it reads a frame (module doc): the output and poses.tum
    beside it, the dataset's time series, the method, the map. Returns (resolved conf, the
    dataset, its series, the inputs the outputs must not be), so that a chain that makes the
    features first (stages.pipelines.images_to_poses) refuses a run before extracting."""
    conf = resolve_localize_conf(conf)
    # the method's ranges (its BOUNDS) and rules (its check_conf; its run checks them too):
    # refused before any input is read or features extracted
    module = method_module(conf["method"])
    check_bounds(conf, getattr(module, "BOUNDS", {}))
    if hasattr(module, "check_conf"):
        module.check_conf(conf)
    output = Path(output)
    features, points = split_features(features)
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise DatasetError(f"dataset folder not found: {dataset_dir}")
    dataset = open_dataset(dataset_dir, need_images=False)
    inputs_given = {**dataset.files(), "map": map_path, "features": features, "points": points,
                    "templates": templates}
    check_output(output, inputs_given, overwrite=overwrite, schema=SCHEMA)
    check_tum_output(output, inputs_given, overwrite)
    series = {k: dataset.optional(k) for k in ("odometry", "imu", "truth")}  # refused if bad
    method_module(conf["method"])
    if points is not None:  # binned into an omni camera's scan lines (PointFrames)
        _check_camera_kind(conf["method"], None, f"--points {points}", kind="omni",
                           said="line points, read as an omni camera's scan lines",
                           readers=[m for m in available_methods() if not uses_templates(m)])
    if features is None and points is None and not uses_templates(conf["method"]):
        # the features still to be made are of the dataset's camera: a method that cannot
        # read them refused now, not after minutes of extraction left a features file
        _check_camera_kind(conf["method"], None, dataset_dir, kind=dataset.camera().kind)
    if map_path is not None:
        MapFile(map_path).close()
    elif not uses_templates(conf["method"]):
        raise FieldlocError(f"method {conf['method']} needs a map (--map)")
    return conf, dataset, series, inputs_given


def _main_templates(conf, dataset_dir, map_path, output, templates, *, overwrite, progress):
    """``main`` of a method that localises images against templates (module doc)."""
    from ..common.templates import read_templates

    if templates is None:
        raise FieldlocError(f"method {conf['method']} needs a template database (--templates,"
                            " from fieldloc build-templates)")
    conf, dataset, _series, _given = check_run(conf, dataset_dir, map_path, output,
                                               overwrite=overwrite, templates=templates)
    dataset = open_dataset(dataset_dir)  # the images this time
    db = read_templates(templates)
    inputs = {"dataset": _abs(dataset_dir), "templates": _abs(templates),
              "templates_hash": file_hash(templates)}
    map_file = None
    if map_path is not None:
        map_file = MapFile(map_path)
        inputs.update(map=_abs(map_path), map_hash=file_hash(map_path))
        name = db.field.get("name")
        if name and name != map_file.field.name:
            map_file.close()
            raise FieldlocError(f"{templates}: templates of field '{name}', the map {map_path}"
                                f" is of '{map_file.field.name}'")
    try:
        log.info("localize %s with %s: %d frames against %d templates", dataset_dir,
                 conf["method"], len(dataset.names), len(db))
        track = method_module(conf["method"]).run(conf, dataset, db, map_file, progress)
        field = map_file.field if map_file is not None else load_field(db.field["name"])
        set_up_to_mirror(track, field.is_point_symmetric(), conf["min_confidence"])
    finally:
        if map_file is not None:
            map_file.close()
    field_name = map_file.field.name if map_file is not None else db.field.get("name", "")
    attrs = root_attrs(SCHEMA, VERSION, conf, inputs)
    attrs.update(method=conf["method"], field=field_name, dataset=_abs(dataset_dir),
                 method_report=json.dumps(track.meta, sort_keys=True))
    path = write_poses(output, track, attrs)
    log.info("localize %s: %d frames, %d failed -> %s", conf["method"], len(track),
             int(np.sum(track.failed)), path)
    return path


def main(conf: dict | str | None, dataset_dir: str | Path, map_path: str | Path | None,
         output: str | Path, *, features: str | Path | LinePoints | None = None,
         overwrite: bool = False, progress: bool = False, allow_field_mismatch: bool = False,
         templates: str | Path | None = None, write_calib: str | Path | None = None,
         reference: str | Path | None = None) -> Path:
    """Localise the frames of ``dataset_dir`` on ``map_path`` into ``output`` (poses.h5 and
    poses.tum beside it) from ``features`` (a features file, or a team's LinePoints), and
    return its path. ``allow_field_mismatch``: localise even when the features were recorded
    on another field or with other scan lines than the map's. ``templates``: the template
    database of method templates (module doc; ``map_path`` may then be None).
    ``write_calib``: also write the dataset's calib.yaml corrected by what the run's poses
    show of its error (best with ``smooth``): an omni camera's mirror distance error
    (mirror_calibration.py, methods lut and fit), a perspective camera's mount and height
    (mount_calibration.py, method mcl), to this path (never the dataset's own calib.yaml; an
    existing file needs ``overwrite``). A calibration the run's poses cannot give (too few
    sure frames, a fit its halves do not reproduce) raises FieldlocError after the poses are
    written. ``reference``: a poses file of another run of the same recording (the first
    round of stages.pipelines.images_to_poses); a frame this run places elsewhere than it
    holds at most half the probability (``against_reference``)."""
    resolved = resolve_localize_conf(conf)
    if uses_templates(resolved["method"]) and write_calib is not None:
        raise FieldlocError("--write-calib learns a calibration from line features: it needs"
                            " --method lut or fit (omni) or mcl (perspective), not templates")
    if uses_templates(resolved["method"]):
        return _main_templates(resolved, dataset_dir, map_path, output, templates,
                               overwrite=overwrite, progress=progress)
    if templates is not None:
        raise FieldlocError(f"a template database is for --method templates, not"
                            f" {resolved['method']}")
    if features is None:
        raise FieldlocError(
            "localize needs the features of the frames (features=, from extract) or line"
            " points (features=LinePoints(csv)); stages.pipelines.images_to_poses extracts"
            " them first")
    conf, dataset, series, given = check_run(conf, dataset_dir, map_path, output,
                                             features=features, overwrite=overwrite)
    features, points = split_features(features)
    output, dataset_dir = Path(output), Path(dataset_dir)
    if write_calib is not None:
        check_write_calib(write_calib, conf, dataset, points, output, given, overwrite)
    module = method_module(conf["method"])
    inputs = {"dataset": _abs(dataset_dir), "map": _abs(map_path),
              "map_hash": file_hash(map_path)}
    if reference is not None:
        check_output(output, {"reference": reference}, overwrite=None)
        inputs.update(reference=_abs(reference), reference_hash=file_hash(reference))
    map_file = MapFile(map_path)
    try:
        if points is not None:
            feats = PointFrames(points, dataset, map_file.scanlines)
            inputs.update(points=_abs(points), points_hash=file_hash(points))
            recorded = {"field": dataset.field_record(), "scanlines": None, "failures": []}
        else:
            feats = FeaturesFile(features)
            inputs.update(features=_abs(features), features_hash=file_hash(features))
            recorded = {"field": _json_attr(feats, "field"),
                        "scanlines": _json_attr(feats, "scanlines"),
                        "failures": feats.failures}
        try:
            if len(feats.names) == 0 and not recorded["failures"]:
                raise FieldlocError(f"{features or points}: no frames to localise")
            _check_camera_kind(conf["method"], feats, features)
            if isinstance(feats, FeaturesFile):
                feats.check_of(dataset)
            if not allow_field_mismatch:
                _check_same_field(recorded, map_file, features or points)
            _warn_stamps(dataset, feats.stamps, series, conf)
            log.info("localize %s with %s: %d frames on %s", dataset_dir, conf["method"],
                     len(feats.names), map_path)
            track = (module.run(conf, dataset, feats, map_file, progress) if len(feats.names)
                     else PoseTrack())
            track = _with_missing_frames(track, dataset, feats, recorded["failures"])
            if reference is not None:
                against_reference(track, reference, conf["min_confidence"])
            set_up_to_mirror(track, map_file.field.is_point_symmetric(),
                             conf["min_confidence"])
            cols = track.arrays()
            warn = start_half_warning(cols, {"conf": conf}, accumulate_odometry(
                series["odometry"], cols["stamp"])[0] if len(cols["stamp"]) else None)
            if warn:
                log.warning(warn)
            calib_refused = None
            if write_calib is not None:
                try:
                    _write_calib(write_calib, conf, dataset, feats, track, map_file,
                                 _abs(output))
                except FieldlocError as e:  # the poses stand; said once they are written
                    calib_refused = e
        finally:
            feats.close()
    finally:
        map_file.close()
    attrs = root_attrs(SCHEMA, VERSION, conf, inputs)
    attrs.update(method=conf["method"], field=map_file.field.name, dataset=_abs(dataset_dir),
                 method_report=json.dumps(track.meta, sort_keys=True))
    path = write_poses(output, track, attrs)
    n_failed = int(np.sum(track.failed))
    log.info("localize %s: %d frames, %d failed -> %s", conf["method"], len(track), n_failed,
             path)
    if calib_refused is not None:
        raise FieldlocError(f"{calib_refused}; the poses are written: {path}")
    return path


def check_write_calib(path, conf, dataset, points, output, given: dict, overwrite: bool):
    """``write_calib`` refused before any frame is localised (or extracted): on an omni
    dataset a method of the scan-line tables (lut, fit), on a perspective one mcl, either on
    a features file (not a points file); an output that is none of the inputs nor the
    dataset's own calib.yaml nor the poses file."""
    kind = dataset.camera().kind
    if points is not None:
        raise FieldlocError("--write-calib learns the camera's calibration from the frames'"
                            " features: it needs a features file, not --points")
    learnt = RECORDING_CALIBRATIONS.get(kind)
    if learnt is None:
        raise FieldlocError(f"{dataset.root}: --write-calib corrects an omni or perspective"
                            f" calib.yaml, this dataset's camera is '{kind}'")
    if conf["method"] not in learnt.methods:
        raise FieldlocError(f"--write-calib learns {learnt.what}: it needs --method"
                            f" {' or '.join(learnt.methods)}")
    path = Path(path)
    own = dataset.root / "calib.yaml"
    if path.exists() and own.exists() and real_path(path) == real_path(own):
        raise FieldlocError(f"{path} is the dataset's own calib.yaml; it is never written over:"
                            " choose another output")
    tum = Path(output).with_suffix(".tum")
    if os.path.realpath(path) == os.path.realpath(tum):  # written last, over the calibration
        raise FieldlocError(f"{path} is the poses' TUM twin this command writes beside"  # C1-5
                            f" {Path(output).name}: choose another --write-calib output")
    check_output(path, {**given, "poses": output, "calib": own}, overwrite=overwrite,
                 kind="calibration")


def _write_calib(path, conf, dataset, feats, track, map_file, output) -> None:
    """The dataset's calib.yaml corrected by what ``track`` shows of its error, written to
    ``path`` by the camera kind's RECORDING_CALIBRATIONS entry."""
    import yaml

    own = dataset.root / "calib.yaml"
    calib = yaml.safe_load(own.read_text())
    camera = dataset.camera()
    RECORDING_CALIBRATIONS[camera.kind].write(
        path, calib, _CalibrationRun(dataset, camera, feats, track, map_file,
                                     {"source": str(output),
                                      "sources": {"dataset": _abs(dataset.root)}}))


def recording_calibration(kind: str, method: str) -> RecordingCalibration | None:
    """The calibration a run of ``method`` on a ``kind`` camera can learn (None: none)."""
    learnt = RECORDING_CALIBRATIONS.get(kind)
    return learnt if learnt is not None and method in learnt.methods else None


def calibrate_from_poses(path, dataset_dir, features, poses, map_path, *,
                         source: str | None = None) -> Path:
    """Write to ``path`` the dataset's own calib.yaml corrected by what the poses file
    ``poses`` (a run of a method of RECORDING_CALIBRATIONS on ``features``) shows of its error,
    as ``main``'s ``write_calib`` does with its run's poses; ``source``: the recording the
    written record names (default: ``poses``). Refused (FieldlocError) as ``write_calib`` is:
    too few sure frames, a fit its halves do not reproduce."""
    from ..common.poses_file import read_poses

    dataset = open_dataset(dataset_dir, need_images=False)
    cols, _attrs = read_poses(poses)
    with MapFile(map_path) as map_file, FeaturesFile(features) as feats:
        _write_calib(path, None, dataset, feats, cols, map_file,
                     source if source is not None else _abs(poses))
    return Path(path)


class _CalibrationRun(NamedTuple):
    """What a calibration from a run learns from: the dataset and its camera, the features,
    the run's track, the map, and where the written calibration says it came from."""

    dataset: object
    camera: object
    feats: object
    track: object
    map_file: MapFile
    record: dict  # corrected_calibration's source and sources


def _write_mount(path, calib: dict, run: _CalibrationRun) -> None:
    """A perspective camera's mount and height (mount_calibration.py)."""
    from ..common.head_angles import head_table
    from . import mount_calibration as mount

    estimate = mount.estimate_mount(run.map_file.field, run.camera, run.feats, run.track,
                                    head_table(run.dataset))
    new = mount.corrected_calibration(calib, estimate, **run.record)
    mount.write_corrected_calib(path, new, dataset_calib=run.dataset.root / "calib.yaml")
    log.info("calibration from the recording -> %s (pitch_offset %+.4f, roll_offset %+.4f"
             " rad, height %.4f m)", path, estimate.pitch_offset, estimate.roll_offset,
             estimate.height)


def _write_mirror(path, calib: dict, run: _CalibrationRun) -> None:
    """An omni mirror's distance error (mirror_calibration.py)."""
    from . import mirror_calibration as mc
    from .lut import SEARCH, table_search

    error = mc.estimate_distance_error(table_search(run.map_file, SEARCH), run.feats,
                                       run.track)
    new = mc.corrected_calibration(calib, error, **run.record)
    mc.write_corrected_calib(path, new, dataset_calib=run.dataset.root / "calib.yaml")
    log.info("calibration from the recording -> %s (e(d) at 1/2/3 m: %s)", path,
             ", ".join(f"{float(error(d)):+.3f}" for d in (1.0, 2.0, 3.0)))


class RecordingCalibration(NamedTuple):
    """A calibration ``--write-calib`` learns from a run's poses: what it learns (said in
    refusals), the methods whose poses and features it learns from, and its writer."""

    what: str
    methods: tuple[str, ...]
    write: Callable


# by camera kind (docs/recording-calibration.md)
RECORDING_CALIBRATIONS = {
    "omni": RecordingCalibration("the omni mirror's distance error", ("lut", "fit"),
                                 _write_mirror),
    "perspective": RecordingCalibration(
        "a perspective camera's mount (pitch and roll offsets, height)", ("mcl",),
        _write_mount),
}


def _json_attr(feats, key: str):
    try:
        return feats.attr_json(key) if key in feats.h5.attrs else None
    except ValueError:
        return None


def _check_camera_kind(method: str, feats, features, *, kind: str | None = None,
                       said: str | None = None, readers=None) -> None:
    """Features of a camera kind the method does not read (its ``camera_kinds``) refused in
    one line, naming the methods that read them (of ``readers``, default every method).
    ``kind``: the camera kind of a dataset whose features are still to be extracted
    (``features``: the dataset), refused before any frame is, or of a points file (``said``
    says what they are; templates reads images, not points: not among its ``readers``)."""
    said = said or ("a '{}' camera (its calib.yaml)" if kind else "features of a '{}' camera")
    kind = kind or getattr(feats, "camera_kind", "")
    kinds = method_camera_kinds(method)
    if kind and kinds is not None and kind not in kinds:
        others = [m for m in (readers or available_methods())
                  if kind in (method_camera_kinds(m) or ())]
        raise FieldlocError(
            f"{features}: {said.format(kind)}; --method {method} needs"
            f" {' or '.join(kinds)} features" + (f": use --method {' or '.join(others)}"
                                                 if others else ""))


# the keys of a features file's scanlines attribute (ScanLines' fields)
SCANLINE_KEYS = ("n_angles", "max_crossings", "robot_radius", "max_range", "spiral_end_radius",
                 "spiral_samples_per_turn")


def _finite_number(v) -> bool:
    return json_float(v) is not None


def _check_field_record(rec, source) -> None:
    """A features file's ``field`` attribute is a JSON object of a name (text) and a size (two
    finite numbers, m), either absent: a list, or a size of text, ended the field check in a
    traceback (trial Y1-1, Y1-2)."""
    size = rec.get("size") if isinstance(rec, dict) else None
    if not isinstance(rec, dict) or not isinstance(rec.get("name", ""), str) or (
            size is not None and not (isinstance(size, list) and len(size) == 2
                                      and all(_finite_number(v) for v in size))):
        raise SchemaError(f"{source}: damaged features file (attribute 'field' is"
                          f" {str(rec)[:60]}; expected a JSON object of a name and a size of"
                          " two numbers)")


def _check_same_field(recorded: dict, map_file, source) -> None:
    """The features' field and scan lines must be the map's (see the module doc)."""
    hint = "build the map of that field, or pass --allow-field-mismatch"
    fm = map_file.field
    rec = recorded.get("field") or {}
    _check_field_record(rec, source)
    if rec.get("name"):
        size = rec.get("size")
        same_size = size is None or (abs(size[0] - fm.length) < 0.01
                                     and abs(size[1] - fm.width) < 0.01)
        if rec["name"] != fm.name or not same_size:
            where = f" ({size[0]:g} x {size[1]:g} m)" if size else ""
            raise FieldlocError(
                f"{source}: the dataset was recorded on field '{rec['name']}'{where}, the map"
                f" {map_file.path} is of '{fm.name}' ({fm.length:g} x {fm.width:g} m); {hint}")
    sl = recorded.get("scanlines")
    if sl is not None and not (isinstance(sl, dict) and set(sl) <= set(SCANLINE_KEYS) and all(
            _finite_number(v) for v in sl.values())):
        raise SchemaError(f"{source}: damaged features file (attribute 'scanlines' is"
                          f" {str(sl)[:40]}; expected numbers of {', '.join(SCANLINE_KEYS)})")
    if isinstance(sl, dict):
        mine = map_file.scanlines.as_dict()
        diff = [k for k in ("n_angles", "max_crossings", "robot_radius", "max_range",
                            "spiral_end_radius")
                if k in sl and not math.isclose(float(sl[k]), float(mine[k]), abs_tol=1e-6)]
        if diff:
            k = diff[0]
            raise FieldlocError(
                f"{source}: the features' scan lines have {k} = {sl[k]:g}, the map"
                f" {map_file.path} was built with {mine[k]:g}; extract with the map's scan"
                " lines or build the map with the features' (or pass --allow-field-mismatch)")


def _warn_stamps(dataset, stamps, series: dict, conf: dict) -> None:
    """Warn when the frame stamps do not meet the imu/odometry stamps, and say why."""
    from .heading import nearest_rows
    from .motion_model import accumulate_odometry

    stamps = np.asarray(stamps, float)
    if not len(stamps):
        return
    source = STAMP_SOURCES.get(dataset.stamp_source, dataset.stamp_source)
    span = f"{stamps.min():g}..{stamps.max():g} s"
    tol = float(conf.get("stamp_tolerance", 0.02))
    imu = series.get("imu")
    if imu is not None:
        missing = int(np.sum(nearest_rows(imu["stamp"], stamps, tol) < 0))
        if missing:
            log.warning(
                "%d of %d frames have no imu.csv row within %g s: the frame stamps (%s, %s)"
                " and imu.csv (%g..%g s) do not meet", missing, len(stamps), tol, source, span,
                imu["stamp"].min(), imu["stamp"].max())
    odo = series.get("odometry")
    if odo is not None and len(stamps) > 1:
        _inc, has = accumulate_odometry(odo, stamps)
        missing = int(np.sum(~has[1:]))
        if missing:
            log.warning(
                "%d of %d frames have no odometry.csv row since the previous frame: the frame"
                " stamps (%s, %s) and odometry.csv (%g..%g s) do not meet", missing,
                len(stamps) - 1, source, span, odo["stamp"].min(), odo["stamp"].max())


def _failure_reason(text: str) -> str:
    return "unreadable-image" if "unreadable image" in text else "extract-failed"


def against_reference(track: PoseTrack, reference, min_confidence: float) -> None:
    """Frames of ``track`` whose pose lies in another place than the poses file
    ``reference`` holds for them (another run of the same recording, with another camera
    calibration: the first round of stages.pipelines.images_to_poses). Which place the frame
    is at then turns on a few centimetres of calibration, so neither run is sure of it: as a
    pose and its mirror do, the two places hold at most half the probability each (the
    reference's pose is listed as the next hypothesis), the frame is accepted only if that
    reaches ``min_confidence``, and it is flagged ``rounds-disagree``. One place: within the
    smoother's CONFIDENCE_RADIUS_M and CONFIDENCE_RADIUS_RAD (stages.localize.smooth)."""
    from ..common.geometry import wrap_scalar
    from ..common.poses_file import read_poses
    from .smooth import CONFIDENCE_RADIUS_M, CONFIDENCE_RADIUS_RAD

    cols, _attrs = read_poses(reference)
    row = {str(n): j for j, n in enumerate(cols["name"])}
    for i, name in enumerate(track.name):
        j = row.get(name)
        if track.failed[i] or j is None or cols["failed"][j]:
            continue
        ref = np.array([cols["x"][j], cols["y"][j], cols["theta"][j]], float)
        if (math.hypot(track.x[i] - ref[0], track.y[i] - ref[1]) <= CONFIDENCE_RADIUS_M
                and abs(wrap_scalar(track.theta[i] - ref[2])) <= CONFIDENCE_RADIUS_RAD):
            continue
        share = min(track.confidence[i], 0.5)
        hyps = np.array(track.hypotheses[i], float).reshape(-1, 4)
        hyps[0, 3] = share
        track.hypotheses[i] = np.vstack([hyps[:1], [[*ref, share]], hyps[1:]])
        track.confidence[i] = share
        track.accepted[i] = bool(track.accepted[i] and share >= float(min_confidence))
        track.flags[i] = ",".join(f for f in (track.flags[i], "rounds-disagree") if f)


def _with_missing_frames(track: PoseTrack, dataset, feats, failures: list[str]) -> PoseTrack:
    """``track`` plus a failed row for every dataset frame the features lack: frames extract
    could not read or process (their recorded reason), frames not extracted at all, and with
    a points file the frames it names no point of ("no-points"); in stamp order."""
    have = set(track.name)
    stamp_of = dict(zip(dataset.names, (float(s) for s in dataset.stamps)))
    extra = []
    for f in failures:
        name, _, text = f.partition(":")
        name = name.strip()
        if name in have or name not in stamp_of:
            continue
        extra.append((name, stamp_of[name], _failure_reason(text)))
        have.add(name)
    if isinstance(feats, FeaturesFile) and dataset.names:
        absent = [n for n in dataset.names if n not in have]  # another dataset's: check_of
        if absent:
            log.warning("%d frames of %s are not in %s (first: %s); recorded as failed"
                        " (not-extracted)", len(absent), dataset.root, feats.path, absent[0])
        extra += [(n, stamp_of[n], "not-extracted") for n in absent]
    elif isinstance(feats, PointFrames) and dataset.names:
        # a frame the points file names no point of: the team's detector saw no line there
        absent = [n for n in dataset.names if n not in have]
        if absent:
            log.warning("%d frames of %s have no points in %s (first: %s); recorded as failed"
                        " (no-points)", len(absent), dataset.root, feats.path, absent[0])
        extra += [(n, stamp_of[n], "no-points") for n in absent]
    if not extra:
        return track
    rows = [(track.stamp[i], 0, i) for i in range(len(track))]
    rows += [(stamp, 1, k) for k, (_n, stamp, _r) in enumerate(extra)]
    rows.sort(key=lambda r: (r[0], r[1]))
    out = PoseTrack(meta=track.meta)
    fields = [f for f in PoseTrack.__dataclass_fields__ if f != "meta"]  # the per-frame ones
    for stamp, is_extra, k in rows:
        if is_extra:
            name, stamp, reason = extra[k]
            out.add(name, stamp, None, mode="failed", flags=reason)
        else:
            for f in fields:
                getattr(out, f).append(getattr(track, f)[k])
    return out
