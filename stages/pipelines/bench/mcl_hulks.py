"""``fieldloc bench`` row of mcl's still-robot goal on real NAO frames, through the product
path: for each HULKs capture (../shared/realdata/hulks-goalbox-labels) a dataset folder of a
robot standing still (the capture's image repeated, zero odometry, calib.yaml from the
capture's own camera matrix by calibrate's HULKs import: its height, pitch and roll), extracted
and localised by the stage mains with the CLI's defaults (``fieldloc extract DIR``; ``fieldloc
localize DIR --method mcl --init uniform``).

The truth is the pose the capture's labels give (the goal area's labelled lines, projected to
the floor with the frame's camera, placed on the SPL field); the field is 180 deg symmetric and
a uniform start cannot tell a pose from its mirror, so the top hypothesis or its mirror counts.
The goal: within 50 cm (here also 15 deg) once the frame shows at least two non-parallel
lines or a crossing; the confidence low when it does not."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...common.artifacts import atomic_path
from ...common.geometry import wrap_scalar
from ...localize.place_search import best_places, same_place
from ...localize.symmetry import confidence_up_to_mirror
from ..realdata import REALDATA
from .harness import Row

HULKS = REALDATA / "hulks-goalbox-labels" / "measurements"
# captures whose goal-area front and side labels are swapped (the folder's SOURCE.txt)
STILL_UPDATES = 15  # frames of a still robot: the capture repeated
STILL_DT = 0.1  # s between them
NON_PARALLEL = math.radians(20)  # two lines this far from parallel fix a pose (with the map)
DECIDED_NATS = math.log(20.0)  # a frame decides its place when every other is 20x less likely
GOAL_M, GOAL_DEG = 0.5, 15.0


@dataclass
class StillResult:
    """One capture localised standing still."""

    name: str
    informative: bool  # at least two non-parallel usable lines, or a crossing
    hit: bool  # the top hypothesis or its mirror within GOAL_M and GOAL_DEG of the truth
    confidence: float  # the last frame's top hypothesis probability
    pair: float  # the last frame's top hypothesis and its mirror together
    error_m: float  # position error of the better of the top pose and its mirror
    # what the frame itself decides (``decided``): its best place by brute force, unique up to
    # the mirror by DECIDED_NATS, and whether that place is the truth (or its mirror)
    decided: bool = False
    truth_best: bool = False
    # the truth (or its mirror) within GOAL_M and GOAL_DEG of a listed hypothesis (the top,
    # its mirror, the other clusters and rivals)
    listed: bool = False


def label_pose(capture: Path, field) -> np.ndarray | None:
    """The robot's pose (x, y, theta) that a capture's labels give
    (evaluate.hulks_labels.field_pose_from_labels, the labels projected to the floor with the
    capture's camera). None where a label point lies above the horizon or the lines do not
    meet."""
    from ...calibrate import hulks
    from ...evaluate.hulks_labels import field_pose_from_labels, read_labels

    camera = hulks.read_frame(capture).camera
    floor = {k: np.asarray(camera.pixel_to_floor(px), float)
             for k, px in read_labels(capture).items()}
    if not all(np.all(np.isfinite(v)) for v in floor.values()):
        return None
    return field_pose_from_labels(floor, field)


def still_dataset(capture: Path, out: Path, updates: int = STILL_UPDATES) -> Path:
    """A dataset folder of a robot standing still: the capture's image ``updates`` times
    (images/, frames.csv STILL_DT apart), odometry.csv of zero increments and calib.yaml from
    the capture's camera matrix (calibrate's HULKs import with its defaults, as ``fieldloc
    calibrate perspective --from-hulks FILE.json -o DIR/calib.yaml``)."""
    from ...calibrate import hulks

    capture = Path(capture)
    image = next(capture.with_suffix(s) for s in hulks.IMAGE_SUFFIXES
                 if capture.with_suffix(s).is_file())
    images = out / "images"
    images.mkdir(parents=True, exist_ok=True)
    first = images / f"{0:06d}{image.suffix}"
    first.write_bytes(image.read_bytes())
    names = [first.name]
    for i in range(1, updates):  # the same image: links to the first copy
        link = images / f"{i:06d}{image.suffix}"
        link.symlink_to(first.name)
        names.append(link.name)
    stamps = [f"{STILL_DT * i:.3f}" for i in range(updates)]
    _write(out / "frames.csv", ["name,stamp"] + [f"{n},{s}" for n, s in zip(names, stamps)])
    _write(out / "odometry.csv", ["stamp,dx,dy,dtheta"] + [f"{s},0,0,0" for s in stamps])
    hulks.main(None, capture, out / "calib.yaml")
    return out


def _write(path: Path, lines: list[str]) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")


def decided(model, obs, field, truth, frames: int = STILL_UPDATES) -> tuple[bool, bool]:
    """(whether the frame decides its place, whether that place is the truth): the
    observation model's log-likelihood of one frame's ``obs`` over the whole field by brute
    force (0.1 m x 3 deg, the field and half a metre around), its five best places (poses
    more than 1 m or 30 deg apart, a place's mirror image counted with it) each refined on two
    finer local grids (to 1 cm x 0.25 deg; stages.localize.place_search, which mcl's uniform
    start searches with too); the frame decides its place when the best
    beats every other by DECIDED_NATS (20 : 1), and that place is the truth when it or its
    mirror lies within GOAL_M and GOAL_DEG of ``truth``. The odds are those of ``frames``
    still frames as the filter weighs them (each repeated frame as new evidence: the model's
    one-frame log-likelihoods are tempered, a frame's best and second place often lie 1-2
    nats apart). Independent of the filter's search: what the map and the model decide, so
    that a miss there is the filter's, a wrong place the model's or the extraction's, and an
    undecided frame ambiguous."""
    hx, hy = field.length / 2 + 0.5, field.width / 2 + 0.5
    scored = best_places(model, model.prepare(obs), (-hx, hx, -hy, hy), 0.1, 3.0, 5,
                         limit=20000)
    top, top_ll = scored[0]
    rest = [v for q, v in scored[1:] if not same_place(top, q)]
    is_decided = not rest or frames * (top_ll - max(rest)) >= DECIDED_NATS
    return bool(is_decided), bool(judged(top, truth, field)[0])


def localise_still(capture: Path, map_file: Path, work: Path, field, model,
                   updates: int = STILL_UPDATES) -> StillResult | None:
    """One capture through the product path (still_dataset, extract and localize mains with
    the CLI's defaults, mcl from a uniform start), judged against its labels' pose; None when
    the labels give no pose. ``model``: an mcl observation model (its ``usable`` says which
    observations count for the goal's condition)."""
    from ... import extract, localize
    from ...common.camera import load_calib
    from ...common.features_file import FeaturesFile
    from ...common.observations import Observations
    from ...common.poses_file import read_poses

    truth = label_pose(capture, field)
    if truth is None:
        return None
    data = still_dataset(capture, work / capture.stem, updates)
    features = extract.main(None, data, data / "features.h5")
    poses = localize.main({"method": "mcl", "init": "uniform"}, data, map_file,
                          data / "poses-mcl.h5", features=features)
    with FeaturesFile(features) as ff:
        obs = model.usable(Observations.from_features(ff.frame(ff.names[0])))
    cols, _ = read_poses(poses)
    h = np.asarray(cols["hypotheses"][-1], float)
    hit, best = judged(h[0, :3], truth, field)
    own = model.with_conf(dict(model.conf, camera_height=load_calib(
        data / "calib.yaml").height))  # as localize's mcl takes it from calib.yaml
    is_decided, truth_best = decided(own, obs, field, truth, updates)
    return StillResult(capture.stem, informative(obs), bool(hit), float(h[0, 3]),
                       float(cols["confidence_up_to_mirror"][-1]), best, is_decided, truth_best,
                       listed(h, truth, field))


def judged(top, truth, field) -> tuple[bool, float]:
    """Whether the top pose or its mirror lies within GOAL_M and GOAL_DEG of ``truth``, and the
    position error of the nearer of the two."""
    best, hit = math.inf, False
    for p in (top, field.mirror_pose(top)):
        dist = math.hypot(p[0] - truth[0], p[1] - truth[1])
        turn = abs(wrap_scalar(p[2] - truth[2]))
        best = min(best, dist)
        hit |= dist <= GOAL_M and turn <= math.radians(GOAL_DEG)
    return bool(hit), best


def listed(hypotheses, truth, field) -> bool:
    """Whether a listed hypothesis (rows (k, 4), NaN rows unused) or its mirror lies within
    GOAL_M and GOAL_DEG of ``truth``."""
    return any(judged(r[:3], truth, field)[0] for r in np.asarray(hypotheses, float)
               if np.all(np.isfinite(r[:3])))


def informative(obs) -> bool:
    """At least two usable lines more than NON_PARALLEL from parallel, or a crossing."""
    if len(obs.crossings):
        return True
    d = obs.lines[:, 1] if len(obs.lines) else np.zeros(0)
    return bool(np.any(np.abs(np.sin(d[:, None] - d[None, :])) > math.sin(NON_PARALLEL)))


def still_robot(work: Path, captures=None, updates: int = STILL_UPDATES) -> list[StillResult]:
    """Every HULKs capture (or ``captures``) localised standing still (localise_still) on the
    SPL map (built by build_map's main with its defaults into ``work``)."""
    from ... import build_map
    from ...common.field import load_field
    from ...common.map_file import MapFile
    from ...localize import confs
    from ...localize.observation_model import ObservationModel

    work.mkdir(parents=True, exist_ok=True)
    map_file = work / "spl.map.h5"
    if not map_file.exists():
        build_map.main(None, "spl", map_file)
    field = load_field("spl")
    model = ObservationModel.from_map(MapFile(map_file), confs["mcl-uniform"]["observation"])
    captures = sorted(HULKS.glob("*.json")) if captures is None else captures
    out = []
    for js in captures:
        r = localise_still(Path(js), map_file, work, field, model, updates)
        if r is not None:
            out.append(r)
    return out


RENDERED = (("perspective-nao", "spl"), ("perspective-default", "kidsize"))
RENDERED_POSES = 30  # random poses per camera, each localised from two seeds


def rendered_still(preset: str, field_name: str, poses, seeds=(0, 1),
                   updates: int = STILL_UPDATES, conf: dict | None = None) -> list[StillResult]:
    """Rendered frames of a still robot: for each pose one frame of ``preset`` (simulate's
    renderer, the camera at its nominal pitch and roll) through extract's perspective chain
    with its default conf, and mcl from a uniform start with the CLI's defaults (the
    renderer's camera height, as calib.yaml gives it) updated ``updates`` times on it, once per
    seed (``conf``: changes to mcl's uniform preset). The truth is the pose; judged as the
    HULKs frames are."""
    from ... import simulate
    from ...common.field import load_field
    from ...common.observations import Observations
    from ...extract import perspective
    from ...localize import mcl
    from ...localize.observation_model import ObservationModel
    from ...simulate import scene
    from ...simulate.perspective_renderer import PerspectiveRenderer

    fm = load_field(field_name)
    sim = simulate.confs[preset]
    renderer = PerspectiveRenderer(sim["perspective"], scene.build(fm, sim["scene"],
                                                                   np.zeros(1), 4), seed=4)
    cam = renderer.camera
    conf = dict(mcl.confs["uniform"], **(conf or {}))
    obs_conf = dict(conf["observation"], camera_height=cam.height)
    model = ObservationModel.from_field(fm, obs_conf)
    out = []
    for k, pose in enumerate(np.asarray(poses, float)):
        image = renderer.render_view(pose, cam.pitch, cam.roll, frame=0)
        obs = Observations.from_features(perspective.extract_frame(
            image, cam, perspective.confs["default"], pitch=cam.pitch, roll=cam.roll))
        usable = model.usable(obs)
        is_decided, truth_best = decided(model, usable, fm, pose, updates)
        for seed in seeds:
            pf = mcl.ParticleFilter(model, dict(conf, observation=obs_conf, seed=seed))
            pf.initialise()
            for i in range(updates):
                est, _frame = pf.step(np.zeros(3), STILL_DT, obs, first=i == 0)
            hit, best = judged(est.hypotheses[0, :3], pose, fm)
            out.append(StillResult(f"{preset}-{k}-seed{seed}", informative(usable),
                                   hit, float(est.hypotheses[0, 3]),
                                   float(confidence_up_to_mirror(
                                       est.hypotheses[None], fm.is_point_symmetric())[0]),
                                   best, is_decided,
                                   truth_best, listed(est.hypotheses, pose, fm)))
    return out


def random_poses(field_name: str, n: int, seed: int = 11) -> np.ndarray:
    """``n`` poses uniform over the field (x, y inside the lines, any heading)."""
    from ...common.field import load_field

    fm = load_field(field_name)
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-fm.length / 2, fm.length / 2, n),
                     rng.uniform(-fm.width / 2, fm.width / 2, n),
                     rng.uniform(-math.pi, math.pi, n)], axis=1)


def summary(res: list[StillResult], min_confidence: float) -> dict:
    """The goal's figures over still-robot results: hits among the informative frames, the
    pair share (pose and mirror: the confidence up to the mirror, stages.localize.symmetry)
    on hits, misses and uninformative frames, its AUROC for a hit and for an error within
    1 m, and the frames whose pair share reaches ``min_confidence`` while more than 1 m off."""
    from ...evaluate.metrics import auroc

    inf = [r for r in res if r.informative]
    pair = np.array([r.pair for r in res])
    hit = np.array([r.hit for r in res])
    near = np.array([r.error_m <= 1.0 for r in res])

    def med(rs):
        return float(np.median([r.pair for r in rs])) if rs else math.nan

    return {
        "informative": len(inf), "hits": sum(r.hit for r in inf),
        "share": float(np.mean([r.hit for r in inf])) if inf else math.nan,
        "median_error_m": float(np.median([r.error_m for r in inf])) if inf else math.nan,
        "pair_hits": med([r for r in inf if r.hit]),
        "pair_misses": [round(r.pair, 2) for r in inf if not r.hit],
        "pair_uninformative": [round(r.pair, 2) for r in res if not r.informative],
        "auroc_hit": auroc(pair, hit) if 0 < hit.sum() < len(hit) else math.nan,
        "auroc_1m": auroc(pair, near) if 0 < near.sum() < len(near) else math.nan,
        "confidently_wrong": int(np.sum((pair >= min_confidence) & ~near)),
        "frames": len(res),
        # the informative frames that decide their place (decided), and of those the ones
        # whose place is the truth: there a miss is the filter's
        "decided": sum(r.decided for r in inf),
        "decided_truth": sum(r.decided and r.truth_best for r in inf),
        "decided_truth_hits": sum(r.decided and r.truth_best and r.hit for r in inf),
        "undecided_hits": sum((not r.decided) and r.hit for r in inf),
        # the informative frames whose truth is among the listed hypotheses
        "listed": sum(r.listed for r in inf),
    }


def _note(s: dict) -> str:
    def few(v):
        return ", ".join(f"{x:.2f}" for x in sorted(v)[:12]) + (" ..." if len(v) > 12 else "")

    return (f"{s['hits']} of {s['informative']} informative frames ({100 * s['share']:.0f} %),"
            f" median error of the better of top and mirror {100 * s['median_error_m']:.0f} cm;"
            f" pair share (top + mirror): hits median {s['pair_hits']:.2f}, misses"
            f" {few(s['pair_misses']) or '-'}; uninformative frames"
            f" ({len(s['pair_uninformative'])}): {few(s['pair_uninformative']) or '-'}; AUROC"
            f" of the pair share for a hit {s['auroc_hit']:.3f}, for within 1 m"
            f" {s['auroc_1m']:.3f}; >= min_confidence and > 1 m off: {s['confidently_wrong']}"
            f" of {s['frames']}; what the frames decide (brute force over the field: the"
            f" still frames' odds >= 20 : 1 up to the mirror): {s['decided']} of the"
            f" {s['informative']} informative frames decide a place,"
            f" {s['decided_truth']} of them the truth, and mcl hits"
            f" {s['decided_truth_hits']} of those; of the"
            f" {s['informative'] - s['decided']} undecided, mcl hits {s['undecided_hits']};"
            f" the truth is a listed hypothesis (top, mirror, other clusters, rivals) on"
            f" {s['listed']} of the {s['informative']} informative frames")


def rows(repeat: int) -> list[Row]:
    """The share of informative frames whose top hypothesis (or its mirror) is within 50 cm / 15
    deg of the truth after STILL_UPDATES still frames, and how the belief's pair share (top and
    mirror, its confidence up to the symmetry) tells hits from misses: on the HULKs captures
    (their labels' pose), and on rendered NAO and KidSize frames at random poses."""
    from ...localize import mcl
    from .inputs import work_dir

    min_conf = float(mcl.confs["uniform"]["min_confidence"])
    goal = "top or mirror within 50 cm / 15 deg on every informative frame"
    out = []
    if not HULKS.is_dir():
        out.append(Row(name="mcl still robot on the HULKs frames", note=f"skipped: no {HULKS}"))
    else:
        t0 = time.perf_counter()
        res = still_robot(work_dir() / "hulks-still")
        s = summary(res, min_conf)
        out.append(Row(
            name="mcl still robot from a uniform start, real HULKs frames (fieldloc extract +"
                 f" localize --method mcl --init uniform, {STILL_UPDATES} still frames)",
            median_ms=math.nan, goal=goal, meets_goal=s["informative"] > 0 and s["share"] == 1.0,
            repeats=1, note=f"{_note(s)}; {time.perf_counter() - t0:.0f} s",
            extra={"summary": s, "frames": [r.__dict__ for r in res]}))
    t0 = time.perf_counter()
    res = []
    for preset, field_name in RENDERED:
        res += rendered_still(preset, field_name, random_poses(field_name, RENDERED_POSES))
    s = summary(res, min_conf)
    out.append(Row(
        name=f"mcl still robot from a uniform start, rendered NAO and KidSize frames"
             f" ({RENDERED_POSES} random poses each, 2 seeds, {STILL_UPDATES} still frames)",
        median_ms=math.nan, goal=goal, meets_goal=s["informative"] > 0 and s["share"] == 1.0,
        repeats=1, note=f"{_note(s)}; {time.perf_counter() - t0:.0f} s",
        extra={"summary": s, "frames": [r.__dict__ for r in res]}))
    return out
