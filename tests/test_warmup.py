"""Importing fieldloc compiles no numba kernel: every kernel is compiled lazily, on its first
call (or loaded from numba's cache then), so a command pays only for the kernels it runs and
`make install`'s warm-up (stages.pipelines.warmup) is what fills the cache."""

from __future__ import annotations

import json
import os
import subprocess
import sys

# Imports every module of `stages` in a fresh interpreter and reports, per numba dispatcher
# found as a module attribute, the signatures it holds (compiled, or loaded from the cache).
IMPORT_ALL = """
import importlib, json, pkgutil
from numba.core.registry import CPUDispatcher
import stages
kernels = {}
for info in pkgutil.walk_packages(stages.__path__, "stages."):
    module = importlib.import_module(info.name)
    for obj in vars(module).values():
        if isinstance(obj, CPUDispatcher):
            kernels[obj.py_func.__module__ + "." + obj.py_func.__qualname__] = obj
print(json.dumps({"kernels": sorted(kernels),
                  "compiled": {k: [str(s) for s in d.signatures]
                               for k, d in kernels.items() if d.signatures}}))
"""


def test_importing_every_stage_module_compiles_no_kernel(tmp_path):
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}  # empty: nothing to load either
    run = subprocess.run([sys.executable, "-c", IMPORT_ALL], env=env, capture_output=True,
                         text=True, timeout=600, check=True)
    report = json.loads(run.stdout.strip().splitlines()[-1])
    # the walk reached the kernels of every compiled stage (not an import that found none)
    modules = {k.rsplit(".", 1)[0] for k in report["kernels"]}
    for module in ("stages.common.colour_kernels", "stages.common.surf",
                   "stages.extract.perspective.line_fit_kernels",
                   "stages.extract.perspective.line_structure_kernels",
                   "stages.extract.perspective.crossing_kernels", "stages.localize.lut_kernels",
                   "stages.localize.fit_kernels", "stages.localize.mcl_kernels"):
        assert module in modules
    assert report["compiled"] == {}
    assert [p for p in cache.rglob("*") if p.is_file()] == []  # and nothing was cached
