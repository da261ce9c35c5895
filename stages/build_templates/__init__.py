"""Stage build_templates: the SURF template paper's template database from captures at known poses.

    from stages import build_templates
    build_templates.main(None, "data/grid", "templates.h5")

The captures are a dataset folder of omni frames with a truth.csv of their poses: ``fieldloc
simulate omni --grid SPACING`` renders one at every node of a grid (the paper's 1 m), or a real
folder whose robot was placed at measured poses. Every frame becomes one template: its floor's
local features (stages.common.ground_features: unwarped with calib.yaml's f(r), the field's
green and lines only, keypoints in metres in the robot frame, descriptors, sign of the
Laplacian) and its true pose. The file is stages.common.templates (schema
``fieldloc.templates`` v1); it stores the ground-feature conf, so that localize's template
method makes its queries alike.

``conf``: a name of ``confs`` (``default``: our upright SURF described in the field's axes, see
FLOOR_SURF; ``surf``: rotation-invariant SURF in the robot's axes; ``sift``, ``orb``: OpenCV's),
None (default), or a dict of overrides on the default (the keys of ground_features.confs:
``ground``, ``features``, ``field``; and ``field_axes``, ``min_features``,
``truth_tolerance``). With ``field_axes`` every capture is described in its ground image
turned by its true heading (keypoints still stored in its robot frame): queries then need a
heading too (localize's template method takes the IMU's or the track's). A frame without a
truth row within ``truth_tolerance`` s, or with fewer than ``min_features`` features on the
field, is left out with a warning; a folder with no usable frame is an error, and so is a
dataset of another camera than omni.
"""

from __future__ import annotations

import copy
import logging
import os
from pathlib import Path

import numpy as np

from ..common import ground_features as gf
from ..common import local_features
from ..common.artifacts import check_output, file_hash, root_attrs
from ..common.camera import camera_can
from ..common.conf import check_bounds, stage_conf
from ..common.dataset import open_dataset, read_image, read_mask, truth_at
from ..common.errors import DatasetError, FieldlocError
from ..common.templates import SCHEMA, VERSION, TemplateDatabase, write_templates

log = logging.getLogger(__name__)

# SURF on the floor (measured on rendered msl-2015 captures 5-10 cm from their template, 534 px
# ground images of 1.5 cm): the default threshold 4e-4 (stages.common.surf) keeps 5-20
# keypoints, little more than the line crossings; 3e-5 keeps 100-130, and the edge test
# (edge_ratio) rejects nine in ten of them, the features along the lines and arcs that the
# floor mostly has, so it is off. Upright (U-SURF) descriptors computed in the ground image
# turned to the field's axes by the robot's heading (``field_axes``) matched 30-60 % correctly
# against 5-40 % for rotation-invariant SURF on the same pairs (whose orientation estimates
# scatter on the weakly textured floor).
FLOOR_SURF = {"threshold": 3e-5, "edge_ratio": 0.0}


def _preset(kind: str, field_axes: bool) -> dict:
    c = copy.deepcopy(gf.confs["default"])
    c["features"] = copy.deepcopy(local_features.confs[kind])
    if c["features"]["features"] == "surf":
        c["features"].update(FLOOR_SURF)
    c["field_axes"] = field_axes  # describe in the ground image turned by the capture's heading
    c["min_features"] = 8
    c["truth_tolerance"] = 0.02  # s
    return c


confs = {"default": _preset("surf-upright", True), "surf": _preset("surf", False),
         "sift": _preset("sift", False), "orb": _preset("orb", False)}
# the preset of each --features choice
FEATURE_PRESETS = {"surf": "default", "surf-rotating": "surf", "sift": "sift", "orb": "orb"}


# the ranges of the keys besides the ground features' (gf.BOUNDS; common.conf.check_bounds):
# a frame with fewer than min_features features is left out
BOUNDS = {"min_features": (0, None), "truth_tolerance": (0, None)}


def resolve_build_conf(conf: str | dict | None) -> dict:
    """The stage contract's conf: a dict of overrides goes on the default preset of its
    feature kind (``{"features": {"features": "sift"}}`` on ``sift``); its values are checked
    (gf.check_conf, BOUNDS) before any frame is read."""
    default = "default"
    if isinstance(conf, dict) and isinstance(conf.get("features"), dict):
        kind = conf["features"].get("features")
        if kind in ("sift", "orb"):
            default = kind
    resolved = stage_conf(confs, conf, default=default)
    check_bounds(resolved, BOUNDS)
    gf.check_conf(ground_conf(resolved))
    return resolved


def ground_conf(conf: dict) -> dict:
    """The ground-feature part of a build_templates conf (what queries must use too)."""
    return {k: conf[k] for k in gf.confs["default"]}


def main(conf: str | dict | None, dataset_dir: str | Path, output: str | Path, *,
         overwrite: bool = False, progress: bool = False) -> Path:
    """The templates of the captures in ``dataset_dir`` into ``output``; returns its path."""
    from tqdm import tqdm

    conf = resolve_build_conf(conf)
    gconf = gf.check_conf(ground_conf(conf))
    min_features = int(conf["min_features"])
    ds = open_dataset(dataset_dir)
    output = Path(output)
    check_output(output, ds.files(), overwrite=overwrite, schema=SCHEMA)
    camera = ds.camera()
    if not camera_can(camera.kind, "ground_image"):
        raise FieldlocError(f"{ds.root}: a '{camera.kind}' camera; templates are made from"
                            " omni frames (the SURF template paper)")
    truth = ds.optional("truth")
    if truth is None:
        raise DatasetError(f"{ds.root}: no truth.csv: templates need the pose of every capture"
                           " (simulate omni --grid writes it; for a real folder measure it)")
    mask_path = ds.root / "mask.png"
    mask = read_mask(mask_path, camera.image_size) if mask_path.is_file() else None
    tol = float(conf["truth_tolerance"])
    names, poses, feats = [], [], []
    skipped: list[str] = []
    for path, name, stamp in tqdm(list(zip(ds.images, ds.names, ds.stamps)),
                                  desc="build-templates", unit="frame", disable=not progress):
        pose = truth_at(truth, float(stamp), tol)
        if pose is None or not np.all(np.isfinite(pose)):
            skipped.append(f"{name}: no truth pose")
            continue
        try:
            image = read_image(path)
            f = gf.ground_features(image, camera, gconf, mask,
                                   heading=float(pose[2]) if conf["field_axes"] else None)
        except DatasetError as e:  # unreadable, or not the calibration's size
            skipped.append(f"{name}: {e}" if str(path) in str(e) else f"{name}: {path}: {e}")
            continue
        if len(f) < min_features:
            skipped.append(f"{name}: {len(f)} features on the field (< {min_features})")
            continue
        names.append(name)
        poses.append(pose)
        feats.append(f)
    if skipped:
        log.warning("build-templates: %d of %d frames left out (first: %s)", len(skipped),
                    len(ds.images), skipped[0])
    if not names:
        raise FieldlocError(f"{ds.root}: no frame makes a template ({skipped[0]})")
    width, dtype = gf.descriptor_shape(gconf)
    db = TemplateDatabase.from_templates(
        names, poses, feats, feature_kind=gf.feature_kind(gconf), ground_conf=gconf,
        field_axes=bool(conf["field_axes"]),
        field_record=ds.field_record(), descriptor_width=width, descriptor_dtype=dtype)
    inputs = {"dataset": os.path.abspath(ds.root), "calib_hash": file_hash(ds.calib_path),
              "truth_hash": file_hash(ds.root / "truth.csv")}
    if mask is not None:
        inputs["mask_hash"] = file_hash(mask_path)
    path = write_templates(output, db, root_attrs(SCHEMA, VERSION, conf, inputs))
    log.info("build-templates: %d templates, %d features (median %d each) -> %s", len(db),
             len(db.points), int(np.median(np.diff(db.offsets))), path)
    return path
