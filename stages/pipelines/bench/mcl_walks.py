"""``fieldloc bench`` rows of mcl on held-out rendered walks: NAO (``perspective-nao``, the SPL
field) and KidSize (``perspective-default``), 20 walks of 200 frames each from seeds no default
was tuned on, localised with the CLI's defaults three ways, and two more with the IMU's yaw
taken as the field heading (``-c imu_heading_sigma=0.2``: from the placement, and from a
uniform start without ``start_half``, which the IMU's heading decides):

- from the game's placement (the default);
- from a uniform start with ``start_half`` given (the half of the truth's first pose, as a team
  knows it), judged from frame 20 on;
- from a uniform start without it: on the point-symmetric field no frame can tell a pose from
  its mirror image, so what the run decides is the pose up to the mirror (accepted up to the
  mirror, the pose or its mirror within 40 cm), judged from frame 20 on.

``kidnap_rows``: the same walks spliced in pairs at frame 100 (a robot carried elsewhere, as a
referee puts a penalised robot back), how soon mcl finds it again and how many frames after
the kidnap it accepts more than 1 m off.

Every figure is evaluate's: a frame without an accepted pose counts as a miss; "confidently
wrong" is accepted and more than 1 m off; AUROC is of the confidence for "the top pose within
40 cm" (of the confidence up to the mirror for "the pose or its mirror within 40 cm" without
the start half)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from .harness import Row, ranks_well
from .inputs import rendered_inputs, work_dir

# held-out walks: seeds 1300-1319 of each preset (the defaults were chosen on seeds 0-999)
WALK_SEEDS = tuple(range(1300, 1320))
WALK_FRAMES = 200
ROBOTS = (("NAO", "perspective-nao", "spl"), ("KidSize", "perspective-default", "kidsize"))
LATE = 20  # frames a uniform start has to gather its belief before it is judged
# the goals: pooled accepted within 40 cm, every walk, median (m), confidently wrong, AUROC
GOAL_WITHIN, GOAL_WORST, GOAL_MEDIAN, GOAL_WRONG, GOAL_AUROC = 0.97, 0.90, 0.05, 0.005, 0.95
GOAL_MIRROR = 0.95  # without the start half: accepted up to the mirror and the pair right
IMU_SIGMA = 0.2  # rad: imu_heading_sigma of the rows with the IMU heading (docs/manual.md)


def _run(preset: str, field: str, seed: int, conf: dict, tag: str, frames: int = WALK_FRAMES):
    """(frame errors, frame errors up to the mirror, CPU s) of mcl on one held-out walk of
    ``frames`` frames."""
    from ...common.dataset import read_csv
    from ...evaluate.metrics import frame_errors

    inp = rendered_inputs("perspective", field, frames, seed, preset)
    truth = read_csv(Path(inp["data"]) / "truth.csv", "truth")
    conf = _given(dict(conf, method="mcl"), truth)
    out = work_dir() / f"walk-mcl-{preset}-{seed}-{frames}-{tag}.poses.h5"
    cols, cpu = _localised(conf, inp["data"], inp["map"], inp["features"], out)
    return (frame_errors(cols, truth, 0.02), frame_errors(cols, truth, 0.02, up_to_mirror=True),
            cpu)


def _given(conf: dict, truth: dict) -> dict:
    """``conf`` with a start_half or start_side of "given" replaced by the walk's own (the
    half and the touch line of the truth's first pose, as a team knows them)."""
    if conf.get("start_half") == "given":
        conf["start_half"] = "own" if truth["x"][0] < 0 else "opponent"
    if conf.get("start_side") == "given":  # the touch line the walk enters from
        conf["start_side"] = "left" if truth["y"][0] > 0 else "right"
    return conf


def _localised(conf: dict, data, map_path, features, out: Path) -> tuple[dict, float]:
    """The poses columns of ``localize.main`` (``conf``) on the dataset ``data`` written to
    ``out``, and its CPU time (s)."""
    from ... import localize
    from ...common.poses_file import read_poses

    t0 = time.process_time()
    localize.main(conf, data, map_path, out, features=features, overwrite=True)
    cpu = time.process_time() - t0
    return read_poses(out)[0], cpu


def _pooled(runs, first: int, mirror: bool) -> dict:
    from ...evaluate.metrics import auroc

    ok, per_walk, err, wrong, conf, right = [], [], [], [], [], []
    for fe, fm, _cpu in runs:
        f = fm if mirror else fe
        late = f.matched & (np.arange(len(f.matched)) >= first)
        good = f.accepted & (f.position_error <= 0.4)
        ok.append(good[late])
        per_walk.append(float(np.mean(good[late])) if late.any() else math.nan)
        err.append(np.where(f.accepted, f.position_error, np.inf)[late])
        wrong.append((f.accepted & (f.top_error > 1.0))[late])
        conf.append(np.where(f.failed, 0.0, f.confidence)[late])
        right.append((f.top_error <= 0.4)[late])
    ok, err, wrong = np.concatenate(ok), np.concatenate(err), np.concatenate(wrong)
    return {"within": float(np.mean(ok)), "worst": float(np.nanmin(per_walk)),
            "median": float(np.median(err)), "wrong": float(np.mean(wrong)),
            "auroc": auroc(np.concatenate(conf), np.concatenate(right)),
            "top_wrong": int(np.sum(~np.concatenate(right))),
            "frames": len(ok), "cpu": float(np.median([r[2] for r in runs])),
            "per_walk": per_walk}


def _note(p: dict) -> str:
    walks = ", ".join(f"{100 * w:.0f}" for w in p["per_walk"])
    return (f"{100 * p['within']:.2f} % accepted and within 40 cm of {p['frames']} frames (worst"
            f" walk {100 * p['worst']:.0f} %), median {100 * p['median']:.1f} cm (unaccepted"
            f" frames count as misses), accepted and > 1 m off {100 * p['wrong']:.2f} %, AUROC"
            f" {p['auroc']:.3f}; per walk (%): {walks}; median CPU per walk {p['cpu']:.2f} s")


# the walks' goals (GOAL_*), as a row states them
WALK_GOAL = (f">= {100 * GOAL_WITHIN:g} % accepted within 40 cm pooled, every walk >="
             f" {100 * GOAL_WORST:g} %, median <= {100 * GOAL_MEDIAN:g} cm, confidently wrong <="
             f" {100 * GOAL_WRONG:g} %, AUROC >= {GOAL_AUROC:g}")


def _walk_row(name: str, p: dict, note: str | None = None, extra: dict | None = None) -> Row:
    """The row of pooled walk figures ``p`` (``_pooled``) held to WALK_GOAL."""
    met = (p["within"] >= GOAL_WITHIN and p["worst"] >= GOAL_WORST
           and p["median"] <= GOAL_MEDIAN and p["wrong"] <= GOAL_WRONG
           and ranks_well(p["auroc"], p["top_wrong"], GOAL_AUROC))
    return Row(name=name, median_ms=math.nan, cpu_ms=1e3 * p["cpu"], goal=WALK_GOAL,
               meets_goal=bool(met), repeats=1, note=note or _note(p),
               extra={**{k: v for k, v in p.items() if k != "per_walk"}, **(extra or {})})


def rows(repeat: int) -> list[Row]:
    out = []
    for robot, preset, field in ROBOTS:
        label = (f"held-out rendered {robot} walks ({len(WALK_SEEDS)} x {WALK_FRAMES} frames,"
                 f" seeds {WALK_SEEDS[0]}-{WALK_SEEDS[-1]})")
        for how, tag, conf, first in (
                ("from the placement", "placement", {}, 0),
                ("uniform start, start_half given, frame 20 on", "half",
                 {"init": "uniform", "start_half": "given"}, LATE),
                # the IMU's yaw as the field heading (opt-in): it also tells the pose from
                # its mirror, so a uniform start needs no start half
                (f"from the placement, IMU heading (sigma {IMU_SIGMA:g})", "placement-imu",
                 {"imu_heading_sigma": IMU_SIGMA}, 0),
                (f"uniform start, IMU heading (sigma {IMU_SIGMA:g}), no start half, frame 20"
                 " on", "uniform-imu", {"init": "uniform", "imu_heading_sigma": IMU_SIGMA},
                 LATE)):
            p = _pooled([_run(preset, field, s, conf, tag) for s in WALK_SEEDS], first, False)
            out.append(_walk_row(f"mcl {how}, {label}", p))
        conf = {"init": "uniform"}
        p = _pooled([_run(preset, field, s, conf, "uniform") for s in WALK_SEEDS], LATE, True)
        out.append(Row(
            name=f"mcl uniform start up to the mirror, frame 20 on, {label}", median_ms=math.nan,
            cpu_ms=1e3 * p["cpu"],
            goal=f">= {100 * GOAL_MIRROR:g} % accepted up to the mirror with the pose or its"
                 " mirror within 40 cm",
            meets_goal=bool(p["within"] >= GOAL_MIRROR), repeats=1, note=_note(p),
            extra={k: v for k, v in p.items() if k != "per_walk"}))
    return out


# held-out walks of the whole-recording smoother (docs/smoothing.md): three 300-frame walks per
# robot, seeds 1780-1782, which no default and no other row looked at
SMOOTH_WALK_SEEDS = tuple(range(1780, 1783))
SMOOTH_WALK_FRAMES = 300
# the smoother's perspective goals: the NAO's median (m) with --smooth; the KidSize median no
# worse than causal; the smoothed confidence's AUROC and confidently wrong share
GOAL_SMOOTH_NAO_MEDIAN, GOAL_SMOOTH_AUROC, GOAL_SMOOTH_WRONG = 0.04, 0.97, 0.002


def smooth_rows(repeat: int) -> list[Row]:
    """Causal and smoothed (``--smooth``) mcl from the placement, CLI defaults otherwise, on
    the same held-out walks, side by side."""
    out = []
    for robot, preset, field in ROBOTS:
        label = (f"held-out rendered {robot} walks ({len(SMOOTH_WALK_SEEDS)} x"
                 f" {SMOOTH_WALK_FRAMES} frames, seeds {SMOOTH_WALK_SEEDS[0]}-"
                 f"{SMOOTH_WALK_SEEDS[-1]})")
        pooled = {}
        for tag, conf in (("causal", {}), ("smoothed", {"smooth": True})):
            pooled[tag] = _pooled([_run(preset, field, s, conf, tag, SMOOTH_WALK_FRAMES)
                                   for s in SMOOTH_WALK_SEEDS], 0, False)
        causal, smoothed = pooled["causal"], pooled["smoothed"]
        if robot == "NAO":
            goal = f"smoothed median <= {100 * GOAL_SMOOTH_NAO_MEDIAN:g} cm"
            met = smoothed["median"] <= GOAL_SMOOTH_NAO_MEDIAN
        else:
            goal = "smoothed median no worse than causal"
            met = smoothed["median"] <= causal["median"]
        goal += (f"; smoothed AUROC >= {GOAL_SMOOTH_AUROC:g}, confidently wrong <="
                 f" {100 * GOAL_SMOOTH_WRONG:g} %")
        met = (met and ranks_well(smoothed["auroc"], smoothed["top_wrong"], GOAL_SMOOTH_AUROC)
               and smoothed["wrong"] <= GOAL_SMOOTH_WRONG)
        for tag, p in pooled.items():
            out.append(Row(
                name=f"mcl {tag} from the placement, {label}", median_ms=math.nan,
                cpu_ms=1e3 * p["cpu"], goal=goal if tag == "smoothed" else "",
                meets_goal=bool(met) if tag == "smoothed" else None, repeats=1,
                note=_note(p), extra={k: v for k, v in p.items() if k != "per_walk"}))
    return out


def side_rows(repeat: int) -> list[Row]:
    """From the placement with ``start_side`` given (the touch line the walk enters from, as
    a team knows it), on the held-out walks of ``rows``; the note adds the same walks without
    it, from the same run."""
    out = []
    for robot, preset, field in ROBOTS:
        p = _pooled([_run(preset, field, s, {"start_side": "given"}, "side")
                     for s in WALK_SEEDS], 0, False)
        without = _pooled([_run(preset, field, s, {}, "placement") for s in WALK_SEEDS], 0,
                          False)
        out.append(_walk_row(
            f"mcl from the placement, start_side given, held-out rendered {robot} walks"
            f" ({len(WALK_SEEDS)} x {WALK_FRAMES} frames, seeds {WALK_SEEDS[0]}-"
            f"{WALK_SEEDS[-1]})", p, note=f"{_note(p)}; without start_side: {_note(without)}",
            extra={"without": {k: v for k, v in without.items() if k != "per_walk"}}))
    return out


# a kidnapped robot (docs/results.md, "Kidnaps are found slowly"): two held-out walks of one
# robot spliced at KIDNAP_FRAME, the first walk's frames before it and the second's from it
# (images, head angles, odometry, IMU and truth, each by its stamp), as a referee puts a
# penalised robot back elsewhere; pairs of consecutive WALK_SEEDS, both ways round
KIDNAP_FRAME = 100
FOUND_RUN = 5  # frames in a row accepted within 40 cm: the robot is found again


def _spliced(a: Path, b: Path, out: Path, cut: float) -> Path:
    """A dataset folder at ``out``: walk ``a``'s frames (and every stamped row of its CSV
    files) before stamp ``cut``, walk ``b``'s from it; the images copied, the calibration
    and the record of ``a``."""
    import shutil

    from ...common.dataset import csv_rows

    if out.exists():
        return out
    part = out.with_name(out.name + ".part")
    shutil.rmtree(part, ignore_errors=True)
    (part / "images").mkdir(parents=True)
    for name in ("calib.yaml", "simulation.yaml"):
        if (a / name).exists():
            shutil.copy2(a / name, part / name)
    sides = ((a, lambda t: t < cut), (b, lambda t: t >= cut))
    for csv in sorted(p.name for p in a.glob("*.csv")):
        col = 1 if csv == "frames.csv" else 0  # the stamp's column
        rows = []
        for src, keep in sides:
            header, *body = [cells for _line, cells in csv_rows(src / csv)]
            kept = [cells for cells in body if keep(float(cells[col]))]
            rows += kept
            if csv == "frames.csv":
                for cells in kept:
                    shutil.copy2(src / "images" / cells[0], part / "images" / cells[0])
        (part / csv).write_text("".join(",".join(c) + "\n" for c in [header, *rows]))
    part.rename(out)
    return out


def _kidnap_run(preset: str, field: str, a: int, b: int) -> dict:
    """mcl with the CLI's defaults on walks ``a`` and ``b`` spliced at KIDNAP_FRAME: whether
    and when the robot is found again (FOUND_RUN frames in a row accepted within 40 cm), the
    frames accepted more than 1 m off after the kidnap, the frames within 40 cm before it."""
    from ... import extract
    from ...common.dataset import read_csv
    from ...evaluate.metrics import frame_errors

    ia = rendered_inputs("perspective", field, WALK_FRAMES, a, preset)
    ib = rendered_inputs("perspective", field, WALK_FRAMES, b, preset)
    stamps = read_csv(Path(ia["data"]) / "frames.csv", "frames")["stamp"]
    data = _spliced(Path(ia["data"]), Path(ib["data"]),
                    work_dir() / f"kidnap-{preset}-{a}-{b}", float(stamps[KIDNAP_FRAME]))
    feats = extract.main(None, data, data / "features.h5", overwrite=True)
    cols, cpu = _localised({"method": "mcl"}, data, ia["map"], feats, data / "poses.h5")
    f = frame_errors(cols, read_csv(data / "truth.csv", "truth"), 0.02)
    good = f.accepted & (f.position_error <= 0.4)
    after = np.arange(len(good)) >= KIDNAP_FRAME
    found = next((i - KIDNAP_FRAME for i in range(KIDNAP_FRAME, len(good) - FOUND_RUN + 1)
                  if good[i:i + FOUND_RUN].all()), None)
    return {"found": found, "wrong": int(np.sum(f.accepted & (f.top_error > 1.0) & after)),
            "before": float(np.mean(good[:KIDNAP_FRAME])), "cpu": cpu}


def kidnap_rows(repeat: int) -> list[Row]:
    """How mcl (the CLI's defaults, from the placement) finds a robot carried elsewhere: the
    held-out walks of ``rows`` spliced in pairs (``_spliced``). No goal: the issues set none;
    the row measures what docs/results.md states ("Kidnaps are found slowly")."""
    out = []
    pairs = [(s, s + 1) for s in WALK_SEEDS[::2]]
    pairs += [(b, a) for a, b in pairs]
    for robot, preset, field in ROBOTS:
        runs = [_kidnap_run(preset, field, a, b) for a, b in pairs]
        found = [r["found"] for r in runs if r["found"] is not None]
        wrong = [r["wrong"] for r in runs]
        after = WALK_FRAMES - KIDNAP_FRAME
        note = (f"found again ({FOUND_RUN} frames in a row accepted within 40 cm) on"
                f" {len(found)} of {len(runs)}, after a median of"
                f" {np.median(found) if found else math.nan:.0f} frames; accepted more than 1 m"
                f" off after the kidnap {sum(wrong)} of {after * len(runs)} frames"
                f" ({100 * sum(wrong) / (after * len(runs)):.1f} %; per recording:"
                f" {', '.join(str(w) for w in wrong)}); within 40 cm before it"
                f" {100 * np.mean([r['before'] for r in runs]):.1f} %; median CPU per"
                f" recording {np.median([r['cpu'] for r in runs]):.2f} s")
        out.append(Row(
            name=f"mcl kidnapped robot, held-out rendered {robot} walks spliced at frame"
                 f" {KIDNAP_FRAME} ({len(runs)} recordings of {WALK_FRAMES} frames, pairs of"
                 f" seeds {WALK_SEEDS[0]}-{WALK_SEEDS[-1]})", median_ms=math.nan,
            cpu_ms=1e3 * float(np.median([r["cpu"] for r in runs])), repeats=1, note=note,
            extra={"found": len(found), "recordings": len(runs), "wrong": sum(wrong),
                   "median_found": float(np.median(found)) if found else math.nan}))
    return out


def _decidable(preset: str, field: str, seed: int, conf: dict) -> np.ndarray:
    """Per frame of one held-out walk, whether start_bound finds it decidable with mcl's
    defaults (``conf`` overrides them): from the placement, or from a uniform start (up to
    the mirror without ``start_half``)."""
    from ...common.dataset import open_dataset, read_csv
    from ...common.features_file import FeaturesFile
    from ...common.map_file import MapFile
    from ...common.observations import Observations
    from ...localize import mcl, resolve_localize_conf, start_bound

    inp = rendered_inputs("perspective", field, WALK_FRAMES, seed, preset)
    truth = read_csv(Path(inp["data"]) / "truth.csv", "truth")
    conf = resolve_localize_conf(_given(dict(conf, method="mcl"), truth))
    with MapFile(inp["map"]) as map_file, FeaturesFile(inp["features"]) as feats:
        model = mcl.observation_model(conf, open_dataset(inp["data"], need_images=False),
                                      map_file)
        stamps = np.asarray(feats.stamps, float)
        at = np.minimum(np.searchsorted(truth["stamp"], stamps), len(truth["stamp"]) - 1)
        if not np.allclose(truth["stamp"][at], stamps, atol=1e-6):
            raise ValueError(f"{inp['data']}: truth.csv lacks frames' stamps")
        frames = [model.prepare(Observations.from_features(feats.frame(n)))
                  for n in feats.names]
    poses = np.stack([truth[k][at] for k in ("x", "y", "theta")], axis=1)
    if conf["init"] == "uniform":
        start = start_bound.uniform_start(mcl.world_bounds(model.field), conf, poses[0])
    else:
        start = start_bound.placement_start(model.field, conf, poses[0])
    mirror = conf["init"] == "uniform" and conf["start_half"] == "any"
    mass = start_bound.decidable_mass(model, frames, poses, start, up_to_mirror=mirror)
    return mass >= conf["min_confidence"]


# the bound's starts: (robots, how, conf overrides, first frame judged), as the rows of
# ``rows`` and ``side_rows`` judge them; a uniform start's grid takes some 10 s of CPU a walk,
# so only the NAO's (the KidSize walks meet those goals)
BOUND_STARTS = (
    ("NAO KidSize", "from the placement", {}, 0),
    ("NAO KidSize", "from the placement, start_side given", {"start_side": "given"}, 0),
    ("NAO", "uniform start, start_half given, frame 20 on",
     {"init": "uniform", "start_half": "given"}, LATE),
    ("NAO", "uniform start up to the mirror, frame 20 on", {"init": "uniform"}, LATE))


def bound_rows(repeat: int) -> list[Row]:
    """What the walks of ``rows`` and ``side_rows`` decide (stages.localize.start_bound: the
    Bayes posterior over the first pose with odometry without noise, mcl's observation model
    and start prior): the frames decidable pooled and per walk, beside the goals those rows
    hold mcl to. A filter accepting more frames states more than its model's evidence."""
    out = []
    for robot, preset, field in ROBOTS:
        for robots, how, conf, first in BOUND_STARTS:
            if robot not in robots.split():
                continue
            for s in WALK_SEEDS:  # rendered before the clock starts
                rendered_inputs("perspective", field, WALK_FRAMES, s, preset)
            t0 = time.process_time()
            walks = [_decidable(preset, field, s, conf)[first:] for s in WALK_SEEDS]
            cpu = (time.process_time() - t0) / len(walks)
            share = [float(np.mean(w)) for w in walks]
            pooled = float(np.mean(np.concatenate(walks)))
            goal = GOAL_MIRROR if "mirror" in how else GOAL_WITHIN
            below = sum(w < GOAL_WORST for w in share)
            out.append(Row(
                name=f"mcl bound, {how} (odometry without noise), held-out rendered {robot}"
                     f" walks ({len(WALK_SEEDS)} x {WALK_FRAMES} frames, seeds"
                     f" {WALK_SEEDS[0]}-{WALK_SEEDS[-1]})",
                median_ms=math.nan, cpu_ms=1e3 * cpu, goal="", meets_goal=None, repeats=1,
                note=f"{100 * pooled:.2f} % of {sum(len(w) for w in walks)} frames decidable"
                     f" (worst walk {100 * min(share):.0f} %, {below} walks below"
                     f" {100 * GOAL_WORST:g} %): what mcl's own model and start prior decide,"
                     f" beside mcl's goal of {100 * goal:g} %; per walk (%): "
                     + ", ".join(f"{100 * w:.0f}" for w in share)
                     + f"; CPU per walk {cpu:.1f} s",
                extra={"decidable": pooled, "worst": min(share), "below": below,
                       "per_walk": share}))
    return out
