"""``fieldloc bench``: speed (and accuracy where the issue sets a goal) of each stage.

A row is a function of the repeat count returning a ``harness.Row`` (or a list of them), in the
module of its family (``omni``, ``mcl``, ``templates``, ...); ``ROWS`` lists them in order, by
name, and ``run`` runs those asked for. The layers of the package run one way: the rows import
``harness`` (Row, timing, table and JSON) and ``inputs`` (the rendered inputs they share); this
registry imports the rows, each on first use (so ``fieldloc bench --list`` imports none).

A new row: a function ``bench_<what>(repeat)`` in its family's module (or a new module), and
its name here.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from .harness import Row

# name -> (module of the family, function, the arguments before the repeat count), in order
_TABLE: dict[str, tuple[str, str, tuple]] = {
    "build-map-msl-2015": ("build_map", "bench_build_map", ("msl-2015",)),
    "build-map-msl": ("build_map", "bench_build_map", ("msl",)),
    "distance-vs-edt": ("build_map", "bench_distance_vs_edt", ()),
    "lut-search": ("omni", "bench_lut_searches", ()),
    "extract-omni": ("omni", "bench_extract_omni", ()),
    "lut-accuracy": ("omni", "bench_lut_accuracy", ()),
    "extract-perspective": ("perspective", "bench_extract_perspective", ()),
    "mcl-update": ("mcl", "bench_mcl_update", ()),
    "mcl-accuracy": ("mcl", "bench_mcl_accuracy", ()),
    "mcl-nao-accuracy": ("mcl_nao", "bench_mcl_nao_accuracy", ()),
    "mcl-hulks": ("mcl_hulks", "rows", ()),
    "mcl-walks": ("mcl_walks", "rows", ()),
    "mcl-smooth-walks": ("mcl_walks", "smooth_rows", ()),
    "mcl-side-walks": ("mcl_walks", "side_rows", ()),
    "mcl-kidnap-walks": ("mcl_walks", "kidnap_rows", ()),
    "mcl-walks-bound": ("mcl_walks", "bound_rows", ()),
    "surf-speed": ("features", "bench_surf_speed", ()),
    "surf-quality": ("features", "bench_feature_quality", ()),
    "lut-tracked-frame": ("hypotheses", "bench_lut_tracked_frame", ()),
    "lut-calibration": ("hypotheses", "bench_lut_calibration", ()),
    "fit-calibration": ("hypotheses", "bench_fit_calibration", ()),
    "mcl-calibration": ("hypotheses", "bench_mcl_calibration", ()),
    "lut-hidden-run": ("hypotheses", "bench_lut_hidden", ()),
    "smooth-passes": ("smooth", "bench_smooth_passes", ()),
    "smooth-accuracy": ("smooth", "bench_smooth_accuracy", ()),
    "smooth-templates": ("smooth", "bench_smooth_templates", ()),
    "mount-calibration": ("recording_calibration", "rows", ()),
    "mirror-calibration": ("recording_calibration", "mirror_row", ()),
    "real": ("hypotheses", "bench_real", ()),
    "import-rosbag": ("import_rosbag", "bench_import_rosbag", ()),
    "templates": ("templates", "bench_templates", ()),
    "templates-calibration": ("templates", "bench_templates_calibration", ()),
    "fit": ("fit", "rows", ()),
    "error-surface": ("error_surface", "rows", ()),
    "batch-throughput": ("batch", "bench_batch_throughput", ()),
    "lut-first-frame": ("batch", "bench_first_frame", ()),
    "batch-worker-memory": ("batch", "bench_worker_memory", ()),
    "cli-help": ("cli", "rows", ()),
    "first-run-after-install": ("first_run", "bench_first_run", ()),
    "images-to-poses-per-core": ("throughput", "throughput_rows", ()),
    "images-to-poses-startup": ("throughput", "startup_row", ()),
    "images-to-poses-frames": ("throughput", "frames_row", ()),
    "images-to-poses-area": ("throughput", "area_rows", ()),
}


def _row(module: str, function: str, args: tuple) -> Callable[[int], Row | list[Row]]:
    """The row ``function`` of the family ``module``, called with ``args`` and the repeat count
    (its module imported on the first call)."""
    def call(repeat: int) -> Row | list[Row]:
        return getattr(importlib.import_module(f".{module}", __name__), function)(*args, repeat)

    return call


ROWS: dict[str, Callable[[int], Row | list[Row]]] = {
    name: _row(*entry) for name, entry in _TABLE.items()}


def run(only: list[str] | None = None, repeat: int = 5, progress=None) -> list[Row]:
    """The rows whose names contain one of ``only`` (all rows without it), timed ``repeat``
    times each; a name in ``only`` that no row contains is an error (FieldlocError)."""
    from ...common.errors import FieldlocError

    for o in only or []:
        if not o.strip():  # '' is in every name: it selected every row, the whole bench
            raise FieldlocError("--only '' names no row (`fieldloc bench --list` names them)")
        if not any(o in n for n in ROWS):
            shown = o if len(o) <= 40 else o[:37] + "..."
            raise FieldlocError(f"no bench row matches {shown!r} (`fieldloc bench --list` names"
                                " them; give --only once per name)")
    names = [n for n in ROWS if not only or any(o in n for o in only)]
    rows: list[Row] = []
    for name in names:
        if progress:
            progress(name)
        out = ROWS[name](repeat)
        rows.extend(out if isinstance(out, list) else [out])
    return rows

