"""The simulated world, independent of any camera: what an omnidirectional or a perspective
renderer looks at.

- Ground: a colour texture fixed in the world (carpet with seeded noise at several scales,
  mowing stripes, hue patches and the light of ceiling lamps; a grey floor beyond the carpet)
  holding the clutter lying on the floor (cables, sticks, paper, tape), and a line field: the
  distance to the nearest line centre line (``FieldModel.distance_to_lines``, plus the penalty
  marks), the line's orientation, and the paint strength (uneven brightness, worn patches,
  ragged edges). Renderers draw lines of ``field.line_width`` from the line field with the
  coverage of their pixel footprint, so far lines fade instead of aliasing.
- Upright things as vertical cylinders and panels: goals (posts, crossbar, nets), other robots
  (dark bodies with team-colour markers, moving on their own trajectories), people (legs, shoes,
  body; walking slowly on the field), a ball; walls around the hall with audience, furniture and
  lamps on them.
- Lighting over time: a gain and a white balance per frame (lamps, daylight, auto exposure).

All of it is drawn from one seed, or two: ``world_seed`` (the venue: carpet, paint, sun patches,
walls) apart from ``seed`` (a session in it: the clutter lying about, the movers, the lighting
over time), so that two sessions recorded in one lab see the same floor; by default both are
``seed``. Texture coordinates: column = (x - x0) / res, row =
(y - y0) / res over the world rectangle inside the walls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..common.conf import PAIR
from ..common.fixed_remap import remap_linear
from . import trajectory

LINE_LIGHT_RES = 0.1  # m per texel of the paint brightness
LINE_FIELD_CAP = 1.0  # m: the line field holds distances up to this

SCENE_DEFAULTS = {
    "texture_resolution": 0.01,  # m per texel of the ground colour
    "line_resolution": 0.02,  # m per texel of the line field
    "wall_gap": 1.5,  # m between the carpet edge (field + border) and the walls
    "wall_height": 3.0,  # m
    "goal_height": 1.0,  # m
    "carpet_bgr": [56, 132, 60],
    "carpet_variation": 0.10,  # relative brightness, low frequency (metres)
    "carpet_hue_variation": 0.1,  # relative blue/red shift, low frequency
    "carpet_grain": 0.05,  # relative, per texel
    "stripe_width": 1.0,  # m, mowing stripes across the field length
    "stripe_contrast": 0.05,
    "floor_bgr": [92, 98, 102],
    "line_bgr": [244, 242, 250],
    "line_brightness": [0.82, 1.0],  # paint brightness range along the lines
    "line_wear": 0.4,  # strength of worn patches (0: none, 1: paint gone in patches)
    "line_edge_noise": 0.004,  # m, raggedness of the paint edges
    "lamp_spacing": 4.5,  # m between ceiling lamps
    "lamp_contrast": 0.25,  # relative illumination swing between under and between lamps
    "robots": 4,  # other robots on the field
    "robot_speed": [0.2, 1.5],
    "robot_radius": 0.25,
    "robot_height": 0.8,
    "people": 1,  # people walking about the field (legs, shoes, body)
    "person_speed": [0.2, 0.6],
    "handlers": 1,  # people walking along with the recording robot, as in a lab
    "handler_distance": [0.8, 2.5],  # m from the robot
    "balls": 1,
    "cables": 4,  # cables lying on the carpet (some white)
    "sticks": 3,  # sticks and poles lying on the carpet
    "papers": 2,  # white sheets
    "tapes": 6,  # tape marks
    "audience": 80,  # people standing along the walls
    # additions for hall lighting and SPL-like movers (their defaults leave the world as
    # before; the perspective-nao preset sets them)
    "sun_patches": 0,  # patches of sunlight on the floor (through high windows)
    "sun_strength": [0.5, 1.2],  # relative extra light in a patch
    "shadows": 0,  # soft shadow bands across the floor (beams, people, the goal)
    "shadow_strength": [0.25, 0.5],  # relative light lost in a band
    "line_width_variation": 0.0,  # relative change of the painted width along the lines
    "ball_bgr": [30, 110, 235],  # the ball's colour (an SPL ball is white)
    "robot_style": "cylinder",  # "cylinder": dark bodies; "nao": white legs, grey torso
    "lighting": {
        "gain": [0.5, 1.6],  # range of the overall light level over time
        "periods": [3.0, 25.0],  # s, periods of its variation
        "colour_temperature": 0.18,  # +-relative blue/red swing
        "tint": 0.12,  # +-relative green/magenta swing
    },
}


# the ranges of the list-valued keys (common.conf.check_bounds, held where simulate's conf is
# resolved): colours are 8-bit BGR triplets; a range drawn from is an ordered pair [low, high]
BGR = (0, 255, 3)
# relative paint brightness: 0 paints black lines; at 2 any paint colour is clipped white
MAX_LINE_BRIGHTNESS = 2.0
# m/s: faster than any robot or person on a field (MSL robots reach about 4 m/s); a mover at
# 1e12 m/s leaves the field between two frames
MAX_MOVER_SPEED = 10.0
# m: a handler walks along within a few metres; at 10 m they would stand outside a hall's field
MAX_HANDLER_DISTANCE = 10.0
# relative light: a sun patch 10 times the hall's light, or a gain of 10, saturates every pixel
MAX_RELATIVE_LIGHT = 10.0
BOUNDS = {
    "carpet_bgr": BGR, "floor_bgr": BGR, "line_bgr": BGR, "ball_bgr": BGR,
    "line_brightness": ((0,), MAX_LINE_BRIGHTNESS, PAIR),
    "robot_speed": ((0,), MAX_MOVER_SPEED, PAIR),
    "person_speed": ((0,), MAX_MOVER_SPEED, PAIR),
    "handler_distance": ((0,), MAX_HANDLER_DISTANCE, PAIR),
    "sun_strength": (0, MAX_RELATIVE_LIGHT, PAIR),
    "shadow_strength": (0, 1, PAIR),  # the share of the light a band takes
    "lighting.gain": ((0,), MAX_RELATIVE_LIGHT, PAIR),  # its logarithm is drawn from
    "lighting.periods": ((0,), None, PAIR),  # s
}


@dataclass
class Cylinder:
    """An upright cylinder: centre (x, y), radius, height span z0..z1 (m), colour BGR (0..255)."""

    x: float
    y: float
    radius: float
    z0: float
    z1: float
    bgr: tuple
    kind: str = "body"  # body | post | ball | marker


@dataclass
class Panel:
    """An upright rectangle over the ground segment p0-p1, z0..z1, colour BGR, opacity; a net
    pattern makes it a mesh (opacity on the strings, see-through between)."""

    p0: tuple
    p1: tuple
    z0: float
    z1: float
    bgr: tuple
    alpha: float = 1.0
    net: bool = False


@dataclass
class FieldScene:
    field: object
    conf: dict
    walls: tuple  # (x0, x1, y0, y1) inside faces of the walls
    albedo: np.ndarray  # (H, W, 3) uint8 BGR over the walls' rectangle
    albedo_res: float
    line_field: np.ndarray  # (H2, W2, 4) float32: distance, cos 2phi, sin 2phi, paint cover
    line_origin: tuple  # (x, y) of texel (0, 0) of the line field
    line_res: float
    line_light: np.ndarray  # (H3, W3) float32: paint brightness x lamps, same origin
    line_light_res: float
    wall_texture: np.ndarray  # (rows = z / res, cols = s / res, 3) uint8 BGR
    wall_res: float
    panels: list  # static Panel objects (goals)
    posts: list  # static Cylinder objects (goal posts)
    tracks: dict = field(default_factory=dict)  # mover kind -> (K, N, 3) poses
    gain: np.ndarray = None  # (N,) light level per frame
    white_balance: np.ndarray = None  # (N, 3) BGR multipliers per frame

    @property
    def perimeter(self) -> float:
        x0, x1, y0, y1 = self.walls
        return 2 * ((x1 - x0) + (y1 - y0))

    def movers_at(self, frame: int) -> list[list[Cylinder]]:
        """The moving things at ``frame``, each as a list of cylinders (drawn in order)."""
        out = []
        c = self.conf
        for k, pose in enumerate(self.tracks.get("robots", np.zeros((0, 1, 3)))[:, frame]):
            x, y, th = pose
            team = (200, 170, 40) if k % 2 else (170, 60, 200)  # cyan / magenta markers (BGR)
            r, h = c["robot_radius"], c["robot_height"]
            if c.get("robot_style", "cylinder") == "nao":
                out.append(nao_robot(x, y, th, r, h, team, frame + 3 * k))
                continue
            out.append([
                Cylinder(x, y, r, 0.0, h, (34, 34, 38), "body"),
                Cylinder(x, y, r + 0.004, 0.55 * h, 0.72 * h, team, "marker"),
            ])
        for k, pose in enumerate(self.tracks.get("people", np.zeros((0, 1, 3)))[:, frame]):
            x, y, th = pose
            side = np.array([-math.sin(th), math.cos(th)]) * 0.11
            # a slow gait: feet move back and forth along the heading
            step = 0.12 * math.sin(frame * 0.9 + k) * np.array([math.cos(th), math.sin(th)])
            trousers = (40 + 15 * (k % 3), 32, 30)
            shoes = (235, 235, 235) if k % 2 == 0 else (40, 40, 45)
            shirt = ((60, 60, 170), (150, 90, 40), (70, 70, 70))[k % 3]
            parts = []
            for sgn in (-1.0, 1.0):
                fx, fy = np.array([x, y]) + sgn * side + sgn * step
                parts.append(Cylinder(fx, fy, 0.065, 0.0, 0.85, trousers, "body"))
                parts.append(Cylinder(fx, fy, 0.075, 0.0, 0.09, shoes, "body"))
            parts.append(Cylinder(x, y, 0.18, 0.85, 1.55, shirt, "body"))
            out.append(parts)
        ball = tuple(c.get("ball_bgr", (30, 110, 235)))
        for pose in self.tracks.get("balls", np.zeros((0, 1, 3)))[:, frame]:
            out.append([Cylinder(pose[0], pose[1], 0.11, 0.0, 0.22, ball, "ball")])
        return out

    def robot_positions(self) -> np.ndarray:
        """(K, N, 2) positions of the other robots over the frames."""
        return self.tracks.get("robots", np.zeros((0, 0, 3)))[..., :2]


def nao_robot(x, y, theta, radius, height, team, phase) -> list[Cylinder]:
    """A standing or walking NAO as cylinders: two white legs with grey knees and feet, a
    grey-white torso with a team-coloured jersey, white arms, a head (its legs are the white
    bars a perspective camera sees on the carpet)."""
    side = np.array([-math.sin(theta), math.cos(theta)])
    fwd = np.array([math.cos(theta), math.sin(theta)])
    step = 0.04 * math.sin(0.8 * phase) * fwd
    leg_r = 0.22 * radius
    white, grey = (228, 230, 232), (120, 122, 126)
    parts = []
    for sgn in (-1.0, 1.0):
        fx, fy = np.array([x, y]) + sgn * 0.45 * radius * side + sgn * step
        parts.append(Cylinder(fx, fy, leg_r * 1.3, 0.0, 0.03 * height, grey, "body"))  # foot
        parts.append(Cylinder(fx, fy, leg_r, 0.03 * height, 0.48 * height, white, "body"))
        parts.append(Cylinder(fx, fy, leg_r * 1.05, 0.22 * height, 0.27 * height, grey, "body"))
        ax, ay = np.array([x, y]) + sgn * 1.05 * radius * side
        parts.append(Cylinder(ax, ay, 0.55 * leg_r, 0.5 * height, 0.8 * height, white, "body"))
    parts.append(Cylinder(x, y, 0.8 * radius, 0.48 * height, 0.84 * height, grey, "body"))
    parts.append(Cylinder(x, y, 0.82 * radius, 0.6 * height, 0.78 * height, team, "marker"))
    parts.append(Cylinder(x, y, 0.55 * radius, 0.84 * height, height, white, "body"))
    return parts


# ---------------------------------------------------------------------------- noise


def value_noise(shape, cell: float, rng: np.random.Generator) -> np.ndarray:
    """Smooth noise of about unit standard deviation with features ``cell`` texels across."""
    h, w = shape
    cell = max(cell, 1.0)
    gh, gw = int(math.ceil(h / cell)) + 3, int(math.ceil(w / cell)) + 3
    grid = rng.standard_normal((gh, gw)).astype(np.float32)
    big = cv2.resize(grid, (int(gw * cell), int(gh * cell)), interpolation=cv2.INTER_CUBIC)
    out = big[int(cell): int(cell) + h, int(cell): int(cell) + w]
    return out / max(float(out.std()), 1e-6)


# ---------------------------------------------------------------------------- ground


def _carpet(conf, field, shape, res, origin, rng) -> np.ndarray:
    h, w = shape
    x0, y0 = origin
    xs = x0 + (np.arange(w, dtype=np.float32) + 0.5) * res
    ys = y0 + (np.arange(h, dtype=np.float32) + 0.5) * res
    bright = 1.0 + conf["carpet_variation"] * value_noise(shape, 2.5 / res, rng)
    bright += 0.15 * conf["carpet_variation"] * value_noise(shape, 0.4 / res, rng)
    sw = conf["stripe_width"]
    if sw > 0:
        stripes = np.tanh(3.0 * np.sin(np.pi * xs / sw)).astype(np.float32)
        bright += conf["stripe_contrast"] * stripes[None, :]
    hv = conf["carpet_hue_variation"]
    blue = 1.0 + hv * value_noise(shape, 3.0 / res, rng)
    red = 1.0 + hv * value_noise(shape, 3.0 / res, rng)
    grain = 1.0 + conf["carpet_grain"] * rng.standard_normal(shape, dtype=np.float32)
    base = np.asarray(conf["carpet_bgr"], dtype=np.float32)
    carpet = np.empty((h, w, 3), np.float32)
    carpet[..., 0] = base[0] * blue
    carpet[..., 1] = base[1]
    carpet[..., 2] = base[2] * red
    carpet *= (bright * grain)[..., None]
    floor = np.asarray(conf["floor_bgr"], np.float32) * (
        1.0 + 0.08 * value_noise(shape, 0.8 / res, rng) + 0.05 * grain[..., :] - 0.05
    )[..., None]
    cx0, cx1, cy0, cy1 = field.world_bounds()
    inside = ((xs[None, :] >= cx0) & (xs[None, :] <= cx1)) & (
        (ys[:, None] >= cy0) & (ys[:, None] <= cy1)
    )
    return np.where(inside[..., None], carpet, floor)


def illumination(conf, shape, res, origin) -> np.ndarray:
    """Relative light of ceiling lamps on a grid, fixed in the world, mean about 1."""
    h, w = shape
    step = 0.25  # m, then upsampled
    gh, gw = int(h * res / step) + 2, int(w * res / step) + 2
    gx = origin[0] + np.arange(gw) * step
    gy = origin[1] + np.arange(gh) * step
    sp = conf["lamp_spacing"]
    lx = np.arange(-6, 7) * sp + sp / 2
    ly = np.arange(-4, 5) * sp
    dx = (gx[:, None] - lx[None, :]) ** 2
    dy = (gy[:, None] - ly[None, :]) ** 2
    sig2 = (0.45 * sp) ** 2
    lamp = np.exp(-dy[:, None, :, None] / (2 * sig2)) * np.exp(-dx[None, :, None, :] / (2 * sig2))
    light = lamp.sum(axis=(2, 3))
    light = (light - light.mean()) / max(np.ptp(light), 1e-9)
    light = (1.0 + conf["lamp_contrast"] * light).astype(np.float32)
    big = cv2.resize(light, (int(gw * step / res), int(gh * step / res)),
                     interpolation=cv2.INTER_LINEAR)
    return big[:h, :w]


def sun_and_shadows(conf, shape, res, origin, rng) -> np.ndarray:
    """Relative light (H, W) of sun patches (soft-edged bright quadrilaterals, as light
    falling through high windows) and shadow bands (soft dark stripes across the floor) fixed
    in the world; 1 elsewhere."""
    h, w = shape
    step = 0.05  # m, then upsampled
    gh, gw = int(h * res / step) + 2, int(w * res / step) + 2
    light = np.ones((gh, gw), np.float32)
    s0, s1 = conf["sun_strength"]
    for _ in range(int(conf["sun_patches"])):
        c = rng.uniform((0.0, 0.0), (gw, gh))
        a = rng.uniform(0, np.pi)
        size = rng.uniform(0.6, 2.5, 2) / step
        u = np.array([math.cos(a), math.sin(a)]) * size[0] / 2
        v = np.array([-math.sin(a), math.cos(a)]) * size[1] / 2
        shear = rng.uniform(-0.4, 0.4) * u
        poly = np.array([c - u - v, c + u - v + shear, c + u + v + shear, c - u + v])
        m = np.zeros((gh, gw), np.float32)
        cv2.fillConvexPoly(m, np.round(poly).astype(np.int32), 1.0)
        m = cv2.GaussianBlur(m, (0, 0), 0.06 / step)
        light += float(rng.uniform(s0, s1)) * m
    d0, d1 = conf["shadow_strength"]
    for _ in range(int(conf["shadows"])):
        c = rng.uniform((0.0, 0.0), (gw, gh))
        a = rng.uniform(0, np.pi)
        half = rng.uniform(0.05, 0.25) / step
        length = rng.uniform(1.5, 6.0) / step
        u = np.array([math.cos(a), math.sin(a)])
        p0, p1 = c - 0.5 * length * u, c + 0.5 * length * u
        m = np.zeros((gh, gw), np.float32)
        cv2.line(m, tuple(np.round(p0).astype(int)), tuple(np.round(p1).astype(int)), 1.0,
                 max(1, int(round(2 * half))))
        m = cv2.GaussianBlur(m, (0, 0), 0.05 / step)
        light *= 1.0 - float(rng.uniform(d0, d1)) * m
    big = cv2.resize(light, (int(gw * step / res), int(gh * step / res)),
                     interpolation=cv2.INTER_LINEAR)
    return big[:h, :w]


def _draw_clutter(img, conf, field, res, origin, rng):
    """Cables, sticks, paper and tape lying on the carpet, drawn into the colour texture."""
    cx0, cx1, cy0, cy1 = field.world_bounds()
    shift = 4
    k = 1 << shift

    def to_px(p):
        return np.round(((np.asarray(p) - origin) / res) * k).astype(np.int32)

    def rand_point():
        return rng.uniform((cx0 + 0.3, cy0 + 0.3), (cx1 - 0.3, cy1 - 0.3))

    cable_colours = [(28, 28, 30), (225, 228, 230), (150, 70, 30), (120, 120, 120)]
    for i in range(int(conf["cables"])):
        p = rand_point()
        a = rng.uniform(-np.pi, np.pi)
        pts = [p]
        for _ in range(int(rng.integers(15, 40))):
            a += rng.normal(0, 0.35)
            p = p + 0.12 * np.array([math.cos(a), math.sin(a)])
            pts.append(p)
        colour = cable_colours[i % len(cable_colours)]
        width = max(1, int(round(rng.uniform(0.008, 0.015) / res)))
        cv2.polylines(img, [to_px(pts)], False, colour, width, cv2.LINE_AA, shift)
    stick_colours = [(215, 222, 225), (70, 120, 160), (40, 40, 40)]
    for i in range(int(conf["sticks"])):
        p = rand_point()
        a = rng.uniform(-np.pi, np.pi)
        q = p + rng.uniform(0.6, 1.6) * np.array([math.cos(a), math.sin(a)])
        width = max(1, int(round(rng.uniform(0.02, 0.035) / res)))
        cv2.line(img, tuple(to_px(p)), tuple(to_px(q)), stick_colours[i % 3], width,
                 cv2.LINE_AA, shift)

    def rect(size, colour):
        p = rand_point()
        a = rng.uniform(-np.pi, np.pi)
        u = np.array([math.cos(a), math.sin(a)]) * size[0] / 2
        v = np.array([-math.sin(a), math.cos(a)]) * size[1] / 2
        poly = np.array([p - u - v, p + u - v, p + u + v, p - u + v])
        cv2.fillPoly(img, [to_px(poly)], colour, cv2.LINE_AA, shift)

    for _ in range(int(conf["papers"])):
        rect((0.21, 0.297), (242, 244, 245))
    tape_colours = [(225, 230, 232), (225, 230, 232), (40, 200, 230), (50, 50, 210)]
    for i in range(int(conf["tapes"])):
        rect((0.05, rng.uniform(0.15, 0.5)), tape_colours[i % len(tape_colours)])


def _line_field(conf, field, res, rng):
    """(H, W, 4) float32 over the carpet: distance to the nearest line (with ragged edges),
    doubled-angle line orientation (cos 2phi, sin 2phi), and how much of the paint is left
    (1, less in worn patches); and the paint's uneven brightness at 10 cm."""
    x0, x1, y0, y1 = field.world_bounds()
    w = int(math.ceil((x1 - x0) / res)) + 1
    h = int(math.ceil((y1 - y0) / res)) + 1
    xs = (x0 + np.arange(w) * res).astype(np.float64)
    ys = (y0 + np.arange(h) * res).astype(np.float64)
    size = float(field.spec.get("penalty_mark", {}).get("size", 2 * field.line_width))
    lw = field.line_width

    def distance(pts):
        d = field.distance_to_lines(pts)
        for m in field.penalty_marks:  # filled discs of diameter `size`
            dm = np.hypot(pts[..., 0] - m[0], pts[..., 1] - m[1]) - max(size / 2 - lw / 2, 0.0)
            d = np.minimum(d, np.maximum(dm, 0.0))
        return d

    # exact distances only near the lines (coarse pass first); farther away it is capped at
    # LINE_FIELD_CAP, beyond the reach of any pixel footprint that could still show a line
    step = max(1, int(round(0.1 / res)))
    coarse = distance(np.stack(np.meshgrid(xs[::step], ys[::step]), axis=-1)).astype(np.float32)
    up = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR)
    d = np.full((h, w), LINE_FIELD_CAP, np.float32)
    near = np.nonzero(up < LINE_FIELD_CAP + 0.2)
    d[near] = np.minimum(distance(np.stack([xs[near[1]], ys[near[0]]], axis=-1)),
                         LINE_FIELD_CAP)
    gy, gx = np.gradient(d)
    n2 = gx * gx + gy * gy + 1e-12
    c2 = ((gx * gx - gy * gy) / n2).astype(np.float32)
    s2 = (2 * gx * gy / n2).astype(np.float32)
    c2 = cv2.GaussianBlur(c2, (0, 0), 1.0)
    s2 = cv2.GaussianBlur(s2, (0, 0), 1.0)
    edge = conf["line_edge_noise"] * (
        0.7 * value_noise((h, w), 0.03 / res, rng) + 0.3 * value_noise((h, w), 0.2 / res, rng)
    )
    wear_noise = value_noise((h, w), 0.06 / res, rng) + 0.5 * value_noise((h, w), 0.6 / res, rng)
    wear = 1.0 - conf["line_wear"] * np.clip((wear_noise - 1.2) / 0.8, 0.0, 1.0)
    lo, hi = conf["line_brightness"]
    bshape = (int(math.ceil(h * res / LINE_LIGHT_RES)) + 1,
              int(math.ceil(w * res / LINE_LIGHT_RES)) + 1)
    bright = lo + (hi - lo) * 0.5 * (1 + np.tanh(value_noise(bshape, 1.5 / LINE_LIGHT_RES, rng)))
    if conf.get("line_width_variation", 0.0) > 0:  # uneven painted width along the lines
        d = d - (0.5 * lw * conf["line_width_variation"]
                 * value_noise((h, w), 0.8 / res, np.random.default_rng(rng.integers(1 << 32))))
    lf = np.stack([d + edge, c2, s2, wear], axis=-1).astype(np.float32)
    return lf, (x0, y0), bright.astype(np.float32)


# ---------------------------------------------------------------------------- walls


def _wall_texture(conf, perimeter, res, rng) -> np.ndarray:
    """The hall around the field, unrolled along the walls (columns) and up (rows): muted
    greys with many upright things (poles, racks, doors, cables), furniture, people standing,
    and a few lamps and windows high up."""
    height = conf["wall_height"]
    h, w = int(math.ceil(height / res)), int(math.ceil(perimeter / res))
    grey = 115 + 45 * value_noise((1, w), 1.2 / res, rng)[0]
    tint = 1.0 + 0.06 * np.stack([value_noise((1, w), 4.0 / res, rng)[0] for _ in range(3)], 1)
    img = grey[None, :, None] * tint[None, :, :] * np.ones((h, 1, 1), np.float32)
    img *= (1.0 + 0.06 * value_noise((h, w), 0.2 / res, rng))[..., None]
    img = np.clip(img, 0, 255).astype(np.uint8)

    def muted(lo=20, hi=230, keep=0.35):
        g = float(rng.uniform(lo, hi))
        return tuple(int((1 - keep) * g + keep * v) for v in rng.uniform(lo, hi, 3))

    # doors and panels
    for _ in range(int(perimeter / 4)):
        c = int(rng.uniform(0, w))
        cv2.rectangle(img, (c, 0), (c + int(rng.uniform(0.8, 2.0) / res), int(2.1 / res)),
                      muted(40, 200, 0.15), -1)
    # racks and shelves: frames with horizontal boards
    for _ in range(int(perimeter / 6)):
        c = int(rng.uniform(0, w))
        rw, rh = int(rng.uniform(0.6, 1.8) / res), int(rng.uniform(1.2, 2.4) / res)
        col = muted(20, 120, 0.1)
        cv2.rectangle(img, (c, 0), (c + rw, rh), col, 2)
        for z in range(int(0.3 / res), rh, int(0.4 / res)):
            cv2.line(img, (c, z), (c + rw, z), col, 1)
    # furniture, boxes and tables
    for _ in range(int(perimeter / 3)):
        c = int(rng.uniform(0, w))
        bw, bh = int(rng.uniform(0.3, 1.5) / res), int(rng.uniform(0.3, 1.0) / res)
        cv2.rectangle(img, (c, 0), (c + bw, bh), muted(), -1)
    # poles and cables: thin upright lines, dark or shiny
    for _ in range(int(perimeter * 1.5)):
        c = int(rng.uniform(0, w))
        top = int(rng.uniform(0.8, height) / res)
        shade = int(rng.choice([25, 40, 60, 170, 210]))
        cv2.line(img, (c, 0), (c, top), (shade, shade, shade + 5),
                 int(rng.integers(1, 3)))
    # people standing along the walls
    for _ in range(int(conf["audience"])):
        c = int(rng.uniform(0, w))
        tall = rng.uniform(1.5, 1.9)
        bw = int(rng.uniform(0.3, 0.45) / res)
        cv2.rectangle(img, (c, 0), (c + bw, int(0.85 / res)), muted(20, 90, 0.3), -1)
        cv2.rectangle(img, (c - 2, int(0.85 / res)), (c + bw + 2, int((tall - 0.25) / res)),
                      muted(30, 210, 0.45), -1)
        cv2.circle(img, (c + bw // 2, int((tall - 0.12) / res)), int(0.11 / res),
                   (110, 140, 185), -1)
    # barrier boards at the bottom
    board = int(0.3 / res)
    img[:board] = (np.array([40, 40, 42]) if rng.random() < 0.5 else np.array([215, 215, 215]))
    # lamps and windows high up (false white near the horizon)
    for _ in range(int(perimeter / 6)):
        c = int(rng.uniform(0, w))
        z = int(rng.uniform(2.0, height - 0.2) / res)
        cv2.rectangle(img, (c, z), (c + int(rng.uniform(0.3, 1.2) / res), z + int(0.2 / res)),
                      (248, 250, 250), -1)
    return img


# ---------------------------------------------------------------------------- goals


def _goals(conf, field):
    g = field.spec["goal"]
    half_w, depth = g["width"] / 2, g["depth"]
    post_r = g["post_diameter"] / 2
    h = conf["goal_height"]
    gx = field.length / 2
    panels, posts = [], []
    white = (236, 240, 240)
    for sx in (-1.0, 1.0):
        x_line, x_back = sx * gx, sx * (gx + depth)
        panels.append(Panel((x_back, -half_w), (x_back, half_w), 0.0, h, (225, 228, 228),
                            0.55, True))
        for sy in (-1.0, 1.0):
            panels.append(Panel((x_line, sy * half_w), (x_back, sy * half_w), 0.0, h,
                                (225, 228, 228), 0.55, True))
            posts.append(Cylinder(x_line, sy * half_w, post_r, 0.0, h, white, "post"))
        panels.append(Panel((x_line, -half_w), (x_line, half_w), h - 2 * post_r, h, white))
    return panels, posts


# ---------------------------------------------------------------------------- lighting


def lighting(conf: dict, stamps, rng: np.random.Generator):
    """Per-frame gain (N,) and white balance (N, 3) from smooth seeded variations."""
    stamps = np.asarray(stamps, dtype=float)

    def smooth():
        p0, p1 = conf["periods"]
        periods = rng.uniform(p0, p1, 3)
        phases = rng.uniform(0, 2 * np.pi, 3)
        weights = np.array([1.0, 0.6, 0.35])
        s = (weights[:, None] * np.sin(2 * np.pi * stamps[None, :] / periods[:, None]
                                       + phases[:, None])).sum(0)
        return s / weights.sum()

    g0, g1 = conf["gain"]
    gain = np.exp(np.log(g0) + (smooth() + 1) / 2 * (np.log(g1) - np.log(g0)))
    temp = conf["colour_temperature"] * smooth()
    tint = conf["tint"] * smooth()
    wb = np.stack([1.0 - temp, 1.0 - tint, 1.0 + temp], axis=1)
    return gain, wb


# ---------------------------------------------------------------------------- build


def _merged(conf: dict | None) -> dict:
    out = {**SCENE_DEFAULTS, **(conf or {})}
    out["lighting"] = {**SCENE_DEFAULTS["lighting"], **(conf or {}).get("lighting", {})}
    return out


def handler_tracks(robot_poses, count: int, distance, rng) -> np.ndarray:
    """(count, N, 3) poses of people who walk along with the robot: each keeps a distance in
    ``distance`` (m) that changes slowly, on a side that drifts around the robot."""
    robot_poses = np.asarray(robot_poses, dtype=float)
    n = len(robot_poses)
    t = np.arange(n, dtype=float)
    out = np.zeros((count, n, 3))
    for k in range(count):
        ph = rng.uniform(0, 2 * np.pi, 3)
        per = rng.uniform(40, 200, 3)  # frames
        s = np.sin(2 * np.pi * t / per[0] + ph[0])
        radius = distance[0] + (distance[1] - distance[0]) * 0.5 * (1 + s)
        angle = ph[1] + 1.5 * np.sin(2 * np.pi * t / per[1] + ph[2]) + 0.3 * np.sin(
            2 * np.pi * t / per[2])
        out[k, :, 0] = robot_poses[:, 0] + radius * np.cos(angle)
        out[k, :, 1] = robot_poses[:, 1] + radius * np.sin(angle)
        if n > 1:
            step = np.gradient(out[k, :, :2], axis=0)
            out[k, :, 2] = np.arctan2(step[:, 1], step[:, 0] + 1e-9)
    return out


def build(field, conf: dict | None, stamps, seed: int, robot_poses=None,
          world_seed: int | None = None) -> FieldScene:
    """The world for ``field`` over the frames at ``stamps``, drawn from ``seed`` (the venue
    from ``world_seed`` when given, module doc); ``robot_poses`` (N, 3), the recording robot's
    path, places the people who walk along."""
    c = _merged(conf)
    same_world = world_seed is None or int(world_seed) == int(seed)
    ss = np.random.SeedSequence([int(seed), 0x5CE2E])
    rng_ground, rng_lines, rng_walls, rng_movers, rng_light = (
        np.random.default_rng(s) for s in ss.spawn(5)
    )
    rng_clutter = rng_ground  # drawn after the carpet
    if not same_world:  # the venue from world_seed, the session's clutter from seed
        ws = np.random.SeedSequence([int(world_seed), 0x5CE2E])
        rng_ground, rng_lines, rng_walls, _m, _l = (np.random.default_rng(s)
                                                    for s in ws.spawn(5))
        rng_clutter = np.random.default_rng([int(seed), 0xC1077E2])
        ss = ws  # sun patches and shadows below belong to the venue
    stamps = np.asarray(stamps, dtype=float)
    cx0, cx1, cy0, cy1 = field.world_bounds()
    gap = c["wall_gap"]
    walls = (cx0 - gap, cx1 + gap, cy0 - gap, cy1 + gap)
    res = c["texture_resolution"]
    shape = (int(math.ceil((walls[3] - walls[2]) / res)),
             int(math.ceil((walls[1] - walls[0]) / res)))
    origin = (walls[0], walls[2])
    ground = _carpet(c, field, shape, res, origin, rng_ground)
    light = illumination(c, shape, res, origin)
    if int(c.get("sun_patches", 0)) or int(c.get("shadows", 0)):
        light = light * sun_and_shadows(c, shape, res, origin,
                                        np.random.default_rng(ss.spawn(1)[0]))
    albedo = np.clip(ground * light[..., None], 0, 255).astype(np.uint8)
    _draw_clutter(albedo, c, field, res, np.asarray(origin), rng_clutter)
    lf, lorigin, line_light = _line_field(c, field, c["line_resolution"], rng_lines)
    # the lamps light the paint too
    rows = (lorigin[1] - origin[1] + np.arange(line_light.shape[0]) * LINE_LIGHT_RES) / res
    cols = (lorigin[0] - origin[0] + np.arange(line_light.shape[1]) * LINE_LIGHT_RES) / res
    li = np.clip(rows.astype(int), 0, shape[0] - 1)
    lj = np.clip(cols.astype(int), 0, shape[1] - 1)
    line_light *= light[li[:, None], lj[None, :]]
    perimeter = 2 * ((walls[1] - walls[0]) + (walls[3] - walls[2]))
    wall_res = 0.02
    wall_tex = _wall_texture(c, perimeter, wall_res, rng_walls)
    panels, posts = _goals(c, field)

    n = len(stamps)
    rate = 1.0 / float(np.median(np.diff(stamps))) if n > 1 else 10.0
    tracks = {}
    for kind, count, speed, heading in (
        ("robots", c["robots"], c["robot_speed"], "free"),
        ("people", c["people"], c["person_speed"], "along"),
        ("balls", c["balls"], [0.2, 1.0], "along"),
    ):
        poses = []
        for _ in range(int(count)):
            t = trajectory.generate(
                field, n, rate,
                {"speed_min": speed[0], "speed_max": speed[1], "heading": heading,
                 "accel_max": 1.0, "lateral_accel_max": 1.0, "margin": 0.2},
                rng_movers,
            )
            poses.append(t.poses)
        tracks[kind] = np.asarray(poses, dtype=float).reshape(int(count), n, 3)
    if robot_poses is not None and int(c["handlers"]) > 0:
        walkers = handler_tracks(robot_poses, int(c["handlers"]), c["handler_distance"],
                                 rng_movers)
        tracks["people"] = np.concatenate([tracks["people"], walkers], axis=0)
    gain, wb = lighting(c["lighting"], stamps, rng_light)
    return FieldScene(
        field=field, conf=c, walls=walls, albedo=albedo, albedo_res=res, line_field=lf,
        line_origin=lorigin, line_res=c["line_resolution"], line_light=line_light,
        line_light_res=LINE_LIGHT_RES, wall_texture=wall_tex,
        wall_res=wall_res, panels=panels, posts=posts, tracks=tracks, gain=gain,
        white_balance=wb,
    )


def sample_texture(tex: np.ndarray, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
    """Bilinear samples of a texture at scattered texel coordinates (1-D arrays), edges
    replicated (cv2.remap on the 1/32-texel grid of stages.common.fixed_remap, in rows of
    1024 points: it takes at most 32767 rows)."""
    n = len(mx)
    cols = 1024
    rows = -(-n // cols)
    pad = rows * cols - n
    gx = np.pad(mx.astype(np.float32), (0, pad)).reshape(rows, cols)
    gy = np.pad(my.astype(np.float32), (0, pad)).reshape(rows, cols)
    out = remap_linear(tex, gx, gy, cv2.BORDER_REPLICATE)
    return out.reshape(rows * cols, *tex.shape[2:])[:n]
