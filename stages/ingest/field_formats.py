"""Readers of more teams' field files for ``stages.ingest.team_fields`` (one reader per format)
and the format of a file told from its name and content.

    detect_format(path) -> str
    read_minho(path), read_carpenoctem(path, section), read_cambada(path), read_hulks(path)
        -> (spec, used values, not-geometry keys, warnings, extra)

Every reader gives the generic field spec (metres, between line centre lines) and accounts for
each key of the file: used for a dimension, known to describe no white line (``not_geometry``),
or unknown (reported by the CLI). A dimension the file does not give is left out; the caller
takes it from ``--base`` or names it in its error.

Formats:

- ``minho``: the MINHO team's ``.view`` files (``Lar.view``, ``Official.view``;
  minhoteam-msl/minho_team_ros), ``KEY=VALUE`` lines in mm. Their code puts the goal lines at
  +-LENGTH / 2 and the touch lines at +-WIDTH / 2, so LENGTH and WIDTH are read as between line
  centres; ``AREA_*1`` is the goal area, ``AREA_*2`` the penalty area, ``DISTANCE_PENALTY`` the
  penalty mark's distance from the goal line, ``SPOTS`` the mark's size, ``CENTER_RADIUS`` and
  ``RADIUS_CORNER`` radii; the border strips are ``(TOTAL_LENGTH - LENGTH) / 2`` behind the
  goal lines and ``(TOTAL_WIDTH - WIDTH) / 2`` beside the touch lines (the model takes the
  smaller; both are noted when they differ). ``GOAL_WIDTH`` is the goal's inside width
  between the posts (the team's drawing code puts the posts outside ``GOALIE_LENGTH``), so the
  post centres are ``GOAL_WIDTH + GOALIE_POST_WIDTH`` apart; ``GOAL_LENGTH`` is its depth.
- ``carpenoctem``: Carpe Noctem Cassel's ``FootballField.conf`` (dasys-lab/cnc-msl), mm, one
  ``[Name] ... [!Name]`` section per field inside ``[FootballField]``, whose ``CurrentField``
  names the team's current one. ``section`` picks one (default: ``CurrentField``). Their code
  reads ``FieldLength`` / ``FieldWidth`` as the distances between the goal lines and the touch
  lines (centre lines here), ``PenaltyAreaXSize`` / ``YSize`` as the penalty area's length and
  width (``GoalArea*`` the goal area's), ``PenaltySpot`` from the goal line, ``Surrounding``
  the border; ``GoalWidth`` is inside the posts (post centres ``GoalWidth + GoalPostWidth``
  apart). ``GoalInnerAreaExists: false`` drops the goal area, ``CornerCircleExists: false`` the
  corner arcs. No penalty mark size: from ``--base``. A key given twice in a section with the
  same value is noted; with two values it is an error. Their ``Globals.conf`` holds a
  ``[FootballField]`` with one field's keys directly, inside ``[Globals]`` beside team
  settings: that block is the field (``cnc_sections``).
- ``cambada``: CAMBADA's field block (``cambada.conf.xml``'s field attributes as a JSON mapping,
  mm). ``field_length`` 17875 for the 18 m MSL field: centre lines. ``goal_band_width`` (behind
  the goal lines) and ``side_band_width`` are the border strips (the smaller is used).
  ``goal_width`` is taken as the posts' centre distance (the file gives no post width: that
  comes from ``--base``, like the penalty mark's size).
- ``hulks``: HULKs' ``field_dimensions`` (JSON or JSON5, metres, SPL conventions: centre
  lines). ``goal_inner_width`` is inside the posts: post centres ``goal_inner_width +
  goal_post_diameter`` apart. ``corner_arc_radius: 0`` means no corner arcs.
"""

from __future__ import annotations

import re
from pathlib import Path

from ..common.conf import RepeatedKeyError, load_json
from ..common.errors import FieldlocError, file_problem
from ..common.user_numbers import user_number


class FieldFormatError(FieldlocError):
    """A team field file of these formats that cannot be read."""


def _read_text(path: Path) -> str:
    if why := file_problem(path):
        raise FieldFormatError(f"field file {why}: {path}")
    try:
        return path.read_text(encoding="utf-8-sig")  # a BOM, as every reader reads it
    except (OSError, UnicodeDecodeError) as e:
        raise FieldFormatError(f"{path}: unreadable ({e})") from None


def _num(value, key: str, where: str) -> float:
    """A number of a field file (stages.common.user_numbers: text as a .view or .conf holds
    it, no bool, no integer beyond the float range, finite), or FieldFormatError."""
    return user_number(value, f"{where}: '{key}'", error=FieldFormatError)


def _set(spec: dict, path: tuple, value: float):
    d = spec
    for k in path[:-1]:
        d = d.setdefault(k, {})
    d[path[-1]] = float(value)


def _border(spec, behind_goal: float, beside_touch: float, what: str, warnings: list):
    if abs(behind_goal - beside_touch) > 1e-6:
        warnings.append(f"border strips differ: {behind_goal:g} m behind the goal lines,"
                        f" {beside_touch:g} m beside the touch lines ({what}); the model uses"
                        " the smaller")
    _set(spec, ("border",), min(behind_goal, beside_touch))


# ---------------------------------------------------------------------------- detection

FORMAT_HINTS = {
    "bhuman": "B-Human fieldDimensions.cfg",
    "bitbots": "bit-bots map generator config or config.yaml",
    "falcons": "Falcons multiCam.yaml or MSL letters list",
    "minho": "MINHO .view",
    "carpenoctem": "Carpe Noctem FootballField.conf",
    "cambada": "CAMBADA field JSON",
    "hulks": "HULKs field_dimensions JSON/JSON5",
}


def detect_format(path) -> str:
    """The format of a team field file, told by its suffix and content (see FORMAT_HINTS)."""
    path = Path(path)
    text = _read_text(path)
    suffix = path.suffix.lower()
    if suffix == ".view" or re.search(r"^\s*TOTAL_LENGTH\s*=", text, re.M):
        return "minho"
    if re.search(r"^\s*\[FootballField\]", text, re.M):
        return "carpenoctem"
    if re.search(r"\bxPosOpponentGoalLine\s*=", text):
        return "bhuman"
    if suffix in (".json", ".json5"):
        try:
            doc = _json5(text, str(path))
        except FieldFormatError as e:
            if isinstance(e.__cause__, RepeatedKeyError):
                raise  # its format is plain, its key given twice is what to say
            doc = None
        if isinstance(doc, dict):
            if "field_dimensions" in doc:
                return "hulks"
            if "field_length" in doc and "line_thickness" in doc:
                return "cambada"
            if "model" in doc or "A" in doc:
                return "falcons"
    if suffix in (".yaml", ".yml"):
        if "map_generator_config" in text or "parameter_blackboard" in text:
            return "bitbots"
        if re.search(r"^\s*dimensions\w*\s*:", text, re.M) or re.search(r"^A\s*:", text, re.M):
            return "falcons"
    raise FieldFormatError(
        f"{path}: cannot tell the field file's format from its name and content; pass"
        f" --format ({', '.join(FORMAT_HINTS)})")


# ---------------------------------------------------------------------------- MINHO .view

_VIEW_LINE = re.compile(r"^\s*([A-Z][A-Z0-9_]*)\s*=\s*(.*?)\s*$")
_MINHO_NOT_GEOMETRY = {
    "SPOT_CENTER": "centre mark diameter (the model has one mark size)",
    "ROBOT_DIAMETER": "robot size", "BALL_DIAMETER": "ball size",
    "FACTOR": "drawing scale",
    "GOALIE_LENGTH": "goal inside width as the team draws it (checked against GOAL_WIDTH)",
    "GOALIE_WIDTH": "goal frame depth as the team draws it",
    "GOALIE_BOARD_WIDTH": "goal back board thickness",
}
_MINHO_USED = ("TOTAL_LENGTH", "TOTAL_WIDTH", "LENGTH", "WIDTH", "GOAL_WIDTH", "GOAL_LENGTH",
               "LINE_WIDTH", "CENTER_RADIUS", "SPOTS", "AREA_LENGTH1", "AREA_WIDTH1",
               "AREA_LENGTH2", "AREA_WIDTH2", "DISTANCE_PENALTY", "RADIUS_CORNER",
               "GOALIE_POST_WIDTH")


def read_minho(path: Path):
    """(spec, used, not_geometry, warnings, extra) of a MINHO ``.view`` file (module doc)."""
    where = str(path)
    raw, unknown = {}, {}
    for n, line in enumerate(_read_text(path).splitlines(), 1):
        line = line.split("#", 1)[0]
        if not line.strip():
            continue
        m = _VIEW_LINE.match(line)
        if not m:
            raise FieldFormatError(f"{where}:{n}: cannot read '{line.strip()[:40]}' (expected"
                                   " KEY=VALUE in mm)")
        key, value = m.group(1), m.group(2)
        if key in raw:
            raise FieldFormatError(f"{where}:{n}: '{key}' given twice")
        raw[key] = value
    missing = [k for k in _MINHO_USED if k not in raw]
    if missing:
        raise FieldFormatError(f"{where}: a MINHO .view file needs {', '.join(missing)}")
    mm = {k: _num(raw[k], k, where) for k in _MINHO_USED}

    def m_(key):
        return mm[key] / 1000.0

    spec, warnings = {}, []
    _set(spec, ("length",), m_("LENGTH"))
    _set(spec, ("width",), m_("WIDTH"))
    _set(spec, ("line_width",), m_("LINE_WIDTH"))
    _border(spec, (m_("TOTAL_LENGTH") - m_("LENGTH")) / 2, (m_("TOTAL_WIDTH") - m_("WIDTH")) / 2,
            "(TOTAL_LENGTH - LENGTH) / 2 and (TOTAL_WIDTH - WIDTH) / 2", warnings)
    _set(spec, ("centre_circle_diameter",), 2 * m_("CENTER_RADIUS"))
    if mm["RADIUS_CORNER"] > 0:
        _set(spec, ("corner_arc_radius",), m_("RADIUS_CORNER"))
    _set(spec, ("goal_area", "length"), m_("AREA_LENGTH1"))
    _set(spec, ("goal_area", "width"), m_("AREA_WIDTH1"))
    _set(spec, ("penalty_area", "length"), m_("AREA_LENGTH2"))
    _set(spec, ("penalty_area", "width"), m_("AREA_WIDTH2"))
    _set(spec, ("penalty_mark", "distance"), m_("DISTANCE_PENALTY"))
    _set(spec, ("penalty_mark", "size"), m_("SPOTS"))
    _set(spec, ("goal", "width"), m_("GOAL_WIDTH") + m_("GOALIE_POST_WIDTH"))
    _set(spec, ("goal", "depth"), m_("GOAL_LENGTH"))
    _set(spec, ("goal", "post_diameter"), m_("GOALIE_POST_WIDTH"))
    not_geom = {}
    for key, value in raw.items():
        if key in _MINHO_USED:
            continue
        if key in _MINHO_NOT_GEOMETRY:
            not_geom[key] = _MINHO_NOT_GEOMETRY[key]
        else:
            unknown[key] = value
    if "GOALIE_LENGTH" in raw and abs(_num(raw["GOALIE_LENGTH"], "GOALIE_LENGTH", where)
                                      - mm["GOAL_WIDTH"]) > 1e-6:
        warnings.append(f"GOALIE_LENGTH ({raw['GOALIE_LENGTH']}) is not GOAL_WIDTH"
                        f" ({raw['GOAL_WIDTH']}): the goal width is GOAL_WIDTH's")
    used = {k: mm[k] for k in _MINHO_USED}
    return spec, used, not_geom, warnings, {"unknown": unknown,
                                            "kind": "MINHO .view (mm, line centres)"}


# ---------------------------------------------------------------------------- Carpe Noctem

_SECTION = re.compile(r"^\[(!?)([A-Za-z0-9_]+)\]$")
_CNC_KEY = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)\s*=\s*(.*)$")
_CNC_USED = ("FieldLength", "FieldWidth", "LineWidth", "Surrounding", "MiddleCircleRadius",
             "PenaltyAreaXSize", "PenaltyAreaYSize", "PenaltySpot", "GoalWidth", "GoalDepth",
             "GoalPostWidth")
_CNC_OPTIONAL = ("GoalAreaXSize", "GoalAreaYSize", "CornerCircleRadius")
_CNC_FLAGS = ("GoalInnerAreaExists", "CornerCircleExists")
_CNC_NOT_GEOMETRY = {
    "GoalHeight": "goal height",
    "PenaltyAreaMappingTolerance": "localisation setting (mm)",
    "YellowGoalDirection": "compass direction of a goal (rad)",
}


def cnc_sections(text: str, where: str) -> tuple[dict, dict, list]:
    """(top-level keys of [FootballField], {section: [(key, value, line number)]}, the
    sections outside [FootballField]) of a FootballField.conf, or of a conf that holds a
    [FootballField] block among other settings: the team's Globals.conf has it inside
    [Globals], beside [Team] and the like (not read), and with one field's keys in it
    directly: that block is then the one section, named ``FootballField``."""
    stack, top, sections, outside = [], {}, {}, []
    opened = []  # the line of each section in ``stack``
    block = []  # the keys directly in [FootballField], with their line numbers
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        m = _SECTION.match(line)
        if m:
            closing, name = m.group(1) == "!", m.group(2)
            if closing:
                if stack and stack[-1] != name and name in stack:  # an inner one left open (O12)
                    raise FieldFormatError(f"{where}:{opened[-1]}: [{stack[-1]}] is never"
                                           f" closed ([!{stack[-1]}]) before line {n}'s"
                                           f" [!{name}]")
                if not stack or stack[-1] != name:
                    raise FieldFormatError(f"{where}:{n}: [!{name}] closes no open [{name}]")
                stack.pop()
                opened.pop()
            else:
                if stack and stack[-1] == "FootballField":
                    if name in sections:
                        raise FieldFormatError(f"{where}:{n}: section [{name}] given twice")
                    sections[name] = []
                elif "FootballField" in stack:
                    if any(k in top for k in _CNC_USED):  # a field's keys directly in it
                        # (Globals.conf): its [!FootballField] is missing, not a level
                        line = opened[stack.index("FootballField")]
                        raise FieldFormatError(f"{where}:{line}: [FootballField] is never"
                                               " closed ([!FootballField]); line"
                                               f" {n}'s [{name}] lies within it")
                    raise FieldFormatError(f"{where}:{n}: [{name}] nested too deep")
                elif name != "FootballField":
                    outside.append(name)
                elif "FootballField" in sections or top or block:
                    raise FieldFormatError(f"{where}:{n}: [FootballField] given twice")
                stack.append(name)
                opened.append(n)
            continue
        kv = _CNC_KEY.match(line)
        if not kv:
            raise FieldFormatError(f"{where}:{n}: cannot read '{line[:40]}' (expected"
                                   " Key = Value or [Section])")
        if not stack:
            raise FieldFormatError(f"{where}:{n}: '{kv.group(1)}' outside [FootballField]")
        if "FootballField" not in stack:
            continue  # another setting of the conf (outside)
        if stack[-1] == "FootballField":
            if kv.group(1) in top:  # a CurrentField given twice: the last went unseen
                raise FieldFormatError(f"{where}:{n}: key '{kv.group(1)}' given twice")
            top[kv.group(1)] = kv.group(2).strip()
            block.append((kv.group(1), kv.group(2).strip(), n))
        else:
            sections[stack[-1]].append((kv.group(1), kv.group(2).strip(), n))
    if stack:
        raise FieldFormatError(f"{where}:{opened[-1]}: [{stack[-1]}] is never closed"
                               f" ([!{stack[-1]}])")
    if not sections and not block:
        raise FieldFormatError(f"{where}: no [FootballField] block (a field conf holds"
                               " [FootballField] ... [!FootballField])")
    if not sections and any(k in top for k in _CNC_USED):
        return {}, {"FootballField": block}, outside
    if not sections:
        raise FieldFormatError(f"{where}: no field sections inside [FootballField]")
    return top, sections, outside


def _flag(value: str, key: str, where: str) -> bool:
    v = value.strip().lower()
    if v in ("true", "1", "yes"):
        return True
    if v in ("false", "0", "no"):
        return False
    raise FieldFormatError(f"{where}: '{key}' must be true or false, got '{value[:40]}'")


def read_carpenoctem(path: Path, section: str | None = None):
    """(spec, used, not_geometry, warnings, extra) of one section of a Carpe Noctem
    ``FootballField.conf`` (module doc)."""
    where = str(path)
    top, sections, outside = cnc_sections(_read_text(path), where)
    one_block = not top and list(sections) == ["FootballField"]  # Globals.conf's form
    if one_block and section is not None:
        raise FieldFormatError(f"{where}: its [FootballField] holds one field's keys, no"
                               f" sections: import it without --section {section[:40]!r}")
    if section is not None and not section.strip():  # '' was taken for no --section
        raise FieldFormatError(f"{where}: --section {section!r} names no section (sections:"
                               f" {', '.join(sections)})")
    chosen = "FootballField" if one_block else section or top.get("CurrentField")
    if not chosen:
        raise FieldFormatError(f"{where}: no CurrentField; pass --section"
                               f" ({', '.join(sections)})")
    if chosen not in sections:
        raise FieldFormatError(f"{where}: no section [{chosen}] (sections:"
                               f" {', '.join(sections)})")
    raw, warnings = {}, []
    for key, value, n in sections[chosen]:
        if key in raw:
            if raw[key] != value and _maybe_num(raw[key]) != _maybe_num(value):
                raise FieldFormatError(f"{where}:{n}: '{key}' given twice in [{chosen}] with"
                                       f" two values ({raw[key][:20]}, {value[:20]})")
            warnings.append(f"'{key}' is given twice in [{chosen}] (same value)")
            continue
        raw[key] = value
    sub = f"{where} [{chosen}]"
    missing = [k for k in _CNC_USED if k not in raw]
    if missing:
        raise FieldFormatError(f"{sub}: no {', '.join(missing)}")
    mm = {k: _num(raw[k], k, sub) for k in _CNC_USED + _CNC_OPTIONAL if k in raw}
    flags = {k: _flag(raw[k], k, sub) if k in raw else True for k in _CNC_FLAGS}

    def m_(key):
        return mm[key] / 1000.0

    spec = {}
    _set(spec, ("length",), m_("FieldLength"))
    _set(spec, ("width",), m_("FieldWidth"))
    _set(spec, ("line_width",), m_("LineWidth"))
    _set(spec, ("border",), m_("Surrounding"))
    _set(spec, ("centre_circle_diameter",), 2 * m_("MiddleCircleRadius"))
    _set(spec, ("penalty_area", "length"), m_("PenaltyAreaXSize"))
    _set(spec, ("penalty_area", "width"), m_("PenaltyAreaYSize"))
    _set(spec, ("penalty_mark", "distance"), m_("PenaltySpot"))
    _set(spec, ("goal", "width"), m_("GoalWidth") + m_("GoalPostWidth"))
    _set(spec, ("goal", "depth"), m_("GoalDepth"))
    _set(spec, ("goal", "post_diameter"), m_("GoalPostWidth"))
    if flags["GoalInnerAreaExists"]:
        if "GoalAreaXSize" not in mm or "GoalAreaYSize" not in mm:
            raise FieldFormatError(f"{sub}: GoalInnerAreaExists but no GoalAreaXSize and"
                                   " GoalAreaYSize")
        _set(spec, ("goal_area", "length"), m_("GoalAreaXSize"))
        _set(spec, ("goal_area", "width"), m_("GoalAreaYSize"))
    else:
        warnings.append("GoalInnerAreaExists = false: no goal area")
    if flags["CornerCircleExists"] and mm.get("CornerCircleRadius", 0) > 0:
        _set(spec, ("corner_arc_radius",), m_("CornerCircleRadius"))
    used = dict(mm)
    used.update({k: raw[k] for k in _CNC_FLAGS if k in raw})
    not_geom, unknown = {}, {}
    for key, value in raw.items():
        if key in used:
            continue
        if key in _CNC_NOT_GEOMETRY:
            not_geom[key] = _CNC_NOT_GEOMETRY[key]
        else:
            unknown[key] = value
    for key, value in top.items():
        if key == "CurrentField":
            not_geom[key] = f"{value} (the team's current field)"
        else:
            unknown[f"FootballField.{key}"] = value
    others = [s for s in sections if s != chosen]
    if others:
        not_geom["other_sections"] = ", ".join(others)
    if outside:
        not_geom["outside_FootballField"] = ", ".join(outside) + " (the team's other settings)"
    if one_block:
        return spec, used, not_geom, warnings, {
            "unknown": unknown,
            "kind": f"Carpe Noctem {Path(path).name} [FootballField] (mm, line centres)"}
    return spec, used, not_geom, warnings, {
        "unknown": unknown, "section": chosen,
        "kind": f"Carpe Noctem FootballField.conf [{chosen}] (mm, line centres)"}


def _maybe_num(v: str):
    try:
        return float(v)
    except ValueError:
        return v


# ---------------------------------------------------------------------------- CAMBADA

_CAMBADA_USED = {
    "field_length": ("length",), "field_width": ("width",), "line_thickness": ("line_width",),
    "center_circle_radius": None, "corner_arc_radius": ("corner_arc_radius",),
    "goal_area_length": ("goal_area", "length"), "goal_area_width": ("goal_area", "width"),
    "penalty_area_length": ("penalty_area", "length"),
    "penalty_area_width": ("penalty_area", "width"),
    "penalty_marker_distance": ("penalty_mark", "distance"),
    "goal_width": ("goal", "width"), "goal_length": ("goal", "depth"),
    "goal_band_width": None, "side_band_width": None,
}
_CAMBADA_NOT_GEOMETRY = {
    "ball_diameter": "ball size", "goal_height": "goal height", "robot_radius": "robot size",
    "border_line_thickness": "outer lines' width (checked against line_thickness)",
    "source": "where the values come from",
}


# a JSON5 hexadecimal number (its sign, if any, is left before it); _WORD: a character a
# number cannot follow (a key or another number); _HEX_BITS: larger values are read as
# Infinity, which the readers refuse as they refuse any value beyond a field's
_JSON5_HEX = re.compile(r"0[xX]([0-9A-Fa-f]+)")
_WORD = re.compile(r"[A-Za-z0-9_.$]")
_HEX_BITS = 1024


def _json5(text: str, where: str):
    """JSON, or the JSON5 subset teams write: // and /* */ comments, trailing commas,
    unquoted keys, hexadecimal numbers (0x9: JSON5's, read as the decimal they stand for)."""
    try:
        return load_json(text)
    except RecursionError:
        raise FieldFormatError(f"{where}: JSON nested too deep") from None
    except RepeatedKeyError as e:  # JSON, refused (detect_format tells it by its cause)
        raise FieldFormatError(f"{where}: {e}") from e
    except ValueError:  # JSONDecodeError, or an integer of more than 4300 digits
        pass
    out, i, n, in_str = [], 0, len(text), False
    while i < n:  # drop comments outside strings
        c = text[i]
        if in_str:
            out.append(c)
            if c == "\\" and i + 1 < n:
                out.append(text[i + 1])
                i += 1
            elif c == '"':
                in_str = False
        elif c == '"':
            in_str = True
            out.append(c)
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            i = n if j < 0 else j + 2
            continue
        elif ((m := _JSON5_HEX.match(text, i)) and not (out and _WORD.match(out[-1]))
              and not _WORD.match(text, m.end())):  # 0x45d3.5 is no number (trial W2-7)
            value = int(m.group(1), 16)
            # beyond what any field number is (and the decimal digits Python writes)
            out.append(str(value) if value.bit_length() <= _HEX_BITS else "Infinity")
            i = m.end()
            continue
        else:
            out.append(c)
        i += 1
    body = re.sub(r",(\s*[}\]])", r"\1", "".join(out))
    body = re.sub(r"([{,]\s*)([A-Za-z_][A-Za-z0-9_]*)(\s*:)", r'\1"\2"\3', body)
    try:
        return load_json(body)
    except RecursionError:
        raise FieldFormatError(f"{where}: JSON nested too deep") from None
    except RepeatedKeyError as e:
        raise FieldFormatError(f"{where}: {e}") from e
    except ValueError as e:  # JSONDecodeError, or an integer of more than 4300 digits
        raise FieldFormatError(f"{where}: not valid JSON or JSON5 ({str(e)[:80]})") from None


def read_cambada(path: Path):
    """(spec, used, not_geometry, warnings, extra) of CAMBADA's field JSON (module doc)."""
    where = str(path)
    doc = _json5(_read_text(path), where)
    if not isinstance(doc, dict):
        raise FieldFormatError(f"{where}: not a CAMBADA field mapping")
    need = [k for k in ("field_length", "field_width", "line_thickness",
                        "center_circle_radius", "goal_band_width", "side_band_width")
            if k not in doc]
    if need:
        raise FieldFormatError(f"{where}: a CAMBADA field file needs {', '.join(need)}")
    used = {k: _num(doc[k], k, where) for k in _CAMBADA_USED if k in doc}
    spec, warnings = {}, []
    for key, target in _CAMBADA_USED.items():
        if target is not None and key in used and not (key == "corner_arc_radius"
                                                       and used[key] == 0):
            _set(spec, target, used[key] / 1000.0)
    _set(spec, ("centre_circle_diameter",), 2 * used["center_circle_radius"] / 1000.0)
    _border(spec, used["goal_band_width"] / 1000.0, used["side_band_width"] / 1000.0,
            "goal_band_width, side_band_width", warnings)
    if "goal_width" in used:
        warnings.append("goal_width read as the distance between the posts' centres (the file"
                        " gives no post width)")
    not_geom, unknown = {}, {}
    for key, value in doc.items():
        if key in used:
            continue
        if key in _CAMBADA_NOT_GEOMETRY:
            not_geom[key] = _CAMBADA_NOT_GEOMETRY[key]
        else:
            unknown[key] = value
    if "border_line_thickness" in doc and abs(
            _num(doc["border_line_thickness"], "border_line_thickness", where)
            - used["line_thickness"]) > 1e-6:
        warnings.append("border_line_thickness differs from line_thickness: the model has one"
                        " line width (line_thickness)")
    return spec, used, not_geom, warnings, {"unknown": unknown,
                                            "kind": "CAMBADA field (mm, line centres)"}


# ---------------------------------------------------------------------------- HULKs

_HULKS_USED = {
    "length": ("length",), "width": ("width",), "line_width": ("line_width",),
    "penalty_marker_size": ("penalty_mark", "size"),
    "penalty_marker_distance": ("penalty_mark", "distance"),
    "goal_box_area_length": ("goal_area", "length"),
    "goal_box_area_width": ("goal_area", "width"),
    "penalty_area_length": ("penalty_area", "length"),
    "penalty_area_width": ("penalty_area", "width"),
    "center_circle_diameter": ("centre_circle_diameter",),
    "border_strip_width": ("border",), "goal_depth": ("goal", "depth"),
    "goal_post_diameter": ("goal", "post_diameter"),
    "corner_arc_radius": ("corner_arc_radius",),
    "goal_inner_width": None,
}
_HULKS_NOT_GEOMETRY = {"ball_radius": "ball size"}


def read_hulks(path: Path):
    """(spec, used, not_geometry, warnings, extra) of HULKs' field_dimensions (module doc)."""
    where = str(path)
    doc = _json5(_read_text(path), where)
    if not isinstance(doc, dict) or not isinstance(doc.get("field_dimensions"), dict):
        raise FieldFormatError(f"{where}: no 'field_dimensions' mapping (HULKs field file)")
    fd = doc["field_dimensions"]
    used = {k: _num(fd[k], k, where) for k in _HULKS_USED if k in fd}
    spec, warnings = {}, []
    for key, target in _HULKS_USED.items():
        if target is not None and key in used and not (key == "corner_arc_radius"
                                                       and used[key] == 0):
            _set(spec, target, used[key])
    if "goal_inner_width" in used and "goal_post_diameter" in used:
        _set(spec, ("goal", "width"), used["goal_inner_width"] + used["goal_post_diameter"])
    not_geom, unknown = {}, {}
    for key, value in fd.items():
        if key in used:
            continue
        if key in _HULKS_NOT_GEOMETRY:
            not_geom[key] = _HULKS_NOT_GEOMETRY[key]
        else:
            unknown[key] = value
    for key, value in doc.items():
        if key != "field_dimensions":
            unknown[key] = value
    return spec, used, not_geom, warnings, {"unknown": unknown,
                                            "kind": "HULKs field_dimensions (m, line centres)"}
