"""The harness of ``fieldloc bench``: a ``Row`` of results, the timing helpers every family of
rows uses, and the table and JSON of a run.

Every row that has a baseline runs it in the same process, on the same input, interleaved with
the measured code (A B A B ...), and reports the ratio of the medians: these machines are shared
and noisy, so a ratio and a median say more than one absolute time. Rows whose work runs in a
process of its own measure it with ``child_cpu`` or ``run_child``.

Nothing here imports a row: the rows import the harness (and ``inputs``), the registry
(``stages.pipelines.bench``) imports the rows.
"""

from __future__ import annotations

import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ...common.artifacts import WRITTEN_MARK, atomic_path, cannot_read
from ...common.conf import load_json


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
                     warmup: int = 1, clock: Callable[[], float] = time.perf_counter
                     ) -> tuple[list[float], list[float]]:
    """Run fn (and baseline) alternately; return the lists of seconds of ``clock`` (wall
    time, or time.process_time: the CPU time of every thread of the process)."""
    for _ in range(warmup):
        fn()
        if baseline is not None:
            baseline()
    a, b = [], []
    for _ in range(repeat):
        t = clock()
        fn()
        a.append(clock() - t)
        if baseline is not None:
            t = clock()
            baseline()
            b.append(clock() - t)
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


def msec(xs):
    """The median of the seconds ``xs`` in milliseconds (NaN for none)."""
    return 1000 * statistics.median(xs) if xs else math.nan


def per_frame(fn, items, repeat):
    """Median over frames of the per-frame median time (s) of fn(item)."""
    per = []
    for it in items:
        ts = []
        for _ in range(max(1, repeat)):
            t0 = time.perf_counter()
            fn(it)
            ts.append(time.perf_counter() - t0)
        per.append(statistics.median(ts))
    return per


def median_time(fn, repeats: int) -> float:
    """Median seconds of ``repeats`` calls of fn()."""
    ts = []
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def pct_within(s, k):
    """The share of frames within ``k`` m (a key of an evaluate summary's ``within``) in %."""
    v = s["within"].get(k)
    return "-" if v is None else f"{100 * v:.0f}"


def run_errors(poses_path: Path, data: Path):
    """(frame errors, poses columns) of the poses file ``poses_path`` against the dataset
    ``data``'s truth (2 cm stamp tolerance)."""
    from ...common.dataset import read_csv
    from ...common.poses_file import read_poses
    from ...evaluate.metrics import frame_errors

    cols, _ = read_poses(poses_path)
    return frame_errors(cols, read_csv(data / "truth.csv", "truth"), 0.02), cols


def ranks_well(auroc: float, top_wrong: int, goal: float) -> bool:
    """Whether a confidence meets an AUROC goal: its AUROC reaches ``goal``, or no frame's top
    pose is off (``top_wrong`` 0), when the AUROC is undefined and nothing is left to rank."""
    return bool(auroc >= goal or top_wrong == 0)


def calibration_rows(method: str, runs, label: str, seconds: float) -> list[Row]:
    """The reliability of a method's confidence over localised rendered runs ``runs`` ((poses
    file, dataset folder) pairs): AUROC and reliability table of "top hypothesis within 40 cm"
    (a failed frame has confidence 0), and the frames accepted while more than 1 m off."""
    from ...evaluate.metrics import auroc, reliability

    conf_all, ok_all, rows, frames = [], [], [], 0
    wrong = not_acc = within = 0
    for out, data in runs:
        fe, _cols = run_errors(out, data)
        sel = fe.matched & ~fe.failed
        conf_all.append(np.where(sel, fe.confidence, 0.0)[fe.matched])
        ok_all.append((fe.top_error <= 0.4)[fe.matched])
        frames += int(fe.matched.sum())
        wrong += int(np.sum(fe.matched & fe.accepted & (fe.top_error > 1.0)))
        not_acc += int(np.sum(fe.matched & ~fe.accepted))
        within += int(np.sum(fe.matched & (fe.position_error <= 0.4)))
    c, ok = np.concatenate(conf_all), np.concatenate(ok_all)
    table = reliability(c, ok)
    big = [r for r in table if r["frames"] >= 20]
    gap = max((abs(r["observed"] - r["confidence"]) for r in big), default=math.nan)
    a = auroc(c, ok)
    rel = "; ".join(f"{r['bin'][0]:.1f}-{r['bin'][1]:.1f}: {r['frames']} frames,"
                    f" {r['confidence']:.2f} -> {r['observed']:.2f}" for r in table)
    rows.append(Row(
        name=f"{method} confidence calibration, {label}", median_ms=math.nan,
        goal="AUROC >= 0.95; per bin |observed - confidence| <= 0.1",
        meets_goal=bool(ranks_well(a, int(np.sum(~ok)), 0.95) and gap <= 0.1), repeats=1,
        note=f"{len(runs)} sets, {frames} frames, {seconds:.0f} s; AUROC"
             f" {a:.3f}; largest gap {gap:.2f} over bins of >= 20 frames; {rel}",
        extra={"reliability": table, "auroc": a, "top_wrong": int(np.sum(~ok))}))
    share = wrong / max(frames, 1)
    rows.append(Row(
        name=f"{method} frames confidently wrong, {label}", median_ms=math.nan,
        goal="<= 1 % accepted and > 1 m off", meets_goal=share <= 0.01, repeats=1,
        note=f"{wrong} of {frames} frames ({100 * share:.2f} %); not accepted"
             f" {100 * not_acc / max(frames, 1):.1f} %; within 40 cm counting those"
             f" {100 * within / max(frames, 1):.1f} %"))
    return rows


# ---------------------------------------------------------------------------- processes


def child_cpu(code: str, env: dict) -> float:
    """CPU seconds (user + system) of ``code`` run by this Python in a process of its own."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-c", code], env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


# run as `python -c`: report the process's peak resident set (VmHWM) on stderr at exit, then run
# {code} with the command line's arguments
REPORTING = """\
import atexit, sys
def _hwm():
    with open("/proc/self/status") as f:
        sys.stderr.write(next((l for l in f if l.startswith("VmHWM:")), "VmHWM: nan kB") + "\\n")
atexit.register(_hwm)
{code}
"""
CLI = REPORTING.format(code="from fieldloc_cli.main import cli\nsys.exit(cli())")
BASELINE = REPORTING.format(code="import click")


def run_child(code: str, args: list[str]) -> tuple[float, float, float]:
    """(wall s, user + sys CPU s, peak resident MB) of one process running ``code`` (REPORTING
    of some code) with ``args``; its stdout is discarded, a non-zero exit is an error."""
    t = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    err = p.stderr.read()  # help texts are short: the child never blocks on a full pipe
    _pid, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    p.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
    p.stderr.close()
    if p.returncode != 0:
        raise RuntimeError(f"fieldloc {' '.join(args)} exited with {p.returncode}: {err}")
    hwm = [line.split()[1] for line in err.splitlines() if line.startswith("VmHWM:")]
    return wall, usage.ru_utime + usage.ru_stime, float(hwm[-1]) / 1024 if hwm else math.nan


def warm_bytecode() -> None:
    """Python's bytecode of fieldloc's own modules, compiled as an import would write it. A
    process started with PYTHONDONTWRITEBYTECODE (as on this machine) never writes it, so
    every start would compile fieldloc's sources again (about 0.1 s of a lut run's start);
    ``make install`` compiles them once, and so do the rows that time a process's start, for
    a warm start."""
    import compileall

    root = Path(__file__).resolve().parents[3]
    for package in ("stages", "fieldloc_cli"):
        compileall.compile_dir(str(root / package), quiet=1)


# ---------------------------------------------------------------------------- table and JSON


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


def format_markdown(rows: list[Row]) -> str:
    """The rows as docs/results.md's performance table (``make bench-readme``)."""
    def f(v, unit=""):
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return ""
        if isinstance(v, float):
            return f"{v:.3g}{unit}" if v < 100 else f"{v:.0f}{unit}"
        return str(v)

    out = ["| row | median | CPU | baseline (same run) | ratio | peak MB | goal | met |",
           "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        base = f"{r.baseline}: {f(r.baseline_ms, ' ms')}" if r.baseline else ""
        met = "" if r.meets_goal is None else ("yes" if r.meets_goal else "not met")
        cells = [r.name, f(r.median_ms, " ms"), f(r.cpu_ms, " ms"), base, f(r.ratio),
                 f(r.peak_mb), r.goal, met]
        out.append("| " + " | ".join(str(c).replace("|", "/") for c in cells) + " |")
    notes = [f"- {r.name}: {r.note}" for r in rows if r.note]
    return "\n".join(out + ([""] + notes if notes else [])) + "\n"


# the largest bench --json file read: a full run's rows take a few dozen kB, so this is far
# above any real one and still refuses /dev/zero or a stray huge file before memory runs out
MAX_JSON_BYTES = 16 << 20


def read_json(path: str | Path) -> list[Row]:
    """The rows of a ``bench --json`` file: a regular file (a FIFO would block the read, a
    device never end it) of at most MAX_JSON_BYTES."""
    from ...common.errors import FieldlocError, file_problem

    problem = file_problem(path)
    if problem is not None:
        raise FieldlocError(f"{path}: {problem}, not a bench --json file")
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_JSON_BYTES + 1)
        if len(raw) > MAX_JSON_BYTES:
            raise FieldlocError(f"{path}: larger than {MAX_JSON_BYTES >> 20} MiB, not a bench"
                                " --json file")
        data = load_json(raw)
    except PermissionError as e:
        raise cannot_read(path, e) from None
    except (OSError, ValueError, RecursionError) as e:
        raise FieldlocError(f"{path}: not a bench --json file ({e})") from None
    rows = data.get("rows") if isinstance(data, dict) else None
    if not isinstance(rows, list):
        raise FieldlocError(f"{path}: not a bench --json file (no list of rows)")
    return [_row_from_json(path, i, r) for i, r in enumerate(rows)]


# The JSON kind of each Row field: write_json writes a non-finite float as null, so a number
# field takes null too (read back as NaN)
_NUMBER_FIELDS = ("median_ms", "baseline_ms", "ratio", "peak_mb", "cpu_ms")
_TEXT_FIELDS = ("name", "goal", "baseline", "note")
# the largest magnitude a number field takes: a time, a ratio or a memory figure above it is no
# measure (an integer of 401 digits made a 400-character table column)
MAX_BENCH_NUMBER = 1e300


def _row_from_json(path, i: int, r) -> Row:
    """Row ``i`` of a bench --json file, refused in one line when a field has the wrong kind
    (a name of 5 would otherwise print as a row of the table). Keys Row does not know are
    ignored: a newer run's file still prints."""
    from ...common.errors import FieldlocError, shown
    from ...common.one_line import has_control

    def wrong(what: str) -> FieldlocError:
        return FieldlocError(f"{path}: not a bench --json file (row {i}: {what})")

    if not isinstance(r, dict):
        raise wrong("not an object")
    if "name" not in r:
        raise wrong("no name")
    values = {}
    for k, v in r.items():
        if k in _NUMBER_FIELDS:
            if v is None:
                v = math.nan
            elif isinstance(v, bool) or not isinstance(v, int | float):
                raise wrong(f"{k} is not a number")
            elif abs(v) > MAX_BENCH_NUMBER:  # an int beyond the float range too; NaN passes
                raise wrong(f"{k} {shown(v, 20)} is beyond {MAX_BENCH_NUMBER:g}")
        elif k in _TEXT_FIELDS and not isinstance(v, str):
            raise wrong(f"{k} is not text")
        elif k in _TEXT_FIELDS and has_control(v):  # ESC [31m, a line break: printed raw
            raise wrong(f"{k} {shown(v, 30)} holds a control character")
        elif k == "meets_goal" and not (v is None or isinstance(v, bool)):
            raise wrong("meets_goal is not true, false or null")
        elif k == "repeats" and (isinstance(v, bool) or not isinstance(v, int) or v < 0
                                 or v > MAX_BENCH_NUMBER):
            raise wrong(f"repeats {shown(v, 20)} is not a whole number >= 0")
        elif k == "extra" and not isinstance(v, dict):
            raise wrong("extra is not an object")
        elif k not in Row.__dataclass_fields__:
            continue
        values[k] = v
    return Row(**values)


def merge_runs(runs: list[list[Row]]) -> list[Row]:
    """One table from several runs' rows: the first run's rows in their order, each replaced by
    the row of the same name from the latest run that has one, then the rows only later runs
    have, in their order. A full bench run takes hours; the rows a shared machine's load
    distorts are timed again alone, and ``fieldloc bench --from-json FULL --from-json AGAIN``
    makes the table of both."""
    merged: dict[str, Row] = {}
    for rows in runs:
        for row in rows:
            merged[row.name] = row  # a dict keeps the first insertion's place
    return list(merged.values())


def write_json(rows: list[Row], path: str | Path) -> Path:
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        return v

    data = {"generator": WRITTEN_MARK, "rows": [clean(asdict(r)) for r in rows]}
    with atomic_path(Path(path), suffix=".json") as tmp:
        tmp.write_text(json.dumps(data, indent=2))
    return Path(path)
