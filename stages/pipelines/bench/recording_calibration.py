"""``fieldloc bench`` rows of the perspective camera's mount learnt from a recording
(stages/localize/mount_calibration.py, docs/recording-calibration.md).

Each held-out seed renders a walk of a robot whose calib.yaml is off by MOUNT_ERROR, runs
``localize --method mcl --smooth --write-calib`` on it with the CLI defaults, and scores what
is written twice: against the renderer's camera (within TOLERANCE), and by a second recording
of the same robot (seed + SECOND_RECORDING) localised causally once with its own,
miscalibrated calib.yaml and once with the learnt one (features extracted with each). A
refused calibration writes nothing: it counts as not within tolerance, and its second
recording keeps the original calib.yaml's errors.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np

from .harness import Row, run_errors
from .inputs import work_dir

# held-out walks: the mount fit's constants and its track check were chosen on seeds 3, 5,
# 11, 21-23 and 200-223 (docs/recording-calibration.md); these seeds and their second
# recordings (1660-1679) were not looked at before this row's first run
MOUNT_SEEDS = tuple(range(1640, 1660))
SECOND_RECORDING = 20  # seed offset of the second recording of the same robot
FRAMES = 200
# the calib.yaml's error: about 2 deg of pitch, -1.5 deg of roll, 3 cm of height (the
# renderer's camera has no offsets)
MOUNT_ERROR = {"pitch_offset": 0.035, "roll_offset": -0.026, "height_offset": 0.03}
# a learnt mount is right within these (rad, m): 0.3 deg moves a line 2 m away by 1 cm
TOLERANCE = (math.radians(0.3), 0.01)
# the omni calibration's goals, held to the mount: >= 90 % of seeds within tolerance, the
# second recording's pooled median error <= 0.5x with the learnt calib.yaml
GOAL_SHARE, GOAL_RATIO = 0.9, 0.5
ROBOTS = {"NAO": ("perspective-nao", "spl"), "KidSize": ("perspective-default", "kidsize")}


def _render(preset: str, field: str, seed: int, out: Path) -> Path:
    from ... import simulate

    conf = dict(simulate.confs[preset], frames=FRAMES, seed=seed,
                calib_error={**simulate.confs[preset]["calib_error"], **MOUNT_ERROR})
    return simulate.main(conf, field, out)


def _localise(data: Path, map_path: Path, out: Path, conf: dict, **kw) -> Path:
    from ... import extract, localize

    feats = extract.main(None, data, data / "features.h5")
    return localize.main(conf, data, map_path, out, features=feats, **kw)


def _with_calib(data: Path, calib: Path, out: Path) -> Path:
    """A copy of the dataset ``data`` with ``calib`` as its calib.yaml (images linked)."""
    out.mkdir()
    for f in data.iterdir():
        if f.name == "images":
            (out / "images").symlink_to(f.resolve(), target_is_directory=True)
        elif f.is_file() and f.suffix in (".csv", ".yaml") and f.name != "calib.yaml":
            shutil.copy(f, out / f.name)
    shutil.copy(calib, out / "calib.yaml")
    return out


def _mount_error(learnt: Path, data: Path) -> np.ndarray:
    """The learnt calib.yaml's pitch offset, roll offset (rad) and height (m) less the
    renderer's camera's."""
    import yaml

    true = yaml.safe_load((data / "simulation.yaml").read_text())["true_camera"]
    got = yaml.safe_load(learnt.read_text())
    return np.array([got.get("pitch_offset", 0.0) - true.get("pitch_offset", 0.0),
                     got.get("roll_offset", 0.0) - true.get("roll_offset", 0.0),
                     got["height"] - true["height"]])


def _seed_run(robot: str, seed: int) -> dict:
    from ... import build_map
    from ...common.errors import FieldlocError

    preset, field = ROBOTS[robot]
    d = work_dir() / f"mount-{robot}-{seed}"
    d.mkdir()
    map_path = work_dir() / f"{field}.map.h5"
    if not map_path.exists():
        build_map.main(None, field, map_path)
    first = _render(preset, field, seed, d / "first")
    learnt = d / "learnt.yaml"
    refused = None
    try:
        _localise(first, map_path, d / "first.poses.h5", {"method": "mcl", "smooth": True},
                  write_calib=learnt)
    except FieldlocError as e:
        refused = str(e)
    second = _render(preset, field, seed + SECOND_RECORDING, d / "second")
    mis, _ = run_errors(_localise(second, map_path, d / "mis.poses.h5", {"method": "mcl"}),
                        second)
    out = {"seed": seed, "refused": refused, "error": None,
           "mis": np.where(mis.matched, mis.position_error, np.inf)[mis.matched]}
    out["fix"] = out["mis"]
    if refused is None:
        out["error"] = _mount_error(learnt, first)
        fixed = _with_calib(second, learnt, d / "second-learnt")
        fe, _ = run_errors(_localise(fixed, map_path, d / "fix.poses.h5", {"method": "mcl"}),
                           fixed)
        out["fix"] = np.where(fe.matched, fe.position_error, np.inf)[fe.matched]
    return out


def _within(err) -> bool:
    return err is not None and bool(
        abs(err[0]) <= TOLERANCE[0] and abs(err[1]) <= TOLERANCE[0]
        and abs(err[2]) <= TOLERANCE[1])


def mount_row(robot: str, seeds=MOUNT_SEEDS) -> Row:
    """The mount learnt from a recording on held-out walks of ``robot`` (module doc)."""
    runs = [_seed_run(robot, s) for s in seeds]
    n = len(runs)
    within = sum(_within(r["error"]) for r in runs)
    refused = sum(r["refused"] is not None for r in runs)
    mis = np.concatenate([r["mis"] for r in runs])
    fix = np.concatenate([r["fix"] for r in runs])
    ratio = float(np.median(fix) / np.median(mis)) if np.median(mis) > 0 else math.nan
    # a written calib that made its robot's second recording worse (median error up by more
    # than a tenth): the harm a wrong calibration does
    worse = [r["seed"] for r in runs if r["refused"] is None
             and not np.median(r["fix"]) <= 1.1 * np.median(r["mis"])]
    far = [r["seed"] for r in runs if r["error"] is not None and (
        max(abs(r["error"][0]), abs(r["error"][1])) > math.radians(1.0)
        or abs(r["error"][2]) > 0.03)]
    share = within / max(n, 1)
    return Row(
        name=f"mount from a recording, held-out {robot} walks ({n} x {FRAMES} frames,"
             f" seeds {seeds[0]}-{seeds[-1]})",
        goal=f">= {100 * GOAL_SHARE:g} % of seeds within 0.3 deg and 1 cm; 2nd recording"
             f" median <= {GOAL_RATIO:g}x",
        meets_goal=bool(share >= GOAL_SHARE and ratio <= GOAL_RATIO), repeats=1,
        note=(f"within tolerance {within}/{n}, refused {refused}, written > 1 deg or 3 cm off"
              f" {len(far)} {far}; 2nd recording median {100 * np.median(mis):.1f} ->"
              f" {100 * np.median(fix):.1f} cm ({ratio:.2f}x), within 40 cm"
              f" {100 * np.mean(mis <= 0.4):.1f} -> {100 * np.mean(fix <= 0.4):.1f} %;"
              f" worse with the written calib: {worse}"),
        extra={"within": within, "seeds": n, "refused": refused, "ratio": ratio,
               "far": far, "worse": worse,
               "refusals": {r["seed"]: r["refused"] for r in runs if r["refused"]},
               "errors": {r["seed"]: (None if r["error"] is None else
                                      [round(float(v), 5) for v in r["error"]])
                          for r in runs}})


def rows(repeat: int) -> list[Row]:
    return [mount_row(robot) for robot in ROBOTS]
