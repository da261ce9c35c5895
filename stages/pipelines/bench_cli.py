"""``fieldloc bench`` row of issue 22's start-up goal: `fieldloc --help` and
`fieldloc localize --help` each cost <= 0.5 s of CPU and <= 100 MB of resident memory, warm (the
interpreter's bytecode caches written by a first, untimed run).

Each run is its own process running the CLI's entry point (what the `fieldloc` script runs).
Its CPU (user + sys) comes from ``os.wait4``, which reports it for that one child. Its peak
resident set is the child's own VmHWM, which the child writes to stderr as it exits: Linux
counts a child's resident set before its exec (this bench process, numpy loaded) in the
child's ``ru_maxrss``, so that figure says more about the parent than about the CLI. The
baseline, interleaved with the measured runs, is the floor every run pays: an interpreter that
imports click and exits.
"""

from __future__ import annotations

import math
import os
import statistics
import subprocess
import sys
import time

from .bench import Row

GOAL_CPU_S, GOAL_RSS_MB = 0.5, 100.0
COMMANDS = (("fieldloc --help", ["--help"]), ("fieldloc localize --help", ["localize", "--help"]))

# run as `python -c`: report the process's peak resident set (VmHWM) on stderr at exit, then run
# {code} with the command line's arguments
_REPORTING = """\
import atexit, sys
def _hwm():
    with open("/proc/self/status") as f:
        sys.stderr.write(next((l for l in f if l.startswith("VmHWM:")), "VmHWM: nan kB") + "\\n")
atexit.register(_hwm)
{code}
"""
CLI = _REPORTING.format(code="from fieldloc_cli.main import cli\nsys.exit(cli())")
BASELINE = _REPORTING.format(code="import click")


def run_child(code: str, args: list[str]) -> tuple[float, float, float]:
    """(wall s, user + sys CPU s, peak resident MB) of one process running ``code`` (one of
    the above) with ``args``; its stdout is discarded, a non-zero exit is an error."""
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


def rows(repeat: int) -> list[Row]:
    """One row per command: median wall time and CPU, largest resident set (module doc)."""
    out = []
    for name, args in COMMANDS:
        run_child(CLI, args)  # warm: bytecode written, files in the page cache
        run_child(BASELINE, [])
        runs, base = [], []
        for _ in range(repeat):
            runs.append(run_child(CLI, args))
            base.append(run_child(BASELINE, []))
        wall = statistics.median(r[0] for r in runs)
        cpu = statistics.median(r[1] for r in runs)
        rss = max(r[2] for r in runs)
        base_wall = statistics.median(b[0] for b in base)
        out.append(Row(
            name=f"cli help: {name} (warm, own process)",
            median_ms=1000 * wall, cpu_ms=1000 * cpu, peak_mb=rss, repeats=repeat,
            goal=f"<= {GOAL_CPU_S:g} s CPU, <= {GOAL_RSS_MB:g} MB max RSS",
            meets_goal=cpu <= GOAL_CPU_S and rss <= GOAL_RSS_MB,
            baseline="python -c 'import click'", baseline_ms=1000 * base_wall,
            ratio=wall / base_wall,
            note=f"peak MB: the process's peak resident set (VmHWM); baseline CPU"
                 f" {1000 * statistics.median(b[1] for b in base):.0f} ms,"
                 f" {max(b[2] for b in base):.0f} MB"))
    return out
