"""Bench rows of the batch runner (stages.pipelines.batch) and of the table search's lookup
cache (stages.localize.lookup_cache), registered in stages.pipelines.bench.ROWS:

- ``bench_batch_throughput``: one grid of 8 lut runs (4 rendered msl-2015 datasets x lut on
  independent frames with two heading sources; features and map made beforehand) run by the
  whole ``batch.main`` on running LocalClusters of 1 and 2 workers, one cluster at a time in
  blocks (1, 2, 2, 1 workers, against drift), each after a first batch on the cluster (the
  workers' imports and caches, reported apart); the ratio of the medians is the throughput
  gain (goal >= 1.8x);
- ``bench_first_frame``: ``fieldloc localize`` of a one-frame dataset on msl-2015 through the
  CLI in a new process, with the lookup cache warm (the goal: the first frame starts <= 1 s
  after the process does) and, as the baseline, cold (the cache removed before each run);
  the time to the first frame is the process's wall time less the frame's own runtime
  (recorded in poses.h5): an upper bound, since writing the poses and the interpreter's exit
  are left in;
- ``bench_worker_memory``: the peak resident memory of each worker process of a 2-worker batch
  of lut runs on the msl field (21.9 x 13.9 m between centre lines) with the lookup mapped
  (goal <= 1.5 GB), next to the lookup's size.
"""

from __future__ import annotations

import json
import logging
import math
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import yaml

from .harness import Row, warm_bytecode
from .inputs import rendered_inputs, work_dir


def _spec(folder: Path, datasets: list[Path], map_path: Path, methods) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    spec = {"map": str(map_path), "datasets": [{"path": str(d)} for d in datasets],
            "methods": methods}
    path = folder / "spec.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def _warm(map_path: Path) -> None:
    """The map's lookup cache written (as a first run would)."""
    from ...common.map_file import MapFile
    from ...localize import lut

    with MapFile(map_path) as mf:
        lut.table_search(mf, lut.SEARCH)


def bench_batch_throughput(repeat: int) -> Row:
    from dask.distributed import LocalCluster

    from .. import batch

    frames = 120
    inputs = [rendered_inputs("omni", "msl-2015", frames, 21 + k) for k in range(4)]
    map_path = inputs[0]["map"]
    _warm(map_path)
    work = work_dir() / "batch-throughput"
    methods = ["lut-independent", {"name": "lut-independent-histogram", "method": "lut",
                                   "conf": {"independent": True, "heading": "histogram"}}]
    spec = _spec(work, [Path(i["data"]) for i in inputs], map_path, methods)
    times: dict[int, list[float]] = {1: [], 2: []}
    first: dict[int, float] = {}
    runs = 0
    quiet = {"threads_per_worker": 1, "processes": True, "dashboard_address": ":0",
             "silence_logs": logging.WARNING}
    run_s: list[float] = []  # the runs' own seconds on 1 worker (their sum: the runs' share)
    # blocks of batches on one running cluster at a time (an idle cluster's scheduler, nanny
    # and worker would take some of the busy one's cores), 1 2 2 1 against drift, each
    # cluster's first batch apart (its workers' imports, numba caches and mapped lookup)
    per_block = max(1, math.ceil(repeat / 2))
    for n in (1, 2, 2, 1):
        with LocalCluster(n_workers=n, **quiet) as cluster:
            for k in range(1 + per_block):
                out = work / f"results-{n}"
                t = time.perf_counter()
                batch.main({"scheduler": cluster.scheduler_address}, spec, out,
                           overwrite=True, report=lambda _line: None)
                dt = time.perf_counter() - t
                if k == 0:
                    first.setdefault(n, dt)
                    continue
                times[n].append(dt)
                index = json.loads((out / "batch.json").read_text())
                runs = len(index["runs"])
                assert all(r["status"] == "ok" for r in index["runs"]), index["runs"]
                if n == 1:
                    run_s.append(sum(r["seconds"] for r in index["runs"]))
    one_s, two_s = statistics.median(times[1]), statistics.median(times[2])
    gain = one_s / two_s
    # the datasets' CDF pictures, which the workers draw beside the runs: timed here on the
    # same results with the same function
    from ...common.batch_file import load_batch
    from ...show import comparison

    res = work / "results-1"
    index = load_batch(res)
    t = time.perf_counter()
    for name in index["datasets"]:
        comparison.draw_dataset_cdf(res, name, index["runs"])
    pictures_s = time.perf_counter() - t
    # Amdahl: the batch's own part (plan, comparison table, summary picture; in this process)
    # stays, the runs' and the dataset pictures' part halves on 2 free cores
    par = min(statistics.median(run_s) + pictures_s, one_s)
    bound = one_s / (one_s - par + par / 2)
    return Row(
        name=f"batch throughput, 2 workers vs 1 ({runs} lut runs, msl-2015)",
        median_ms=1000 * two_s, goal=">= 1.8x one worker's throughput", meets_goal=gain >= 1.8,
        baseline="the same batch on 1 worker", baseline_ms=1000 * one_s, ratio=two_s / one_s,
        repeats=len(times[2]),
        note=f"{runs} runs of {frames} frames (4 rendered datasets x lut on independent frames,"
             f" imu and histogram heading): the whole batch.main (plan, runs, comparison"
             f" table and pictures) on running LocalClusters of 1 and 2 workers, one at a"
             f" time, in blocks of {per_block} batches (1, 2, 2, 1 workers);"
             f" throughput gain {gain:.2f}x (the runs and the dataset pictures, drawn on the"
             f" workers, are {100 * par / one_s:.0f} % of the 1-worker batch: {bound:.2f}x on"
             f" 2 free cores); the first batch on fresh"
             f" workers (imports, numba caches) {first[1]:.1f} s on 1, {first[2]:.1f} s on 2;"
             f" {os.cpu_count()} cores shared with other work")


def _one_frame_dataset() -> dict:
    """A one-frame omni dataset on msl-2015 with its features and the map (bench inputs)."""
    return rendered_inputs("omni", "msl-2015", 1, 31)


def _cli_localize(inp: dict, out: Path) -> tuple[float, float, float]:
    """(wall s, CPU s of the process, the frame's recorded runtime s) of one
    ``fieldloc -q localize`` process."""
    from ...common.poses_file import read_poses

    exe = Path(sys.executable).with_name("fieldloc")
    cmd = [str(exe), "-q", "localize", str(inp["data"]), "--map", str(inp["map"]),
           "--features", str(inp["features"]), "-o", str(out), "--overwrite"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    runtime = float(read_poses(out)[0]["runtime"][0])
    return wall, cpu, runtime


def bench_first_frame(repeat: int) -> Row:
    from ...localize.lookup_cache import cache_folder

    inp = _one_frame_dataset()
    out = work_dir() / "first-frame.poses.h5"
    warm_bytecode()
    _cli_localize(inp, out)  # the numba caches and the lookup cache warm
    warm, warm_cpu, cold = [], [], []
    for _ in range(max(1, repeat)):
        wall, cpu, rt = _cli_localize(inp, out)
        warm.append(wall - rt)
        warm_cpu.append(cpu - rt)
    for _ in range(max(1, repeat // 3)):
        shutil.rmtree(cache_folder(inp["map"]), ignore_errors=True)
        wall, _cpu, rt = _cli_localize(inp, out)
        cold.append(wall - rt)
    w, c, b = (statistics.median(v) for v in (warm, warm_cpu, cold))
    return Row(
        name="lut first frame after the process starts, warm lookup cache (msl-2015, CLI)",
        median_ms=1000 * w, cpu_ms=1000 * c, goal="<= 1 s", meets_goal=w <= 1.0,
        baseline="cold cache (the lookup built in the process)", baseline_ms=1000 * b,
        ratio=w / b, repeats=len(warm),
        note="fieldloc -q localize of a one-frame dataset in a new process, its caches warm"
             " (numba's, the lookup's, Python's bytecode): wall time less the"
             " frame's own runtime (an upper bound: writing poses.h5 and the exit are in it);"
             f" cpu = the process's CPU time less the frame's ({1000 * c:.0f} ms); on this"
             " shared 2-core machine the wall time is the CPU time plus the other helpers'"
             " load")


def _worker_peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_worker_memory(repeat: int) -> Row:
    from dask.distributed import Client, LocalCluster

    from .. import batch
    from ..batch_spec import read_spec

    inputs = [rendered_inputs("omni", "msl", 20, 41 + k) for k in range(2)]
    map_path = inputs[0]["map"]
    _warm(map_path)
    from ...localize.lookup_cache import cache_folder

    lookup_mb = sum(p.stat().st_size for p in cache_folder(map_path).glob("*.npy")) / 2**20
    work = work_dir() / "batch-memory"
    spec = _spec(work, [Path(i["data"]) for i in inputs], map_path, ["lut", "lut-no-fusion"])
    plan = read_spec(spec, work / "results")
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0", silence_logs=logging.WARNING) as cluster, \
            Client(cluster) as client:
        batch.main({"scheduler": cluster.scheduler_address}, spec, work / "results",
                   overwrite=True)
        peaks = client.run(_worker_peak_mb)
    peak = max(peaks.values())
    return Row(
        name="batch worker peak memory, lut on msl (21.9 x 13.9 m), lookup mapped",
        median_ms=float("nan"), peak_mb=peak, goal="<= 1.5 GB per worker",
        meets_goal=peak <= 1536, repeats=1,
        note=f"peak RSS of each of 2 workers after {len(plan.runs)} lut runs:"
             f" {', '.join(f'{v:.0f}' for v in sorted(peaks.values()))} MB (mapped pages"
             f" included); the cached lookup is {lookup_mb:.0f} MB on disk")
