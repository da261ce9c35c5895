"""Compile fieldloc's numba kernels once, at install, so that a user's first command does not.

    python -m stages.pipelines.warmup        (`make install` runs it after pip install)

Every kernel is compiled lazily, for the argument types of its first call, and numba keeps the
machine code in ``__pycache__`` beside the source (``cache=True``; the index is keyed on the
source file's modification time and size, so a fresh clone's warm-up writes a cache valid for
that clone). Compiling for the types a command really passes needs the command's own calls,
so the warm-up runs the product's stage mains with their default confs on tiny inputs in a
temporary folder, which the real commands then find compiled:

- simulate: a few omni frames (``omni-default``), a few perspective frames of the KidSize
  (``perspective-default``) and NAO (``perspective-nao``) presets, and a coarse (4 m) omni
  template grid;
- build-map of each field simulated (kernels take a field's lines and tables as data, not as
  types: one small field per camera is enough, and the cell size only sizes the tables);
- extract of every dataset with its kind's default preset;
- localize with every method: lut with the IMU heading and the histogram heading, fit, mcl on
  the perspective features (placed, and from a uniform start, which searches the whole field),
  templates against templates built from the grid (build-templates);
- evaluate of one run.

``coverage()`` lists the kernels of ``stages`` that ran (compiled now or loaded from the cache)
and those that did not.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
import tempfile
import time
from pathlib import Path

# CPU seconds of a warm-up on an empty cache (98 s on a busy 2-core AMD EPYC, 141 s of wall
# time), for the line it prints
EXPECTED_CPU_S = 100
OMNI_FIELD = "kidsize"  # the smallest field: its tables and lookup are built in seconds
MAP_CONF = {"resolution": 0.2}  # m: the cell size sizes the tables, the kernels are the same
# frames per dataset: omni runs need a few tracked frames before lut and fit teach their radial
# correction (whose kernels then compile), perspective ones need none
FRAMES = {"omni": 6, "perspective": 3}


def _steps(root: Path):
    """(what, function) of each warm-up step, in order; each runs one stage main."""
    from .. import build_map, build_templates, evaluate, extract, localize, simulate

    def sim(name, preset, field, **over):
        conf = simulate.resolve_simulate_conf(preset)
        conf["frames"] = FRAMES[conf["camera"]]
        for k, v in over.items():
            conf[k].update(v) if isinstance(v, dict) else conf.__setitem__(k, v)
        return simulate.main(conf, field, root / name)

    def loc(dataset, method, run, **conf):
        return localize.main({"method": method, **conf}, root / dataset,
                             root / f"{dataset}.map.h5", root / "runs" / f"{run}.h5",
                             features=root / dataset / "features.h5")

    omni, kid, nao = "omni", "kidsize", "nao"
    return [
        ("simulate omni", lambda: sim(omni, "omni-default", OMNI_FIELD)),
        ("simulate perspective (KidSize)", lambda: sim(kid, "perspective-default", "kidsize")),
        ("simulate perspective (NAO)", lambda: sim(nao, "perspective-nao", "spl")),
        ("simulate an omni template grid",
         lambda: sim("grid", "omni-default", OMNI_FIELD,
                     trajectory={"kind": "grid", "grid_spacing": 4.0, "grid_headings": 1})),
        ("build-map", lambda: [build_map.main(MAP_CONF, f, root / f"{d}.map.h5")
                               for d, f in ((omni, OMNI_FIELD), (kid, "kidsize"),
                                            (nao, "spl"))]),
        ("extract", lambda: [extract.main(None, root / d, root / d / "features.h5")
                             for d in (omni, kid, nao)]),
        ("localize lut (IMU heading)", lambda: loc(omni, "lut", "lut-imu", heading="imu")),
        ("localize lut (IMU heading, the whole-field belief)",
         lambda: loc(omni, "lut", "lut-imu-grid", heading="imu", belief="grid")),
        ("localize lut (histogram heading)",
         lambda: loc(omni, "lut", "lut-histogram", heading="histogram")),
        ("localize fit", lambda: loc(omni, "fit", "fit")),
        ("localize mcl", lambda: [loc(d, "mcl", f"mcl-{d}") for d in (kid, nao)]),
        ("localize mcl (uniform start: the global place search)",
         lambda: loc(kid, "mcl", "mcl-uniform", init="uniform")),
        ("build-templates", lambda: build_templates.main(None, root / "grid",
                                                         root / "templates.h5")),
        ("localize templates",
         lambda: localize.main({"method": "templates"}, root / omni, None,
                               root / "runs" / "templates.h5",
                               templates=root / "templates.h5")),
        ("evaluate", lambda: evaluate.main(None, root / "runs" / "fit.h5", root / omni,
                                           root / "report")),
    ]


def run(workdir: str | Path | None = None, *, verbose: bool = False) -> float:
    """Run every warm-up step in ``workdir`` (default: a temporary folder, removed after);
    returns the seconds it took."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fieldloc-warmup-") as tmp:
        root = Path(workdir) if workdir is not None else Path(tmp)
        (root / "runs").mkdir(parents=True, exist_ok=True)
        for what, step in _steps(root):
            t = time.perf_counter()
            step()
            if verbose:
                print(f"  {what}: {time.perf_counter() - t:.1f} s", file=sys.stderr)
    return time.perf_counter() - t0


def kernels() -> dict:
    """Every numba dispatcher of ``stages`` (imports every module): "module.name" -> it."""
    from numba.core.registry import CPUDispatcher

    import stages

    found = {}
    for info in pkgutil.walk_packages(stages.__path__, "stages."):
        module = importlib.import_module(info.name)
        for obj in vars(module).values():
            if isinstance(obj, CPUDispatcher):
                found[f"{obj.py_func.__module__}.{obj.py_func.__qualname__}"] = obj
    return found


def coverage() -> dict:
    """What the kernels of ``stages`` did in this process: per kernel the signatures it
    compiled (``compiled``), loaded from numba's cache (``loaded``), and the kernels that hold
    none (``unused``): never called, inlined into their callers (``inline="always"``), or,
    when a caller was loaded from the cache, called only from compiled code."""
    out = {"compiled": {}, "loaded": {}, "unused": []}
    for name, disp in sorted(kernels().items()):
        if not disp.signatures:
            out["unused"].append(name)
            continue
        hits, misses = disp.stats.cache_hits, disp.stats.cache_misses
        for sig in disp.signatures:
            kind = "loaded" if hits.get(sig) and not misses.get(sig) else "compiled"
            out[kind].setdefault(name, []).append(str(sig))
    return out


def command(argv=None) -> int:
    """``python -m stages.pipelines.warmup [--workdir DIR] [-v]``."""
    parser = argparse.ArgumentParser(prog="python -m stages.pipelines.warmup",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, default=None,
                        help="keep the warm-up's datasets there (default: a temporary folder)")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="time each step and list the kernels compiled, loaded, unused")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    print(f"fieldloc: compiling fieldloc's numba kernels once, so that the first command does"
          f" not (about {EXPECTED_CPU_S} s of CPU on an empty cache, seconds when cached)",
          file=sys.stderr, flush=True)
    seconds = run(args.workdir, verbose=args.verbose)
    if args.verbose:
        cov = coverage()
        for kind in ("compiled", "loaded"):
            n = sum(len(v) for v in cov[kind].values())
            print(f"  {kind}: {n} signatures of {len(cov[kind])} kernels", file=sys.stderr)
        print(f"  holding no signature: {len(cov['unused'])} kernels:"
              f" {', '.join(cov['unused'])}", file=sys.stderr)
        print(f"  {seconds:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(command())
