"""``fieldloc bench``: speed (and accuracy where the issue sets a goal) of each stage.

Every row that has a baseline runs it in the same process, on the same input, interleaved with
the measured code (A B A B ...), and reports the ratio of the medians: these machines are shared
and noisy, so a ratio and a median say more than one absolute time.

A row is a function of the repeat count returning a ``Row`` (or a list of them); ``ROWS``
lists them in order.
"""

from __future__ import annotations

import json
import math
import statistics
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..common.artifacts import atomic_path


@dataclass
class Row:
    name: str
    median_ms: float = math.nan
    goal: str = ""
    meets_goal: bool | None = None
    baseline: str = ""
    baseline_ms: float = math.nan
    ratio: float = math.nan  # median / baseline median
    peak_mb: float = math.nan
    cpu_ms: float = math.nan  # median process CPU time: what one core spent, load or not
    repeats: int = 0
    note: str = ""
    extra: dict = field(default_factory=dict)


def time_interleaved(fn: Callable, baseline: Callable | None = None, repeat: int = 5,
                     warmup: int = 1) -> tuple[list[float], list[float]]:
    """Run fn (and baseline) alternately; return the lists of seconds."""
    for _ in range(warmup):
        fn()
        if baseline is not None:
            baseline()
    a, b = [], []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        a.append(time.perf_counter() - t)
        if baseline is not None:
            t = time.perf_counter()
            baseline()
            b.append(time.perf_counter() - t)
    return a, b


def peak_memory_mb(fn: Callable) -> float:
    """Peak of memory allocated through Python's allocators (numpy included) while fn runs."""
    tracemalloc.start()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 2**20


def _ms(xs):
    return 1000 * statistics.median(xs) if xs else math.nan


# ---------------------------------------------------------------------------- rows: build-map


def bench_build_map(field_name: str, repeat: int) -> Row:
    from ..build_map import build_tables, confs
    from ..common.field import load_field

    fm = load_field(field_name)
    conf = confs["default"]
    cpu = []

    def build():
        t = time.process_time()
        build_tables(fm, conf)
        cpu.append(time.process_time() - t)

    times, _ = time_interleaved(build, repeat=max(1, repeat // 3), warmup=0)
    peak = peak_memory_mb(lambda: build_tables(fm, conf))
    med = _ms(cpu)
    return Row(
        name=f"build-map tables {field_name}",
        median_ms=med,
        goal="<= 10 s and <= 300 MB (msl)",
        meets_goal=(med <= 10_000 and peak <= 300) if field_name == "msl" else None,
        peak_mb=peak,
        cpu_ms=_ms(cpu),
        repeats=len(times),
        note=f"radial + spiral + distance tables; goal judged on CPU time (wall {_ms(times):.0f}"
             " ms on this shared machine)",
    )


def bench_distance_vs_edt(repeat: int) -> Row:
    import cv2
    from scipy.ndimage import distance_transform_edt

    from ..build_map.tables import distance_table
    from ..common.field import load_field
    from ..common.map_file import Grid

    fm = load_field("msl-2015")
    grid = Grid.around(fm, 1.0, 0.1)

    def edt():
        # the raster baseline: lines drawn on the same grid, then the Euclidean transform
        img = np.full(grid.shape, 255, np.uint8)

        def px(x, y):
            return (int(round((x - grid.origin[0]) / grid.resolution)),
                    int(round((y - grid.origin[1]) / grid.resolution)))

        for (ax, ay), (bx, by) in fm.segments:
            cv2.line(img, px(ax, ay), px(bx, by), 0, 1)
        for cx, cy, r, a0, sweep in fm.arcs:
            cv2.ellipse(img, px(cx, cy), (int(round(r / grid.resolution)),) * 2, 0,
                        math.degrees(a0), math.degrees(a0 + sweep), 0, 1)
        return distance_transform_edt(img > 0) * grid.resolution

    a, b = time_interleaved(lambda: distance_table(fm, grid), edt, repeat=repeat)
    return Row(
        name="distance table msl-2015 (analytic)",
        median_ms=_ms(a),
        baseline="scipy EDT on a raster of the same grid",
        baseline_ms=_ms(b),
        ratio=_ms(a) / _ms(b),
        repeats=repeat,
        note="exact distances vs pixel-quantised ones",
    )


# ---------------------------------------------------------------------------- registry

ROWS: dict[str, Callable[[int], Row | list[Row]]] = {
    "build-map-msl-2015": lambda n: bench_build_map("msl-2015", n),
    "build-map-msl": lambda n: bench_build_map("msl", n),
    "distance-vs-edt": bench_distance_vs_edt,
}


def run(only: list[str] | None = None, repeat: int = 5, progress=None) -> list[Row]:
    names = [n for n in ROWS if not only or any(o in n for o in only)]
    rows: list[Row] = []
    for name in names:
        if progress:
            progress(name)
        out = ROWS[name](repeat)
        rows.extend(out if isinstance(out, list) else [out])
    return rows


def format_table(rows: list[Row]) -> str:
    def f(v, unit=""):
        if v is None or (isinstance(v, float) and math.isnan(v)):
            return "-"
        if isinstance(v, float):
            return f"{v:.3g}{unit}" if v < 100 else f"{v:.0f}{unit}"
        return str(v)

    head = ["row", "median", "cpu", "baseline", "ratio", "peak MB", "goal", "met"]
    lines = [head]
    for r in rows:
        base = f"{f(r.baseline_ms, ' ms')} ({r.baseline})" if r.baseline else "-"
        met = "-" if r.meets_goal is None else ("yes" if r.meets_goal else "NO")
        lines.append([r.name, f(r.median_ms, " ms"), f(r.cpu_ms, " ms"), base, f(r.ratio),
                      f(r.peak_mb),
                      r.goal or "-", met])
    widths = [max(len(str(line[c])) for line in lines) for c in range(len(head))]
    out = []
    for n, line in enumerate(lines):
        out.append("  ".join(str(v).ljust(w) for v, w in zip(line, widths)).rstrip())
        if n == 0:
            out.append("  ".join("-" * w for w in widths))
    notes = [f"  {r.name}: {r.note}" for r in rows if r.note]
    return "\n".join(out + (["", "notes:"] + notes if notes else []))


def write_json(rows: list[Row], path: str | Path) -> Path:
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        return v

    data = {"rows": [clean(asdict(r)) for r in rows]}
    with atomic_path(Path(path), suffix=".json") as tmp:
        tmp.write_text(json.dumps(data, indent=2))
    return Path(path)
