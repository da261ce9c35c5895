"""The perspective chain on real NAO frames (the NAO goals):
../shared/realdata/hulks-goalbox-labels, 107 frames (50 top, 57 bottom camera) of SPL halls, each
with the robot's camera matrix and six hand-clicked points on the goal line, the goal-area front
line and the goal-area side line (read its README and SOURCE.txt).

The product path only: the folder becomes a dataset with ``fieldloc calibrate perspective
--from-hulks`` (stages.calibrate.hulks: images, calib.yaml, head.csv with each frame's own
camera pose) and ``fieldloc extract`` runs on it with its default preset. The labels are
compared with what the extractor wrote, both projected with the frame's own camera matrix:

- lines: each labelled line longer than 40 px in the image has an extracted line within 3 deg
  and 5 px in the image, or within 3 deg and 10 cm on the floor (the part of it within 3 m);
- crossings: the goal-area L corner (front x side line) and the T on the goal line (goal x side
  line), where the intersection lies in the image: an extracted crossing of the right type
  within 15 px; of another type only: a wrong type;
- false lines: extracted lines whose floor points (within 4 m) lie farther than 30 cm from
  every labelled line and every line of the SPL field placed at the goal area the labels show
  (``field_pose_from_labels``): a share, reported;
- goal posts: the goal's posts stand on the goal line 0.3 m (and 1.9 m) from the labelled T,
  towards the goal-area's inside; where a post's foot is in the image, an extracted post
  within 3 deg of bearing.

Pixel coordinates of the labels are HULKs' (origin at the top-left pixel's corner) and are
moved by half a pixel to fieldloc's (origin at its centre), as the importer does with the
principal point. Four files hold the front and side labels swapped (SOURCE.txt); they are
swapped back here. Skipped when ../shared/realdata is absent.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from stages.common.field import load_field
from stages.common.geometry import robot_to_field
from stages.evaluate.hulks_labels import SWAPPED, field_pose_from_labels, intersect, read_labels

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
HULKS = REALDATA / "hulks-goalbox-labels" / "measurements"
pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not HULKS.is_dir(), reason="needs ../shared/realdata"),
]

MIN_LABEL_PX = 40.0
LINE_DEG, LINE_PX, LINE_M, LINE_RANGE = 3.0, 5.0, 0.10, 3.0
CROSSING_PX = 15.0
FALSE_M, FALSE_RANGE = 0.30, 4.0
POST_DEG = 3.0


# ---------------------------------------------------------------------------- labels


def _direction_deg(p: np.ndarray) -> float:
    d = p[1] - p[0]
    return math.degrees(math.atan2(d[1], d[0]))


def _angle_diff_deg(a: float, b: float) -> float:
    return abs((a - b + 90.0) % 180.0 - 90.0)


def _point_line_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    d = line[1] - line[0]
    n = np.array([-d[1], d[0]]) / max(np.hypot(*d), 1e-12)
    return np.abs((np.asarray(points, float) - line[0]) @ n)


def _clip_to_range(seg: np.ndarray, radius: float) -> np.ndarray | None:
    """The part of a floor segment (2, 2) within ``radius`` of the robot, or None."""
    p, d = seg[0], seg[1] - seg[0]
    a, b, c = d @ d, 2 * p @ d, p @ p - radius * radius
    if a < 1e-12:
        return seg if c <= 0 else None
    disc = b * b - 4 * a * c
    if disc <= 0:
        return None
    t0, t1 = (-b - math.sqrt(disc)) / (2 * a), (-b + math.sqrt(disc)) / (2 * a)
    t0, t1 = max(t0, 0.0), min(t1, 1.0)
    if t1 <= t0:
        return None
    return np.stack([p + t0 * d, p + t1 * d])


def line_matches(label_px: np.ndarray, label_floor: np.ndarray, ends_px: np.ndarray,
                 ends_floor: np.ndarray) -> bool:
    """An extracted line (image ends (2, 2), floor ends (2, 2)) is the labelled line: within
    3 deg and 5 px in the image where their extents overlap, or within 3 deg and 10 cm on the
    floor over its part within 3 m of the robot."""
    d = label_px[1] - label_px[0]
    u = d / np.hypot(*d)
    t = (ends_px - label_px[0]) @ u
    overlap = min(t.max(), float(np.hypot(*d))) - max(t.min(), 0.0)
    if overlap > 0 and _angle_diff_deg(_direction_deg(ends_px), _direction_deg(label_px)) \
            <= LINE_DEG and _point_line_distance(ends_px, label_px).max() <= LINE_PX:
        return True
    if not (np.all(np.isfinite(label_floor)) and np.all(np.isfinite(ends_floor))):
        return False
    near = _clip_to_range(ends_floor, LINE_RANGE)
    if near is None or np.hypot(*(near[1] - near[0])) < 0.05:
        return False
    return (_angle_diff_deg(_direction_deg(ends_floor), _direction_deg(label_floor)) <= LINE_DEG
            and _point_line_distance(near, label_floor).max() <= LINE_M)


def post_positions(floor: dict[str, np.ndarray], field, pose: np.ndarray) -> np.ndarray:
    """The goal's post feet (2, 2) in the robot frame at ``pose`` (field_pose_from_labels)."""
    half = field.spec["goal"]["width"] / 2
    posts = np.array([[field.length / 2, -half], [field.length / 2, half]])
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rel = posts - pose[:2]
    return np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)


# ---------------------------------------------------------------------------- evaluation


def evaluate(dataset: Path, features: Path) -> dict:
    """All figures of the module doc over the frames of ``features``."""
    from stages.calibrate import hulks
    from stages.common.features_file import FeaturesFile

    spl = load_field("spl")
    out = {"lines": [], "lines_used": [], "crossings": [], "false": [], "false_all": [],
           "posts": [], "per_frame": {}}
    with FeaturesFile(features) as ff:
        names = list(ff.names)
        frames = {n: ff.frame(n) for n in names}
    for name in names:
        fr = frames[name]
        cam = hulks.read_frame(HULKS / f"{name}.json").camera
        w, h = cam.image_size
        lab = read_labels(HULKS / f"{name}.json")
        floor = {k: cam.pixel_to_floor(v) for k, v in lab.items()}
        ends_px = fr["line_ends_px"].reshape(-1, 2, 2).astype(float)
        ends_fl = fr["line_ends"].reshape(-1, 2, 2).astype(float)
        used = fr["lines"][:, 3] > 0 if len(fr["lines"]) else np.zeros(0, bool)
        rec = {"lines": {}, "crossings": {}}
        for key, px in lab.items():
            if np.hypot(*(px[1] - px[0])) <= MIN_LABEL_PX:
                continue
            hits = [line_matches(px, floor[key], e, f) for e, f in zip(ends_px, ends_fl)]
            found = any(hits)
            found_used = any(hh and u for hh, u in zip(hits, used))
            out["lines"].append(found)
            out["lines_used"].append(found_used)
            rec["lines"][key] = found
        for kind, (a, b) in (("L", ("front", "side")), ("T", ("goal", "side"))):
            x = intersect(lab[a], lab[b])
            if x is None or not (0 <= x[0] <= w - 1 and 0 <= x[1] <= h - 1):
                continue
            near = [("LTX"[int(c[0])], np.hypot(*(p - x))) for c, p in
                    zip(fr["crossings"], fr["crossings_px"])]
            right = any(t == kind and d <= CROSSING_PX for t, d in near)
            wrong = not right and any(t != kind and d <= CROSSING_PX for t, d in near)
            verdict = "right" if right else "wrong" if wrong else "missed"
            out["crossings"].append((kind, verdict))
            rec["crossings"][kind] = verdict
        pose = field_pose_from_labels(floor, spl)
        if pose is not None:
            for e, u in zip(ends_fl, used):
                near = _clip_to_range(e, FALSE_RANGE)
                if near is None:
                    continue
                s = np.linspace(0.0, 1.0, 7)[:, None]
                pts = near[0] * (1 - s) + near[1] * s
                d_model = spl.distance_to_lines(robot_to_field(pose, pts))
                d_label = np.min([_point_line_distance(pts, f) for f in floor.values()
                                  if np.all(np.isfinite(f))], axis=0)
                false = bool(np.max(np.minimum(d_model, d_label)) > FALSE_M)
                out["false_all"].append(false)
                if u:
                    out["false"].append(false)
            rec["pose"] = pose
            posts = post_positions(floor, spl, pose)
            posts_px = cam.floor_to_pixel(posts)
            for p, ppx in zip(posts, posts_px):
                if not np.all(np.isfinite(ppx)):
                    continue
                bearing = math.atan2(p[1], p[0])
                found = [abs(math.remainder(b - bearing, 2 * math.pi)) for b in
                         fr["posts"][:, 1]] if len(fr["posts"]) else []
                out["posts"].append(bool(found) and min(found) <= math.radians(POST_DEG))
        out["per_frame"][name] = rec
    return out


def summary(res: dict) -> dict:
    cr = res["crossings"]
    n_cr = max(len(cr), 1)
    return {
        "labelled lines": len(res["lines"]),
        "line recall": float(np.mean(res["lines"])),
        "line recall (used lines)": float(np.mean(res["lines_used"])),
        "crossings in image": len(cr),
        "crossings right": sum(v == "right" for _, v in cr) / n_cr,
        "crossings wrong type": sum(v == "wrong" for _, v in cr) / n_cr,
        "L right": float(np.mean([v == "right" for k, v in cr if k == "L"] or [np.nan])),
        "T right": float(np.mean([v == "right" for k, v in cr if k == "T"] or [np.nan])),
        "false share (used lines)": float(np.mean(res["false"])) if res["false"] else 0.0,
        "false share (all lines)": float(np.mean(res["false_all"])) if res["false_all"] else 0.0,
        "used lines": len(res["false"]),
        "posts in image": len(res["posts"]),
        "post recall": float(np.mean(res["posts"])) if res["posts"] else float("nan"),
    }


# ---------------------------------------------------------------------------- tests


@pytest.fixture(scope="module")
def extracted(hulks_extracted):
    """The HULKs folder imported and extracted by the CLI with its defaults (conftest)."""
    return hulks_extracted


def test_projection_of_the_labels_reproduces_the_source_figures(extracted):
    """SOURCE.txt: the projected goal line and front line lie 0.57 m apart (median; the rules
    say 0.6 m), the side line about perpendicular to the goal line."""
    from stages.calibrate import hulks

    gaps, angles = [], []
    for js in sorted(HULKS.glob("*.json")):
        if js.stem in SWAPPED:
            continue
        cam = hulks.read_frame(js).camera
        fl = {k: cam.pixel_to_floor(v) for k, v in read_labels(js).items()}
        if not all(np.all(np.isfinite(v)) for v in fl.values()):
            continue
        gaps.append(_point_line_distance(fl["front"].mean(axis=0)[None], fl["goal"])[0])
        angles.append(_angle_diff_deg(_direction_deg(fl["goal"]), _direction_deg(fl["side"])))
    assert len(gaps) >= 95
    assert abs(np.median(gaps) - 0.57) < 0.01
    assert 85.0 < np.median(angles) <= 90.0


@pytest.fixture(scope="module")
def figures(extracted):
    return summary(evaluate(*extracted))


def test_labelled_lines_are_extracted(figures):
    """The NAO goal: >= 85 % of the labelled lines (met: 0.90)."""
    assert figures["labelled lines"] >= 250
    assert figures["line recall"] >= 0.85, figures


def test_goal_area_crossings_are_found_and_typed(figures):
    """The NAO goals: the L and T found and typed right on >= 75 %, wrong types <= 5 %. Both
    are met: 0.75 right (L 0.78, T 0.73; 0.53 before the crossings were checked on the
    full-resolution white mask where the grid does not resolve them, with short stems at line
    ends for the far goal area's side line), 0.01 wrong. The misses left: a side line too
    short or faint even there (most of them beyond 2.7 m), T's hidden on one side by a goal
    post, crossings at the image's edge whose type the view cannot tell. The floors here
    guard what is reached."""
    assert figures["crossings in image"] >= 200
    assert figures["crossings wrong type"] <= 0.02, figures
    assert figures["crossings right"] >= 0.75, figures


def test_few_false_lines(figures):
    """Extracted lines farther than 30 cm from every labelled line and every line of the SPL
    field placed at the labelled goal area: a share the issue asks to report (0.08 of the
    used lines, 0.10 before the field's edge against a bright hall floor was told from a
    line; goal posts, robots and balls, the hall's own floor markings near the field edge,
    and the labels' goal-area placement off by the camera matrices' few degrees)."""
    assert figures["used lines"] >= 400
    assert figures["false share (used lines)"] <= 0.15, figures


def test_goal_posts_are_found_where_the_labels_put_them(figures):
    """Posts where the labelled goal area puts them, found within 3 deg of bearing: 0.38 of
    those whose foot is in the image (posts against the hall's white floor or walls, or cut by
    the image's edge, are missed). The floor guards what is reached."""
    assert figures["posts in image"] >= 100
    assert figures["post recall"] >= 0.3, figures
