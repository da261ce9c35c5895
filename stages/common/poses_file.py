"""The poses artifact (schema ``fieldloc.poses``) written by ``localize``, and its TUM twin.

Root attributes: the common ones plus ``method`` (lut, mcl, templates), ``field`` (name),
``dataset``, ``method_report`` (JSON: what the method learnt over the run, e.g. lut's
estimated calibration error; ``read_poses`` decodes it, as ``conf`` and ``inputs``).

    /poses/name        (N,) str    frame name
    /poses/stamp       (N,) f8     s
    /poses/x, /y       (N,) f8     m, field frame: the top hypothesis; NaN where the frame failed
    /poses/theta       (N,) f8     rad
    /poses/failed      (N,) bool   no hypothesis beat the null (never a fallback pose)
    /poses/accepted    (N,) bool   v2: not failed and confidence >= min_confidence
    /poses/error       (N,) f4     method's own error term (lut: weighted matching error)
    /poses/confidence  (N,) f4     0..1, the probability of the top hypothesis
    /poses/confidence_up_to_mirror (N,) f4  v2, optional: the probability of the top hypothesis
                                   or its mirror image under the field's 180 deg symmetry
                                   (equal to ``confidence`` on a field without it)
    /poses/accepted_up_to_mirror   (N,) bool  v2, optional: not failed and
                                   confidence_up_to_mirror >= min_confidence
    /poses/mode        (N,) str    how the pose was found: global, local, tracking, ...
    /poses/runtime     (N,) f4     s, time the method spent on the frame
    /poses/covariance  (N, 3, 3) f4  optional, m^2 / rad^2
    /poses/flags       (N,) str    optional notes per frame (e.g. "mirror-ambiguous")
    /hypotheses        (N, K, 4) f8  v2: per frame up to K hypotheses, ranked, as
                                   (x m, y m, theta rad, probability); NaN rows pad

Version 1 files (no ``accepted``, no ``/hypotheses``) are read as if every frame that did not
fail was accepted and had one hypothesis, its pose with its confidence. Files without the
``*_up_to_mirror`` columns are read with them equal to ``confidence`` and ``accepted``.

A file whose columns or root attributes are of another type than these (text in a number
column, a flag other than true/false or 0/1, ``conf``, ``inputs`` or ``method_report`` not a
JSON object, an input's path not text, ``method``, ``field`` or ``dataset`` not text or longer
than a name or path) is refused in one line (SchemaError), and so is one whose values no run
writes: a stamp that is not finite or beyond dataset.MAX_STAMP, a pose that is infinite or
beyond dataset.MAX_VALUE (or NaN on an accepted frame), a confidence or hypothesis probability
outside [0, 1] or NaN, a hypotheses row part NaN or a frame that did not fail without its top
hypothesis, a runtime negative or not finite, an error below 0, a covariance neither finite nor
all NaN (none given), a frame both accepted (or accepted up to the mirror) and failed, a frame
name given twice or not a plain image name (a folder, ..), a mode no
writer records (MODES), a text column (name, mode, flags) of other values; and, before
any data is read (``_stored``), a dataset that is a group, a link to another file, virtual or
stored outside the file, or of more than MAX_FRAMES frames or MAX_HYPOTHESES hypotheses.
``created`` and ``method`` are labels no command decides by, and are not checked.
``tum_twin`` is not checked: a record matching no file vouches for no twin, so
``--overwrite`` keeps the twin (``twin_vouched``), the safe side.

``poses.tum`` beside it holds "stamp x y z qx qy qz qw" rows of the accepted frames (the top
hypothesis), readable by evo; its first line is the header ``# stamp x y z qx qy qz qw``. The
poses file records the twin's size and SHA-256 as written (root attribute ``tum_twin``):
``--overwrite`` replaces a twin only where the poses file beside it is fieldloc's and its
record matches the twin (``check_tum_output``), never a twin edited below its header nor a
user's file that starts with the header.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from .artifacts import (
    MAX_FRAMES,
    as_written,
    atomic_path,
    check_output,
    file_entry,
    may_replace,
    open_artifact,
    read_json_attr,
    refuse_inputs,
    starts_with,
    stored_dataset,
    write_artifact,
    writing,
)
from .dataset import MAX_STAMP, MAX_VALUE, stamp_error
from .errors import FieldlocError, SchemaError

SCHEMA = "fieldloc.poses"
VERSION = 2

COLUMNS = {
    # name: (dtype, units)
    "stamp": ("f8", "s"),
    "x": ("f8", "m"),
    "y": ("f8", "m"),
    "theta": ("f8", "rad"),
    "failed": ("bool", ""),
    "accepted": ("bool", ""),
    "error": ("f4", ""),
    "confidence": ("f4", ""),
    "runtime": ("f4", "s"),
    "confidence_up_to_mirror": ("f4", ""),
    "accepted_up_to_mirror": ("bool", ""),
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
    accepted: list = field(default_factory=list)
    error: list = field(default_factory=list)
    confidence: list = field(default_factory=list)
    confidence_up_to_mirror: list = field(default_factory=list)  # localize sets it (module doc)
    accepted_up_to_mirror: list = field(default_factory=list)
    mode: list = field(default_factory=list)
    runtime: list = field(default_factory=list)
    covariance: list = field(default_factory=list)
    flags: list = field(default_factory=list)
    hypotheses: list = field(default_factory=list)  # per frame (k, 4) x, y, theta, probability
    meta: dict = field(default_factory=dict)  # what the method learnt over the run (JSON)

    def add(self, name, stamp, pose=None, *, error=math.nan, confidence=0.0, mode="",
            runtime=0.0, covariance=None, flags="", hypotheses=None, accepted=None):
        """Record one frame; ``pose=None`` records a failure (NaN pose, failed=True, no
        hypotheses). ``hypotheses`` (k, 4): ranked (x, y, theta, probability), the first
        being ``pose``; by default the pose alone with ``confidence``. ``accepted``: by
        default every frame that did not fail."""
        failed = pose is None
        x, y, th = (math.nan, math.nan, math.nan) if failed else (float(v) for v in pose)
        if mode not in MODES:  # a reader refuses any other (_check_frames)
            raise ValueError(f"mode {mode!r} is none of {sorted(MODES)}")
        self.name.append(str(name))
        self.stamp.append(float(stamp))
        self.x.append(x)
        self.y.append(y)
        self.theta.append(th)
        self.failed.append(failed)
        self.accepted.append(bool(not failed if accepted is None else accepted and not failed))
        self.error.append(float(error))
        self.confidence.append(float(confidence))
        self.confidence_up_to_mirror.append(float(confidence))
        self.accepted_up_to_mirror.append(self.accepted[-1])
        self.mode.append(str(mode))
        self.runtime.append(float(runtime))
        self.covariance.append(
            np.full((3, 3), np.nan) if covariance is None else np.asarray(covariance, float)
        )
        # a frame's flags are a set of notes (each once, in the order first given): a note
        # raised by each of a frame's tracks is said once
        self.flags.append(",".join(dict.fromkeys(f for f in str(flags).split(",") if f)))
        if failed:
            h = np.zeros((0, 4))
        elif hypotheses is None:
            h = np.array([[x, y, th, float(confidence)]])
        else:
            h = np.asarray(hypotheses, float).reshape(-1, 4)
        self.hypotheses.append(h)

    def __len__(self):
        return len(self.name)

    def arrays(self) -> dict[str, np.ndarray]:
        out = {k: np.asarray(getattr(self, k), dtype=COLUMNS[k][0]) for k in COLUMNS}
        out["name"] = np.asarray(self.name, dtype=object)
        out["mode"] = np.asarray(self.mode, dtype=object)
        out["flags"] = np.asarray(self.flags, dtype=object)
        out["covariance"] = np.asarray(self.covariance, dtype=np.float32).reshape(-1, 3, 3)
        out["hypotheses"] = pad_hypotheses(self.hypotheses)
        return out


def pad_hypotheses(per_frame: list) -> np.ndarray:
    """(N, K, 4) from a list of (k_i, 4) arrays, K = max k_i (at least 1), NaN padded."""
    k = max([len(h) for h in per_frame] + [1])
    out = np.full((len(per_frame), k, 4), np.nan)
    for i, h in enumerate(per_frame):
        if len(h):
            out[i, :len(h)] = h
    return out


def write_poses(path: str | Path, track: PoseTrack, attrs: dict, *, tum: bool = True) -> Path:
    """Write poses.h5 and, with ``tum``, poses.tum beside it, as one pair: both are written in
    full (temporary parts) before either is committed, so that a failure while writing either
    (a full disk) leaves neither part and the old pair as it was; then the old twin goes
    (``drop_twin``), the poses are committed, and the twin."""
    path = Path(path)
    arr = track.arrays()
    with contextlib.ExitStack() as pair:
        # a full disk met while writing either file is told as the poses file's (the output
        # the user gave); the twin would otherwise be named, as the outer block
        pair.enter_context(writing(path))
        if tum:  # committed last (the outer block), removed if the poses fail
            tum_part = pair.enter_context(atomic_path(path.with_suffix(".tum"), suffix=".tum"))
            with open(tum_part, "w", newline="\n") as f:
                write_tum_to(f, arr)
            attrs = {**attrs, TWIN_ATTR: file_entry(tum_part)}  # what vouches for the twin
        # the new poses are committed next: the old twin must not outlive them
        with write_artifact(path, attrs,
                            before_commit=(lambda: drop_twin(path)) if tum else None) as h5:
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
            ds = h5.create_dataset("hypotheses", data=arr["hypotheses"])
            ds.attrs["units"] = "m, m, rad, 1"
            ds.attrs["columns"] = "x, y, theta, probability"
    return path


TUM_HEADER = "stamp x y z qx qy qz qw"  # write_tum's first line, after "# "
# the poses file's root attribute holding its TUM twin's ``file_entry`` as written ("<size>
# <SHA-256>"): the header line alone is kept by an edit below it and by a user's copy
TWIN_ATTR = "tum_twin"


def drop_twin(path: str | Path) -> None:
    """Remove the TUM twin (X.tum) of the poses file ``path`` just before new poses are
    committed there, so that a run stopped between the two commits (SIGTERM, SIGKILL, power
    loss) leaves new poses without a twin rather than beside the previous run's: the pair
    never disagrees. Only a twin this run may replace goes (``may_replace``, as its commit
    would) and only one the poses file vouches for (``twin_vouched``); any other file is
    kept."""
    tum = Path(path).with_suffix(".tum")
    if not (tum.is_file() and twin_vouched(path)(tum)):
        return
    rule = may_replace(tum)
    if rule is False or (callable(rule) and not rule(tum)):
        return  # another run's, written meanwhile: the twin's own commit refuses it
    tum.unlink(missing_ok=True)


def is_fieldloc_tum(path: str | Path) -> bool:
    """Whether ``path`` starts with the header line ``write_tum`` writes: a TUM file of
    fieldloc's shape (a report's truth.tum, export's output); no proof that it is as written."""
    return starts_with(path, f"# {TUM_HEADER}\n".encode())


def twin_vouched(poses: str | Path):
    """The test ``--overwrite`` applies to the TUM twin of the poses file ``poses``: whether
    that poses file is fieldloc's and records the twin as it is now (TWIN_ATTR). A poses file
    that is absent, not fieldloc's, of an older fieldloc (no record) or unreadable vouches for
    nothing."""
    poses = Path(poses)

    def vouched(tum: str | Path) -> bool:
        try:
            with h5py.File(poses, "r") as f:
                schema, entry = f.attrs.get("schema"), f.attrs.get(TWIN_ATTR)
        except (OSError, ValueError, RuntimeError):
            return False
        schema = schema.decode(errors="replace") if isinstance(schema, bytes) else schema
        entry = entry.decode(errors="replace") if isinstance(entry, bytes) else entry
        return (schema == SCHEMA and isinstance(entry, str) and not Path(tum).is_symlink()
                and as_written(tum, entry))  # a link is a user's, wherever it points
    return vouched


def check_tum_output(poses: str | Path, inputs: dict | None, overwrite: bool) -> Path:
    """The rule of the TUM twin (X.tum) written beside the poses file ``poses`` (X.h5): none
    of the ``inputs``; an existing one needs ``overwrite``, and even then is replaced only
    where the poses file beside it vouches for it (``twin_vouched``): never a twin edited
    since, nor a user's trajectory of the same name. Returns the twin's path."""
    tum = Path(poses).with_suffix(".tum")
    refuse_inputs(tum, inputs)
    if overwrite and (tum.is_file() or tum.is_symlink()) and not twin_vouched(poses)(tum):
        raise FieldlocError(f"{tum} is not the TUM twin of {Path(poses).name} as fieldloc"
                            " wrote it (edited since, a user's file, or beside no poses"
                            " file of fieldloc's that records it): --overwrite never replaces"
                            " it; move it aside or choose another output")
    return check_output(tum, inputs, overwrite=overwrite, ours=twin_vouched(poses))


def write_tum(path: str | Path, arr: dict) -> Path:
    """TUM trajectory rows 'stamp x y z qx qy qz qw' (z = 0, yaw-only quaternion) of the
    accepted frames, into the file ``path`` (atomically)."""
    with atomic_path(Path(path), suffix=".tum") as tmp:
        with open(tmp, "w", newline="\n") as f:
            write_tum_to(f, arr)
    return Path(path)


def write_tum_to(stream, arr: dict) -> None:
    """``write_tum``'s text, written to the open text ``stream`` (a file, or stdout)."""
    ok = np.asarray(arr["accepted"], bool) if "accepted" in arr else ~arr["failed"]
    th = arr["theta"][ok]
    rows = np.stack(
        [arr["stamp"][ok], arr["x"][ok], arr["y"][ok], np.zeros(ok.sum()),
         np.zeros(ok.sum()), np.zeros(ok.sum()), np.sin(th / 2), np.cos(th / 2)],
        axis=1,
    )
    np.savetxt(stream, rows, fmt="%.6f", header=TUM_HEADER)


def read_poses(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """Columns and root attributes (with ``conf`` and ``inputs`` decoded) of a poses file,
    version 1 or 2. The columns include ``accepted`` and ``hypotheses`` (N, K, 4) for both
    versions (see the module doc for version 1)."""
    try:
        return _read_poses(path)
    except (KeyError, ValueError, TypeError, OSError) as e:
        raise SchemaError(f"{path}: damaged poses file ({e})") from None


def run_inputs(attrs: dict) -> dict[str, list[Path]]:
    """The files the poses were made from (the dataset's own files, the map, features and
    points the poses file names): a command reading the poses (export, show hypotheses)
    never writes over them, --overwrite or not."""
    from .dataset import open_dataset

    out: dict[str, list[Path]] = {}
    root = attrs.get("dataset")
    if isinstance(root, str) and root and Path(root).is_dir():
        try:
            out = {f"the run's dataset: {k}": v
                   for k, v in open_dataset(root, need_images=False).files().items()}
        except FieldlocError:
            out = {}
    for role in ("map", "features", "points"):
        path = (attrs.get("inputs") or {}).get(role)
        if isinstance(path, str) and path:
            out[f"the run's {role}"] = [Path(path)]
    return out


REQUIRED = ("name", "stamp", "x", "y", "theta", "failed", "confidence")


def _check_shapes(out: dict, path) -> None:
    """Every column one value per frame, ``covariance`` (N, 3, 3) and ``/hypotheses``
    (N, K, 4) numbers: a file edited or damaged elsewhere is refused in one line rather than
    read with columns out of step."""
    missing = [k for k in REQUIRED if k not in out]
    if missing:
        raise SchemaError(f"{path}: damaged poses file (no /poses/{missing[0]})")
    n = len(out["name"]) if np.ndim(out["name"]) == 1 else -1
    for k, v in out.items():
        want = {"covariance": (n, 3, 3)}.get(k)
        if k == "hypotheses":
            if v.ndim != 3 or v.shape[0] != n or v.shape[2] != 4 or v.dtype.kind not in "fiu":
                raise SchemaError(f"{path}: damaged poses file (/hypotheses has shape"
                                  f" {v.shape} of {v.dtype}; expected ({n}, K, 4) numbers)")
        elif want is not None:
            if v.shape != want:
                raise SchemaError(f"{path}: damaged poses file (/poses/{k} has shape {v.shape};"
                                  f" expected {want})")
        elif v.ndim != 1 or len(v) != n:
            raise SchemaError(f"{path}: damaged poses file (/poses/{k} has shape {v.shape};"
                              f" /poses/name has {n} frames)")


# root attributes that are text where present, and the most characters each may hold: a
# method's or field's name is a word (fieldloc's longest are a dozen characters), the dataset
# a folder's path (Linux's PATH_MAX); longer text is damage, and was drawn into every plot
# title of a report (100,000 characters took matplotlib minutes)
TEXT_ATTRS = {"method": 64, "field": 256, "dataset": 4096}
# columns of text, one string per frame (frame name, mode, flags)
TEXT_COLUMNS = ("name", "mode", "flags")
# numbers of more than one a frame, beside COLUMNS
NUMBER_ARRAYS = ("covariance", "hypotheses")
# JSON mappings ({} where absent); ``inputs`` maps each input's role to its path or hash
JSON_ATTRS = ("conf", "inputs", "method_report")


def _check_types(out: dict, attrs: dict, path) -> None:
    """Each column of COLUMNS numbers (its flags bool or integer 0/1) and the root attributes
    of their kind (TEXT_ATTRS, JSON_ATTRS): a file edited or damaged elsewhere is refused in
    one line rather than failing where a command first uses the value."""
    for k, v in out.items():
        dtype = COLUMNS.get(k, ("",))[0]
        if dtype == "bool":
            ok = v.dtype.kind == "b" or (v.dtype.kind in "iu" and np.isin(v, (0, 1)).all())
            want = "true/false (or 0/1)"
        else:
            ok = (k not in COLUMNS and k not in NUMBER_ARRAYS) or v.dtype.kind in "fiu"
            want = "numbers"
        if not ok:
            held = "text" if v.dtype.kind in "OSU" else f"{v.dtype} values"
            where = k if k == "hypotheses" else f"poses/{k}"
            raise SchemaError(f"{path}: damaged poses file (/{where} holds {held};"
                              f" expected {want})")
    for k in TEXT_COLUMNS:
        if k in out and not all(isinstance(s, str) for s in out[k]):
            raise SchemaError(f"{path}: damaged poses file (/poses/{k} holds"
                              f" {out[k].dtype} values; expected text)")
    for k, most in TEXT_ATTRS.items():
        if k in attrs and not isinstance(attrs[k], str):
            raise SchemaError(f"{path}: damaged poses file (attribute '{k}' is"
                              f" {str(attrs[k])[:40]!r}; expected text)")
        if k in attrs and len(attrs[k]) > most:
            raise SchemaError(f"{path}: damaged poses file (attribute '{k}' holds"
                              f" {len(attrs[k])} characters, {attrs[k][:20]!r}...; expected"
                              f" at most {most})")
    for k in JSON_ATTRS:
        if not isinstance(attrs[k], dict):
            raise SchemaError(f"{path}: damaged poses file (attribute '{k}' is"
                              f" {str(attrs[k])[:40]!r}; expected a JSON object)")
    wrong = [k for k, v in attrs["inputs"].items() if not isinstance(v, str)]
    if wrong:  # a role's path is opened (show hypotheses: the map) or checked against -o
        raise SchemaError(f"{path}: damaged poses file (attribute 'inputs' gives {wrong[0][:40]!r}"
                          f" {str(attrs['inputs'][wrong[0]])[:40]!r}; expected a path as text)")


# the most hypotheses a frame lists: the methods' ``hypotheses`` conf keys are bounded far
# below it; more is damage, refused before the array is read
MAX_HYPOTHESES = 10_000
# the modes writers record (PoseTrack.add refuses any other): lut's and the fit's global,
# global-heading, local, null; the grid belief's grid and predicted; mcl's tracking,
# predicted, recovering, initial; smoothing's smoothed; failed; "" where none is given
MODES = frozenset({"", "global", "global-heading", "local", "null", "grid", "predicted",
                   "tracking", "recovering", "initial", "smoothed", "failed"})


# columns that are probabilities: a number from 0 to 1 in every frame (a failed frame's is 0)
PROBABILITIES = ("confidence", "confidence_up_to_mirror")
# how far past 1 a probability may round: a sum of probabilities (up to the mirror) in f8
# rounds a few ulps past 1; anything beyond this is not a probability
PROBABILITY_SLACK = 1e-6
# columns of a pose: NaN where the frame failed, else a number no larger than MAX_VALUE
# (metres, radians), as a dataset's values
POSE_COLUMNS = ("x", "y", "theta")


def _check_values(out: dict, path) -> None:
    """Each frame's stamp finite and within MAX_STAMP (as the dataset's and features'
    stamps), its pose NaN (failed) or within MAX_VALUE and finite where the frame is accepted
    (up to the mirror or not), its confidences in [0, 1], its
    hypotheses' poses and probabilities likewise (NaN rows pad): a file edited or damaged
    elsewhere is refused in one line, rather than evaluated into a report of NaN or of
    confidences of 1e30, with numpy's warnings on the way."""
    def bad(k: str, v: np.ndarray, i: int, want: str) -> SchemaError:
        return SchemaError(f"{path}: damaged poses file (/poses/{k} of frame"
                           f" {str(out['name'][i])[:40]} is {float(v[i]):.6g}; expected {want})")

    stamp = np.asarray(out["stamp"], float)
    wrong = np.flatnonzero(~(np.abs(stamp) <= MAX_STAMP))
    if len(wrong):
        i = int(wrong[0])
        raise SchemaError(f"{path}: damaged poses file (frame {str(out['name'][i])[:40]}:"
                          f" {stamp_error(float(stamp[i]))})")
    _check_frames(out, path)
    failed = np.asarray(out["failed"], bool)
    accepted = np.zeros(len(stamp), bool)  # a frame a command uses: its pose must be finite
    for k in ("accepted", "accepted_up_to_mirror"):
        v = np.asarray(out.get(k, ~failed), bool)
        wrong = np.flatnonzero(v & failed)
        if len(wrong):  # evaluate counted it failed, export wrote its row
            raise SchemaError(f"{path}: damaged poses file (frame"
                              f" {str(out['name'][int(wrong[0])])[:40]} both {k} and failed)")
        accepted |= v
    for k, want, ok in (("runtime", "a finite time of 0 s or more",
                         lambda v: np.isfinite(v) & (v >= 0)),
                        ("error", "NaN or a number of 0 or more", lambda v: ~(v < 0))):
        if k in out:
            v = np.asarray(out[k], float)
            wrong = np.flatnonzero(~ok(v))
            if len(wrong):
                raise bad(k, v, int(wrong[0]), want)
    if "covariance" in out:  # nine numbers, or nine NaN where none was given (PoseTrack.add)
        c = np.asarray(out["covariance"], float)
        wrong = np.flatnonzero(~(np.isfinite(c).all(axis=(1, 2)) | np.isnan(c).all(axis=(1, 2))))
        if len(wrong):  # export wrote its inf entries
            raise SchemaError(f"{path}: damaged poses file (/poses/covariance of frame"
                              f" {str(out['name'][int(wrong[0])])[:40]} is neither finite nor"
                              " all NaN (none given))")
    for k in POSE_COLUMNS:
        v = np.asarray(out[k], float)
        wrong = np.flatnonzero(~(np.isnan(v) | (np.abs(v) <= MAX_VALUE)))
        if len(wrong):
            raise bad(k, v, int(wrong[0]), f"NaN or a number within {MAX_VALUE:g}")
        wrong = np.flatnonzero(accepted & np.isnan(v))
        if len(wrong):  # export wrote "nan" rows of it, evaluate scored them
            raise SchemaError(f"{path}: damaged poses file ({k} not finite on accepted frame"
                              f" {str(out['name'][int(wrong[0])])[:40]})")
    for k in PROBABILITIES:
        if k in out:
            v = np.asarray(out[k], float)
            wrong = np.flatnonzero(~((v >= 0) & (v <= 1 + PROBABILITY_SLACK)))
            if len(wrong):
                raise bad(k, v, int(wrong[0]), "a probability from 0 to 1")
    if "hypotheses" in out:
        h = np.asarray(out["hypotheses"], float)
        ok = np.isnan(h) | (np.abs(h) <= MAX_VALUE)
        ok[..., 3] &= ~(h[..., 3] < 0) & ~(h[..., 3] > 1 + PROBABILITY_SLACK)
        # a row is a hypothesis (four numbers) or padding (four NaN, as pad_hypotheses writes)
        nan = np.isnan(h)
        ok &= (nan == nan.all(axis=2, keepdims=True))
        wrong = np.argwhere(~ok)
        if len(wrong):
            i, k, c = (int(n) for n in wrong[0])
            raise SchemaError(f"{path}: damaged poses file (/hypotheses of frame"
                              f" {str(out['name'][i])[:40]}: row {k} column {c} is"
                              f" {h[i, k, c]:.6g}; expected a pose within {MAX_VALUE:g} and a"
                              " probability from 0 to 1, or NaN padding)")
        first = h[:, 0, 3] if h.shape[1] else np.full(len(h), np.nan)  # (N, 0, 4): none
        wrong = np.flatnonzero(~np.asarray(out["failed"], bool) & np.isnan(first))
        if len(wrong):  # every writer ranks a frame's pose first (PoseTrack.add)
            raise SchemaError(f"{path}: damaged poses file (/hypotheses of frame"
                              f" {str(out['name'][int(wrong[0])])[:40]} holds none; a frame"
                              " that did not fail has its pose as the first)")


def _check_frames(out: dict, path) -> None:
    """The frames as a dataset lists them (localize writes them in its order): each name once
    and a plain image name (no folder, no ..), each mode one that writers record (MODES). A
    file edited elsewhere is refused in one line: evaluate matched truth by name and stamp,
    and a name was drawn into paths and plot titles. Stamps are not held to an order: a
    dataset stamped from its file names orders its frames by name (9.5.png after 10.5.png)."""
    seen = set()
    for name in out["name"]:
        if (name in seen or name in ("", ".", "..") or "/" in name or "\\" in name
                or not name.isprintable() or name != name.strip()):  # a line break, a tab
            why = "given twice" if name in seen else "not a plain image name"
            raise SchemaError(f"{path}: damaged poses file (frame name {name[:40]!r} is {why})")
        seen.add(name)
    wrong = [m for m in out.get("mode", ()) if m not in MODES]
    if wrong:
        raise SchemaError(f"{path}: damaged poses file (/poses/mode {wrong[0][:40]!r} is none"
                          f" of {', '.join(sorted(m for m in MODES if m))})")


def _group(h5, name: str, path):
    """The group ``name`` of a poses file, stored in it (not a link elsewhere)."""
    link = h5.get(name, getlink=True)
    if not isinstance(link, h5py.HardLink) or not isinstance(h5[name], h5py.Group):
        raise SchemaError(f"{path}: damaged poses file (/{name} is no group of the file)")
    return h5[name]


def _stored(h5, name: str, path):
    """The dataset ``name`` of a poses file, read after its checks: stored in the file and of
    numbers or short text (artifacts.stored_dataset), of one value per frame (``hypotheses``
    (N, K, 4), ``covariance`` (N, 3, 3)) for at most MAX_FRAMES frames and MAX_HYPOTHESES
    hypotheses (a compressed 15 kB file of (6, 2e8, 4) read for a minute into "out of
    memory", trial Q10)."""
    d = stored_dataset(h5, name, "poses file")
    shape = d.shape or ()
    tail = {"hypotheses": 3, "poses/covariance": 3}.get(name, 1)
    names = h5.get("poses/name") if name != "poses/name" else None  # checked as read first
    frames = names.shape[:1] if isinstance(names, h5py.Dataset) else ()
    if (len(shape) != tail or shape[0] > MAX_FRAMES or (frames and shape[0] != frames[0])
            or (name == "hypotheses" and (shape[1] > MAX_HYPOTHESES or shape[2] != 4))
            or (name == "poses/covariance" and shape[1:] != (3, 3))):
        want = {"hypotheses": f"(N, K <= {MAX_HYPOTHESES:,}, 4)",
                "poses/covariance": "(N, 3, 3)"}.get(name, "(N,)")
        n = f"N = {frames[0]:,} frames (/poses/name)" if frames else f"N <= {MAX_FRAMES:,} frames"
        raise SchemaError(f"{path}: damaged poses file (/{name} has shape {shape}; expected"
                          f" {want} for {n})")
    return d[()]


def _read_poses(path):
    with open_artifact(path, SCHEMA, VERSION) as h5:
        g = _group(h5, "poses", path)
        out = {}
        for k in g.keys():
            v = _stored(h5, f"poses/{k}", path)
            if v.dtype.kind in ("O", "S"):
                try:
                    v = np.array([s.decode() if isinstance(s, bytes) else s for s in v],
                                 dtype=object)
                except UnicodeDecodeError:
                    raise SchemaError(f"{path}: damaged poses file (/poses/{k} holds text that"
                                      " is not UTF-8)") from None
            out[k] = v
        if "hypotheses" in h5:
            out["hypotheses"] = _stored(h5, "hypotheses", path)
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()}
        for k in JSON_ATTRS:
            try:
                attrs[k] = read_json_attr(h5, k)
            except (ValueError, RecursionError):
                raise SchemaError(f"{path}: damaged poses file (attribute '{k}' is"
                                  f" {str(h5.attrs[k])[:40]!r}; expected a JSON object)") from None
    _check_shapes(out, path)
    _check_types(out, attrs, path)
    _check_values(out, path)
    failed = np.asarray(out["failed"], bool)
    if "accepted" not in out:
        out["accepted"] = ~failed
    if "confidence_up_to_mirror" not in out and "confidence" in out:
        out["confidence_up_to_mirror"] = out["confidence"]
    if "accepted_up_to_mirror" not in out:
        out["accepted_up_to_mirror"] = out["accepted"]
    if "hypotheses" not in out:
        h = np.full((len(failed), 1, 4), np.nan)
        h[:, 0, 0], h[:, 0, 1], h[:, 0, 2] = out["x"], out["y"], out["theta"]
        h[:, 0, 3] = np.where(failed, np.nan, out["confidence"])
        out["hypotheses"] = h
    return out, attrs

