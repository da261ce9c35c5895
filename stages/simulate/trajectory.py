"""Smooth, seeded robot trajectories on the field: poses (x, y, theta) at a fixed frame rate.

The path follows waypoints with a speed-limited, acceleration-limited and curvature-limited
controller (lateral acceleration bounds the turn rate at speed), integrated in sub-steps between
frames, so speed and heading change smoothly. The robot stays ``margin`` metres inside the field
lines: near the boundary it slows down to ``speed_min`` (which shrinks its turn radius) and turns
towards its waypoint, which always lies well inside.

The heading either follows the direction of travel (``heading: along``, a walking humanoid or a
differential drive), or turns on its own towards random targets (``heading: free``, an
omnidirectional MSL robot). Every number is a conf value, so the same generator drives a fast
MSL robot (0.2-2 m/s) or a slow humanoid (e.g. 0.05-0.3 m/s, ``heading: along``).

Kinds: ``random`` (random waypoints inside the field), ``loop`` (the same controller around a fixed
ring of waypoints, a repeatable tour of the field), ``grid`` (no path: the robot placed at the
nodes of a square grid, each at ``grid_headings`` headings, as the SURF template paper takes
its template captures; ``grid_poses``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..common.conf import PAIR
from ..common.errors import FieldlocError, shown
from ..common.geometry import wrap_angle

PATH_KINDS = ("random", "loop")  # a path driven by the controller
KINDS = (*PATH_KINDS, "grid")

# The conf keys a trajectory needs (stage presets carry them under "trajectory").
DEFAULTS = {
    "kind": "random",
    "speed_min": 0.2,  # m/s
    "speed_max": 2.0,  # m/s
    "accel_max": 1.5,  # m/s^2, along the path
    "lateral_accel_max": 2.0,  # m/s^2: turn rate <= lateral_accel_max / speed
    "turn_rate_max": 3.0,  # rad/s: how fast the direction of travel may turn
    "heading": "free",  # free | along
    "yaw_rate_max": 2.0,  # rad/s (free heading)
    "yaw_accel_max": 4.0,  # rad/s^2 (free heading)
    "heading_hold": [2.0, 6.0],  # s between new heading targets (free heading)
    "margin": 0.3,  # m: the robot centre stays this far inside the field lines
    "waypoint_margin": 0.8,  # m: waypoints lie this far inside the margin box
    "start": None,  # [x, y, theta] or None (random, seeded)
    "substeps": 10,  # integration steps per frame
    # kind grid: nodes at multiples of grid_spacing (m) on the field (inside its lines), each at
    # grid_headings headings 360 / grid_headings deg apart from grid_heading (rad); with
    # grid_centre [x, y] and grid_half_size (m) only the nodes of that square, spaced from its
    # centre
    "grid_spacing": 1.0,
    "grid_headings": 1,
    "grid_heading": 0.0,
    "grid_centre": None,
    "grid_half_size": None,
}

# the ranges of the list-valued keys (common.conf.check_bounds): ``start`` (None, "touchline"
# or [x, y, theta]) and ``grid_centre`` are held by simulate's check_conf
BOUNDS = {"heading_hold": ((0,), None, PAIR)}  # s, a range drawn from


@dataclass
class Trajectory:
    stamps: np.ndarray  # (N,) s
    poses: np.ndarray  # (N, 3) x, y, theta (field frame)

    @property
    def speeds(self) -> np.ndarray:
        """Speed (m/s) between consecutive frames, (N-1,)."""
        dt = np.diff(self.stamps)
        return np.hypot(*np.diff(self.poses[:, :2], axis=0).T) / dt

    @property
    def length(self) -> float:
        return float(np.hypot(*np.diff(self.poses[:, :2], axis=0).T).sum())


def _check(conf: dict, box: tuple[float, float]):
    c = {**DEFAULTS, **conf}
    if c["kind"] not in KINDS:
        raise FieldlocError(f"unknown trajectory '{c['kind']}' (choose from {', '.join(KINDS)})")
    if c["heading"] not in ("free", "along"):
        raise FieldlocError(f"trajectory heading must be 'free' or 'along', got {c['heading']!r}")
    if not 0 < c["speed_min"] <= c["speed_max"]:
        raise FieldlocError(
            f"trajectory speeds need 0 < speed_min <= speed_max, got {c['speed_min']},"
            f" {c['speed_max']}"
        )
    if box[0] <= 0 or box[1] <= 0:
        raise FieldlocError(
            f"trajectory margin {c['margin']} m leaves no room on the field"
        )
    if c["start"] is not None:
        s = c["start"]
        if len(s) != 3:
            raise FieldlocError(f"trajectory start must be [x, y, theta], got {shown(s, 40)}")
        if abs(s[0]) > box[0] or abs(s[1]) > box[1]:
            raise FieldlocError(
                f"trajectory start ({s[0]}, {s[1]}) is not on the field (|x| <= {box[0]:.2f},"
                f" |y| <= {box[1]:.2f} m with the margin)"
            )
    return c


def grid_count(field, conf: dict) -> int:
    """The number of poses of kind ``grid`` (``grid_poses``), counted without making them: a
    grid of millions of headings is refused by its memory estimate (simulate's
    ``estimate_needs``), not by the memory it would take to list it."""
    xs, ys, n_head, _ = _grid_axes(field, conf)
    return len(xs) * len(ys) * n_head


def grid_poses(field, conf: dict) -> np.ndarray:
    """The poses (N, 3) of kind ``grid`` (module doc): nodes in rows of increasing y, x
    increasing within a row, all headings of a node in a row, headings counter-clockwise."""
    xs, ys, n_head, heading = _grid_axes(field, conf)
    th = wrap_angle(heading + 2 * math.pi * np.arange(n_head) / n_head)
    gy, gx, gt = np.meshgrid(ys, xs, th, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.asarray(gt, float).ravel()], axis=1)


# the most nodes of a grid along one axis: a million, a node every 0.02 mm of the largest
# field; more would only come from a grid_spacing that is a mistake, and listing them would
# take the memory the run's estimate is there to refuse
MAX_GRID_NODES_PER_AXIS = 1_000_000


def _grid_axes(field, conf: dict) -> tuple[np.ndarray, np.ndarray, int, float]:
    """(node x values, node y values, number of headings, first heading) of kind ``grid``."""
    c = {**DEFAULTS, **conf}
    try:
        spacing = float(c["grid_spacing"])
        n_head = int(c["grid_headings"])
        heading = float(c["grid_heading"])
    except (TypeError, ValueError) as e:
        raise FieldlocError(f"trajectory grid: malformed value ({e})") from None
    if not (spacing > 0 and math.isfinite(spacing)) or n_head < 1 or not math.isfinite(heading):
        raise FieldlocError(f"trajectory grid needs grid_spacing > 0 and grid_headings >= 1, got"
                            f" {c['grid_spacing']!r} and {c['grid_headings']!r}")
    hx, hy = field.length / 2, field.width / 2
    if c["grid_centre"] is None:
        cx = cy = 0.0
        ax, ay = hx, hy
    else:
        try:
            cx, cy = (float(v) for v in c["grid_centre"])
            half = float(c["grid_half_size"]) if c["grid_half_size"] is not None else max(hx, hy)
        except (TypeError, ValueError):
            raise FieldlocError("trajectory grid_centre must be [x, y] and grid_half_size a"
                                " number of metres") from None
        ax = ay = half
    eps = 1e-9 * max(1.0, hx, hy)

    def axis(c0, a, lim):
        # nodes farther than |c0| + lim from the centre are off the field: not listed
        reach = min(a, abs(c0) + lim + spacing) / spacing + 1e-9  # inf for a spacing of 1e-308
        k_max = math.floor(min(reach, MAX_GRID_NODES_PER_AXIS))
        if 2 * k_max + 1 > MAX_GRID_NODES_PER_AXIS:
            raise FieldlocError(f"trajectory grid: grid_spacing {spacing:g} m makes more than"
                                f" {MAX_GRID_NODES_PER_AXIS} nodes along one side")
        k = np.arange(-k_max, k_max + 1)
        v = c0 + k * spacing
        return v[np.abs(v) <= lim + eps]

    xs, ys = axis(cx, ax, hx), axis(cy, ay, hy)
    if not len(xs) or not len(ys):
        raise FieldlocError(f"trajectory grid: no node of the grid around ({cx:g}, {cy:g}) lies"
                            f" on the field ({field.length:g} x {field.width:g} m)")
    return xs, ys, n_head, heading


def generate(field, n_frames: int, rate_hz: float, conf: dict, rng: np.random.Generator,
             ) -> Trajectory:
    """A trajectory of ``n_frames`` poses at ``rate_hz`` on ``field`` (a FieldModel)."""
    if n_frames < 1:
        raise FieldlocError(f"need at least one frame, got {n_frames}")
    if rate_hz <= 0:
        raise FieldlocError(f"frame rate must be > 0, got {rate_hz}")
    margin = float({**DEFAULTS, **conf}["margin"])
    box = (field.length / 2 - margin, field.width / 2 - margin)
    c = _check(conf, box)
    if c["kind"] == "grid":  # placements, no path: n_frames is the grid's
        poses = grid_poses(field, c)
        return Trajectory(stamps=np.arange(len(poses)) / rate_hz, poses=poses)
    vmin, vmax = float(c["speed_min"]), float(c["speed_max"])
    a_max, a_lat = float(c["accel_max"]), float(c["lateral_accel_max"])
    w_max = float(c["turn_rate_max"])
    wm = float(c["waypoint_margin"])
    wbox = (max(box[0] - wm, 0.25 * box[0]), max(box[1] - wm, 0.25 * box[1]))
    sub = max(1, int(c["substeps"]))
    dt = 1.0 / (rate_hz * sub)

    def new_waypoint():
        return tuple(float(a) for a in rng.uniform((-wbox[0], -wbox[1]), (wbox[0], wbox[1])))

    loop = None
    if c["kind"] == "loop":
        ang = np.linspace(0, 2 * np.pi, 8, endpoint=False) + np.pi / 8
        loop = np.stack([wbox[0] * np.cos(ang), wbox[1] * np.sin(ang)], axis=1)
        loop_i = int(rng.integers(len(loop)))

    if c["start"] is not None:
        px, py, theta = (float(a) for a in c["start"])
    else:
        px, py = (float(a) for a in rng.uniform((-wbox[0], -wbox[1]), (wbox[0], wbox[1])))
        theta = float(rng.uniform(-np.pi, np.pi))
    wx, wy = loop[loop_i] if loop is not None else new_waypoint()
    travel = math.atan2(wy - py, wx - px)
    if c["heading"] == "along":
        if c["start"] is not None:
            travel = theta  # set off along the given heading, then turn smoothly
        theta = travel
    v = min(vmin * 1.01, vmax)
    v_target = float(rng.uniform(vmin, vmax))
    yaw_rate = 0.0
    ymax, yacc = float(c["yaw_rate_max"]), float(c["yaw_accel_max"])
    hold = c["heading_hold"]
    heading_target = theta
    next_heading_change = float(rng.uniform(*hold))
    t = 0.0

    poses = np.empty((n_frames, 3))
    poses[0] = (px, py, theta)
    for i in range(1, n_frames):
        for _ in range(sub):
            t += dt
            if math.hypot(wx - px, wy - py) < max(0.4, v * v / a_lat):
                if loop is not None:
                    loop_i = (loop_i + 1) % len(loop)
                    wx, wy = loop[loop_i]
                else:
                    wx, wy = new_waypoint()
                v_target = float(rng.uniform(vmin, vmax))
            turn = float(wrap_angle(math.atan2(wy - py, wx - px) - travel))
            # near the boundary: slow down so that the turn radius shrinks
            look = v * v / (2 * a_max) + v * v / a_lat + 0.2
            ax, ay = px + look * math.cos(travel), py + look * math.sin(travel)
            v_des = v_target * max(math.cos(turn), 0.0)
            if abs(ax) > box[0] or abs(ay) > box[1]:
                v_des = vmin
            # the floor keeps the chord between frames (what a speed check measures) >= vmin
            v_des = min(max(v_des, vmin * 1.01), vmax)
            v += min(max(v_des - v, -a_max * dt), a_max * dt)
            w_step = min(a_lat / max(v, 1e-3), w_max) * dt
            travel = float(wrap_angle(travel + min(max(turn, -w_step), w_step)))
            px += v * dt * math.cos(travel)
            py += v * dt * math.sin(travel)
            # last resort, not reached with sane limits: slide along the margin box
            px = min(max(px, -box[0]), box[0])
            py = min(max(py, -box[1]), box[1])
            if c["heading"] == "along":
                theta = travel
            else:
                if t >= next_heading_change:
                    heading_target = float(rng.uniform(-np.pi, np.pi))
                    next_heading_change = t + float(rng.uniform(*hold))
                err = float(wrap_angle(heading_target - theta))
                # the rate that stops at the target under the yaw acceleration limit
                want = math.copysign(min(ymax, math.sqrt(2 * yacc * abs(err))), err)
                yaw_rate += min(max(want - yaw_rate, -yacc * dt), yacc * dt)
                theta = float(wrap_angle(theta + yaw_rate * dt))
        poses[i] = (px, py, theta)
    stamps = np.arange(n_frames) / rate_hz
    return Trajectory(stamps=stamps, poses=poses)
