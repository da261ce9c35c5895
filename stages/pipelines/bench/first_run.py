"""``fieldloc bench`` rows of the first run after an install: the CPU of a command's first
run right after the install's warm-up (stages.pipelines.warmup) on an empty numba cache, against
a second run of the same command."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from .harness import Row, child_cpu


def bench_first_run(repeat: int) -> list:
    """Bench rows: the CPU of the first extract of a 10-frame perspective dataset and of the
    first ``localize --method fit`` of a 10-frame omni one after an install (the warm-up run
    on an empty numba cache, NUMBA_CACHE_DIR), each against a second run of the same command
    in a new process (goal <= 1.5x). One run each (``repeat`` is not used): a first run
    happens once per cache."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="fieldloc-first-run-") as tmp:
        d = Path(tmp)
        env = {**os.environ, "NUMBA_CACHE_DIR": str(d / "numba-cache")}
        # the inputs, made with a numba cache of their own (thrown away)
        child_cpu(
            "from stages import build_map, extract, simulate\n"
            f"c = dict(simulate.confs['perspective-default'], frames=10, seed=1)\n"
            f"simulate.main(c, 'kidsize', {str(d / 'kid')!r})\n"
            f"c = dict(simulate.confs['omni-default'], frames=10, seed=1)\n"
            f"simulate.main(c, 'msl-2015', {str(d / 'omni')!r})\n"
            f"extract.main(None, {str(d / 'omni')!r}, {str(d / 'omni.features.h5')!r})\n"
            f"build_map.main(None, 'msl-2015', {str(d / 'msl.map.h5')!r})\n",
            {**os.environ, "NUMBA_CACHE_DIR": str(d / "inputs-cache")})
        install = child_cpu("from stages.pipelines import warmup; warmup.run()", env)
        commands = {
            "extract, 10 KidSize perspective frames": lambda k: (
                f"from stages import extract\n"
                f"extract.main(None, {str(d / 'kid')!r}, {str(d / f'kid-{k}.h5')!r})"),
            "localize --method fit, 10 omni frames (msl-2015)": lambda k: (
                f"from stages import localize\n"
                f"localize.main({{'method': 'fit'}}, {str(d / 'omni')!r},"
                f" {str(d / 'msl.map.h5')!r}, {str(d / f'fit-{k}.h5')!r},"
                f" features={str(d / 'omni.features.h5')!r})"),
        }
        for what, code in commands.items():
            first = child_cpu(code(1), env)
            second = child_cpu(code(2), env)
            rows.append(Row(
                name=f"first run after install: {what}", cpu_ms=1e3 * first,
                baseline="a second run", baseline_ms=1e3 * second, ratio=first / second,
                goal="<= 1.5x a second run's CPU", meets_goal=first <= 1.5 * second,
                repeats=1,
                note=f"CPU of the command's process (import, lookup caches, compiling what"
                     f" the warm-up left), right after the install's warm-up on an empty"
                     f" numba cache (it took {install:.0f} s of CPU)"))
    return rows
