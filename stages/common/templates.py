"""The template database (schema ``fieldloc.templates``, version 1): the SURF template paper's sets
of local features of the floor, one per capture at a known pose, from ``build-templates``;
localize's template method matches queries against it.

Root attributes: the common ones (artifacts.root_attrs: schema, version, conf, inputs) plus

    @feature_kind        surf | sift | orb
    @descriptor_metric   l2 | hamming (ORB's bytes)
    @ground_features     JSON: the stages.common.ground_features conf the features were made
                         with (ground image grid, i.e. the unwarp conf, feature conf, field mask
                         conf); a query must be made with the same conf
    @field               JSON: the field record of the captures (name, size), as in features
    @n_templates         T
    @field_axes          1: every template was described in its ground image turned to the
                         field's axes by its heading (upright descriptors that compare across
                         headings; a query must be described so too), 0: in the robot's axes

Datasets (the features of all templates one after another, template k owning rows
``offsets[k]:offsets[k + 1]``, each template's strongest first):

    /names        (T,)    str     the capture's frame name
    /poses        (T, 3)  m, rad  the capture's pose on the field (x, y, theta)
    /offsets      (T + 1,) int64  first feature row of each template, then N
    /points       (N, 2)  m       keypoint positions in the capture's robot frame (x forward,
                                  y left)
    /orientation  (N,)    rad     keypoint orientation in the robot frame (0 for upright SURF)
    /scale        (N,)    m       the detector's sigma on the floor
    /laplacian    (N,)    int8    sign of the Laplacian (+1 dark blob, -1 bright; 0: unknown)
    /response     (N,)            detector strength
    /descriptors  (N, D)          float32 (SURF 64, SIFT 128) or uint8 (ORB 32 bytes)

A flat layout (not one group per template): the whole database loads in a few reads, and a
descriptor index over it is one array. A file that is not of this schema, or whose arrays do
not agree (lengths, offsets, descriptor width) or are not numbers, or whose JSON attributes are
not objects, or whose numbers are not finite or place a pose or keypoint beyond
dataset.MAX_VALUE, is refused with one line (SchemaError).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from dataclasses import field as _field
from pathlib import Path

import h5py
import numpy as np

from .artifacts import MAX_FRAMES, open_artifact, read_json_attr, stored_dataset, write_artifact
from .dataset import MAX_VALUE
from .errors import SchemaError
from .ground_features import GroundFeatures

SCHEMA = "fieldloc.templates"
VERSION = 1

# name -> units of the per-feature datasets
FEATURE_DATASETS = {"points": "m", "orientation": "rad", "scale": "m", "laplacian": "",
                    "response": "", "descriptors": ""}


@dataclass
class TemplateDatabase:
    """All templates of a file, in memory (module doc for the fields)."""

    names: list[str]
    poses: np.ndarray  # (T, 3)
    offsets: np.ndarray  # (T + 1,)
    points: np.ndarray  # (N, 2)
    orientation: np.ndarray
    scale: np.ndarray
    laplacian: np.ndarray  # int8
    response: np.ndarray
    descriptors: np.ndarray  # (N, D)
    feature_kind: str
    ground_conf: dict
    field: dict = _field(default_factory=dict)
    field_axes: bool = False
    path: Path | None = None
    attrs: dict = _field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.names)

    @property
    def owner(self) -> np.ndarray:
        """(N,) the template index of every feature row."""
        return np.repeat(np.arange(len(self.names)), np.diff(self.offsets))

    def template(self, k: int) -> GroundFeatures:
        """Template k's features (views into the database's arrays)."""
        a, b = int(self.offsets[k]), int(self.offsets[k + 1])
        return GroundFeatures(points=self.points[a:b], orientation=self.orientation[a:b],
                              scale=self.scale[a:b], laplacian=self.laplacian[a:b],
                              response=self.response[a:b], descriptors=self.descriptors[a:b])

    @classmethod
    def from_templates(cls, names, poses, feats: list[GroundFeatures], *, feature_kind: str,
                       ground_conf: dict, field_record: dict | None = None,
                       field_axes: bool = False,
                       descriptor_width: int, descriptor_dtype) -> TemplateDatabase:
        """A database of the captures ``names`` at ``poses`` with features ``feats``."""
        counts = [len(f) for f in feats]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

        def cat(attr, shape, dtype):
            parts = [np.asarray(getattr(f, attr), dtype).reshape((-1, *shape)) for f in feats]
            return np.concatenate(parts) if parts else np.zeros((0, *shape), dtype)

        return cls(names=[str(n) for n in names],
                   poses=np.asarray(poses, float).reshape(-1, 3), offsets=offsets,
                   points=cat("points", (2,), np.float64),
                   orientation=cat("orientation", (), np.float64),
                   scale=cat("scale", (), np.float64),
                   laplacian=cat("laplacian", (), np.int8),
                   response=cat("response", (), np.float64),
                   descriptors=cat("descriptors", (descriptor_width,), descriptor_dtype),
                   feature_kind=feature_kind, ground_conf=ground_conf,
                   field=dict(field_record or {}), field_axes=bool(field_axes))


def write_templates(path: str | Path, db: TemplateDatabase, attrs: dict) -> Path:
    """Write ``db`` atomically with the root ``attrs`` (artifacts.root_attrs) to ``path``."""
    from .local_features import DESCRIPTOR_METRIC

    path = Path(path)
    all_attrs = dict(attrs)
    all_attrs.update(feature_kind=db.feature_kind,
                     descriptor_metric=DESCRIPTOR_METRIC[db.feature_kind],
                     ground_features=json.dumps(db.ground_conf, sort_keys=True),
                     field=json.dumps(db.field, sort_keys=True), n_templates=len(db),
                     field_axes=int(db.field_axes))
    with write_artifact(path, all_attrs) as f:
        f.create_dataset("names", data=np.array(db.names, dtype=object),
                         dtype=h5py.string_dtype())
        d = f.create_dataset("poses", data=db.poses.astype(np.float64))
        d.attrs["units"] = "m, m, rad"
        f.create_dataset("offsets", data=db.offsets.astype(np.int64))
        for name, units in FEATURE_DATASETS.items():
            arr = getattr(db, name)
            d = f.create_dataset(name, data=arr, compression="gzip" if arr.size > 4096 else None,
                                 shuffle=arr.size > 4096)
            if units:
                d.attrs["units"] = units
    return path


def _attribute_problems(attrs: dict, kind: str, t: int) -> list[str]:
    """What the root attributes say against the file: a feature kind the matcher knows, the
    descriptor metric of that kind, and ``n_templates`` the templates held (each used by
    localize --method templates to match and to size its search; a wrong one matched
    descriptors with another metric, or passed unnoticed)."""
    from .local_features import DESCRIPTOR_METRIC

    if kind not in DESCRIPTOR_METRIC:
        return [f"feature_kind {kind[:40]!r} is none of {', '.join(sorted(DESCRIPTOR_METRIC))}"]
    out = []
    metric = attrs.get("descriptor_metric")
    metric = metric.decode() if isinstance(metric, bytes) else metric
    if metric is not None and metric != DESCRIPTOR_METRIC[kind]:
        out.append(f"descriptor_metric {str(metric)[:40]!r} is not {kind}'s"
                   f" ({DESCRIPTOR_METRIC[kind]})")
    count = attrs.get("n_templates")
    if count is not None and not (isinstance(count, (int, np.integer)) and int(count) == t):
        out.append(f"n_templates is {str(count)[:40]}, the file holds {t}")
    return out


# datasets of positions (m), each value within MAX_VALUE as a dataset's: a capture's pose and
# its keypoints lie on or near a field
POSITIONS = ("poses", "points")


def _value_problems(arrays: dict) -> list[str]:
    """Numbers no build-templates writes: any that is not finite (a NaN pose, descriptor or
    point), or a pose or keypoint beyond MAX_VALUE. localize matched against such templates
    failed every frame, with numpy's warnings and no word of the file."""
    out = []
    for k in ("poses", *FEATURE_DATASETS):
        v = arrays[k]
        if v.dtype.kind == "f" and not np.isfinite(v).all():
            out.append(f"{k} holds {v[~np.isfinite(v)].flat[0]:.6g} where finite"
                       " numbers belong")
        elif k in POSITIONS and v.size and not (np.abs(v) <= MAX_VALUE).all():
            out.append(f"{k} holds {v[~(np.abs(v) <= MAX_VALUE)].flat[0]:.6g} m;"
                       f" positions on a field lie within {MAX_VALUE:g} m")
    return out


# the most features a template may hold: a template is one ground image (about a megapixel);
# build-templates' SURF keeps 5-130 keypoints on one, so 10,000 a template is far beyond what
# it writes, and bounds what a reader reads (a 0.2 MB file of (3e8,) offsets read 2.4 GB for
# 11 s before it was refused, trial T)
MAX_FEATURES_PER_TEMPLATE = 10_000
# the widest descriptor (SIFT's 128 numbers; SURF's 64, ORB's 32 bytes)
MAX_DESCRIPTOR = 128


def _stored_shapes(f: h5py.File) -> list[str]:
    """What the datasets' shapes and element types say against the file, before a byte of
    them is read (stored_dataset refuses one not stored in the file or of elements no writer
    writes): T names, poses (T, 3), offsets (T + 1,), N rows of each feature dataset (points
    (N, 2), descriptors (N, D)), for at most MAX_FRAMES templates of MAX_FEATURES_PER_TEMPLATE
    features each."""
    d = {k: stored_dataset(f, k, f"'{SCHEMA}' file")
         for k in ("names", "poses", "offsets", *FEATURE_DATASETS)}
    if d["names"].dtype.kind not in "OSU":  # numbers where frame names belong (trial V1-6)
        return [f"names hold {d['names'].dtype} values where text belongs"]
    t = d["names"].shape[0] if d["names"].ndim == 1 else -1
    n = d["points"].shape[0] if d["points"].ndim == 2 else -1
    want = {"names": (t,), "poses": (t, 3), "offsets": (t + 1,), "points": (n, 2),
            "descriptors": (n, d["descriptors"].shape[-1] if d["descriptors"].ndim else -1)}
    if not 0 <= t <= MAX_FRAMES:
        return [f"names has shape {d['names'].shape}; expected (T,) for T <= {MAX_FRAMES:,}"]
    if not 0 <= n <= MAX_FEATURES_PER_TEMPLATE * max(t, 1):
        return [f"points has shape {d['points'].shape}; expected (N, 2) for N <="
                f" {MAX_FEATURES_PER_TEMPLATE:,} a template"]
    if not 1 <= want["descriptors"][1] <= MAX_DESCRIPTOR:
        return [f"descriptors has shape {d['descriptors'].shape}; expected (N, D) for D <="
                f" {MAX_DESCRIPTOR}"]
    return [f"{k} has shape {d[k].shape}, expected {want.get(k, (n,))}" for k in d
            if d[k].shape != want.get(k, (n,))][:1]


def read_templates(path: str | Path) -> TemplateDatabase:
    """The database of a templates file; SchemaError (one line) for anything else."""
    path = Path(path)
    f = open_artifact(path, SCHEMA, VERSION)
    with f:
        problems = _stored_shapes(f)
        if problems:
            raise SchemaError(f"{path}: damaged '{SCHEMA}' file: {problems[0]}")
        try:
            names = [n.decode() if isinstance(n, bytes) else str(n) for n in f["names"][()]]
            arrays = {k: f[k][()] for k in ("poses", "offsets", *FEATURE_DATASETS)}
            kind = f.attrs["feature_kind"]
            kind = kind.decode() if isinstance(kind, bytes) else str(kind)
            ground_conf = read_json_attr(f, "ground_features")
            field_record = read_json_attr(f, "field")
            field_axes = bool(int(f.attrs["field_axes"]))
            attrs = {k: f.attrs[k] for k in f.attrs}
        except (KeyError, OSError, ValueError, TypeError) as e:
            raise SchemaError(f"{path}: damaged '{SCHEMA}' file ({e})") from None
    t, n = len(names), len(arrays["points"])
    off = np.asarray(arrays["offsets"])
    problems = []
    if arrays["poses"].shape != (t, 3):
        problems.append(f"poses {arrays['poses'].shape} for {t} templates")
    if off.shape != (t + 1,) or (t + 1 and (off[0] != 0 or off[-1] != n
                                             or np.any(np.diff(off) < 0))):
        problems.append("offsets do not partition the features")
    for k in FEATURE_DATASETS:
        if len(arrays[k]) != n:
            problems.append(f"{k} has {len(arrays[k])} rows, points {n}")
    if arrays["points"].ndim != 2 or arrays["points"].shape[1:] != (2,):
        problems.append("points are not (N, 2)")
    if arrays["descriptors"].ndim != 2:
        problems.append("descriptors are not (N, D)")
    problems += [f"{k} holds {'text' if arrays[k].dtype.kind in 'OSU' else arrays[k].dtype}"
                 " where numbers belong" for k in ("poses", "offsets", *FEATURE_DATASETS)
                 if arrays[k].dtype.kind not in "fiu"]
    if not problems:
        problems += _value_problems(arrays)
    problems += [f"attribute '{k}' is {str(v)[:40]!r}, not a JSON object"
                 for k, v in (("ground_features", ground_conf), ("field", field_record))
                 if not isinstance(v, dict)]
    problems += _attribute_problems(attrs, kind, t)
    if problems:
        raise SchemaError(f"{path}: damaged '{SCHEMA}' file: {problems[0]}")
    return TemplateDatabase(names=names, poses=np.asarray(arrays["poses"], float),
                            offsets=off.astype(np.int64),
                            points=np.asarray(arrays["points"], float),
                            orientation=np.asarray(arrays["orientation"], float),
                            scale=np.asarray(arrays["scale"], float),
                            laplacian=np.asarray(arrays["laplacian"]).astype(np.int8),
                            response=np.asarray(arrays["response"], float),
                            descriptors=arrays["descriptors"], feature_kind=kind,
                            ground_conf=ground_conf, field=field_record, field_axes=field_axes,
                            path=path, attrs=attrs)
