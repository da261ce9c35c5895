"""Synthetic perspective observations and walks, generated from a field model at known poses.

What a forward-looking humanoid camera would report through ``extract`` (lines, crossings, goal
posts in the robot frame, see stages.common.observations), made directly from the field
geometry: for tests of the particle filter, for the bench, and for measuring the filter apart
from the image pipeline. The errors follow a head camera at ``camera_height``: one pitch and
roll error per frame shifts all floor points coherently (far points much more than near ones),
plus independent noise per point; some features are missed; false lines, crossings and posts
appear with lower confidence; L/T types are sometimes confused.

    obs = synthetic_observations(field_model, pose, rng)
    truth, odometry = synthetic_walk(field_model, 300, seed=1)
"""

from __future__ import annotations

import math

import numpy as np

from stages.common.field import FieldModel
from stages.common.geometry import field_to_robot
from stages.common.observations import CROSSING_CODES, Observations

DEFAULTS = {
    "fov": math.radians(80.0),  # rad, horizontal field of view, centred on the heading
    "camera_height": 0.5,  # m
    "min_range": 0.3,  # m, nearest visible floor (below the lower image edge)
    "max_range": 5.0,  # m, lines farther away are not extracted
    "crossing_max_range": 4.0,  # m
    "post_max_range": 6.0,  # m
    "pitch_noise": 0.01,  # rad, per-frame camera pitch error (shared by all points)
    "roll_noise": 0.01,  # rad, per-frame roll error (lateral shift growing with distance)
    "point_noise": 0.02,  # m, independent noise per point at 1 m (grows linearly)
    "bearing_noise": 0.01,  # rad, independent
    "orientation_noise": 0.08,  # rad, crossing orientation
    "p_miss_line": 0.1,
    "p_miss_crossing": 0.25,
    "p_miss_post": 0.2,
    "false_lines": 0.2,  # expected number per frame
    "false_crossings": 0.15,
    "false_posts": 0.05,
    "p_type_confusion": 0.05,  # an L reported as T or the other way round
    "min_line_length": 0.3,  # m
    "arc_chord": math.radians(40.0),  # rad, arcs are reported as chords of this angle
    "sample_step": 0.02,  # m, visibility sampling along lines
}


def _visible(pts_robot: np.ndarray, c: dict, max_range: float) -> np.ndarray:
    d = np.hypot(pts_robot[:, 0], pts_robot[:, 1])
    b = np.arctan2(pts_robot[:, 1], pts_robot[:, 0])
    return (d >= c["min_range"]) & (d <= max_range) & (np.abs(b) <= c["fov"] / 2)


def _runs(mask: np.ndarray):
    """(start, stop) index pairs of the True runs of ``mask`` (stop inclusive)."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


def _perspective_error(pts: np.ndarray, pitch_err: float, roll_err: float, c: dict,
                       rng: np.random.Generator) -> np.ndarray:
    """Floor points (K, 2) in the robot frame as a camera with the given pitch and roll error
    would project them, plus independent noise."""
    if not len(pts):
        return pts
    h = c["camera_height"]
    d = np.hypot(pts[:, 0], pts[:, 1])
    b = np.arctan2(pts[:, 1], pts[:, 0])
    depression = np.arctan2(h, d) + pitch_err
    d_new = h / np.tan(np.maximum(depression, math.radians(1.0)))
    b_new = b + rng.normal(0.0, c["bearing_noise"], len(pts))
    d_new = d_new + rng.normal(0.0, 1.0, len(pts)) * c["point_noise"] * np.maximum(d, 0.3)
    out = np.stack([d_new * np.cos(b_new), d_new * np.sin(b_new)], axis=1)
    # roll tilts the floor sideways: a lateral shift that grows with distance
    out[:, 1] += roll_err * d_new
    return out


def _line_row(p0: np.ndarray, p1: np.ndarray, confidence: float):
    """[r, perpendicular angle, length, confidence] and end points of a floor segment."""
    d = p1 - p0
    length = float(np.hypot(*d))
    t = d / max(length, 1e-12)
    n = np.array([-t[1], t[0]])
    r = float(n @ p0)
    if r < 0:
        n, r = -n, -r
    return [r, math.atan2(n[1], n[0]), length, confidence], [*p0, *p1]


def synthetic_observations(field_model: FieldModel, pose, rng: np.random.Generator,
                           conf: dict | None = None) -> Observations:
    """What a forward-looking camera at ``pose`` (x, y, theta) reports, with noise, misses and
    false detections drawn from ``rng``."""
    c = dict(DEFAULTS, **(conf or {}))
    unknown = set(c) - set(DEFAULTS)
    if unknown:
        raise KeyError(f"unknown synthetic-observation keys: {sorted(unknown)}")
    fm = field_model
    pose = np.asarray(pose, float)
    pitch_err = rng.normal(0.0, c["pitch_noise"])
    roll_err = rng.normal(0.0, c["roll_noise"])
    lines, ends = [], []

    def add_piece(pr0, pr1, conf_):
        q = _perspective_error(np.array([pr0, pr1]), pitch_err, roll_err, c, rng)
        if np.hypot(*(q[1] - q[0])) < c["min_line_length"]:
            return
        row, e = _line_row(q[0], q[1], conf_)
        lines.append(row)
        ends.append(e)

    step = c["sample_step"]
    for a, b in np.asarray(fm.segments, float):
        n = max(int(np.hypot(*(b - a)) / step), 2)
        pts = field_to_robot(pose, a + np.linspace(0, 1, n + 1)[:, None] * (b - a))
        for i0, i1 in _runs(_visible(pts, c, c["max_range"])):
            if rng.random() < c["p_miss_line"]:
                continue
            add_piece(pts[i0], pts[i1], rng.uniform(0.6, 1.0))
    for cx, cy, r, a0, sweep in np.asarray(fm.arcs, float):
        n = max(int(r * sweep / step), 8)
        phi = a0 + np.linspace(0, sweep, n + 1)
        pts = field_to_robot(pose, np.stack([cx + r * np.cos(phi), cy + r * np.sin(phi)], 1))
        for i0, i1 in _runs(_visible(pts, c, c["max_range"])):
            span = phi[i1] - phi[i0]
            pieces = max(int(math.ceil(span / c["arc_chord"] - 1e-9)), 1)
            cuts = np.linspace(i0, i1, pieces + 1).round().astype(int)
            for k0, k1 in zip(cuts[:-1], cuts[1:]):
                if rng.random() < c["p_miss_line"]:
                    continue
                add_piece(pts[k0], pts[k1], rng.uniform(0.5, 0.9))
    # false lines: random short segments in view
    for _ in range(rng.poisson(c["false_lines"])):
        d = rng.uniform(c["min_range"], c["max_range"] * 0.7)
        b = rng.uniform(-c["fov"] / 2, c["fov"] / 2)
        ang = rng.uniform(0, math.pi)
        ln = rng.uniform(c["min_line_length"], 1.0)
        mid = np.array([d * math.cos(b), d * math.sin(b)])
        half = 0.5 * ln * np.array([math.cos(ang), math.sin(ang)])
        row, e = _line_row(mid - half, mid + half, rng.uniform(0.2, 0.7))
        lines.append(row)
        ends.append(e)

    crossings = []
    cr = field_to_robot(pose, fm.crossings) if len(fm.crossings) else np.zeros((0, 2))
    vis = _visible(cr, c, c["crossing_max_range"]) if len(cr) else np.zeros(0, bool)
    for k in np.flatnonzero(vis):
        if rng.random() < c["p_miss_crossing"]:
            continue
        q = _perspective_error(cr[k:k + 1], pitch_err, roll_err, c, rng)[0]
        kind = str(fm.crossing_types[k])
        if kind in ("L", "T") and rng.random() < c["p_type_confusion"]:
            kind = "T" if kind == "L" else "L"
        orient = fm.crossing_orientation[k] - pose[2] + rng.normal(0, c["orientation_noise"])
        if kind == "X":
            orient = float(np.mod(orient, math.pi / 2))
        else:
            orient = math.remainder(orient, 2 * math.pi)
        crossings.append([CROSSING_CODES[kind], math.hypot(*q), math.atan2(q[1], q[0]),
                          orient, rng.uniform(0.6, 1.0)])
    for _ in range(rng.poisson(c["false_crossings"])):
        kind = int(rng.integers(0, 3))
        orient = rng.uniform(-math.pi, math.pi)
        if kind == 2:
            orient = float(np.mod(orient, math.pi / 2))
        crossings.append([kind, rng.uniform(c["min_range"], c["crossing_max_range"]),
                          rng.uniform(-c["fov"] / 2, c["fov"] / 2), orient,
                          rng.uniform(0.2, 0.7)])

    posts = []
    pr = field_to_robot(pose, fm.goal_posts) if len(fm.goal_posts) else np.zeros((0, 2))
    vis = _visible(pr, c, c["post_max_range"]) if len(pr) else np.zeros(0, bool)
    for k in np.flatnonzero(vis):
        if rng.random() < c["p_miss_post"]:
            continue
        q = _perspective_error(pr[k:k + 1], pitch_err, roll_err, c, rng)[0]
        posts.append([math.hypot(*q), math.atan2(q[1], q[0]), rng.uniform(0.6, 1.0)])
    for _ in range(rng.poisson(c["false_posts"])):
        posts.append([rng.uniform(c["min_range"], c["post_max_range"]),
                      rng.uniform(-c["fov"] / 2, c["fov"] / 2), rng.uniform(0.2, 0.6)])

    return Observations(
        np.asarray(lines, float).reshape(-1, 4),
        np.asarray(ends, float).reshape(-1, 4),
        np.asarray(crossings, float).reshape(-1, 5),
        np.asarray(posts, float).reshape(-1, 3),
    )


def sector_view(conf: dict | None = None, arc_points: int = 13) -> np.ndarray:
    """The floor the synthetic camera sees (the sector ``fov`` wide from ``min_range`` to
    ``max_range``), as the polygon (V, 2) extract writes as a frame's ``view``. Not attached
    to the synthetic observations: the filter's tests on them run without the unseen term;
    the bench's update times it with this view."""
    c = dict(DEFAULTS, **(conf or {}))
    a = np.linspace(-c["fov"] / 2, c["fov"] / 2, arc_points)
    near = np.column_stack([c["min_range"] * np.cos(a), c["min_range"] * np.sin(a)])
    far = np.column_stack([c["max_range"] * np.cos(a[::-1]), c["max_range"] * np.sin(a[::-1])])
    return np.concatenate([near, far])


def initial_placement_pose(field_model: FieldModel, rng: np.random.Generator) -> np.ndarray:
    """A pose where robots enter the field: own half (x < 0), on a touch line, facing in."""
    fm = field_model
    side = 1.0 if rng.random() < 0.5 else -1.0  # +1: left touch line (y > 0)
    x = rng.uniform(-fm.length / 2 + 0.5, -0.5)
    return fm.touchline_pose(x, side)


def synthetic_walk(field_model: FieldModel, n_frames: int, *, seed: int = 0,
                   rate_hz: float = 10.0, speed: float = 0.2, start=None,
                   odometry_noise: float = 0.05, odometry_bias: float = 0.05):
    """A walk over the field at about ``speed`` m/s towards random waypoints, turning on the
    way (with some sidestep). Returns (truth (F, 3), odometry (F, 3), stamps (F,)): the true
    poses, and per frame the odometry increment since the previous frame (robot frame, zeros
    in the first row) with a per-walk scale bias (``odometry_bias``, relative) and noise
    (``odometry_noise``, relative to the step plus a floor). ``start``: a pose, or None for an
    initial placement at a touch line."""
    fm = field_model
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    pose = initial_placement_pose(fm, rng) if start is None else np.asarray(start, float)
    hx, hy = fm.length / 2 - 0.5, fm.width / 2 - 0.5

    def waypoint():
        return np.array([rng.uniform(-hx, hx), rng.uniform(-hy, hy)])

    goal = waypoint()
    bias = 1.0 + rng.normal(0.0, odometry_bias, 3)
    truth = np.zeros((n_frames, 3))
    odom = np.zeros((n_frames, 3))
    max_turn = 0.6 * dt  # rad per frame
    for f in range(n_frames):
        if f > 0:
            v = goal - pose[:2]
            if np.hypot(*v) < 0.3:
                goal = waypoint()
                v = goal - pose[:2]
            want = math.remainder(math.atan2(v[1], v[0]) - pose[2], 2 * math.pi)
            dth = float(np.clip(want, -max_turn, max_turn))
            fwd = speed * dt * max(math.cos(want), 0.2)
            side = 0.2 * speed * dt * math.sin(want)
            step = np.array([fwd, side, dth]) + rng.normal(0, 1, 3) * [0.002, 0.002, 0.005]
            c, s = math.cos(pose[2]), math.sin(pose[2])
            pose = np.array([pose[0] + c * step[0] - s * step[1],
                             pose[1] + s * step[0] + c * step[1],
                             math.remainder(pose[2] + step[2], 2 * math.pi)])
            noise = rng.normal(0, 1, 3) * (odometry_noise * np.abs(step) + [0.002, 0.002, 0.004])
            odom[f] = step * bias + noise
        truth[f] = pose
    stamps = np.arange(n_frames) * dt
    return truth, odom, stamps


def write_synthetic_run(field_model: FieldModel, out_dir, n_frames: int, *, seed: int = 0,
                        rate_hz: float = 10.0, observation_conf: dict | None = None,
                        walk: dict | None = None):
    """A dataset folder without images for the particle filter: ``truth.csv`` and
    ``odometry.csv`` of a ``synthetic_walk`` and ``features.h5`` (camera kind perspective)
    with ``synthetic_observations`` per frame. Frames are named f000000, ... Returns the path
    of the features file. The features file records in its attributes that it is synthetic."""
    import json
    from pathlib import Path

    from stages.common.artifacts import root_attrs
    from stages.common.dataset import write_csv
    from stages.common.features_file import SCHEMA, VERSION, write_features

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    truth, odom, stamps = synthetic_walk(field_model, n_frames, seed=seed, rate_hz=rate_hz,
                                         **(walk or {}))
    write_csv(out / "truth.csv", "truth",
              {"stamp": stamps, "x": truth[:, 0], "y": truth[:, 1], "theta": truth[:, 2]})
    write_csv(out / "odometry.csv", "odometry",
              {"stamp": stamps, "dx": odom[:, 0], "dy": odom[:, 1], "dtheta": odom[:, 2]})
    conf = dict(DEFAULTS, **(observation_conf or {}))
    attrs = root_attrs(SCHEMA, VERSION, conf={"synthetic_observations": conf, "seed": seed},
                       inputs={"field": field_model.name})
    attrs.update(camera_kind="perspective", dataset=str(out), calib_hash="",
                 synthetic=json.dumps({"generator": __name__, "seed": seed}))
    rng = np.random.default_rng(seed + 1)
    path = out / "features.h5"
    with write_features(path, attrs) as w:
        for i in range(n_frames):
            obs = synthetic_observations(field_model, truth[i], rng, observation_conf)
            w.add_frame(f"f{i:06d}", float(stamps[i]), obs.to_features())
    return path
