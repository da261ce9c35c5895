"""What the calibrations learnt from a recording share (mirror_calibration.py for omni
cameras, mount_calibration.py for perspective ones): the frames of a track they may use, the
inputs a features file records, the ``calibration`` record written into calib.yaml, and the
atomic writing of the corrected calib.yaml that never replaces the recording's own.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np

from .. import __version__
from ..common.artifacts import atomic_path
from ..common.camera import calib_text
from ..common.errors import FieldlocError, real_path

# the median absolute deviation times this is a normal distribution's standard deviation
MAD_TO_SIGMA = 1.4826


def cauchy_scale(residuals: np.ndarray, inside: np.ndarray, min_scale: float) -> float:
    """The Cauchy loss's scale of a calibration's reweighting round: the residuals ``inside``
    the gate's median absolute value as a standard deviation, at least ``min_scale``."""
    return max(float(min_scale),
               MAD_TO_SIGMA * float(np.median(np.abs(residuals[inside]))))


def cauchy_weights(residuals: np.ndarray, scale: float, inside: np.ndarray) -> np.ndarray:
    """Iteratively reweighted least squares with the Cauchy loss (Holland and Welsch 1977):
    1 / (1 + (r / scale)^2) inside the gate, 0 outside."""
    return np.where(inside, 1.0 / (1.0 + (residuals / scale) ** 2), 0.0)


def track_arrays(track, symmetric: bool = False) -> dict:
    """names, x, y, theta, confidence, accepted of a PoseTrack or of its arrays. On a
    point-symmetric field (``symmetric``) a pose and its mirror image see the same lines, so a
    frame's confidence and acceptance up to the mirror are used when the track has them
    (stages.localize.symmetry)."""
    arr = track.arrays() if hasattr(track, "arrays") else track
    if symmetric and "confidence_up_to_mirror" in arr and "accepted_up_to_mirror" in arr:
        arr = {**arr, "confidence": arr["confidence_up_to_mirror"],
               "accepted": arr["accepted_up_to_mirror"]}
    names = arr.get("names", arr.get("name"))
    if names is None:
        raise FieldlocError("the poses have no frame names")
    out = {"names": [n.decode() if isinstance(n, bytes) else str(n) for n in names]}
    for k in ("x", "y", "theta", "confidence", "accepted"):
        if k not in arr:
            raise FieldlocError(f"the poses have no '{k}'")
        out[k] = np.asarray(arr[k], dtype=bool if k == "accepted" else float)
    if any(len(out[k]) != len(out["names"]) for k in ("x", "y", "theta", "confidence")):
        raise FieldlocError("the poses' arrays differ in length")
    return out


def usable_rows(arr: dict, min_confidence: float) -> np.ndarray:
    """Indices of the track's frames accepted with confidence >= ``min_confidence`` and a
    finite pose."""
    use = (arr["accepted"] & (arr["confidence"] >= min_confidence)
           & np.isfinite(arr["x"]) & np.isfinite(arr["y"]) & np.isfinite(arr["theta"]))
    return np.flatnonzero(use)


def features_inputs(features) -> dict:
    """The features file and the dataset, calib.yaml (and its hash) it was extracted from, as
    its attributes record them."""
    out = {}
    path = getattr(features, "path", None)
    if path is not None:
        out["features"] = str(path)
    try:
        rec = features.attr_json("inputs") or {}
    except (AttributeError, KeyError, ValueError, TypeError):
        rec = {}
    if isinstance(rec, dict):
        for k in ("dataset", "calib", "calib_hash"):
            if isinstance(rec.get(k), str) and rec[k]:
                out[k] = rec[k]
    return out


def plain(v):
    """A numpy scalar as the Python number YAML writes."""
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    return v


def record_header(*, source: str, inputs: dict, sources: dict | None, conf: dict) -> dict:
    """The first entries of a ``calibration`` record, as stages.calibrate records its own:
    fieldloc_version, created, method ``recording``, ``source`` (the recording it came from:
    the poses file or the dataset), ``sources`` (``inputs``, the features file and the
    dataset and calib.yaml it was extracted from, updated with ``sources``) and the
    estimator's ``conf``."""
    return {
        "fieldloc_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "method": "recording",
        "source": str(source),
        "sources": {**inputs, **{str(k): str(v) for k, v in (sources or {}).items()}},
        "conf": {k: plain(v) for k, v in conf.items()},
    }


def own_calibs(calib_dict: dict, dataset_calib=None) -> list[Path]:
    """The calib.yaml files a corrected calibration must never be written over: the one the
    recording's features were extracted with (``sources.calib``), the dataset's own
    (``sources.dataset``/calib.yaml, ``source``/calib.yaml when the source is a dataset
    folder) and ``dataset_calib``."""
    rec = calib_dict.get("calibration") if isinstance(calib_dict, dict) else None
    rec = rec if isinstance(rec, dict) else {}
    src = rec.get("sources") if isinstance(rec.get("sources"), dict) else {}
    out = []
    if dataset_calib is not None:
        out.append(Path(dataset_calib))
    if src.get("calib"):
        out.append(Path(src["calib"]))
    for folder in (src.get("dataset"), rec.get("source")):
        if folder and Path(folder).is_dir():
            out.append(Path(folder) / "calib.yaml")
    return out


def write_calib_file(path, calib_dict: dict, read_back, *, dataset_calib=None) -> Path:
    """Write ``calib_dict`` as a calib.yaml at ``path``, atomically (a temporary file beside
    it, renamed at the end). Refused (FieldlocError): ``path`` is the recording's own
    calib.yaml (``own_calibs``), or ``read_back(calib_dict, where)`` (the camera model's
    from_dict) refuses the mapping."""
    path = Path(path)
    for own in own_calibs(calib_dict, dataset_calib):
        if same_file(path, own):
            raise FieldlocError(f"{path} is the recording's own calib.yaml; it is never written"
                                " over: choose another output")
    read_back(calib_dict, str(path))  # what is written reads back
    with atomic_path(path, suffix=".yaml") as tmp:
        tmp.write_text(calib_text(calib_dict))
    return path


def same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return a.samefile(b)
    except OSError:
        pass
    return real_path(a) == real_path(b)
