"""HDF5 artifacts: atomic writing, common root attributes, schema checks, and a tree listing.

Each artifact schema (map, features, poses, templates) is owned by one module in this package
that builds on these helpers. Writing always goes to a temporary file beside the target that is
renamed over it at the end, so an interrupted run leaves neither a half file under the real name
nor a damaged earlier result.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import h5py
import numpy as np

from .. import __version__
from .errors import FieldlocError, SchemaError


def file_hash(path: str | Path, algo: str = "sha256") -> str:
    h = hashlib.new(algo)
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return f"{algo}:{h.hexdigest()[:16]}"


def text_hash(text: str) -> str:
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()[:16]


def root_attrs(schema: str, version: int, conf: dict | None = None, inputs: dict | None = None):
    """The attributes every artifact carries at its root."""
    return {
        "schema": schema,
        "schema_version": int(version),
        "fieldloc_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "conf": json.dumps(conf or {}, sort_keys=True, default=_json_default),
        "inputs": json.dumps(inputs or {}, sort_keys=True, default=_json_default),
    }


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def _check_writable(path: Path):
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise FieldlocError(f"cannot write {path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise FieldlocError(f"cannot write {path}: folder {parent} is not writable")
    if path.is_dir():
        raise FieldlocError(f"cannot write {path}: it is a folder")


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success."""
    path = Path(path)
    _check_writable(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or ".part", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | Path, *, overwrite: bool = False):
    """Yield a temporary folder beside ``path``; on success it replaces ``path`` (an existing
    folder only with ``overwrite``), so an interrupted run leaves neither a half folder under
    the real name nor a damaged earlier one."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FieldlocError(f"cannot write folder {path}: it is a file")
    if path.is_dir() and any(path.iterdir()) and not overwrite:
        raise FieldlocError(f"folder {path} exists and is not empty (use --overwrite to"
                            " replace it)")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FieldlocError(f"cannot write {path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise FieldlocError(f"cannot write {path}: folder {parent} is not writable")
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=parent))
    try:
        yield tmp
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=parent))
            os.replace(path, old / "previous")
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def write_artifact(path: str | Path, attrs: dict, *, resume: bool = False):
    """Open a new HDF5 artifact for writing, atomically.

    With ``resume`` and an existing file of the same schema, its content is copied into the
    temporary file first so per-frame stages can skip frames already done; the original stays
    untouched until the new file is complete.
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        if resume and path.exists():
            shutil.copyfile(path, tmp)
            f = h5py.File(tmp, "a", libver="latest")
        else:
            f = h5py.File(tmp, "w", libver="latest")
        try:
            for k, v in attrs.items():
                f.attrs[k] = v
            yield f
        finally:
            f.close()


def _open_hdf5(path: Path) -> h5py.File:
    """Open an HDF5 file for reading, or fail with one clear line."""
    if not path.exists():
        raise FieldlocError(f"file not found: {path}")
    try:
        return h5py.File(path, "r")
    except OSError:
        raise SchemaError(
            f"{path}: not an HDF5 file (corrupt or not a fieldloc artifact)"
        ) from None


def open_artifact(path: str | Path, schema: str, max_version: int) -> h5py.File:
    """Open an artifact for reading, checking that it exists and is of ``schema``."""
    path = Path(path)
    f = _open_hdf5(path)
    got = f.attrs.get("schema")
    if isinstance(got, bytes):
        got = got.decode()
    if got != schema:
        f.close()
        what = f"a '{got}' file" if got else "not a fieldloc artifact"
        raise SchemaError(f"{path}: expected a '{schema}' file, but it is {what}")
    version = int(f.attrs.get("schema_version", -1))
    if not 1 <= version <= max_version:
        f.close()
        raise SchemaError(
            f"{path}: '{schema}' version {version} is not supported (this fieldloc reads"
            f" versions 1..{max_version})"
        )
    return f


def read_json_attr(f: h5py.File, key: str):
    v = f.attrs.get(key, "{}")
    return json.loads(v.decode() if isinstance(v, bytes) else v)


def describe(path: str | Path) -> str:
    """A text listing of an artifact's root attributes and tree (datasets with shape, dtype and
    units), for ``fieldloc inspect``."""
    path = Path(path)
    f = _open_hdf5(path)
    lines = [f"{path}"]
    with f:
        if "schema" not in f.attrs:
            lines.append("  (no 'schema' attribute: not a fieldloc artifact)")
        for k in sorted(f.attrs):
            lines.append(f"  @{k} = {_fmt_attr(f.attrs[k])}")
        groups_shown: dict[str, int] = {}

        def visit(name, obj):
            depth = name.count("/")
            parent = name.rsplit("/", 1)[0] if "/" in name else ""
            # per-frame files: show the first three frame groups, then a count
            if depth == 1 and isinstance(obj, h5py.Group) and parent in ("frames", "templates"):
                groups_shown[parent] = groups_shown.get(parent, 0) + 1
                if groups_shown[parent] == 4:
                    lines.append(f"  {'  ' * depth}... ({len(f[parent])} groups in /{parent})")
            if parent in groups_shown and groups_shown[parent] > 3:
                return
            if "/" in name and name.split("/")[0] in groups_shown:
                if groups_shown[name.split("/")[0]] > 3:
                    return
            indent = "  " * (depth + 1)
            if isinstance(obj, h5py.Dataset):
                units = obj.attrs.get("units", "")
                units = units.decode() if isinstance(units, bytes) else units
                u = f" [{units}]" if units else ""
                lines.append(f"{indent}/{name}  {obj.shape} {obj.dtype}{u}")
            else:
                lines.append(f"{indent}/{name}/")

        f.visititems(visit)
    return "\n".join(lines)


def _fmt_attr(v):
    if isinstance(v, bytes):
        v = v.decode()
    if isinstance(v, np.ndarray):
        return np.array2string(v, precision=4, separator=", ")
    s = str(v)
    return s if len(s) <= 300 else s[:297] + "..."
