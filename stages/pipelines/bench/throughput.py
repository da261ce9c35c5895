"""``fieldloc bench`` rows "images to poses, per core": what one core spends to
take a rendered dataset's images to poses, through the stage mains a user's command calls, and
whether that cost grows linearly with the frames and with the field.

- Throughput (``throughput_rows``): frames per second of CPU of stages.extract.main followed by
  stages.localize.main (CLI defaults; templates reads the images itself, so it is
  stages.localize.main alone) over one 400-frame dataset, in this process, warm: the map's
  tables, the lookup cache and numba's kernels loaded by one untimed run of the same work
  first. Process CPU time (all threads) is the measure, as the machine is shared and its wall
  time holds the other processes' load; the wall time is reported beside it. The baseline is
  the CPU of reading and decoding the same image files alone, the floor of any pipeline that
  starts from them.
- Start-up (``startup_row``): ``fieldloc -q localize`` of a one-frame dataset (extracting
  its features) as its own process, wall and CPU time and peak resident set, against an
  interpreter that does nothing (``python -c pass``) in the same run.
- Linearity in frames (``frames_row``): CPU per frame of extract + localize lut over 100, 400
  and 1600 frames; the largest set's over the smallest's.
- Linearity in field area (``area_rows``): lut's localize CPU per frame and the peak resident
  set of a ``fieldloc -q localize`` process on msl-2015, msl and a field of twice msl's area
  (its length and width times sqrt 2, written as a field YAML), against the ratio of their
  table cells (the 10 cm grid around each field).

The omni datasets are rendered by one robot in one venue (the template robot's calib and world
seeds, bench.inputs), so the template database of bench.templates serves them; each size is
rendered once per bench run.
"""

from __future__ import annotations

import math
import statistics
import time
from functools import partial
from pathlib import Path

import numpy as np

from .harness import Row
from .inputs import INPUTS, work_dir

THROUGHPUT_FRAMES = 400
LINEAR_FRAMES = (100, 400, 1600)
AREA_FRAMES = 200
AREA_FIELDS = ("msl-2015", "msl", "msl-double")
SEED = 71
# (camera kind, method, field, goal in frames per second of CPU, where one is set)
PIPELINES = (("omni", "lut", "msl-2015", 200.0), ("omni", "fit", "msl-2015", None),
             ("omni", "templates", "msl-2015", None), ("perspective", "mcl", "kidsize", 150.0))
LINEAR_GOAL = 1.3  # largest / smallest set's CPU per frame (frames); over the area ratio (area)
SHARED = "process CPU time (all threads): the machine is shared, wall time holds its load"


# ---------------------------------------------------------------------------- inputs


def double_msl_field() -> Path:
    """A field YAML of msl's lines on twice its area (length and width times sqrt 2, the
    areas, circle, goals and line width as msl's), written once per bench run."""
    import yaml

    from ...common.field import MAPS_DIR

    path = work_dir() / "msl-double.yaml"
    if not path.exists():
        spec = yaml.safe_load((MAPS_DIR / "msl.yaml").read_text())
        spec["name"] = "msl-double"
        spec["source"] = "msl.yaml with letters A and B (length, width) times sqrt 2"
        for k in ("A", "B"):
            spec["letters"][k] = round(spec["letters"][k] * math.sqrt(2), 3)
        path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def _field_arg(field: str) -> str:
    return str(double_msl_field()) if field == "msl-double" else field


def field_map(field: str) -> Path:
    """The map of ``field`` (a preset name or "msl-double"), built once per bench run, at the
    path inputs.rendered_inputs uses for presets (so the rows share it)."""
    from ... import build_map

    mp = work_dir() / f"{field}.map.h5"
    if not mp.exists():
        build_map.main(None, _field_arg(field), mp)
    return mp


def rendered_run(kind: str, field: str, frames: int, seed: int = SEED) -> Path:
    """A rendered dataset of ``kind`` (omni: the template robot and venue) without a
    features file, built once per bench run."""
    key = ("throughput", kind, field, frames, seed)
    if key not in INPUTS:
        from ... import simulate
        from .inputs import CALIB_SEED, WORLD_SEED

        conf = dict(simulate.confs[f"{kind}-default"], frames=frames, seed=seed)
        if kind == "omni":
            conf.update(calib_seed=CALIB_SEED, world_seed=WORLD_SEED)
        INPUTS[key] = simulate.main(conf, _field_arg(field),
                                     work_dir() / f"throughput-{kind}-{field}-{frames}-{seed}")
    return INPUTS[key]


def cli_conf(method: str) -> dict:
    """The conf `fieldloc localize --method METHOD` runs with no other option."""
    from ... import localize
    from ...common.conf import resolve_conf

    return resolve_conf(localize.confs, localize.preset_name(method, "default"), {})


# ---------------------------------------------------------------------------- measuring


def images_to_poses(method: str, data: Path, map_path: Path | None, out_dir: Path,
                    templates: Path | None = None) -> tuple[float, float, float]:
    """(wall s, extract CPU s, localize CPU s) of one run of ``data`` to poses with
    ``method``'s CLI defaults: stages.extract.main into a fresh features file, then
    stages.localize.main on it (templates: stages.localize.main on the images)."""
    from ... import extract, localize

    conf = cli_conf(method)
    out = out_dir / f"{data.name}-{method}.poses.h5"
    t, c = time.perf_counter(), time.process_time()
    if method == "templates":
        c_extract = c
        localize.main(conf, data, None, out, templates=templates, overwrite=True)
    else:
        feats = extract.main(None, data, out_dir / f"{data.name}.features.h5", overwrite=True)
        c_extract = time.process_time()
        localize.main(conf, data, map_path, out, features=feats, overwrite=True)
    c_end = time.process_time()
    return time.perf_counter() - t, c_extract - c, c_end - c_extract


def timed_runs(run, runs: int) -> dict:
    """One untimed run of ``run`` (warm: tables, lookup cache, numba kernels, page cache),
    then ``runs`` timed ones; medians of its (wall, extract CPU, localize CPU) seconds."""
    run()
    rs = [run() for _ in range(max(1, runs))]
    wall, ext, loc = (statistics.median(r[k] for r in rs) for k in range(3))
    return {"wall_s": wall, "extract_cpu_s": ext, "localize_cpu_s": loc,
            "cpu_s": ext + loc, "runs": len(rs)}


def decode_cpu_s(data: Path) -> float:
    """CPU seconds to read and decode every image of ``data`` (the floor of any pipeline
    that starts from the image files)."""
    from ...common.dataset import open_dataset, read_image

    paths = open_dataset(data).images
    c = time.process_time()
    for p in paths:
        read_image(p)
    return time.process_time() - c


def _out_dir(name: str) -> Path:
    d = work_dir() / "throughput" / name
    d.mkdir(parents=True, exist_ok=True)
    return d


# ---------------------------------------------------------------------------- rows


def throughput_rows(repeat: int, frames: int = THROUGHPUT_FRAMES,
                    pipelines=PIPELINES) -> list[Row]:
    """One row per (camera, method) of ``pipelines``: frames per second of CPU of images to
    poses over ``frames`` rendered frames, warm (module doc)."""
    rows = []
    for kind, method, field, goal in pipelines:
        data = rendered_run(kind, field, frames)
        templates = None
        if method == "templates":
            from .inputs import template_inputs

            templates = template_inputs()["templates"]
        mp = None if method == "templates" else field_map(field)
        out = _out_dir("pipelines")
        r = timed_runs(partial(images_to_poses, method, data, mp, out, templates),
                       max(1, repeat // 5))
        fps, wall_fps = frames / r["cpu_s"], frames / r["wall_s"]
        decode_ms = 1e3 * decode_cpu_s(data) / frames
        steps = ("localize on the images (ground features, matching, pose)"
                 if method == "templates" else
                 f"extract {1e3 * r['extract_cpu_s'] / frames:.2f} + localize"
                 f" {1e3 * r['localize_cpu_s'] / frames:.2f} ms CPU per frame")
        rows.append(Row(
            name=f"images to poses, per core: {kind} + {method} ({field}, {frames} frames)",
            median_ms=1e3 * r["wall_s"] / frames, cpu_ms=1e3 * r["cpu_s"] / frames,
            goal=f">= {goal:g} frames/s per core (CPU time)" if goal else "",
            meets_goal=(fps >= goal) if goal else None, repeats=r["runs"],
            baseline="decoding its images alone, CPU", baseline_ms=decode_ms,
            ratio=1e3 * r["cpu_s"] / frames / decode_ms,
            note=f"{fps:.0f} frames/s of CPU, {wall_fps:.0f} frames/s wall; {steps};"
                 f" stage mains with the CLI defaults, one process, warm (one untimed run"
                 f" first), start-up excluded; median and cpu per frame; {SHARED}",
            extra={**r, "frames": frames, "frames_per_cpu_s": fps, "decode_cpu_ms": decode_ms,
                   "frames_per_wall_s": wall_fps}))
    return rows


def _one_frame_dataset() -> Path:
    """A one-frame omni dataset without features (so the command extracts them)."""
    return rendered_run("omni", "msl-2015", 1, SEED + 1)


def startup_row(repeat: int, method: str = "lut") -> Row:
    """``fieldloc -q localize DIR --map MAP --method METHOD`` of a one-frame dataset (extract
    + ``method``) in its own process, warm (bytecode compiled, numba and lookup caches written
    by a first run), against ``python -c pass``, interleaved."""
    from ...common.poses_file import read_poses
    from .harness import CLI, REPORTING, run_child, warm_bytecode

    data, mp = _one_frame_dataset(), field_map("msl-2015")
    out = _out_dir("startup") / "poses.h5"
    args = ["-q", "localize", str(data), "--map", str(mp), "--method", method, "-o", str(out),
            "--overwrite"]
    nothing = REPORTING.format(code="pass")

    def localize_once():
        # extracted again each run: the command resumes a features file it finds
        (out.with_name(out.stem + ".features.h5")).unlink(missing_ok=True)
        return run_child(CLI, args)

    warm_bytecode()
    localize_once()
    run_child(nothing, [])
    runs, base, frame = [], [], []
    for _ in range(max(1, repeat)):
        runs.append(localize_once())
        frame.append(float(read_poses(out)[0]["runtime"][0]))
        base.append(run_child(nothing, []))
    wall, cpu = (statistics.median(r[k] for r in runs) for k in range(2))
    rss = max(r[2] for r in runs)
    b_wall, b_cpu = (statistics.median(b[k] for b in base) for k in range(2))
    return Row(
        name=f"images to poses, start-up: fieldloc localize of 1 omni frame (extract +"
             f" {method})",
        median_ms=1e3 * wall, cpu_ms=1e3 * cpu, peak_mb=rss, repeats=len(runs),
        baseline="python -c pass", baseline_ms=1e3 * b_wall, ratio=wall / b_wall,
        note=f"own process, warm (bytecode, numba and lookup caches); CPU from wait4; the"
             f" frame's own runtime {1e3 * statistics.median(frame):.1f} ms; baseline CPU"
             f" {1e3 * b_cpu:.0f} ms, {max(b[2] for b in base):.0f} MB; peak MB: VmHWM;"
             f" wall times include this shared machine's load",
        extra={"wall_s": wall, "cpu_s": cpu, "baseline_wall_s": b_wall,
               "baseline_cpu_s": b_cpu, "frame_runtime_s": statistics.median(frame)})


def frames_row(repeat: int, sizes=LINEAR_FRAMES, method: str = "lut") -> Row:
    """CPU per frame of extract + localize ``method`` (CLI defaults) over datasets of ``sizes``
    frames (msl-2015, one seed each), each warm; the largest set's over the smallest's."""
    mp = field_map("msl-2015")
    out = _out_dir("frames")
    per = {}
    for n in sizes:
        data = rendered_run("omni", "msl-2015", n)
        r = timed_runs(partial(images_to_poses, method, data, mp, out), max(1, repeat // 5))
        per[n] = {**r, "cpu_ms_per_frame": 1e3 * r["cpu_s"] / n,
                  "wall_ms_per_frame": 1e3 * r["wall_s"] / n}
    lo, hi = per[min(sizes)], per[max(sizes)]
    ratio = hi["cpu_ms_per_frame"] / lo["cpu_ms_per_frame"]
    return Row(
        name=f"images to poses, cost in frames: omni + {method} ({' / '.join(map(str, sizes))}"
             " frames)",
        median_ms=hi["wall_ms_per_frame"], cpu_ms=hi["cpu_ms_per_frame"],
        baseline=f"{min(sizes)} frames, CPU per frame", baseline_ms=lo["cpu_ms_per_frame"],
        ratio=ratio, goal=f"<= {LINEAR_GOAL:g} x CPU per frame ({max(sizes)} vs {min(sizes)})",
        meets_goal=ratio <= LINEAR_GOAL, repeats=min(r["runs"] for r in per.values()),
        note=f"extract + localize {method} CPU per frame: " + " / ".join(
            f"{per[n]['cpu_ms_per_frame']:.2f}" for n in sizes) + " ms (localize alone "
             + " / ".join(f"{1e3 * per[n]['localize_cpu_s'] / n:.2f}" for n in sizes)
             + ", extract alone "
             + " / ".join(f"{1e3 * per[n]['extract_cpu_s'] / n:.2f}" for n in sizes)
             + f" ms); median and cpu: the {max(sizes)}-frame set; one process, warm; {SHARED}",
        extra={str(n): v for n, v in per.items()})


def table_cells(field: str) -> int:
    """Cells of the 10 cm grid around ``field`` (1 m margin): what lut's tables hold."""
    from ...common.field import load_field
    from ...common.map_file import Grid

    return int(np.prod(Grid.around(load_field(_field_arg(field)), 1.0, 0.1).shape))


def _localize_rss(data: Path, features: Path, mp: Path, out: Path,
                  method: str) -> tuple[float, float]:
    """(CPU s, peak resident MB) of one ``fieldloc -q localize --features`` process."""
    from .harness import CLI, run_child

    _wall, cpu, rss = run_child(CLI, ["-q", "localize", str(data), "--map", str(mp),
                                      "--features", str(features), "--method", method,
                                      "-o", str(out),
                                      "--overwrite"])
    return cpu, rss


def area_rows(repeat: int, fields=AREA_FIELDS, frames: int = AREA_FRAMES,
              method: str = "lut") -> list[Row]:
    """Per field of ``fields``: ``method``'s localize CPU per frame (in this process, warm) and the
    peak resident set of a localize process on the same features (warm lookup cache), each
    against the first field's as a ratio beside the ratio of their table cells."""
    from ... import extract, localize

    conf = cli_conf(method)
    per = {}
    for field in fields:
        data = rendered_run("omni", field, frames)
        mp = field_map(field)
        out = _out_dir(f"area-{field}")
        feats = extract.main(None, data, out / "features.h5", overwrite=True)

        def run(data=data, mp=mp, out=out, feats=feats):
            c = time.process_time()
            t = time.perf_counter()
            localize.main(conf, data, mp, out / "poses.h5", features=feats, overwrite=True)
            return time.perf_counter() - t, 0.0, time.process_time() - c

        r = timed_runs(run, max(1, repeat // 5))
        rss = [_localize_rss(data, feats, mp, out / "cli.poses.h5", method)
               for _ in range(max(1, repeat // 5))]
        per[field] = {**r, "cpu_ms_per_frame": 1e3 * r["cpu_s"] / frames,
                      "wall_ms_per_frame": 1e3 * r["wall_s"] / frames,
                      "process_cpu_s": statistics.median(x[0] for x in rss),
                      "peak_mb": max(x[1] for x in rss), "cells": table_cells(field)}
    first = per[fields[0]]
    rows = []
    for field in fields:
        p = per[field]
        area = p["cells"] / first["cells"]
        cpu_ratio = p["cpu_ms_per_frame"] / first["cpu_ms_per_frame"]
        rss_ratio = p["peak_mb"] / first["peak_mb"]
        is_first = field == fields[0]
        rows.append(Row(
            name=f"images to poses, cost in field area: {method} localize on {field}"
                 f" ({frames} frames)",
            median_ms=p["wall_ms_per_frame"], cpu_ms=p["cpu_ms_per_frame"],
            peak_mb=p["peak_mb"], repeats=p["runs"],
            baseline="" if is_first else f"{fields[0]}, CPU per frame",
            baseline_ms=math.nan if is_first else first["cpu_ms_per_frame"],
            ratio=math.nan if is_first else cpu_ratio,
            goal="" if is_first else
            f"CPU per frame and peak RSS <= {LINEAR_GOAL:g} x the area ratio",
            meets_goal=None if is_first else
            (cpu_ratio <= LINEAR_GOAL * area and rss_ratio <= LINEAR_GOAL * area),
            note=f"{p['cells']:,} table cells ({area:.2f} x {fields[0]}'s);"
                 f" peak RSS {rss_ratio:.2f} x; the localize process (fieldloc -q localize"
                 f" --features, warm lookup cache, VmHWM) {p['process_cpu_s']:.2f} s CPU;"
                 f" median and cpu: localize alone per frame, one process, warm; {SHARED}",
            extra=p))
    return rows

