"""Omni extraction on real catadioptric images of the MINHO team (../shared/realdata, read
its README): distances to a line at known distances (minho-distance), and the share of
extracted points that are not on field lines (minho-lab) against rendered frames.

Calibrations come from the team's own files through the product path, ``stages.calibrate.
from_minho`` (``fieldloc calibrate omni --from-minho DIR``) with its defaults: mirror.cfg's
radii at STEP, 2 STEP, ... and image.cfg's IMG_CENTER and TILT (90: the robot's front is up; the
line the minho-distance robot faces is at the top of every image), as the monotone table model.
minho-distance also holds the images of that line, named by its distance: the calibration
measures them (``--line-images``), because the team's table is 4-6 px off between 1.25 and 2 m
(see test_minho_distance_mirror_table_is_off).
"""

from __future__ import annotations

import copy
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from stages import calibrate, extract
from stages.common.camera import load_calib
from stages.common.features_file import FeaturesFile
from stages.common.field import field_from_spec
from stages.evaluate.line_share import LineRaster
from stages.extract import read_mask
from stages.pipelines.realdata import lab_field

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
pytestmark = pytest.mark.skipif(not REALDATA.exists(), reason="../shared/realdata is absent")

LAB_RANGE = 4.0  # m, the paper's sensor range (beyond ~3.5 m one pixel spans 0.1-0.25 m)
# the preset a user takes for real images, with the 360 extra radial lines of "dense" so that a
# line 2 m away gives enough points to fit
REAL_DENSE = {"points_radial_lines": 360}


def make_dataset(folder, out, images=None, line_images=None):
    """A dataset folder (GUIDE section 4) from a realdata folder: images, mask.png and the
    calib.yaml of ``calibrate.from_minho`` with its defaults (``line_images``: a folder of
    images named by the distance of the line ahead, measured into the calibration)."""
    out.mkdir(parents=True)
    calibrate.from_minho(None, folder, out / "calib.yaml", line_images=line_images)
    (out / "images").mkdir()
    for p in sorted((folder / "images").glob("*.png")):
        if images is None or p.stem in images:
            shutil.copy(p, out / "images" / p.name)
    shutil.copy(folder / "mask.png", out / "mask.png")
    return out


# ---------------------------------------------------------------------------- minho-distance


def hough_votes(points, rho_max=3.5, rho_step=0.02):
    """Votes (360, n) of robot-frame points for straight lines p . n(phi) = rho, phi in 1 deg
    steps, rho in ``rho_step`` bins (each vote also counts in the neighbouring rho bins)."""
    phi = np.radians(np.arange(360))
    n_rho = int(rho_max / rho_step)
    rho = points[:, :1] * np.cos(phi) + points[:, 1:] * np.sin(phi)
    ok = (rho > 0.2) & (rho < rho_max)
    idx = (np.arange(360)[None, :] * n_rho + (rho / rho_step).astype(int))[ok]
    v = np.bincount(idx, minlength=360 * n_rho).reshape(360, n_rho).astype(float)
    return v + np.roll(v, 1, axis=1) + np.roll(v, -1, axis=1), rho_step


def line_ahead(point_sets, min_votes=12):
    """The distance of the line each frame's robot faces, without knowing where it faces.

    The robot was moved straight back from one line, so that line keeps its bearing while its
    distance changes from frame to frame; a line beside the robot (parallel to the motion)
    keeps both. Per frame and normal bearing phi (1 deg) the strongest straight line (Hough
    votes of the line points) gives a distance and a strength; the scene's lines are the
    bearings where the summed strength peaks, and of those seen in most frames (>=
    ``min_votes`` points) the one whose distance varies most over the frames is the line
    ahead's. ("The nearest strong crossing cluster" is not enough: from 1.25 m on, the
    penalty-area line beside the robot at ~0.7 m is nearer.) Per frame, the strongest line
    within 5 deg of that bearing is refined by a total-least-squares fit of the points within
    5 cm of it. Returns the bearing (deg, robot frame) and per frame (distance, mask of the
    points on the line, unit normal towards the line)."""
    votes = [hough_votes(p) for p in point_sets]
    best_rho = np.array([(v.argmax(axis=1) + 0.5) * step for v, step in votes])
    strongest = np.array([v.max(axis=1) for v, _ in votes])  # (frames, 360)
    present = strongest >= min_votes
    strength = (strongest / strongest.max(axis=1, keepdims=True)).sum(axis=0)
    # straight lines of the scene: bearings that are the strongest within +-10 deg
    window = np.stack([np.roll(strength, k) for k in range(-10, 11)])
    peaks = np.flatnonzero((strength >= window.max(axis=0))
                           & (strength >= 0.5 * strength.max()))
    need = int(math.ceil(0.75 * len(point_sets)))
    spread = {int(k): np.std(best_rho[present[:, k], k]) for k in peaks
              if present[:, k].sum() >= need}
    phi_star = max(spread, key=spread.get)
    out = []
    for p, (v, step) in zip(point_sets, votes):
        rows = [(phi_star + d) % 360 for d in range(-5, 6)]
        a, b = np.unravel_index(int(np.argmax(v[rows])), v[rows].shape)
        phi = math.radians(rows[a])
        normal = np.array([math.cos(phi), math.sin(phi)])
        on = np.abs(p @ normal - (b + 0.5) * step) <= 0.05
        dist, n = total_least_squares(p[on])
        out.append((dist, on, n))
    return phi_star, out


def total_least_squares(q):
    """The straight line through points q (n, 2): its distance from the origin and its unit
    normal pointing from the origin towards it."""
    c = q.mean(axis=0)
    n = np.linalg.svd(q - c)[2][1]
    if c @ n < 0:
        n = -n
    return float(c @ n), n


def distance_run(ds, max_named=2.0):
    """Extract ``ds`` (preset "real" with dense points) and find the line ahead in the frames
    up to ``max_named`` m: the named and measured distances, the points used, and how far out
    (px) the extractor's points lie from where the calibration puts a straight line at the
    named distance (median over the points within 15 deg of its normal)."""
    out = extract.main(extract.resolve_extract_conf("omni", "real", REAL_DENSE), ds,
                       ds / "features.h5")
    with FeaturesFile(out) as ff:
        names = [n for n in ff.names if float(n) <= max_named + 1e-9]
        points = [ff.frame(n)["points"].astype(float) for n in names]
        pixels = [ff.frame(n)["points_px"].astype(float) for n in names]
    phi, lines = line_ahead(points)
    cam = load_calib(ds / "calib.yaml")
    named = np.array([float(n) for n in names])
    offset = []
    for d, p, px, (_, on, n) in zip(named, points, pixels, lines):
        off = np.arctan2(p[on, 0] * n[1] - p[on, 1] * n[0], p[on] @ n)
        r = np.hypot(px[on, 0] - cam.centre[0], px[on, 1] - cam.centre[1])
        near = np.abs(off) <= math.radians(15)
        offset.append(float(np.median(r[near] - cam.radius_of_distance(d / np.cos(off[near])))))
    return {"bearing": phi, "named": named, "measured": np.array([d for d, _, _ in lines]),
            "used": [int(on.sum()) for _, on, _ in lines], "radius_offset": np.array(offset),
            "pixels": pixels, "lines": lines, "calib": ds / "calib.yaml"}


def errors_cm(run):
    return dict(zip(run["named"], np.round(100 * (run["measured"] - run["named"]), 1)))


@pytest.fixture(scope="module")
def distance_lines(tmp_path_factory):
    """The product path: calibrate omni --from-minho DIR --line-images DIR/images, then
    extract with the real preset."""
    folder = REALDATA / "minho-distance"
    ds = make_dataset(folder, tmp_path_factory.mktemp("real") / "minho-distance",
                      line_images=folder / "images")
    return distance_run(ds)


def test_minho_distance_line_ahead(distance_lines):
    """The line is found straight ahead (TILT says the robot faces up in the image), and the
    extractor's white runs lie within 1.5 px of the radius where the calibration (which
    measured the same line as a luminance ridge) puts the named distance."""
    r = distance_lines
    assert min(r["bearing"], 360 - r["bearing"]) <= 10
    assert min(r["used"]) >= 8
    px = r["radius_offset"]
    assert np.all(np.abs(px) <= 1.5), dict(zip(r["named"], np.round(px, 2)))


def test_minho_distance_within_5cm_up_to_2m(distance_lines):
    """Real-data goal: the line ahead within 5 cm of its distance at every distance up to 2 m."""
    err = distance_lines["measured"] - distance_lines["named"]
    assert np.all(np.abs(err) <= 0.05), errors_cm(distance_lines)


def test_minho_distance_held_out_lines(tmp_path_factory):
    """The line-image calibration is not a lookup of the tested images: calibrated from the
    images at 0.5, 1, 1.5, 2 and 2.5 m only, the lines at 0.75, 1.25 and 1.75 m are still found
    within 5 cm."""
    folder = REALDATA / "minho-distance"
    tmp = tmp_path_factory.mktemp("held-out")
    marks = tmp / "marks"
    marks.mkdir()
    for name in ("0.50", "1.00", "1.50", "2.00", "2.50"):
        shutil.copy(folder / "images" / f"{name}.png", marks / f"{name}.png")
    run = distance_run(make_dataset(folder, tmp / "ds", line_images=marks))
    held = np.isin(np.round(run["named"], 2), [0.75, 1.25, 1.75])
    assert held.sum() == 3
    err = (run["measured"] - run["named"])[held]
    assert np.all(np.abs(err) <= 0.05), errors_cm(run)


def test_minho_distance_mirror_table_is_off(distance_lines, tmp_path):
    """Why the line images are needed: the team's mirror.cfg disagrees with the team's own
    images of a line from 1.25 to 2 m, and the images are right.

    - Where the line ahead appears: within 1.5 px of the table's radius at 0.5-1 m, but 3-7 px
      farther out at 1.25-2 m (the table says 10-14 cm too far).
    - Independently of the far images' names: the same straight line seen in the near frames
      (0.75 and 1 m, where table and images agree) reaches 1.25-1.75 m at the sides (30-55 deg
      off its normal). Mapped with the table, those ridge points lie 5 cm or more beyond the
      line through its near points; mapped with the line-image calibration, within 2 cm."""
    from stages.calibrate.line_images import ridge_radii
    from stages.common.dataset import read_image

    folder = REALDATA / "minho-distance"
    rec = calibrate.report(distance_lines["calib"])
    marks = {m["distance_m"]: m["radius_px"] - m["source_radius_px"]
             for m in rec["line_images"]}
    assert all(abs(marks[d]) <= 1.5 for d in (0.5, 0.75, 1.0)), marks
    assert all(3.0 <= marks[d] <= 7.0 for d in (1.25, 1.5, 1.75, 2.0)), marks
    cams = {"table": load_calib(calibrate.from_minho(None, folder, tmp_path / "table.yaml")),
            "images": load_calib(distance_lines["calib"])}
    mask = read_mask(folder / "mask.png", (480, 480))
    bearings = np.arange(-70, 70.01, 0.5)
    bend = {}
    for name in ("0.75", "1.00"):
        cam = cams["images"]
        r, _ = ridge_radii(read_image(folder / "images" / f"{name}.png"), bearings,
                           centre=cam.centre, forward_angle=cam.forward_angle,
                           valid_radius=cam.valid_radius, mask=mask)
        seen = np.isfinite(r)
        b = np.radians(bearings[seen])
        for label, cam in cams.items():
            d = cam.distance_of_radius(r[seen])
            p = np.stack([d * np.cos(b), d * np.sin(b)], axis=1)
            near = d <= 1.1 * float(name) + 0.1
            rho, n = total_least_squares(p[near])
            side = (d >= 1.25) & (d < 1.75)
            bend[(name, label)] = round(float(np.median(p[side] @ n - rho)), 3)
    for name in ("0.75", "1.00"):
        assert bend[(name, "table")] >= 0.05, bend
        assert abs(bend[(name, "images")]) <= 0.02, bend


# ---------------------------------------------------------------------------- minho-lab

@pytest.fixture(scope="module")
def lab_points(tmp_path_factory):
    ds = make_dataset(REALDATA / "minho-lab", tmp_path_factory.mktemp("real") / "minho-lab")
    out = extract.main("dense", ds, ds / "features.h5")
    with FeaturesFile(out) as ff:
        return {n: ff.frame(n)["points"].astype(float) for n in ff.names}


def off_line_points(fm, point_sets, min_points=20, seed=0):
    """Over frames with enough points: (points not within 15 cm of a line at each frame's
    best-fitting pose, the same for random-bearing copies of the points (the null baseline),
    all points)."""
    raster = LineRaster(fm)
    rng = np.random.default_rng(seed)
    off = off_null = total = 0
    for p in point_sets:
        if len(p) < min_points:
            continue
        rho = np.hypot(p[:, 0], p[:, 1])
        b = rng.uniform(0, 2 * np.pi, len(p))
        null = np.stack([rho * np.cos(b), rho * np.sin(b)], axis=1)
        off += round((1 - raster.best_pose(p)[0]) * len(p))
        off_null += round((1 - raster.best_pose(null)[0]) * len(p))
        total += len(p)
    return off, off_null, total


# rendered frames for the clutter comparison: RENDERED_FRAMES frames of each of RENDERED_SEEDS
# (omni-default draws a team's calibration per seed, and clutter comes in episodes: a white
# stick crossing many scan lines for a while), pooled
RENDERED_SEEDS = (0, 1, 2, 3)
RENDERED_FRAMES = 5


@pytest.fixture(scope="module")
def rendered_points(tmp_path_factory):
    """Line points and true poses of rendered omni-default frames (lab clutter, the seed
    team's mirror and a team's calibration: stages.simulate), extracted as the real ones."""
    from stages import simulate
    from stages.common.dataset import open_dataset

    pts, poses = [], []
    for seed in RENDERED_SEEDS:
        conf = copy.deepcopy(simulate.confs["omni-default"])
        conf.update(frames=RENDERED_FRAMES, seed=seed)
        ds = simulate.main(conf, "msl-2015", tmp_path_factory.mktemp("sim") / f"omni-{seed}")
        out = extract.main("dense", ds, ds / "features.h5")
        truth = open_dataset(ds).optional("truth")
        with FeaturesFile(out) as ff:
            pts += [ff.frame(n)["points"].astype(float) for n in ff.names]
        poses += list(np.stack([truth["x"], truth["y"], truth["theta"]], axis=1))
    return pts, np.asarray(poses)


@pytest.fixture(scope="module")
def clutter(lab_points, rendered_points):
    """Clutter: the share of extracted points that are not within 15 cm of a field line. Real:
    at the pose that explains the most points (no truth: an optimistic bound), next to the null
    baseline of random bearings; rendered: at the true pose."""
    from stages.common.field import load_field
    from stages.common.geometry import robot_to_field

    lab = field_from_spec(lab_field())
    off, off_null, total = off_line_points(lab, list(lab_points.values()))
    msl = load_field("msl-2015")
    pts, poses = rendered_points
    dist = np.concatenate([msl.distance_to_lines(robot_to_field(q, p))
                           for p, q in zip(pts, poses)])
    out = {"real": off / total, "null": off_null / total, "real_points": total,
           "rendered": float(np.mean(dist > 0.15)), "rendered_points": len(dist)}
    print(f"\nclutter (share of points > 15 cm from a line): minho-lab {out['real']:.3f} of"
          f" {total} points (null baseline {out['null']:.3f}); rendered omni-default"
          f" {out['rendered']:.3f} of {len(dist)} points")
    return out


def test_minho_lab_points_are_mostly_on_lines(clutter):
    assert clutter["real_points"] >= 500
    assert clutter["real"] <= clutter["null"] - 0.15
    assert clutter["real"] <= 0.35


def test_rendered_clutter_is_of_the_same_order_as_real(clutter):
    """GUIDE section 7 and the real-data goals: rendered omni-default frames are as hard as the real
    minho-lab ones: 15-25 % of the extracted points lie off the lines at the true pose (real:
    ~20 % at the best-fitting pose), from a team's calibration misplacing real lines, soft far
    lines and false white, as in the real frames."""
    assert clutter["rendered_points"] >= 2000
    assert 0.15 <= clutter["rendered"] <= 0.25
    assert 2 / 3 <= clutter["rendered"] / clutter["real"] <= 3 / 2


def test_minho_lab_mask_and_extraction_run(lab_points):
    assert len(lab_points) == 10
    mask = read_mask(REALDATA / "minho-lab" / "mask.png", (480, 480))
    assert 0.2 < (~mask).mean() < 0.6  # the painted struts, body and surroundings
    assert sum(len(p) for p in lab_points.values()) >= 300
    img = cv2.imread(str(REALDATA / "minho-lab" / "images" / "01.png"))
    assert img is not None
