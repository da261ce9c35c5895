"""``fieldloc bench`` rows of mcl's goals on rendered NAO walks (``simulate perspective
--preset perspective-nao``: 640 x 480, the SPL field, hall lighting, other robots, people and
balls): from the game's placement, median <= 10 cm and >= 95 % within 40 cm (evaluate's
figures: a frame without an accepted pose counts as a miss); from a uniform start the belief
holds a pose and its mirror image at 0.5 each, so it is judged by the pair (the top pose or
its mirror), from frame 20 on."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .harness import Row, pct_within
from .inputs import rendered_inputs, work_dir

# rendered NAO walks: (frames, seed); seeds no test uses
NAO_WALKS = [(300, 0), (300, 1), (300, 2)]


def _walks():
    return [rendered_inputs("perspective", "spl", n, s, "perspective-nao") for n, s in NAO_WALKS]


def bench_mcl_nao_accuracy(repeat: int) -> list[Row]:
    from ... import localize
    from ...common.dataset import read_csv
    from ...common.poses_file import read_poses
    from ...evaluate import evaluate_poses

    walks = _walks()
    label = f"rendered NAO walks (SPL, {len(walks)} x {NAO_WALKS[0][0]} frames)"
    rows = []
    # from the placement: every walk evaluated, the figures pooled over their frames
    errors, runtimes, per_walk = [], [], []
    for (_n, seed), inp in zip(NAO_WALKS, walks):
        out = work_dir() / f"nao-mcl-default-{seed}.poses.h5"
        localize.main("mcl-default", inp["data"], inp["map"], out, features=inp["features"],
                      overwrite=True)
        cols, _ = read_poses(out)
        truth = read_csv(Path(inp["data"]) / "truth.csv", "truth")
        fe, s = evaluate_poses(cols, truth)
        errors.append(fe.position_error)  # inf where no pose was accepted
        runtimes.append(s["runtime_ms"]["median"])
        per_walk.append(f"seed {seed}: {100 * s['position_error_m']['median']:.1f} cm, "
                        f"{pct_within(s, '0.4')} %")
    e = np.concatenate(errors)
    med, w40 = float(np.median(e)), float(np.mean(e <= 0.4))
    rows.append(Row(
        name=f"mcl accuracy, {label}, from the placement",
        median_ms=float(np.median(runtimes)), goal="median <= 10 cm, >= 95 % within 40 cm",
        meets_goal=med <= 0.10 and w40 >= 0.95, repeats=1,
        note=f"median {100 * med:.1f} cm, within 10/20/40 cm {100 * np.mean(e <= 0.1):.0f}/"
             f"{100 * np.mean(e <= 0.2):.0f}/{100 * w40:.1f} % of all frames (unaccepted frames"
             f" count as misses); {'; '.join(per_walk)}"))
    # from a uniform start: judged by the pair
    folded, high = [], 0
    for (_n, seed), inp in zip(NAO_WALKS, walks):
        out = work_dir() / f"nao-mcl-uniform-{seed}.poses.h5"
        localize.main("mcl-uniform", inp["data"], inp["map"], out, features=inp["features"],
                      overwrite=True)
        cols, _ = read_poses(out)
        fe, _ = evaluate_poses(cols, read_csv(Path(inp["data"]) / "truth.csv", "truth"))
        late = np.arange(len(fe.top_error)) >= 20  # after the belief has gathered
        folded.append(fe.best_error[late])  # the mirror is the top pose's second hypothesis
        high += int(np.sum(late & fe.accepted & (fe.top_error > 1.0)))
    f = np.concatenate(folded)
    med, w40 = float(np.median(f)), float(np.mean(f <= 0.4))
    rows.append(Row(
        name=f"mcl accuracy, {label}, from a uniform start (pose or mirror, frame 20 on)",
        median_ms=math.nan, goal="median <= 10 cm, >= 95 % within 40 cm",
        meets_goal=med <= 0.10 and w40 >= 0.95, repeats=1,
        note=f"median {100 * med:.1f} cm, within 40 cm {100 * w40:.1f} % of {len(f)} frames;"
             f" accepted and > 1 m off: {high}"))
    return rows
