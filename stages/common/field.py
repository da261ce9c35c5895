"""Field models: league fields from ``maps/*.yaml`` (or a user's own YAML) as line geometry.

All dimensions are metres, measured between line centre lines (as B-Human's field files do). The
MSL rulebook measures its letters "from the outer side of any line" (a line belongs to the area
it bounds), as the teams' own field files show (CAMBADA: field_length 17875 mm for A = 18 m;
Carpe Noctem 17870; Falcons subtract the line thickness from every letter): a field given by
letters gets its centre lines from them as the Falcons do (``msl_letter_value``: A..I minus the
line width K, J and K as they are, the border L plus K / 2). The model holds the white lines as
straight segments and circular arcs (their centre lines) with one line width, the penalty marks,
the goal posts, and the L/T/X crossings derived from the geometry (never typed by hand).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .conf import load_yaml, read_record
from .errors import FieldSpecError, file_problem, shown
from .geometry import wrap_angle
from .user_numbers import user_number

MAPS_DIR = Path(__file__).resolve().parents[2] / "maps"

# MSL rulebook letters -> (key path in the generic schema). M..Q are accepted and recorded but
# describe no white line (technical area, team areas), so they do not change the geometry.
MSL_LETTERS = {
    "A": ("length",),
    "B": ("width",),
    "C": ("penalty_area", "width"),
    "D": ("goal_area", "width"),
    "E": ("penalty_area", "length"),
    "F": ("goal_area", "length"),
    "G": ("corner_arc_radius",),
    "H": ("centre_circle_diameter",),
    "I": ("penalty_mark", "distance"),
    "J": ("penalty_mark", "size"),
    "K": ("line_width",),
    "L": ("border",),
}
MSL_UNUSED_LETTERS = set("MNOPQ")
# letters measured from the outer side of the lines: one line width more than the centre lines
MSL_OUTER_SIDE_LETTERS = set("ABCDEFGHI")


def msl_letter_value(letter: str, value: float, line_width: float) -> float:
    """The centre-line dimension of MSL rulebook letter ``letter`` (metres, measured from the
    lines' outer side): A..I less the line width, the border L (from the lines' outer side to
    the field's edge) plus half of it, J (the penalty mark's size) and K as they are."""
    if letter in MSL_OUTER_SIDE_LETTERS:
        return float(value) - line_width
    if letter == "L":
        return float(value) + line_width / 2
    return float(value)


# the length and width (m) a field may have: the leagues' fields run from 9 x 6 m (SPL,
# KidSize) to 22 x 14 m (MSL), labs' from ~6 x 4 m; a file in another unit lands far outside
# (a team's "A": 22000 in mm gave a 22 km field; a 4 km one took build-map 106 s and 2.7 GB)
FIELD_SIDE_M = (1.0, 40.0)
# m: the widest border (floor around the lines) a field may have: 1 m in MSL's rules, up to
# ~2 m in a lab; 10 m holds any hall (a 5 km border wrote a map simulate could not hold)
MAX_BORDER_M = 10.0

# The generic schema: key -> (type, required, sub-schema or None).
_NUM = (int, float)
SCHEMA = {
    "name": (str, True, None),
    "league": (str, False, None),
    "source": (str, True, None),
    "length": (_NUM, True, None),
    "width": (_NUM, True, None),
    "line_width": (_NUM, True, None),
    "border": (_NUM, True, None),
    "centre_circle_diameter": (_NUM, True, None),
    "corner_arc_radius": (_NUM, False, None),
    "penalty_area": (dict, False, {"length": (_NUM, True, None), "width": (_NUM, True, None)}),
    "goal_area": (dict, False, {"length": (_NUM, True, None), "width": (_NUM, True, None)}),
    "penalty_mark": (dict, False, {"distance": (_NUM, True, None), "size": (_NUM, True, None)}),
    "goal": (
        dict,
        True,
        {
            "width": (_NUM, True, None),
            "depth": (_NUM, True, None),
            "post_diameter": (_NUM, True, None),
        },
    ),
    "letters": (dict, False, None),
    "notes": (str, False, None),
    # how `fieldloc field import` made the file (team file, its values, unknown keys); the
    # model does not read it
    "imported": (dict, False, None),
}

CROSSING_TYPES = ("L", "T", "X")
# no dimension beyond this (m): far past any venue, and far below where the geometry's squares
# lose their precision or overflow; a run too large for the machine is refused by its stage
# with a memory estimate (stages.common.resources)
MAX_DIMENSION = 1e6
MIN_DIMENSION = 1e-3  # below a millimetre a value is a unit slip, and segments degenerate
# the rules of every league paint lines 5 to 12.5 cm wide and build goals 0.5 to 0.6 m deep; a
# value past these limits is a unit slip or a damaged file, and would draw a field no camera
# sees (a 5 m line covers a goal area)
MAX_LINE_WIDTH = 0.5
MAX_GOAL_DEPTH = 2.0
# a field's name becomes part of file names (build-map's <name>.map.h5, a batch's
# maps/<name>-<hash>.map.h5) and the first line of an imported field's YAML: a plain token,
# so that no name leads out of a folder (/, ..), hides a file (a leading .) or breaks a line
NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")
NAME_MAX = 64


@dataclass
class FieldModel:
    """Line geometry of one field, in the field frame (origin at the centre spot)."""

    name: str
    source: str
    spec: dict
    spec_text: str
    length: float
    width: float
    line_width: float
    border: float
    segments: np.ndarray  # (S, 2, 2) line centre lines: [[x0, y0], [x1, y1]]
    arcs: np.ndarray  # (A, 5) cx, cy, r, start angle, sweep (rad, counter-clockwise > 0)
    penalty_marks: np.ndarray  # (P, 2), includes the centre spot
    goal_posts: np.ndarray  # (G, 2) post centres
    crossings: np.ndarray = field(default=None)  # (C, 2) positions
    crossing_types: np.ndarray = field(default=None)  # (C,) 'L' | 'T' | 'X'
    crossing_arms: np.ndarray = field(default=None)  # (C, 4) arm directions (rad), NaN padded
    crossing_orientation: np.ndarray = field(default=None)  # (C,) rad

    def __post_init__(self):
        if self.crossings is None:
            pos, types, arms = derive_crossings(self.segments, self.arcs)
            self.crossings = pos
            self.crossing_types = types
            self.crossing_arms = arms
            self.crossing_orientation = np.array(
                [crossing_orientation(t, a) for t, a in zip(types, arms)], dtype=float
            )

    # ------------------------------------------------------------------ geometry
    def world_bounds(self, border: float | None = None):
        """(xmin, xmax, ymin, ymax) of the field plus ``border`` (default: the field's own)."""
        b = self.border if border is None else border
        return (-self.length / 2 - b, self.length / 2 + b, -self.width / 2 - b, self.width / 2 + b)

    def distance_to_lines(self, points) -> np.ndarray:
        """Distance (m) from each point (..., 2) to the nearest line centre line."""
        return distance_to_lines(points, self.segments, self.arcs)

    def nearest_line_direction(self, points) -> np.ndarray:
        """Unit vector (..., 2) from each point towards its nearest centre-line point."""
        p = np.asarray(points, dtype=float)
        near = nearest_line_point(p, self.segments, self.arcs)
        d = near - p
        n = np.linalg.norm(d, axis=-1, keepdims=True)
        return np.divide(d, n, out=np.zeros_like(d), where=n > 0)

    def is_on_field(self, points, margin: float = 0.0) -> np.ndarray:
        p = np.asarray(points, dtype=float)
        return (np.abs(p[..., 0]) <= self.length / 2 + margin) & (
            np.abs(p[..., 1]) <= self.width / 2 + margin
        )

    @staticmethod
    def mirror_pose(pose) -> np.ndarray:
        """The pose that sees the same field under the 180 deg symmetry of the field; of
        poses (..., 3) each one's."""
        p = np.asarray(pose, dtype=float)
        return np.stack([-p[..., 0], -p[..., 1], wrap_angle(p[..., 2] + math.pi)], axis=-1)

    def touchline_pose(self, x, side, inset=0.0) -> np.ndarray:
        """Where a robot enters in a game: on a touch line at ``x`` along it, facing into the
        field; ``side`` +1 is the left touch line (y > 0), -1 the right one; ``inset`` metres
        inside the line (negative: outside). Arrays broadcast to poses (..., 3). The own half
        (x < 0) and the spread along and across the line are the caller's draw."""
        x, side, inset = np.broadcast_arrays(*(np.asarray(v, float) for v in (x, side, inset)))
        return np.stack([x, side * (self.width / 2 - inset), -side * math.pi / 2], axis=-1)

    def is_point_symmetric(self, tol: float = 1e-6) -> bool:
        """Whether the field looks the same after a 180 deg turn about the centre spot (line
        segments, arcs, crossings with their types, goal posts): then a pose and its mirror
        (FieldModel.mirror_pose) explain every observation equally."""

        def same_sets(a, b) -> bool:
            a = np.asarray(a, float).reshape(len(a), -1)
            b = np.asarray(b, float).reshape(len(b), -1)
            if a.shape != b.shape:
                return False
            if not len(a):
                return True
            d = np.abs(a[:, None, :] - b[None, :, :]).max(axis=2)
            return bool(np.all(d.min(axis=1) < tol) and np.all(d.min(axis=0) < tol))

        def unordered(seg):  # a segment as its end points in lexicographic order
            seg = np.asarray(seg, float).reshape(-1, 2, 2)
            swap = (seg[:, 0, 0] > seg[:, 1, 0] + tol) | (
                (np.abs(seg[:, 0, 0] - seg[:, 1, 0]) <= tol) & (seg[:, 0, 1] > seg[:, 1, 1]))
            seg = seg.copy()
            seg[swap] = seg[swap][:, ::-1]
            return seg.reshape(-1, 4)

        fm = self
        if not same_sets(unordered(fm.segments), unordered(-np.asarray(fm.segments, float))):
            return False
        arcs = np.asarray(fm.arcs, float).reshape(-1, 5)
        arcs_m = arcs.copy()
        arcs_m[:, 0:2] *= -1
        arcs_m[:, 3] += math.pi
        arcs_key = np.column_stack([arcs[:, 0:3], np.cos(arcs[:, 3]), np.sin(arcs[:, 3]),
                                    arcs[:, 4]])
        arcs_m_key = np.column_stack([arcs_m[:, 0:3], np.cos(arcs_m[:, 3]), np.sin(arcs_m[:, 3]),
                                      arcs_m[:, 4]])
        full = arcs[:, 4] >= 2 * math.pi - 1e-9  # a full circle has no start to compare
        arcs_key[full, 3:5] = arcs_m_key[full, 3:5] = 0.0
        if not same_sets(arcs_key, arcs_m_key):
            return False
        types = np.asarray(fm.crossing_types)
        for kind in np.unique(types):
            pos = np.asarray(fm.crossings, float)[types == kind]
            if not same_sets(-pos, pos):
                return False
        return same_sets(-np.asarray(fm.goal_posts, float), fm.goal_posts)

    def summary(self) -> dict:
        counts = {t: int(np.sum(self.crossing_types == t)) for t in CROSSING_TYPES}
        return {
            "name": self.name,
            "length_m": self.length,
            "width_m": self.width,
            "line_width_m": self.line_width,
            "segments": int(len(self.segments)),
            "arcs": int(len(self.arcs)),
            "crossings": counts,
            "penalty_marks": int(len(self.penalty_marks)),
            "goal_posts": int(len(self.goal_posts)),
        }


# ---------------------------------------------------------------------------- loading


def preset_names() -> list[str]:
    return sorted(p.stem for p in MAPS_DIR.glob("*.yaml"))


def field_file(field) -> Path | None:
    """The YAML file a field argument names: None for a preset name or no argument (a
    command that reads the file never writes over it)."""
    if not field:
        return None
    p = Path(field)
    return p if p.suffix.lower() in (".yaml", ".yml") or p.exists() else None


def load_field(name_or_path: str | Path) -> FieldModel:
    """Load a preset by name (``msl-2015``, ``msl``, ``spl``, ``kidsize``, ``adultsize``) or a
    path to a field YAML. Raises FieldSpecError with the file and key on any problem."""
    p = Path(name_or_path)
    if p.suffix.lower() in (".yaml", ".yml") or p.exists():
        path = p
        if why := file_problem(path):
            raise FieldSpecError(f"field file {why}: {path}")
    else:
        path = MAPS_DIR / f"{name_or_path}.yaml"
        if not path.is_file():
            raise FieldSpecError(
                f"unknown field preset '{name_or_path}' (presets: {', '.join(preset_names())};"
                " or give a path to a field YAML)"
            )
    try:
        text = read_record(path).decode("utf-8-sig")
    except UnicodeDecodeError:
        raise FieldSpecError(f"{path}: not a text YAML file (binary content)") from None
    except OSError as e:
        raise FieldSpecError(f"{path}: cannot be read ({e.strerror or e})") from None
    try:
        spec = load_yaml(text)
    except yaml.YAMLError as e:
        raise FieldSpecError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    return field_from_spec(spec, str(path), text)


def check_field_name(name, where: str) -> str:
    """``name`` if it is a plain field name (NAME_RE, at most NAME_MAX characters: it names
    output files), else FieldSpecError."""
    if not isinstance(name, str) or len(name) > NAME_MAX or not NAME_RE.fullmatch(name):
        raise FieldSpecError(f"{where}: field name {shown(name, 40)} is not a plain name"
                             f" (letters, digits, . _ + -, starting with a letter or digit,"
                             f" at most {NAME_MAX} characters)")
    return name


def _check(spec: dict, schema: dict, where: str, prefix: str = ""):
    if not isinstance(spec, dict):
        raise FieldSpecError(f"{where}: '{prefix or 'field'}' must be a mapping")
    for key in spec:
        if key not in schema:
            raise FieldSpecError(
                f"{where}: unknown key {shown(f'{prefix}{key}')} (allowed: {', '.join(schema)})"
            )
    for key, (typ, required, sub) in schema.items():
        if key not in spec:
            if required:
                raise FieldSpecError(f"{where}: missing key '{prefix}{key}'")
            continue
        v = spec[key]
        if isinstance(v, bool) or not isinstance(v, typ):
            want = "a number" if typ is _NUM else typ.__name__
            raise FieldSpecError(f"{where}: key '{prefix}{key}' must be {want}, got {shown(v)}")
        if typ is _NUM:  # an integer beyond the float range refused in one line
            v = user_number(v, f"{where}: key '{prefix}{key}'", finite=False,
                            error=FieldSpecError)
        if typ is _NUM and (not math.isfinite(v) or v < 0):
            raise FieldSpecError(f"{where}: key '{prefix}{key}' must be >= 0, got {v}")
        if typ is _NUM and 0 < v < MIN_DIMENSION:
            raise FieldSpecError(
                f"{where}: key '{prefix}{key}' is {v:g} m; dimensions are metres, 0 or at least"
                f" {MIN_DIMENSION:g}")
        if typ is _NUM and v > MAX_DIMENSION:
            raise FieldSpecError(
                f"{where}: key '{prefix}{key}' is {v:g} m; dimensions are metres, at most"
                f" {MAX_DIMENSION:g}")
        if sub is not None:
            _check(v, sub, where, prefix=f"{prefix}{key}.")


def _apply_letters(spec: dict, where: str) -> dict:
    letters = spec.get("letters")
    if letters is None:
        return spec
    if not isinstance(letters, dict):
        raise FieldSpecError(f"{where}: 'letters' must be a mapping of MSL letters A..Q")
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in spec.items()}
    for letter, value in letters.items():
        if letter not in MSL_LETTERS and letter not in MSL_UNUSED_LETTERS:
            raise FieldSpecError(
                f"{where}: unknown key {shown(f'letters.{letter}')} (MSL letters A..Q)")
        if isinstance(value, bool) or not isinstance(value, _NUM):
            raise FieldSpecError(
                f"{where}: key 'letters.{letter}' must be a number, got {shown(value)}")
        user_number(value, f"{where}: key 'letters.{letter}'", error=FieldSpecError)
    line_width = letters.get("K", spec.get("line_width"))
    if not isinstance(line_width, _NUM) or isinstance(line_width, bool):
        raise FieldSpecError(f"{where}: 'letters' needs K (the line width): the rulebook's"
                             " letters are measured from the lines' outer side")
    for letter, value in letters.items():
        if letter in MSL_UNUSED_LETTERS:
            continue
        value = msl_letter_value(letter, value, float(line_width))
        keys = MSL_LETTERS[letter]
        if len(keys) == 1:
            if keys[0] in spec:
                raise FieldSpecError(f"{where}: '{keys[0]}' given both directly and as {letter}")
            out[keys[0]] = value
        else:
            out.setdefault(keys[0], {})
            if not isinstance(out[keys[0]], dict):
                raise FieldSpecError(f"{where}: '{keys[0]}' must be a mapping")
            out[keys[0]][keys[1]] = value
    return out


def field_from_spec(spec, where: str = "<field>", text: str | None = None) -> FieldModel:
    if not isinstance(spec, dict):
        raise FieldSpecError(f"{where}: a field file must be a mapping of keys")
    spec = _apply_letters(spec, where)
    _check(spec, SCHEMA, where)
    check_field_name(spec["name"], where)
    L, W = float(spec["length"]), float(spec["width"])
    lw = float(spec["line_width"])
    for key in ("length", "width", "line_width"):
        if spec[key] <= 0:
            raise FieldSpecError(f"{where}: key '{key}' must be > 0, got {spec[key]}")
    low, high = FIELD_SIDE_M
    for key in ("length", "width"):
        if not low <= spec[key] <= high:
            raise FieldSpecError(f"{where}: key '{key}' is {float(spec[key])!r} m, not a soccer"
                                 f" field's ({low:g}-{high:g} m): is the file in another unit?")
    if spec["border"] > MAX_BORDER_M:
        raise FieldSpecError(f"{where}: key 'border' is {float(spec['border'])!r} m; the floor"
                             f" around a field is at most {MAX_BORDER_M:g} m")
    for area in ("goal_area", "penalty_area"):
        if area in spec:
            a = spec[area]
            if a["length"] <= 0 or a["width"] <= 0:
                raise FieldSpecError(f"{where}: '{area}' length and width must be > 0")
            if a["length"] >= L / 2:
                raise FieldSpecError(
                    f"{where}: key '{area}.length' ({a['length']} m) reaches past the halfway"
                    f" line of a field {L} m long"
                )
            if a["width"] >= W:
                raise FieldSpecError(
                    f"{where}: key '{area}.width' ({a['width']} m) is not smaller than the field"
                    f" width ({W} m)"
                )
    if "goal_area" in spec and "penalty_area" in spec:
        g, p = spec["goal_area"], spec["penalty_area"]
        if g["length"] >= p["length"] or g["width"] >= p["width"]:
            raise FieldSpecError(f"{where}: 'goal_area' must lie inside 'penalty_area'")
    r_c = float(spec["centre_circle_diameter"]) / 2
    if r_c >= W / 2 or r_c >= L / 2:
        raise FieldSpecError(f"{where}: key 'centre_circle_diameter' is larger than the field")
    r_corner = float(spec.get("corner_arc_radius", 0.0))
    if r_corner >= min(L, W) / 2:
        raise FieldSpecError(f"{where}: key 'corner_arc_radius' is larger than the field")
    if spec["goal"]["width"] >= W:
        raise FieldSpecError(f"{where}: key 'goal.width' is not smaller than the field width")
    for key, value, most in (("line_width", lw, MAX_LINE_WIDTH),
                             ("goal.depth", float(spec["goal"]["depth"]), MAX_GOAL_DEPTH)):
        if value > most:
            raise FieldSpecError(f"{where}: key '{key}' ({value:g} m) is more than {most:g} m,"
                                 " beyond any league's field")
    if "penalty_mark" in spec:  # a mark on each half, d from its goal line, on the field
        d, size = float(spec["penalty_mark"]["distance"]), float(spec["penalty_mark"]["size"])
        if d >= L / 2:
            raise FieldSpecError(
                f"{where}: key 'penalty_mark.distance' ({d:g} m) reaches past the halfway line"
                f" of a field {L:g} m long")
        if size >= min(L, W) / 2:
            raise FieldSpecError(
                f"{where}: key 'penalty_mark.size' ({size:g} m) is larger than the field")

    hx, hy = L / 2, W / 2
    segs = [
        [[-hx, -hy], [hx, -hy]],  # right touch line
        [[-hx, hy], [hx, hy]],  # left touch line
        [[-hx, -hy], [-hx, hy]],  # own goal line
        [[hx, -hy], [hx, hy]],  # opponent goal line
        [[0.0, -hy], [0.0, hy]],  # halfway line
    ]
    for area in ("goal_area", "penalty_area"):
        if area not in spec:
            continue
        al, aw = float(spec[area]["length"]), float(spec[area]["width"]) / 2
        for sx in (-1.0, 1.0):
            gx, fx = sx * hx, sx * (hx - al)
            segs += [
                [[fx, -aw], [fx, aw]],
                [[gx, -aw], [fx, -aw]],
                [[gx, aw], [fx, aw]],
            ]
    arcs = [[0.0, 0.0, r_c, 0.0, 2 * math.pi]]
    if r_corner > 0:
        for cx, cy in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)):
            start = math.atan2(-math.copysign(1, cy), -math.copysign(1, cx))  # into the field
            arcs.append([cx, cy, r_corner, start - math.pi / 4, math.pi / 2])
    marks = [[0.0, 0.0]]
    if "penalty_mark" in spec:
        d = float(spec["penalty_mark"]["distance"])
        marks += [[-hx + d, 0.0], [hx - d, 0.0]]
    gw = float(spec["goal"]["width"]) / 2
    posts = [[sx * hx, sy * gw] for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)]
    return FieldModel(
        name=str(spec["name"]),
        source=str(spec["source"]),
        spec=spec,
        spec_text=text if text is not None else yaml.safe_dump(spec, sort_keys=False),
        length=L,
        width=W,
        line_width=lw,
        border=float(spec["border"]),
        segments=np.asarray(segs, dtype=float),
        arcs=np.asarray(arcs, dtype=float),
        penalty_marks=np.asarray(marks, dtype=float),
        goal_posts=np.asarray(posts, dtype=float),
    )


# ---------------------------------------------------------------------------- distances


def _arc_angle_inside(phi, a0, sweep):
    """Whether angle phi lies on the arc starting at a0 sweeping ``sweep`` counter-clockwise."""
    if sweep >= 2 * math.pi - 1e-12:
        return np.ones(np.shape(phi), dtype=bool)
    return np.mod(phi - a0, 2 * math.pi) <= sweep


def nearest_line_point(points, segments, arcs) -> np.ndarray:
    """Nearest point on any line centre line for each point (..., 2)."""
    p = np.asarray(points, dtype=float)
    best = np.full(p.shape[:-1], np.inf)
    out = np.zeros_like(p)
    for (x0, y0), (x1, y1) in segments:
        dx, dy = x1 - x0, y1 - y0
        t = ((p[..., 0] - x0) * dx + (p[..., 1] - y0) * dy) / (dx * dx + dy * dy)
        t = np.clip(t, 0.0, 1.0)
        qx, qy = x0 + t * dx, y0 + t * dy
        d2 = (p[..., 0] - qx) ** 2 + (p[..., 1] - qy) ** 2
        m = d2 < best
        best = np.where(m, d2, best)
        out[..., 0] = np.where(m, qx, out[..., 0])
        out[..., 1] = np.where(m, qy, out[..., 1])
    for cx, cy, r, a0, sweep in arcs:
        vx, vy = p[..., 0] - cx, p[..., 1] - cy
        phi = np.arctan2(vy, vx)
        inside = _arc_angle_inside(phi, a0, sweep)
        qx_in, qy_in = cx + r * np.cos(phi), cy + r * np.sin(phi)
        ends = [(cx + r * math.cos(a), cy + r * math.sin(a)) for a in (a0, a0 + sweep)]
        for qx, qy, valid in [(qx_in, qy_in, inside)] + [
            (ex, ey, ~inside) for ex, ey in ends
        ]:
            d2 = (p[..., 0] - qx) ** 2 + (p[..., 1] - qy) ** 2
            m = valid & (d2 < best)
            best = np.where(m, d2, best)
            out[..., 0] = np.where(m, qx, out[..., 0])
            out[..., 1] = np.where(m, qy, out[..., 1])
    return out


def distance_to_lines(points, segments, arcs) -> np.ndarray:
    """Distance (m) from points (..., 2) to the nearest line centre line."""
    p = np.asarray(points, dtype=float)
    best = np.full(p.shape[:-1], np.inf)
    for (x0, y0), (x1, y1) in segments:
        dx, dy = x1 - x0, y1 - y0
        t = ((p[..., 0] - x0) * dx + (p[..., 1] - y0) * dy) / (dx * dx + dy * dy)
        t = np.clip(t, 0.0, 1.0)
        d2 = (p[..., 0] - x0 - t * dx) ** 2 + (p[..., 1] - y0 - t * dy) ** 2
        np.minimum(best, d2, out=best)
    for cx, cy, r, a0, sweep in arcs:
        vx, vy = p[..., 0] - cx, p[..., 1] - cy
        rho = np.hypot(vx, vy)
        d2 = (rho - r) ** 2
        if sweep < 2 * math.pi - 1e-12:
            inside = _arc_angle_inside(np.arctan2(vy, vx), a0, sweep)
            ends = [(cx + r * math.cos(a), cy + r * math.sin(a)) for a in (a0, a0 + sweep)]
            d_end = np.minimum(*[(p[..., 0] - ex) ** 2 + (p[..., 1] - ey) ** 2 for ex, ey in ends])
            d2 = np.where(inside, d2, d_end)
        np.minimum(best, d2, out=best)
    return np.sqrt(best)


# ---------------------------------------------------------------------------- crossings

_TOL = 1e-6


def _cross(a, b) -> float:
    """z of the 2-D cross product."""
    return float(a[0] * b[1] - a[1] * b[0])


def _segment_arms(seg, p):
    """Arm directions (rad) leaving point p along segment seg, or [] if p is not on it."""
    a, b = np.asarray(seg[0]), np.asarray(seg[1])
    d = b - a
    n = np.linalg.norm(d)
    u = d / n
    t = float(np.dot(p - a, u))
    if t < -_TOL or t > n + _TOL or abs(_cross(u, p - a)) > 1e-6:
        return []
    ang = math.atan2(u[1], u[0])
    arms = []
    if t < n - _TOL:
        arms.append(ang)
    if t > _TOL:
        arms.append(ang + math.pi)
    return arms


def _arc_arms(arc, p):
    cx, cy, r, a0, sweep = arc
    v = p - (cx, cy)
    if abs(np.hypot(*v) - r) > 1e-6:
        return []
    phi = math.atan2(v[1], v[0])
    full = sweep >= 2 * math.pi - 1e-12
    rel = (phi - a0) % (2 * math.pi)
    if not full and rel > 2 * math.pi - 1e-9:
        rel = 0.0
    if not full and rel > sweep + 1e-9:
        return []
    arms = []
    tangent_ccw = phi + math.pi / 2
    at_start = not full and (rel < 1e-9)
    at_end = not full and abs(rel - sweep) < 1e-9
    if not at_end:
        arms.append(tangent_ccw)
    if not at_start:
        arms.append(tangent_ccw + math.pi)
    return arms


def _candidate_points(segments, arcs):
    pts = []
    for s in segments:
        pts += [s[0], s[1]]
    for i in range(len(segments)):
        a, b = segments[i]
        for j in range(i + 1, len(segments)):
            c, d = segments[j]
            r, s = b - a, d - c
            den = _cross(r, s)
            if abs(den) < 1e-12:
                continue
            t = _cross(c - a, s) / den
            u = _cross(c - a, r) / den
            if -_TOL <= t <= 1 + _TOL and -_TOL <= u <= 1 + _TOL:
                pts.append(a + t * r)
    for cx, cy, r, a0, sweep in arcs:
        if sweep < 2 * math.pi - 1e-12:
            for a in (a0, a0 + sweep):
                pts.append(np.array([cx + r * math.cos(a), cy + r * math.sin(a)]))
        for a, b in segments:
            d = b - a
            f = a - (cx, cy)
            qa, qb, qc = d @ d, 2 * f @ d, f @ f - r * r
            disc = qb * qb - 4 * qa * qc
            if disc < 0:
                continue
            for t in ((-qb - math.sqrt(disc)) / (2 * qa), (-qb + math.sqrt(disc)) / (2 * qa)):
                if -_TOL <= t <= 1 + _TOL:
                    pts.append(a + t * d)
    uniq = []
    for p in pts:
        p = np.asarray(p, dtype=float)
        if not any(np.linalg.norm(p - q) < 1e-6 for q in uniq):
            uniq.append(p)
    return uniq


_CROSSINGS: dict[bytes, tuple] = {}  # derive_crossings per line geometry, in this process


def derive_crossings(segments, arcs):
    """Every L, T and X junction of the line centre lines: positions (C, 2), types (C,), and arm
    directions (C, 4) in radians (NaN padded). Two collinear arms are a continuation, not an L.
    Worked out once per geometry in a process (a map's field is built by each reader); each
    call gets its own arrays."""
    seg = np.ascontiguousarray(segments, dtype=float)
    arc = np.ascontiguousarray(arcs, dtype=float)
    key = repr((seg.shape, arc.shape)).encode() + seg.tobytes() + arc.tobytes()
    if key not in _CROSSINGS:
        _CROSSINGS[key] = _derive_crossings(segments, arcs)
    return tuple(a.copy() for a in _CROSSINGS[key])


def _derive_crossings(segments, arcs):
    positions, types, arms_out = [], [], []
    for p in _candidate_points(segments, arcs):
        arms = []
        for s in segments:
            arms += _segment_arms(s, p)
        for a in arcs:
            arms += _arc_arms(a, p)
        arms = sorted({round(math.remainder(a, 2 * math.pi), 9) for a in arms})
        n = len(arms)
        if n == 2:
            if abs(abs(math.remainder(arms[0] - arms[1], 2 * math.pi)) - math.pi) < 1e-6:
                continue
            kind = "L"
        elif n == 3:
            kind = "T"
        elif n == 4:
            kind = "X"
        else:
            continue
        positions.append(p)
        types.append(kind)
        arms_out.append(arms + [math.nan] * (4 - n))
    order = np.lexsort((np.round([q[1] for q in positions], 6),
                        np.round([q[0] for q in positions], 6)))
    return (
        np.asarray(positions, dtype=float)[order].reshape(-1, 2),
        np.asarray(types, dtype="<U1")[order],
        np.asarray(arms_out, dtype=float)[order].reshape(-1, 4),
    )


def crossing_orientation(kind: str, arms) -> float:
    """The crossing's orientation: an L's bisector of its arms, a T's stem (the arm with no
    opposite), an X's first arm folded into [0, pi/2)."""
    arms = [a for a in arms if not math.isnan(a)]
    if kind == "L":
        a, b = arms
        return math.atan2(math.sin(a) + math.sin(b), math.cos(a) + math.cos(b))
    if kind == "T":
        for a in arms:
            if not any(
                abs(abs(math.remainder(a - b, 2 * math.pi)) - math.pi) < 1e-6 for b in arms
            ):
                return math.remainder(a, 2 * math.pi)
        return arms[0]
    return float(np.mod(arms[0], math.pi / 2))
