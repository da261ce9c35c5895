"""``fieldloc bench`` row of the start-up goal: `fieldloc --help` and
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

import statistics

from .harness import BASELINE, CLI, Row, run_child

GOAL_CPU_S, GOAL_RSS_MB = 0.5, 100.0
COMMANDS = (("fieldloc --help", ["--help"]), ("fieldloc localize --help", ["localize", "--help"]))

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
