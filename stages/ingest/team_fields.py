"""Team field files into a fieldloc field YAML (stages.common.field's schema, metres, between
line centre lines).

    main(conf, path, output, *, fmt=None, venue=None, section=None, base=None, name=None,
         overwrite=False) -> Path
    read_team_field(path, fmt=None, *, venue=None, section=None, base=None, name=None)
        -> ImportedField

Formats (``fmt``; None: told from the file's suffix and content by
``field_formats.detect_format``). ``minho`` (.view), ``carpenoctem`` (FootballField.conf,
``section``), ``cambada`` and ``hulks`` are read by ``stages.ingest.field_formats`` (see its
doc); the first three here:

- ``bhuman``: B-Human's ``fieldDimensions.cfg`` (mm, positions of line middles from the centre
  spot: ``xPosOpponentGoalLine``, ``yPosLeftPenaltyArea``, ...; a value may name another key,
  with a sign). The border is the smaller of the two border strips (goal-line side and touch
  side; both are listed when they differ), the goal depth runs from the goal line to the middle
  of the goal's back (``xPosOpponentGoal``). Their ``fieldLines`` list is checked against the
  model built from the dimensions: every line of the model must be one of theirs (within 1
  mm), the short crosses of the penalty marks and the centre mark aside;
- ``bitbots``: either the bit-bots map generator's config (``header.type:
  map_generator_config``, cm: field_length, goal_area_width, stroke_width = line width,
  field_feature_size = mark size, ...; the generator draws lines centred on these
  coordinates) or their ROS parameter file ``config.yaml`` (``parameter_blackboard: ...
  field: {size: {x, y, padding}, markings: {penalty_area: {size: {x}}}, goal: {width,
  depth}}``, metres), which lacks most dimensions: those must come from ``base``;
- ``falcons``: the Falcons ``multiCam.yaml`` (one ``dimensions<Venue>`` block per venue:
  ``venue`` picks one, default the block ``global.dimensions`` names) or an MSL letters list
  (a mapping A..Q, or the Falcons/MRA ``DefaultParams.json`` with its ``model`` block). MSL
  measures "from the outer side of any line" (the lines belong to the areas they bound), and
  the Falcons vision code subtracts the line thickness from every letter to get centre lines;
  so does this importer: length = A - t, width = B - t, penalty area C - t by E - t, goal area
  D - t by F - t, corner arc G - t, centre circle diameter H - t, penalty mark distance I - t
  (t: ``lineThickness`` in multiCam.yaml, letter K in a letters list). The border strips are
  measured from the lines' outer side (+ t / 2). multiCam's J is the penalty mark diameter and
  K the centre mark's; a letters list's J is the mark diameter, K the line width, L the
  border. Goal: ``goalWidth`` includes both posts, so the post centres are ``goalWidth -
  goalPostTichness`` apart (a letters list gives no goal: it comes from ``base``).

Every key of the team file ends up somewhere: used for a dimension, or listed in the YAML's
``imported`` record as ``not_geometry`` (known keys that describe no white line: robot
positions, drawing settings, heights) or ``unknown`` (keys this importer does not know; the
CLI reports them). ``base`` (a preset name or field YAML) supplies the dimensions the team file
does not give; the record lists them under ``from_base``. Without ``base``, a missing
dimension is an error that names it.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .. import __version__
from ..common.artifacts import (
    WRITTEN_MARK,
    atomic_path,
    check_output,
    file_hash,
    first_line_says,
    storable,
    storable_text,
)
from ..common.conf import load_json, load_yaml, read_record
from ..common.errors import FieldlocError, FieldSpecError, file_problem
from ..common.field import (
    FIELD_SIDE_M,
    MSL_LETTERS,
    NAME_MAX,
    check_field_name,
    field_from_spec,
    load_field,
    msl_letter_value,
)
from ..common.user_numbers import user_number
from . import field_formats as _formats

# the first line of a field YAML field import writes: "# <name>: imported from <file> ..."; by
# it --overwrite tells the file from a calib.yaml fieldloc wrote (trial Z2-1)
IMPORTED_FROM = ": imported from "
FORMATS = ("bhuman", "bitbots", "falcons", "minho", "carpenoctem", "cambada", "hulks")
confs = {"default": {"decimals": 6, "check_tolerance_m": 0.001}}

# the generic schema's dimensions, as (key path) -> what a team file must provide
DIMENSIONS = (
    ("length",), ("width",), ("line_width",), ("border",), ("centre_circle_diameter",),
    ("goal_area", "length"), ("goal_area", "width"), ("penalty_area", "length"),
    ("penalty_area", "width"), ("penalty_mark", "distance"), ("penalty_mark", "size"),
    ("goal", "width"), ("goal", "depth"), ("goal", "post_diameter"),
)
OPTIONAL = {("corner_arc_radius",)}


class TeamFieldError(FieldlocError):
    """A team field file that cannot be read or lacks a dimension."""


@dataclass
class ImportedField:
    spec: dict  # the generic field spec (metres)
    record: dict  # the ``imported`` record
    unknown: dict = field(default_factory=dict)
    from_base: list = field(default_factory=list)
    warnings: list = field(default_factory=list)


def _set(spec: dict, path: tuple, value: float):
    d = spec
    for k in path[:-1]:
        d = d.setdefault(k, {})
    d[path[-1]] = float(value)


def _get(spec: dict, path: tuple):
    d = spec
    for k in path:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _read_text(path: Path) -> str:
    if why := file_problem(path):
        raise TeamFieldError(f"field file {why}: {path}")
    try:
        return read_record(path).decode("utf-8-sig")  # a BOM, as every reader reads it
    except (OSError, UnicodeDecodeError) as e:
        raise TeamFieldError(f"{path}: unreadable ({getattr(e, 'strerror', None) or e})"
                             ) from None


# ---------------------------------------------------------------------------- B-Human

_BH_COMMENT = re.compile(r"//[^\n]*|/\*.*?\*/", re.S)
_BH_GEOMETRY_LISTS = {"fieldLines", "goalFrameLines", "centerCircle", "corners"}
_BH_NOT_GEOMETRY = {
    "xPosOpponentGoalPost": "goal post x (the model puts the posts on the goal line)",
    "xPosPenaltyStrikerStartPosition": "robot start position",
    "xPosReturnFromPenalty": "robot position", "yPosLeftReturnFromPenalty": "robot position",
    "crossBarRadius": "goal bar", "goalHeight": "goal height",
    "xPosHalfwayLine": "always 0 in the model",
}


def _bh_statements(text: str, where: str) -> dict[str, str]:
    """Top-level ``name = value;`` statements; values in brackets kept as raw text."""
    text = _BH_COMMENT.sub("", text)
    out, i, n = {}, 0, len(text)
    pat = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*")
    while i < n:
        if text[i:].strip() == "":
            break
        m = pat.match(text, i)
        if not m:
            snippet = text[i:i + 40].strip().splitlines()[0] if text[i:].strip() else ""
            raise TeamFieldError(f"{where}: cannot read B-Human config near '{snippet}'")
        key, j = m.group(1), m.end()
        depth, k = 0, j
        while k < n:
            c = text[k]
            if c in "[{":
                depth += 1
            elif c in "]}":
                depth -= 1
            elif c == ";" and depth == 0:
                break
            k += 1
        if k >= n:
            raise TeamFieldError(f"{where}: '{key}' has no closing ';'")
        if key in out:  # B-Human's reader keeps the last: a second value went by unseen
            raise TeamFieldError(f"{where}: key '{key}' given twice")
        out[key] = text[j:k].strip()
        i = k + 1
    return out


def _bh_value(raw: dict, key: str, where: str, seen=()) -> float:
    if key not in raw:
        raise TeamFieldError(f"{where}: missing key '{key}'")
    v = raw[key].replace(" ", "")
    sign = 1.0
    if v.startswith("-"):
        sign, v = -1.0, v[1:]
    try:
        return sign * float(v)
    except ValueError:
        pass
    if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", v):
        if v in seen:
            raise TeamFieldError(f"{where}: '{key}' refers to itself through '{v}'")
        return sign * _bh_value(raw, v, where, (*seen, key))
    raise TeamFieldError(f"{where}: '{key}' = '{raw[key]}' is not a number or a key name")


def _bh_point(text: str, raw: dict, where: str):
    vals = {}
    for axis in ("x", "y"):
        m = re.search(rf"\b{axis}\s*=\s*([^;]+);", text)
        if not m:
            raise TeamFieldError(f"{where}: a line end lacks '{axis}' ({text.strip()})")
        expr = m.group(1).strip()
        tmp = dict(raw, __v=expr)
        vals[axis] = _bh_value(tmp, "__v", where) / 1000.0
    return vals["x"], vals["y"]


def _bh_lines(text: str, raw: dict, where: str) -> np.ndarray:
    segs = []
    for m in re.finditer(r"from\s*=\s*\{(.*?)\}\s*;\s*to\s*=\s*\{(.*?)\}", text, re.S):
        segs.append([_bh_point(m.group(1), raw, where), _bh_point(m.group(2), raw, where)])
    return np.asarray(segs, float).reshape(-1, 2, 2)


def read_bhuman(path: Path) -> tuple[dict, dict, dict, list, dict]:
    """(spec, used values, not-geometry keys, warnings, extra) of a fieldDimensions.cfg."""
    where = str(path)
    raw = _bh_statements(_read_text(path), where)

    def mm(key):
        return _bh_value(raw, key, where) / 1000.0

    gl, tl = mm("xPosOpponentGoalLine"), mm("yPosLeftTouchline")
    border_x, border_y = mm("xPosOpponentFieldBorder") - gl, mm("yPosLeftFieldBorder") - tl
    warnings = []
    if abs(border_x - border_y) > 1e-6:
        warnings.append(f"border strips differ: {border_x:g} m behind the goal lines,"
                        f" {border_y:g} m beside the touch lines; the model uses the smaller")
    spec = {}
    _set(spec, ("length",), 2 * gl)
    _set(spec, ("width",), 2 * tl)
    _set(spec, ("line_width",), mm("fieldLinesWidth"))
    _set(spec, ("border",), min(border_x, border_y))
    _set(spec, ("centre_circle_diameter",), 2 * mm("centerCircleRadius"))
    _set(spec, ("goal_area", "length"), gl - mm("xPosOpponentGoalArea"))
    _set(spec, ("goal_area", "width"), 2 * mm("yPosLeftGoalArea"))
    _set(spec, ("penalty_area", "length"), gl - mm("xPosOpponentPenaltyArea"))
    _set(spec, ("penalty_area", "width"), 2 * mm("yPosLeftPenaltyArea"))
    _set(spec, ("penalty_mark", "distance"), gl - mm("xPosOpponentPenaltyMark"))
    _set(spec, ("penalty_mark", "size"), mm("penaltyMarkSize"))
    _set(spec, ("goal", "width"), 2 * mm("yPosLeftGoal"))
    _set(spec, ("goal", "depth"), mm("xPosOpponentGoal") - gl)
    _set(spec, ("goal", "post_diameter"), 2 * mm("goalPostRadius"))
    used_keys = {"xPosOpponentGoalLine", "yPosLeftTouchline", "xPosOpponentFieldBorder",
                 "yPosLeftFieldBorder", "fieldLinesWidth", "centerCircleRadius",
                 "xPosOpponentGoalArea", "yPosLeftGoalArea", "xPosOpponentPenaltyArea",
                 "yPosLeftPenaltyArea", "xPosOpponentPenaltyMark", "penaltyMarkSize",
                 "yPosLeftGoal", "xPosOpponentGoal", "goalPostRadius"}
    # the own-side and right-side keys mirror the used ones (checked) or name robot positions
    used, not_geom, unknown = {}, {}, {}
    for key, value in raw.items():
        if key in used_keys:
            used[key] = _bh_value(raw, key, where)
        elif key in _BH_GEOMETRY_LISTS:
            not_geom[key] = "line list (checked against the model)" if key == "fieldLines" \
                else "derived geometry"
        elif key in _BH_NOT_GEOMETRY:
            not_geom[key] = _BH_NOT_GEOMETRY[key]
        else:
            mirror = _bh_mirror(key)
            if mirror in used_keys:
                if abs(_bh_value(raw, key, where) + _bh_value(raw, mirror, where)) > 1e-6:
                    warnings.append(f"'{key}' is not the mirror of '{mirror}': the model is"
                                    " symmetric and uses the opponent/left values")
                not_geom[key] = f"mirror of {mirror}"
            elif mirror in _BH_NOT_GEOMETRY:
                not_geom[key] = _BH_NOT_GEOMETRY[mirror]
            else:
                unknown[key] = value
    extra = {"unknown": unknown}
    if "fieldLines" in raw:
        extra["field_lines"] = _bh_lines(raw["fieldLines"], raw, where)
    return spec, used, not_geom, warnings, extra


def _bh_mirror(key: str) -> str:
    for a, b in (("Own", "Opponent"), ("Right", "Left")):
        if a in key:
            return key.replace(a, b)
    return ""


def _check_lines(model, lines: np.ndarray, tol: float) -> list[str]:
    """Model segments that are none of the file's lines (end points within ``tol``, either
    order); the file's short mark crosses are not lines of the model."""
    out = []
    for s in model.segments:
        d1 = np.abs(lines - s[None]).max(axis=(1, 2))
        d2 = np.abs(lines - s[None, ::-1]).max(axis=(1, 2))
        if not len(lines) or min(d1.min(), d2.min()) > tol:
            out.append(f"({s[0, 0]:.3f}, {s[0, 1]:.3f})-({s[1, 0]:.3f}, {s[1, 1]:.3f})")
    return out


# ---------------------------------------------------------------------------- bit-bots

_BB_GENERATOR = {
    "field_length": ("length",), "field_width": ("width",), "stroke_width": ("line_width",),
    "border_strip_width": ("border",), "center_circle_diameter": ("centre_circle_diameter",),
    "goal_area_length": ("goal_area", "length"), "goal_area_width": ("goal_area", "width"),
    "penalty_area_length": ("penalty_area", "length"),
    "penalty_area_width": ("penalty_area", "width"),
    "penalty_mark_distance": ("penalty_mark", "distance"),
    "field_feature_size": ("penalty_mark", "size"),
    "goal_width": ("goal", "width"), "goal_depth": ("goal", "depth"),
}
_BB_GENERATOR_DRAWING = {"map_type", "penalty_mark", "center_point", "goal_back", "mark_type",
                         "field_feature_style", "distance_map", "distance_decay", "invert"}
_BB_PARAMS = {
    ("size", "x"): ("length",), ("size", "y"): ("width",), ("size", "padding"): ("border",),
    ("markings", "penalty_area", "size", "x"): ("penalty_area", "length"),
    ("goal", "width"): ("goal", "width"), ("goal", "depth"): ("goal", "depth"),
}


def _flatten(d: dict, prefix=()) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, (*prefix, str(k))))
        else:
            out[(*prefix, str(k))] = v
    return out


def _number(v, key, where) -> float:
    """A number of a YAML or JSON field file (stages.common.user_numbers: no bool, no integer
    beyond the float range, finite), or TeamFieldError."""
    return user_number(v, f"{where}: '{key}'", error=TeamFieldError)


def read_bitbots(path: Path):
    where = str(path)
    try:
        doc = load_yaml(_read_text(path))
    except yaml.YAMLError as e:
        raise TeamFieldError(f"{where}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise TeamFieldError(f"{where}: not a bit-bots field file (not a mapping)")
    spec, used, not_geom, unknown, warnings = {}, {}, {}, {}, []
    if isinstance(doc.get("header"), dict) and doc["header"].get("type") == \
            "map_generator_config":
        params = doc.get("parameters")
        if not isinstance(params, dict):
            raise TeamFieldError(f"{where}: map generator config without 'parameters'")
        for key, value in params.items():
            if key in _BB_GENERATOR:
                used[key] = _number(value, key, where)
                _set(spec, _BB_GENERATOR[key], used[key] / 100.0)  # cm
            elif key in _BB_GENERATOR_DRAWING:
                not_geom[key] = value
            else:
                unknown[key] = value
        if params.get("penalty_mark") is False:
            spec.pop("penalty_mark", None)
            warnings.append("penalty_mark: false (the generator draws no penalty marks)")
        for key in ("header",):
            not_geom[key] = doc[key]
        for key in doc:
            if key not in ("header", "parameters"):
                unknown[key] = doc[key]
        kind = "map generator config (cm)"
    elif "parameter_blackboard" in doc:
        try:
            fld = doc["parameter_blackboard"]["ros__parameters"]["field"]
        except (KeyError, TypeError):
            raise TeamFieldError(f"{where}: no parameter_blackboard.ros__parameters.field"
                                 " block") from None
        flat = _flatten(fld)
        for key, value in flat.items():
            name = ".".join(key)
            if key in _BB_PARAMS:
                used[name] = _number(value, name, where)
                _set(spec, _BB_PARAMS[key], used[name])
            else:
                unknown[name] = value
        rest = _flatten(doc)
        for key, value in rest.items():
            if key[:3] != ("parameter_blackboard", "ros__parameters", "field"):
                unknown[".".join(key)] = value
        kind = "ROS parameters (m)"
    else:
        raise TeamFieldError(f"{where}: neither a bit-bots map generator config (header.type:"
                             " map_generator_config) nor their parameter file"
                             " (parameter_blackboard)")
    return spec, used, not_geom, warnings, {"unknown": unknown, "kind": kind}


# ---------------------------------------------------------------------------- Falcons

_MULTICAM_NOT_GEOMETRY = {"K": "centre mark diameter (the model has one mark size)",
                          "metersToPixels": "drawing scale",
                          "remoteMetersToPixels": "drawing scale"}
_RULE_NOT_LINES = set("MNOPQ")


def _falcons_convert(v: dict, t: float, spec: dict):
    """Outer-side MSL measurements to centre lines (see the module doc); J is the penalty
    mark's diameter in both Falcons formats."""
    for letter in "ABCDEFGHIJ":  # the rulebook's convention, as the field model reads it
        if letter in v:
            _set(spec, MSL_LETTERS[letter], msl_letter_value(letter, v[letter], t))
    _set(spec, ("line_width",), t)


def read_falcons(path: Path, venue: str | None):
    where = str(path)
    text = _read_text(path)
    if path.suffix.lower() == ".json":
        try:
            doc = load_json(text)
        except ValueError as e:  # JSONDecodeError, or an integer of more than 4300 digits
            raise TeamFieldError(f"{where}: not valid JSON ({str(e)[:80]})") from None
    else:
        body = "\n".join(line for line in text.splitlines() if not line.startswith("%YAML"))
        try:
            doc = load_yaml(body)
        except yaml.YAMLError as e:
            raise TeamFieldError(f"{where}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise TeamFieldError(f"{where}: not a Falcons field file (not a mapping)")
    blocks = {k[len("dimensions"):]: v for k, v in doc.items()
              if k.startswith("dimensions") and isinstance(v, dict)}
    spec, used, not_geom, unknown, warnings = {}, {}, {}, {}, []
    if blocks:
        chosen = venue
        if chosen is None:
            chosen = str((doc.get("global") or {}).get("dimensions", ""))
            chosen = chosen[len("dimensions"):] if chosen.startswith("dimensions") else chosen
            if chosen not in blocks:
                raise TeamFieldError(f"{where}: {len(blocks)} venues; choose one with --venue"
                                     f" ({', '.join(blocks)})")
            warnings.append(f"venue {chosen}: the one global.dimensions names (others:"
                            f" {', '.join(b for b in blocks if b != chosen)})")
        chosen = chosen[len("dimensions"):] if chosen.startswith("dimensions") else chosen
        if chosen not in blocks:
            raise TeamFieldError(f"{where}: no venue '{venue}' (venues: {', '.join(blocks)})")
        block = blocks[chosen]
        v = {k: _number(x, k, where) for k, x in block.items()}
        if "lineThickness" not in v:
            raise TeamFieldError(f"{where}: venue {chosen} has no lineThickness")
        t = v["lineThickness"]
        _falcons_convert(v, t, spec)
        post = v.get("goalPostTichness", t)
        if "goalWidth" in v:
            _set(spec, ("goal", "width"), v["goalWidth"] - post)
        _set(spec, ("goal", "post_diameter"), post)
        if "goalDepth" in v:
            _set(spec, ("goal", "depth"), max(0.0, v["goalDepth"] - t / 2))
            if v["goalDepth"] == 0:
                warnings.append("goalDepth is 0 in the file (the team disabled it): depth 0")
        borders = [v[k] + t / 2 for k in ("goalLineBorder", "touchLineBorder") if k in v]
        if borders:
            _set(spec, ("border",), min(borders))
            if len(borders) == 2 and abs(borders[0] - borders[1]) > 1e-9:
                warnings.append(f"border strips differ: {borders[0]:g} m behind the goal"
                                f" lines, {borders[1]:g} m beside the touch lines (from the"
                                " lines' centres); the model uses the smaller")
        geometry = set("ABCDEFGHIJ") | {"lineThickness", "goalWidth", "goalDepth",
                                        "goalPostTichness", "goalLineBorder", "touchLineBorder"}
        for key, value in v.items():
            if key in geometry:
                used[key] = value
            elif key in _MULTICAM_NOT_GEOMETRY:
                not_geom[key] = _MULTICAM_NOT_GEOMETRY[key]
            else:
                unknown[key] = value
        kind = f"multiCam.yaml venue {chosen} (m, outer side of lines)"
        extra = {"venue": chosen}
    else:
        letters = doc.get("model", doc)
        if not isinstance(letters, dict) or not any(k in letters for k in "AB"):
            raise TeamFieldError(f"{where}: neither multiCam.yaml (dimensions<Venue> blocks)"
                                 " nor an MSL letters list (A, B, ...)")
        v = {}
        for key, value in letters.items():
            if len(str(key)) == 1 and str(key) in "ABCDEFGHIJKL":
                v[str(key)] = _number(value, key, where)
            elif str(key) in _RULE_NOT_LINES:
                not_geom[str(key)] = value
            else:
                unknown[str(key)] = value
        if "K" not in v:
            raise TeamFieldError(f"{where}: letters list without K (the line width)")
        t = v["K"]
        _falcons_convert(v, t, spec)
        if "L" in v:
            _set(spec, ("border",), msl_letter_value("L", v["L"], t))
        used = dict(v)
        for key in doc:
            if key != "model" and "model" in doc:
                not_geom[key] = "not field geometry" if key in ("solver", "shapes", "debug") \
                    else doc[key]
        kind = "MSL letters list (m, outer side of lines)"
        extra = {}
    extra.update(unknown=unknown, kind=kind)
    return spec, used, not_geom, warnings, extra


# ---------------------------------------------------------------------------- main


def read_team_field(path, fmt: str | None = None, *, venue: str | None = None,
                    section: str | None = None, base=None, name: str | None = None,
                    conf: dict | None = None) -> ImportedField:
    """The generic field spec of a team file (see the module doc), checked by building the
    field model. ``fmt`` None: told from the file (stages.ingest.field_formats.detect_format).
    """
    conf = conf or confs["default"]
    path = Path(path)
    if name is not None:
        check_field_name(name, "--name")  # it names files, and heads the YAML written
    if fmt is None:
        fmt = _formats.detect_format(path)
    if fmt not in FORMATS:
        raise TeamFieldError(f"unknown field format '{fmt}' ({', '.join(FORMATS)})")
    if venue is not None and fmt != "falcons":
        raise TeamFieldError("--venue is for the falcons format (multiCam.yaml)")
    if section is not None and fmt != "carpenoctem":
        raise TeamFieldError("--section is for the carpenoctem format (FootballField.conf)")
    if fmt == "bhuman":
        spec, used, not_geom, warnings, extra = read_bhuman(path)
    elif fmt == "bitbots":
        spec, used, not_geom, warnings, extra = read_bitbots(path)
    elif fmt == "falcons":
        spec, used, not_geom, warnings, extra = read_falcons(path, venue)
    elif fmt == "minho":
        spec, used, not_geom, warnings, extra = _formats.read_minho(path)
    elif fmt == "carpenoctem":
        spec, used, not_geom, warnings, extra = _formats.read_carpenoctem(path, section)
    elif fmt == "cambada":
        spec, used, not_geom, warnings, extra = _formats.read_cambada(path)
    else:
        spec, used, not_geom, warnings, extra = _formats.read_hulks(path)
    base_model = load_field(base) if base is not None else None
    no_marks = fmt == "bitbots" and any("penalty_mark: false" in w for w in warnings)
    wanted = [k for k in DIMENSIONS + tuple(sorted(OPTIONAL))
              if not (no_marks and k[0] == "penalty_mark")]
    from_base = []
    for key in wanted:
        if _get(spec, key) is None and base_model is not None \
                and _get(base_model.spec, key) is not None:
            _set(spec, key, _get(base_model.spec, key))
            from_base.append(".".join(key))
    missing = [".".join(k) for k in wanted if k not in OPTIONAL and _get(spec, k) is None]
    if missing:
        raise TeamFieldError(f"{path}: the file gives no {', '.join(missing)}; pass --base"
                             " FIELD (a preset or field YAML) to take them from it")
    low, high = FIELD_SIDE_M
    for key in ("length", "width"):
        if not low <= spec[key] <= high:
            raise TeamFieldError(
                f"{path}: the field's {key} would be {spec[key]:.6g} m, not a soccer field's"
                f" ({low:g}-{high:g} m): is the file in another unit?")
    dec = int(conf["decimals"])
    spec = _rounded(spec, dec)
    stem = extra.get("venue") or extra.get("section") or path.stem
    # the default name from a file, venue or section name: its other characters as '-'
    stem = re.sub(r"[^A-Za-z0-9._+-]", "-", stem)[:NAME_MAX - len(fmt) - 1]
    out = {"name": name or f"{fmt}-{stem}",
           "source": f"imported by fieldloc field import --format {fmt} from {path.name}"
                     f" ({extra.get('kind', fmt)})"}
    out.update(spec)
    record = {
        "format": fmt,
        "file": str(path),
        "file_hash": file_hash(path),
        "kind": extra.get("kind", fmt),
        "fieldloc_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "values": {str(k): _plain(v) for k, v in used.items()},
        "not_geometry": {str(k): _plain(v) for k, v in not_geom.items()},
        "unknown": {str(k): _plain(v) for k, v in extra["unknown"].items()},
    }
    if "venue" in extra:
        record["venue"] = extra["venue"]
    if "section" in extra:
        record["section"] = extra["section"]
    if from_base:
        record["from_base"] = {"field": str(base), "keys": from_base}
    if warnings:
        record["notes"] = warnings
    out["imported"] = record
    try:
        model = field_from_spec(out, str(path))
    except FieldSpecError as e:
        raise TeamFieldError(f"the imported dimensions are not a valid field: {e}") from None
    if "field_lines" in extra:
        stray = _check_lines(model, extra["field_lines"], float(conf["check_tolerance_m"]))
        record["field_lines_check"] = ("every model line is one of the file's fieldLines"
                                       if not stray else f"not in fieldLines: {stray}")
        if stray:
            warnings.append(f"{len(stray)} model line(s) are not in the file's fieldLines")
            record["notes"] = warnings
    return ImportedField(spec=out, record=record, unknown=record["unknown"],
                         from_base=from_base, warnings=warnings)


def _rounded(d, dec):
    if isinstance(d, dict):
        return {k: _rounded(v, dec) for k, v in d.items()}
    return round(float(d), dec) if isinstance(d, float) else d


def _plain(v):
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def main(conf: str | dict | None, path, output, *, fmt: str | None = None,
         venue: str | None = None, section: str | None = None, base=None,
         name: str | None = None, overwrite: bool = False, progress: bool = False) -> Path:
    """Write the field YAML of a team file to ``output``; returns ``output``."""
    from ..common.conf import stage_conf

    conf = stage_conf(confs, conf)
    base_file = Path(base) if base is not None and Path(base).is_file() else None
    output = check_output(output, {"the team file": path, "base": base_file},
                          overwrite=overwrite, error=TeamFieldError,
                          ours=first_line_says(f"# [^\\n]*?{IMPORTED_FROM}"))
    imp = read_team_field(path, fmt, venue=venue, section=section, base=base, name=name,
                          conf=conf)
    fmt = imp.record["format"]
    # the team file's name as JSON writes it: a line break or bytes not UTF-8 in it broke the
    # comment line (trial B2-3)
    shown_name = json.dumps(storable_text(Path(path).name))[1:-1]
    text = (f"# {imp.spec['name']}{IMPORTED_FROM}{shown_name} (--format {fmt}); metres,"
            f" between line centre lines; {WRITTEN_MARK}\n"
            + yaml.safe_dump(storable(imp.spec), sort_keys=False))
    # what is written must read back as a field: checked before writing (a refusal writes
    # nothing)
    field_from_spec(load_yaml(text), str(output), text)
    with atomic_path(output, suffix=".yaml") as tmp:
        tmp.write_text(text)
    return output
