"""``fieldloc bench`` rows of method fit (Lauer, Lange and Riedmiller 2006): accuracy beside lut on
the same rendered msl-2015 sets in the same run, and the time of a tracked fit.

``bench_fit_accuracy``: the four omni-default sets of 100 frames (seeds 41-44, tracking with
odometry), each localised by lut and by fit with the IMU heading and with the histogram
heading; per heading source one row: over all 400 frames the median and p90 position error
and the share within 40 cm (failed frames count as failures, infinite error), the failure
share (failed frames; a frame not accepted counts as a failure in the errors, as in
``fieldloc evaluate``, and their number is given beside it), and the
median runtime of a frame, fit's beside lut's. Goals: fit's median <= 3 cm and
fewer failed frames than lut with the IMU heading.

``bench_fit_tracked``: the tracked fit alone (RPROP from a prior 14 cm and 1 deg off the
frame's pose, with the IMU heading's prior) on the frames of seed 41, against lut's local
search from the same prior on the same frames; the whole tracked frame of fit (fit, null,
fusion, hypotheses) in the note. Goal: <= 0.25 ms.
"""

from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import numpy as np

from .harness import Row, msec
from .inputs import rendered_inputs, work_dir

SETS = [("omni-default", "msl-2015", 100, s) for s in (41, 42, 43, 44)]
HEADINGS = ("imu", "histogram")


def _run(method: str, heading: str, inp: dict, tag: str):
    """(position errors of the matched frames, failed inf; failed flags; runtimes s; modes;
    flags) of one localize run. Without the IMU the field's symmetry is resolved as a team
    does, by the half the robot starts in (``start_half`` from the truth's first frame)."""
    from ... import localize
    from ...common.dataset import read_csv
    from ...common.poses_file import read_poses
    from ...evaluate.metrics import frame_errors

    truth = read_csv(Path(inp["data"]) / "truth.csv", "truth")
    conf = {"method": method, "heading": heading}
    if heading == "histogram":
        conf["start_half"] = "own" if truth["x"][0] < 0 else "opponent"
    out = work_dir() / f"fit-bench-{method}-{heading}-{tag}.poses.h5"
    localize.main(conf, inp["data"], inp["map"], out, features=inp["features"],
                  overwrite=True)
    cols, _ = read_poses(out)
    fe = frame_errors(cols, truth, 0.02)
    m = fe.matched
    return {"error": np.asarray(fe.position_error[m], float),
            "failed": np.asarray(fe.failed[m], bool),
            "not_accepted": np.asarray(~fe.accepted[m] & ~fe.failed[m], bool),
            "runtime": np.asarray(cols["runtime"], float),
            "mode": [str(v) for v in cols["mode"]], "flags": [str(v) for v in cols["flags"]]}


def _figures(runs: list[dict]) -> dict:
    e = np.concatenate([r["error"] for r in runs])
    f = np.concatenate([r["failed"] for r in runs])
    na = np.concatenate([r["not_accepted"] for r in runs])
    rt = np.concatenate([r["runtime"] for r in runs])
    return {"frames": int(len(e)), "median_cm": 100 * float(np.median(e)),
            "p90_cm": 100 * float(np.percentile(e, 90)),
            "within_40cm": float(np.mean(e <= 0.4)), "failures": int(f.sum()),
            "failure_share": float(f.mean()),
            "not_accepted": int(na.sum()), "runtime_ms": 1000 * float(np.median(rt)),
            "per_set_median_cm": [round(100 * float(np.median(r["error"])), 1) for r in runs]}


def _cm(v: float) -> str:
    return "inf" if not math.isfinite(v) else f"{v:.1f}"


def bench_fit_accuracy(repeat: int) -> list[Row]:
    rows = []
    for heading in HEADINGS:
        res = {"lut": [], "fit": []}
        for preset, field, n, seed in SETS:
            inp = rendered_inputs("omni", field, n, seed, preset)
            for method in res:
                res[method].append(_run(method, heading, inp, f"{preset}-{seed}"))
        fit, lut = _figures(res["fit"]), _figures(res["lut"])
        goal = "median <= 3 cm" + (", fewer failures than lut" if heading == "imu" else "")
        ok = fit["median_cm"] <= 3.0 and (heading != "imu"
                                          or fit["failures"] < lut["failures"])
        note = "; ".join(
            f"{m}: median {_cm(v['median_cm'])} cm (per set {v['per_set_median_cm']}), p90"
            f" {_cm(v['p90_cm'])} cm, within 40 cm {100 * v['within_40cm']:.1f} %, failed"
            f" {v['failures']} ({100 * v['failure_share']:.1f} %), not accepted"
            f" {v['not_accepted']}, {v['runtime_ms']:.2f}"
            " ms/frame" for m, v in (("fit", fit), ("lut", lut)))
        rows.append(Row(
            name=f"fit vs lut, rendered msl-2015 (4 x 100 omni-default frames, odometry,"
                 f" {heading} heading)",
            median_ms=fit["runtime_ms"], goal=goal, meets_goal=ok,
            baseline="lut on the same sets, same run", baseline_ms=lut["runtime_ms"],
            ratio=fit["runtime_ms"] / lut["runtime_ms"], repeats=1, note=note,
            extra={"fit": fit, "lut": lut}))
    return rows


def bench_fit_tracked(repeat: int) -> Row:
    from ...common.dataset import read_csv
    from ...common.features_file import FeaturesFile
    from ...common.map_file import MapFile
    from ...localize import fit as fit_mod
    from ...localize import heading as heading_mod
    from ...localize import lut
    from ...localize.lut_search import Observation

    preset, field, n, seed = SETS[0]
    inp = rendered_inputs("omni", field, n, seed, preset)
    run = _run("fit", "imu", inp, f"{preset}-{seed}")
    whole = [1000 * t for t, m, f in zip(run["runtime"], run["mode"], run["flags"])
             if m == "local" and "global-check" not in f]
    mf = MapFile(inp["map"])
    engine = fit_mod.fit_engine(mf)
    search = lut.table_search(mf, lut.SEARCH)
    sl = search.scanlines
    truth = read_csv(Path(inp["data"]) / "truth.csv", "truth")
    a, b, pts = [], [], []
    with FeaturesFile(inp["features"]) as ff:
        for i, name in enumerate(ff.names):
            fr = ff.frame(name)
            obs = fit_mod.observation_from_points(fit_mod.frame_points(fr, sl))
            lobs = Observation.from_scanlines(fr["radial"], fr.get("spiral"), search.params,
                                              sl.max_range, sl.spiral_end_radius,
                                              sl.robot_radius)
            if len(obs) < fit_mod.MIN_POINTS or len(lobs) < 20:
                continue
            x, y, th = truth["x"][i], truth["y"][i], truth["theta"][i]
            start = np.array([x + 0.1, y - 0.1, th + math.radians(1.0)])
            ta, tb = [], []
            for _ in range(max(1, repeat)):
                t = time.perf_counter()
                engine.fit(obs, start, heading=(th, heading_mod.IMU_SIGMA_RAD),
                           temperature=fit_mod.TEMPERATURE * fit_mod.TRACK_CORRELATION)
                ta.append(time.perf_counter() - t)
                t = time.perf_counter()
                search.local_search(lobs, th, (x + 0.1, y - 0.1),
                                    half_width=0.5 * lut.WINDOW_M)
                tb.append(time.perf_counter() - t)
            a.append(statistics.median(ta))
            b.append(statistics.median(tb))
            pts.append(len(obs))
    med = msec(a)
    return Row(name="fit tracked fit, RPROP from the prior (msl-2015, omni-default, IMU)",
               median_ms=med, goal="<= 0.25 ms", meets_goal=med <= 0.25,
               baseline="lut's local search from the same prior", baseline_ms=msec(b),
               ratio=med / msec(b), repeats=repeat,
               note=f"{len(a)} frames, median {statistics.median(pts):.0f} line points; the"
                    f" whole tracked frame of fit (fit, null, fusion, hypotheses): median"
                    f" {statistics.median(whole):.2f} ms over {len(whole)} frames")


def rows(repeat: int) -> list[Row]:
    """The rows of method fit, in order (``ROWS["fit"]`` of stages.pipelines.bench)."""
    return bench_fit_accuracy(repeat) + [bench_fit_tracked(repeat)]
