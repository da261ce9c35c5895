"""Arrays the table search derives from a map, on disk beside the map, so that a process maps
them in milliseconds instead of computing them again: the scan-line tables in millimetres and
the min-pooled error lookup of stages.localize.lut_tables (25 + 20 MB and about 1 s on
msl-2015, in every process of every run; the full error lookup, 352 MB, is computed from the
tables where a search reads it and not stored), and the 2 cm line-distance raster of
stages.localize.point_fit (3.5 MB, 0.2-0.5 s).

    <map>.lookup/<key>.<array>.npy   one array per file (.npy: np.load maps it)
    <map>.lookup/<key>.json          what the key stands for: the map, its hash, the parameters

``<key>`` is ``<map hash>-<parameters hash>``: the map file's content hash (sha256, as every
artifact records its inputs) and a hash of what the arrays are (``what``), the parameters they
depend on (the min-pooled lookup: ``c``, ``range_scale``, ``distance_bin``, ``coarse_step``,
the distance bins it pools; not ``use_spiral`` or ``pair_tolerance``, which only the searches
read), their shapes and dtypes, and ``CACHE_VERSION``. A map rebuilt in place has another
hash, so its arrays are computed again, and the files of that map's earlier hashes are removed
then (a process that still maps them keeps its pages: unlinking a mapped file is safe).

Written atomically (each file to a part beside it, renamed: stages.common.artifacts), and read
with ``np.load(mmap_mode="c")``: pages come from the disk, or from the page cache that every
process on the machine shares, as a search touches them; copy-on-write because the numba
kernels take writable arrays, and nothing writes to them. Two processes that miss the same key
at once (two Dask workers starting) do not both compute it: the first holds ``<key>.lock``
(flock) while it computes and writes, the other waits and maps what it wrote. A folder that
cannot be written (a shared read-only map) or a disk without room leaves the arrays in memory,
with a warning; a damaged file or one of another shape is computed again.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import math
import os
import re
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..common.artifacts import atomic_path, current_umask, file_hash
from ..common.errors import FieldlocError, real_path

log = logging.getLogger(__name__)

CACHE_VERSION = 3  # raise when an array is computed differently: older files are not read
# (2: the radial table in metres as (line, cell, crossing); 3: no fine error lookup, the
# tables in millimetres)
SUFFIX = ".lookup"
# builds of this size and more announce themselves on stderr (_announce); the rate is that of
# msl-2015's former full error lookup built and written on a busy 2-core AMD EPYC, for the
# rough duration the line states (the min-pooled lookup, 20 MB on msl-2015, builds in about
# 1 s, unannounced)
ANNOUNCE_BYTES = 64 << 20
BUILD_BYTES_PER_S = 80e6


def cache_folder(map_path: str | Path) -> Path:
    """Where the arrays of a map are kept: ``<map>.lookup/`` beside it."""
    map_path = Path(map_path)
    return map_path.with_name(map_path.name + SUFFIX)


def map_hash(map_path: str | Path) -> str:
    """The content hash of a map file (stages.common.artifacts.file_hash, which reads an
    unchanged file once per process)."""
    return file_hash(real_path(map_path))


def cache_key(map_digest: str, what: str, params: dict, shapes: dict) -> str:
    """The key of the arrays ``what`` of a map (content hash ``map_digest``) computed with
    ``params`` (JSON values), as ``shapes`` (name -> (shape, dtype)) describes them."""
    record = {"version": CACHE_VERSION, "what": what, "params": params,
              "arrays": {k: [list(s), np.dtype(d).str] for k, (s, d) in sorted(shapes.items())}}
    text = json.dumps(record, sort_keys=True)
    digest = map_digest.split(":", 1)[-1][:16]
    return f"{digest}-{hashlib.sha256(text.encode()).hexdigest()[:12]}"


def load_or_build(map_path: str | Path, what: str, params: dict, shapes: dict,
                  build: Callable[[], dict]) -> tuple[dict, str]:
    """The arrays (name -> array, named and shaped as ``shapes``: name -> (shape, dtype)) of
    the map at ``map_path``: mapped from its cache folder when it holds them, else ``build()``
    (name -> array) and written there. Returns (arrays, how: "mapped", "built" or "built, not
    cached")."""
    folder = cache_folder(map_path)
    key = cache_key(map_hash(map_path), what, params, shapes)
    found = _mapped(folder, key, shapes)
    if found is not None:
        return found, "mapped"
    try:
        folder.mkdir(exist_ok=True)
        lock = os.open(folder / f"{key}.lock", os.O_RDWR | os.O_CREAT, 0o666 & ~current_umask())
    except OSError as e:
        log.warning("cannot cache the %s beside %s (%s): computed in memory", what, map_path,
                    e.strerror or e)
        return build(), "built, not cached"
    try:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when closed
        found = _mapped(folder, key, shapes)  # written by another process while we waited
        if found is not None:
            return found, "mapped"
        _announce(what, map_path, folder, shapes)
        arrays = build()
        try:
            _write(folder, key, arrays, map_path, what, params)
        except (OSError, FieldlocError) as e:
            log.warning("cannot cache the %s in %s (%s): it stays in memory", what, folder,
                        getattr(e, "strerror", None) or e)
            return arrays, "built, not cached"
        _remove_other_hashes(folder, key)
    finally:
        os.close(lock)
    found = _mapped(folder, key, shapes)
    return (found, "built") if found is not None else (arrays, "built, not cached")


def _announce(what: str, map_path, folder: Path, shapes: dict) -> None:
    """One line on stderr before a build that takes seconds to a minute, even under --quiet
    (a command must not sit silent that long): what is built, why, how large, roughly how
    long. Small builds say nothing."""
    nbytes = sum(math.prod(s) * np.dtype(d).itemsize for s, d in shapes.values())
    if nbytes < ANNOUNCE_BYTES:
        return
    seconds = nbytes / BUILD_BYTES_PER_S
    print(f"fieldloc: building the {what} of {Path(map_path).name} ({nbytes / 1e6:.0f} MB,"
          f" about {max(5, round(seconds / 5) * 5)} s): once per map, kept in {folder} so"
          " that later runs map it in a second", file=sys.stderr, flush=True)


def _mapped(folder: Path, key: str, shapes: dict) -> dict | None:
    """The arrays of ``key`` mapped from ``folder``, or None when a file is missing, damaged or
    of another shape or dtype."""
    out = {}
    for name, (shape, dtype) in shapes.items():
        path = folder / f"{key}.{name}.npy"
        if not path.is_file():
            return None
        try:
            arr = np.load(path, mmap_mode="c", allow_pickle=False)
        except (OSError, ValueError) as e:
            log.warning("%s is damaged (%s): computed again", path, e)
            return None
        if (arr.shape != tuple(shape) or arr.dtype != np.dtype(dtype)
                or not arr.flags.c_contiguous):
            log.warning("%s holds %s %s, expected %s %s: computed again", path, arr.shape,
                        arr.dtype, tuple(shape), np.dtype(dtype))
            return None
        out[name] = np.asarray(arr)  # a plain ndarray over the mapping (numba takes it)
    return out


def _write(folder: Path, key: str, arrays: dict, map_path, what: str, params: dict) -> None:
    need = sum(a.nbytes for a in arrays.values()) + (1 << 20)
    free = shutil.disk_usage(folder).free
    if need > free:
        raise FieldlocError(f"{need / 2**20:.0f} MiB needed, {free / 2**20:.0f} MiB free")
    t = time.perf_counter()
    for name, arr in arrays.items():
        with atomic_path(folder / f"{key}.{name}.npy", suffix=".npy") as tmp:
            with open(tmp, "wb") as f:
                np.save(f, np.ascontiguousarray(arr), allow_pickle=False)
    record = {"what": what, "map": os.path.abspath(map_path), "map_hash": map_hash(map_path),
              "version": CACHE_VERSION, "params": params,
              "arrays": {n: {"shape": list(a.shape), "dtype": str(a.dtype)}
                         for n, a in arrays.items()}}
    with atomic_path(folder / f"{key}.json", suffix=".json") as tmp:
        tmp.write_text(json.dumps(record, indent=2) + "\n")
    log.info("%s cached in %s (%.0f MB, %.1f s)", what, folder, need / 1e6,
             time.perf_counter() - t)


# the names of the files this module writes: <key>.json, <key>.lock, <key>.<array>.npy
CACHE_FILE = re.compile(r"[0-9a-f]{16}-[0-9a-f]{12}\.(?:json|lock|[A-Za-z0-9_]+\.npy)")


def _remove_other_hashes(folder: Path, key: str) -> None:
    """Remove the cached arrays of earlier contents of the same map (it was rebuilt): only
    files of this module's names (``CACHE_FILE``), never another file in the folder (a user's
    notes, or a folder the .lookup name links to)."""
    digest = key.split("-", 1)[0]
    for p in folder.iterdir():
        if not CACHE_FILE.fullmatch(p.name) or p.name.split("-", 1)[0] == digest:
            continue
        with contextlib.suppress(OSError):
            p.unlink()
            log.info("removed %s: computed from an earlier content of the map", p)
