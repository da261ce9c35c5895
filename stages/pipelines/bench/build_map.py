"""``fieldloc bench`` rows of build-map: its tables of a field, and the analytic distance
table against a raster Euclidean transform."""

from __future__ import annotations

import math
import time

import numpy as np

from .harness import Row, msec, peak_memory_mb, time_interleaved


def bench_build_map(field_name: str, repeat: int) -> Row:
    from ...build_map import build_tables, confs
    from ...common.field import load_field

    fm = load_field(field_name)
    conf = confs["default"]
    cpu = []

    def build():
        t = time.process_time()
        build_tables(fm, conf)
        cpu.append(time.process_time() - t)

    times, _ = time_interleaved(build, repeat=max(1, repeat // 3), warmup=0)
    peak = peak_memory_mb(lambda: build_tables(fm, conf))
    med = msec(cpu)
    return Row(
        name=f"build-map tables {field_name}",
        median_ms=med,
        goal="<= 10 s and <= 300 MB (msl)",
        meets_goal=(med <= 10_000 and peak <= 300) if field_name == "msl" else None,
        peak_mb=peak,
        cpu_ms=msec(cpu),
        repeats=len(times),
        note=f"radial + spiral + distance tables; goal judged on CPU time (wall {msec(times):.0f}"
             " ms on this shared machine)",
    )


def bench_distance_vs_edt(repeat: int) -> Row:
    import cv2
    from scipy.ndimage import distance_transform_edt

    from ...build_map.tables import distance_table
    from ...common.field import load_field
    from ...common.map_file import Grid

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
        median_ms=msec(a),
        baseline="scipy EDT on a raster of the same grid",
        baseline_ms=msec(b),
        ratio=msec(a) / msec(b),
        repeats=repeat,
        note="exact distances vs pixel-quantised ones",
    )
