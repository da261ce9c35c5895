"""``fieldloc inspect FILE``: a short listing of any file fieldloc writes or reads.

By content, not by name: HDF5 artifacts (map, features, poses, templates: root attributes and
tree, artifacts.describe), JSON (report.json, ``bench --json``: schema and top-level values),
YAML (calib.yaml, simulation.yaml, field YAML: what it is and its keys), CSV (the dataset's,
points, calibration pairs, errors.csv: header and rows), poses.tum, PNG/JPG images, and folders
(a dataset, a report folder, extract's resume folder). Anything else is one clear error that
lists what inspect reads.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .artifacts import HDF5_SIGNATURE, human_bytes
from .artifacts import describe as describe_hdf5
from .camera import CALIB_KEYS
from .conf import load_yaml, yaml_problem
from .dataset import CSV_COLUMNS, IMAGE_SUFFIXES, SIMULATION_RECORD, csv_rows
from .errors import FieldlocError, check_file

READS = ("HDF5 artifacts (map, features, poses, templates), report.json, bench JSON, calib.yaml,"
         " simulation.yaml, field YAML, the dataset CSVs, points and calibration CSVs,"
         " errors.csv, poses.tum, PNG/JPG images, dataset and report folders")
OTHER_CSV = {("frame", "x", "y"): "line points (localize --points)",
             ("radius_px", "distance_m"): "calibration pairs (calibrate omni POINTS)"}


def describe_file(path: str | Path) -> str:
    """The listing of ``path`` (see the module doc); FieldlocError when it is none of those."""
    path = Path(path)
    if path.is_dir():
        return _folder(path)
    check_file(path, "file")  # absent, a FIFO (opening one may block forever), a link loop
    try:
        with open(path, "rb") as f:
            head = f.read(2048)
    except OSError as e:
        raise FieldlocError(f"{path}: cannot be read ({e.strerror or e})") from None
    if _is_hdf5(path, head) or path.suffix.lower() in (".h5", ".hdf5"):
        return describe_hdf5(path)  # a damaged .h5 file: "not an HDF5 file (corrupt ...)"
    if head.startswith(b"\x89PNG") or head.startswith(b"\xff\xd8"):
        return _image(path)
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise FieldlocError(f"{path}: not a file fieldloc reads (inspect reads {READS})") from None
    stripped = text.lstrip()
    if stripped.startswith(("{", "[")):
        return _json(path, text)
    if path.suffix.lower() == ".tum" or stripped.startswith("# stamp x y z"):
        return _tum(path, text)
    if path.suffix.lower() in (".csv", ".txt") or ("," in text.splitlines()[0] if text else False):
        out = _csv(path)
        if out:
            return out
    if path.suffix.lower() in (".yaml", ".yml") or ":" in text:
        out = _yaml(path, text)
        if out:
            return out
    raise FieldlocError(f"{path}: not a file fieldloc reads (inspect reads {READS})")


def _is_hdf5(path: Path, head: bytes) -> bool:
    if head.startswith(HDF5_SIGNATURE):
        return True
    try:  # a user block moves the signature to 512, 1024, ... bytes
        import h5py

        return bool(h5py.is_hdf5(str(path)))
    except (OSError, ValueError):
        return False


def _image(path: Path) -> str:
    from .dataset import decode_image_bytes

    img, why = decode_image_bytes(path.read_bytes(), unchanged=True)
    if img is None:
        why = f": {why}" if why else ""
        return (f"{path}\n  image file that cannot be decoded"
                f" ({human_bytes(path.stat().st_size)}{why})")
    ch = 1 if img.ndim == 2 else img.shape[2]
    return f"{path}\n  image {img.shape[1]} x {img.shape[0]} px, {ch} channels, {img.dtype}"


def _json(path: Path, text: str) -> str:
    try:
        d = json.loads(text)
    except (ValueError, RecursionError) as e:  # RecursionError: nested too deep
        raise FieldlocError(f"{path}: not valid JSON ({e})") from None
    lines = [f"{path}"]
    if isinstance(d, dict):
        if "schema" in d:
            lines.append(f"  schema {d.get('schema')} version {d.get('schema_version', '?')}")
        elif "rows" in d:
            lines.append(f"  bench results: {len(d['rows'])} rows")
        for k, v in d.items():
            lines.append(f"  {k}: {_short(v)}")
    else:
        lines.append(f"  JSON list of {len(d)} items")
    return "\n".join(lines)


def _short(v) -> str:
    if isinstance(v, dict):
        s = json.dumps(v)
        return s if len(s) <= 100 else f"{{{len(v)} keys: {', '.join(list(map(str, v))[:6])}...}}"
    if isinstance(v, list):
        s = json.dumps(v)
        return s if len(s) <= 100 else f"[{len(v)} items]"
    return repr(v)


def _tum(path: Path, text: str) -> str:
    rows = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    try:
        arr = np.array([[float(x) for x in ln.split()] for ln in rows]).reshape(-1, 8)
    except ValueError:
        raise FieldlocError(f"{path}: not a TUM trajectory (rows of 8 numbers)") from None
    span = f", stamps {arr[0, 0]:g}..{arr[-1, 0]:g} s" if len(arr) else ""
    return f"{path}\n  TUM trajectory (stamp x y z qx qy qz qw): {len(arr)} poses{span}"


def _csv(path: Path) -> str | None:
    try:
        rows = csv_rows(path)
    except FieldlocError:
        return None
    if not rows:
        return None
    header = tuple(h.strip() for h in rows[0][1])
    what = next((f"{k}.csv" for k, cols in CSV_COLUMNS.items() if tuple(cols) == header), None)
    if what is None and header[:3] == ("name", "stamp", "matched"):
        what = "errors.csv of an evaluate report"
    what = what or OTHER_CSV.get(header)
    if what is None:
        return None
    return (f"{path}\n  {what}: columns {','.join(header)}; {len(rows) - 1} rows")


def _yaml(path: Path, text: str) -> str | None:
    import yaml

    try:
        d = load_yaml(text)
    except yaml.YAMLError as e:
        # a YAML document with a value load_yaml refuses (a seed of 1_0, a key given twice),
        # or a .yaml file that does not parse: what is wrong and where, rather than "not a
        # file fieldloc reads"; other text is none of the files inspect reads
        if isinstance(e, yaml.constructor.ConstructorError):
            raise FieldlocError(f"{path}: {yaml_problem(e, text)}") from None
        if path.suffix.lower() in (".yaml", ".yml"):
            raise FieldlocError(f"{path}: not valid YAML, {yaml_problem(e, text)}") from None
        return None
    if not isinstance(d, dict):
        return None
    keys = ", ".join(map(str, d))
    if "kind" in d and d.get("kind") in CALIB_KEYS:
        what = f"calibration, {d['kind']} camera (version {d.get('version', 1)})"
    elif d.get("generator") == "fieldloc simulate":
        what = (f"simulation record: {d.get('frames')} frames on {d.get('field')}, camera"
                f" {d.get('camera')}, seed {d.get('seed')}")
    elif "length" in d or "letters" in d:
        what = f"field '{d.get('name', '?')}'"
    else:
        return None
    return f"{path}\n  {what}\n  keys: {keys}"


def _folder(path: Path) -> str:
    lines = [f"{path}/"]
    images = path / "images"
    if images.is_dir():
        n = sum(1 for p in images.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        lines.append(f"  dataset: {n} images")
        for name in ("calib.yaml", "mask.png", SIMULATION_RECORD,
                     *(f"{k}.csv" for k in CSV_COLUMNS), "features.h5"):
            if (path / name).exists():
                lines.append(f"  {name}")
        return "\n".join(lines)
    if (path / "report.json").is_file():
        lines.append("  evaluate report folder:")
        lines.append("  " + describe_file(path / "report.json").replace("\n", "\n  "))
        return "\n".join(lines)
    if (path / "run.json").is_file() and path.name.endswith(".parts"):
        n = sum(1 for p in path.iterdir() if p.suffix == ".npz")
        f = sum(1 for p in path.iterdir() if p.suffix == ".failed")
        lines.append(f"  extract resume folder: {n} frames finished, {f} failed")
        return "\n".join(lines)
    raise FieldlocError(f"{path}: a folder fieldloc does not know (inspect reads {READS})")
