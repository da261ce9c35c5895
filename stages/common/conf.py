"""Stage confs: named presets plus `key=value` overrides, stored resolved in artifacts.

An override is checked against the type of the preset's value when it is merged
(``resolve_conf``), so a wrong value fails at once with the key's name instead of deep inside
a stage: a number where the preset has a number (``1e-4`` too, which YAML reads as text), a
whole number where it has one, true/false for a flag, a list for a list (a single value becomes
a one-element list), a group of keys only key by key (``a.b=1``). Numbers must be finite.
Presets whose value is None (optional) take anything.
"""

from __future__ import annotations

import copy
import errno
import importlib
import json
import numbers
import os
import re
from collections.abc import Callable, Iterator, Mapping

import numpy as np
import yaml

from .errors import FieldlocError, shown
from .user_numbers import user_number

_BASE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _StrictLoader(_BASE_LOADER):
    """The safe loader, refusing a mapping that names a key twice (YAML keeps the last one
    silently: a typo'd file would run with a value the user did not mean)."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:  # an unhashable key: the base constructor says so
                break
            if duplicate:
                shown = str(key) if len(str(key)) <= 40 else str(key)[:37] + "..."
                raise yaml.constructor.ConstructorError(
                    None, None, f"the key {shown!r} is given twice", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)

    def construct_plain_number(self, node):
        """An int or float as a person writes one: YAML 1.1 also reads ``1:30`` (base 60) as
        90, ``0x10`` as 16, ``010`` as 8 and ``1_0`` as 10, which no field or conf means (a
        field ``length: 1:30`` was built 90 m long): those are refused."""
        text = self.construct_scalar(node)
        is_int = node.tag.endswith(":int")
        if not (_PLAIN_INT if is_int else _PLAIN_FLOAT).fullmatch(text.strip()):
            raise yaml.constructor.ConstructorError(
                None, None, f"{text[:40]!r} is no decimal number (YAML 1.1's base 60, hex,"
                " octal or underscores); write it in decimal", node.start_mark)
        return super().construct_yaml_int(node) if is_int else super().construct_yaml_float(node)


# the ints and floats YAML reads that mean what they say: decimal (no leading zero, which
# YAML 1.1 reads as octal), a decimal fraction with an exponent, infinity or NaN
_PLAIN_INT = re.compile(r"[-+]?(?:0|[1-9][0-9]*)")
_PLAIN_FLOAT = re.compile(r"[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"
                          r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)")
_StrictLoader.add_constructor("tag:yaml.org,2002:int", _StrictLoader.construct_plain_number)
_StrictLoader.add_constructor("tag:yaml.org,2002:float", _StrictLoader.construct_plain_number)


# values a YAML document may hold once its aliases are expanded: fieldloc's files hold a few
# hundred; a "billion laughs" document (a few nested aliases) holds hundreds of millions
MAX_YAML_VALUES = 100_000


def _refuse_alias_bombs(text: str | bytes) -> None:
    """Refuse a document whose aliases (``*name``) expand to more than MAX_YAML_VALUES values,
    which would hang every reader. Aliases themselves are fine (yaml.dump writes them for a
    value used twice). Only a text with a '*' is scanned: libyaml's event stream, each
    anchored node's expanded size summed as it closes, nothing built."""
    if ("*" if isinstance(text, str) else b"*") not in text:
        return
    sizes: dict[str, int] = {}
    open_nodes: list[list] = [[None, 0]]  # [anchor, values so far] of each open collection
    for event in yaml.parse(text, Loader=_BASE_LOADER):
        if isinstance(event, yaml.CollectionStartEvent):
            open_nodes.append([event.anchor, 1])
            continue
        if isinstance(event, yaml.CollectionEndEvent):
            anchor, n = open_nodes.pop()
        elif isinstance(event, yaml.ScalarEvent):
            anchor, n = event.anchor, 1
        elif isinstance(event, yaml.AliasEvent):
            anchor, n = None, sizes.get(event.anchor, 1)
        else:
            continue
        if anchor is not None:
            sizes[anchor] = n
        open_nodes[-1][1] += n
        if open_nodes[-1][1] > MAX_YAML_VALUES:
            raise yaml.composer.ComposerError(
                None, None, f"YAML aliases expand to more than {MAX_YAML_VALUES} values",
                event.start_mark)


# the most a text file fieldloc reads whole (a dataset's simulation.yaml and calib.yaml, a field
# YAML, a batch SPEC, a team's field file) may weigh: the largest real one is a few tens of kB,
# and a 3 GB (sparse) simulation.yaml was read whole (16 s, 6.4 GB of memory) to be ignored
MAX_RECORD_BYTES = 10 << 20


def read_record(path, most: int = MAX_RECORD_BYTES) -> bytes:
    """The bytes of a small text file fieldloc reads whole; OSError (its strerror the reason,
    as the readers' handlers of an unreadable file quote) when it weighs more than ``most``
    bytes (MAX_RECORD_BYTES), before any of it is read."""
    size = os.stat(path).st_size
    with open(path, "rb") as f:
        data = f.read(most + 1)  # a file that grew since its stat
    if max(size, len(data)) > most:
        raise OSError(errno.EFBIG, f"{size / 1e6:.0f} MB, more than the"
                      f" {most >> 20} MB such a text file may weigh")
    return data


class RepeatedKeyError(ValueError):
    """A JSON object naming a key twice (``load_json``): valid JSON that is refused, which a
    reader trying several formats says as such rather than as no format at all."""


def load_json(raw: str | bytes):
    """The JSON text ``raw`` parsed; RepeatedKeyError (a ValueError, as json's own) where an
    object repeats a key,
    as load_yaml refuses one. json keeps the last of a repeated key: a note written as a first
    "run" key before fieldloc's left a record's digest as written, and a team's field file
    with "length" twice became a 90 m field, silently."""
    def no_repeats(pairs):
        out = dict(pairs)
        if len(out) != len(pairs):
            seen = set()
            key = next(k for k, _ in pairs if k in seen or seen.add(k))
            raise RepeatedKeyError(f"key {shown(key, 40)} given twice")
        return out

    return json.loads(raw, object_pairs_hook=no_repeats)


def load_yaml(text: str | bytes):
    """``yaml.safe_load`` with libyaml's parser where PyYAML has it (the same documents, read
    10-20x faster: a batch reads every dataset's records several times), refusing alias bombs,
    keys given twice and values its constructors cannot build (yaml.YAMLError, as for any
    malformed file)."""
    _refuse_alias_bombs(text)
    try:
        return yaml.load(text, Loader=_StrictLoader)  # noqa: S506 (a safe loader)
    except ValueError as e:  # a constructor's: an int of more than 4300 digits, a date 2024-13-01
        raise yaml.constructor.ConstructorError(
            None, None, f"a value YAML cannot read ({str(e)[:60]})") from None


def yaml_problem(e: yaml.YAMLError, text: str) -> str:
    """What is wrong in the YAML ``text`` that ``load_yaml`` refused with ``e``, in a message's
    words: the problem, after the line it is on, quoted by its first few dozen characters
    (which key: "line 12 ('seed: 1_0'): '1_0' is no decimal number ...")."""
    problem = " ".join(str(getattr(e, "problem", None) or e).split()) or type(e).__name__
    mark = getattr(e, "problem_mark", None)
    if mark is None:
        return problem
    lines = text.splitlines() if isinstance(text, str) else []
    quoted = f" ({shown(lines[mark.line].strip(), 40)})" if mark.line < len(lines) else ""
    return f"line {mark.line + 1}{quoted}: {problem}"


def parse_overrides(items, *, once: bool = False) -> dict:
    """['a=1', 'b.c=x'] -> {'a': 1, 'b': {'c': 'x'}} (values parsed as YAML scalars; their type
    is checked against the preset in ``resolve_conf``). A key given twice: the last wins (the
    command line's ``-c``, where a wrapper may append to a user's options), or with ``once``
    (a file's list, as a batch SPEC's ``conf:``, where a repeat is a slip as a YAML key given
    twice is) FieldlocError "the key KEY is given twice"."""
    out: dict = {}
    seen: set[str] = set()
    for item in items or ():
        if "=" not in item:
            raise FieldlocError(f"conf override '{item}' is not of the form key=value")
        key, value = item.split("=", 1)
        parts = [p.strip() for p in key.strip().split(".")]
        if not all(parts):
            raise FieldlocError(f"conf override '{item}': the key '{key}' is not a conf key name")
        if once and ".".join(parts) in seen:
            raise FieldlocError(f"the key {shown('.'.join(parts), 40)} is given twice")
        seen.add(".".join(parts))
        try:
            parsed = load_yaml(value)
        except yaml.YAMLError:
            parsed = value
        if isinstance(parsed, (dict, list)) and not isinstance(parsed, list):
            raise FieldlocError(
                f"conf override '{item}': give the keys of a group one by one (key.sub=value)")
        if isinstance(parsed, list):
            parsed = [_exponent_number(v) for v in parsed]
        d = out
        for i, p in enumerate(parts[:-1]):
            d = d.setdefault(p, {})
            if not isinstance(d, dict):
                raise FieldlocError(
                    f"conf override '{item}': '{'.'.join(parts[:i + 1])}' was given a value"
                    " before; it cannot also hold keys")
        if isinstance(d.get(parts[-1]), dict):
            raise FieldlocError(
                f"conf override '{item}': '{key.strip()}' was given keys before; it cannot"
                " also hold a value")
        d[parts[-1]] = parsed
    return out


# a number in exponent notation without a point (1e12, -2E-3), which YAML 1.1 reads as text
_EXPONENT_NUMBER = re.compile(r"[-+]?[0-9]+[eE][-+]?[0-9]+")


def _exponent_number(v):
    """``1e12`` (a list element of an override, or the value of a key whose preset is None,
    e.g. a camera height) as the number the user typed: YAML 1.1 reads it as text, which the
    stage would refuse as not a number."""
    if isinstance(v, str) and _EXPONENT_NUMBER.fullmatch(v.strip()):
        return float(v)
    return v


def resolve_conf(confs: dict, preset: str | dict | None, overrides: dict | None = None,
                 default: str = "default") -> dict:
    """A copy of ``confs[preset]`` (or a given dict) with ``overrides`` merged in. Unknown
    preset names and unknown override keys are user errors."""
    if isinstance(preset, dict):
        base = copy.deepcopy(preset)
    else:
        name = preset or default
        if name not in confs:
            raise FieldlocError(f"unknown preset '{name}' (presets: {', '.join(sorted(confs))})")
        base = copy.deepcopy(confs[name])
    for key, value in (overrides or {}).items():
        _merge(base, key, value, key)
    return base


def stage_conf(confs: dict, conf: str | dict | None, default: str = "default") -> dict:
    """The stage contract's conf: a preset name, None (the default preset), or a dict of
    overrides on the default preset (a complete conf is a dict of overrides too; groups are
    merged key by key); unknown preset names and keys are user errors. A stage with kinds of
    presets passes the default preset of the kind in play as ``default`` (simulate: of the
    conf's camera, localize: of its method, extract: of the dataset's camera)."""
    if conf is None or isinstance(conf, str):
        return resolve_conf(confs, conf, default=default)
    if not isinstance(conf, dict):
        raise FieldlocError(f"a conf is a preset name or a dict of values, not {conf!r}")
    return resolve_conf(confs, default, conf, default=default)


def _merge(base: dict, key, value, path):
    if not isinstance(base, dict):
        raise FieldlocError(f"conf '{path}': its parent is not a group of keys")
    if key not in base:
        known = ", ".join(sorted(map(str, base)))
        raise FieldlocError(f"unknown conf key {shown(path)} (known: {known})")
    if isinstance(base[key], dict) and isinstance(value, dict):
        for k, v in value.items():
            _merge(base[key], k, v, f"{path}.{k}")
    else:
        base[key] = checked_value(base[key], value, path)


def _number(value, path: str, whole: bool):
    """A finite number (int when ``whole``) from an override value, or FieldlocError: the
    reading of every number a user writes (stages.common.user_numbers)."""
    return user_number(value, f"conf '{path}'", whole=whole)


def checked_value(old, value, path: str):
    """``value`` as a replacement of the preset value ``old`` (see the module doc), or a
    FieldlocError naming ``path``."""
    if old is None:  # no preset type to read the text by: 5e-1 is the number typed
        return _exponent_number(value)
    if isinstance(old, dict):
        keys = ", ".join(f"{path}.{k}" for k in list(old)[:4])
        raise FieldlocError(
            f"conf '{path}' is a group of keys; set them one by one ({keys}, ...), got"
            f" {shown(value)}")
    if isinstance(old, (bool, np.bool_)):
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise FieldlocError(f"conf '{path}' must be true or false, got {shown(value)}")
    if isinstance(old, numbers.Integral):
        return _number(value, path, whole=True)
    if isinstance(old, numbers.Real):
        return _number(value, path, whole=False)
    if isinstance(old, str):
        if isinstance(value, str):
            return value
        if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
            return str(value)
        raise FieldlocError(f"conf '{path}' must be a text, got {shown(value)}")
    if isinstance(old, (list, tuple, np.ndarray)):
        if isinstance(value, np.ndarray):
            value = value.tolist()
        if isinstance(value, tuple):
            value = list(value)
        if not isinstance(value, list):
            if isinstance(value, (dict, type(None))):
                raise FieldlocError(f"conf '{path}' must be a list, got {shown(value)}")
            value = [value]
        template = list(old)
        if template and all(_is_number(t) for t in template):
            whole = all(isinstance(t, numbers.Integral) for t in template)
            return [_number(v, f"{path}[{i}]", whole) for i, v in enumerate(value)]
        if template and all(isinstance(t, str) for t in template):
            return [checked_value(template[0], v, f"{path}[{i}]") for i, v in enumerate(value)]
        return value
    return value


def _is_number(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def registered_module(registry: dict[str, str], name: str, what: str):
    """The module registered under ``name`` (imported on first use); an unknown name is a user
    error that lists the known ones. ``what`` names the registry in the message."""
    if name not in registry:
        raise FieldlocError(f"unknown {what} '{name}' (known: {', '.join(registry)})")
    return importlib.import_module(registry[name])


class KindPresets(Mapping):
    """The presets of every kind of a stage (its methods, its cameras) as one read-only
    mapping, ``"<kind>-<preset>"`` -> conf, whose kinds' modules are imported only when one of
    their presets is asked for: ``fieldloc localize --method lut`` then loads lut's compiled
    kernels and not mcl's or the template matcher's (a process's start time).
    ``presets_of(kind)`` gives a kind's presets; ``entry(kind, conf)`` the stored entry (e.g.
    with the kind's name added); ``aliases`` maps further names to ``(kind, preset)``
    ("default"). Listing the keys imports every kind."""

    def __init__(self, kinds, presets_of: Callable[[str], dict],
                 entry: Callable[[str, dict], dict] = lambda kind, conf: conf,
                 aliases: dict[str, tuple[str, str]] | None = None):
        self._kinds = list(kinds)
        self._presets_of = presets_of
        self._entry = entry
        self._aliases = dict(aliases or {})

    def __getitem__(self, name: str) -> dict:
        if not isinstance(name, str):
            raise KeyError(name)
        if name in self._aliases:
            kind, preset = self._aliases[name]
        else:
            kind = next((k for k in self._kinds if name.startswith(f"{k}-")), None)
            if kind is None:
                raise KeyError(name)
            preset = name[len(kind) + 1:]
        presets = self._presets_of(kind)
        if preset not in presets:
            raise KeyError(name)
        return self._entry(kind, presets[preset])

    def __iter__(self) -> Iterator[str]:
        yield from self._aliases
        for kind in self._kinds:
            for preset in self._presets_of(kind):
                yield f"{kind}-{preset}"

    def __len__(self) -> int:
        return sum(1 for _ in self)


# a count of a check_bounds entry: two numbers [low, high] with low <= high (the range a
# value is drawn from: reversed, every draw falls outside it or the draw is refused deep inside)
PAIR = "pair"
# a count of a check_bounds entry: one number, not a list (a key whose preset is None takes any
# YAML value when resolved, so a list or a mapping would otherwise reach the stage)
SCALAR = "scalar"
_ABSENT = object()  # check_bounds: a key an optional entry names that the conf does not hold


def check_bounds(conf: dict, bounds: Mapping[str, tuple], prefix: str = "",
                 optional: bool = False) -> None:
    """Each ``bounds`` entry, ``"key.path": (low, high)``, holds the conf value at that path to
    low <= value <= high; a bound written as a one-element tuple ``(x,)`` is strict (the value
    must not equal x), None is no bound. A list value is held element by element, and an entry
    ``(low, high, count)`` holds its length too: ``count`` elements, or between the two of a
    ``(fewest, most)`` pair (a pair of thresholds given one number unpacks into nothing), or
    ``PAIR``: a range [low, high] whose first number is not above its second; a value that is
    not a list is refused there (a key whose preset is None takes any value when resolved);
    ``SCALAR``: one number, a list refused.
    Every value held is a finite number. One FieldlocError line for the first value outside,
    naming the key as ``prefix`` + its path (the group a part of a conf was taken from).
    With ``optional``, a key the conf does not hold is passed over (a conf of another kind, or
    a stored one, holds only some of them).
    The types of keys with a preset value are checked where the conf is resolved
    (checked_value); these are the ranges a value must lie in for the method to run at all (a
    zero count divides by zero, a count of 1e12 runs for hours)."""
    for key, (low, high, *count) in bounds.items():
        v = conf
        for part in key.split("."):
            if optional and (not isinstance(v, dict) or part not in v):
                v = _ABSENT
                break
            v = v[part]
        if v is _ABSENT:
            continue
        path = prefix + key
        if v is None:
            continue
        if isinstance(v, np.ndarray):
            v = v.tolist()
        if count and count[0] == SCALAR:
            if isinstance(v, (list, tuple)):
                raise FieldlocError(f"conf '{path}' must be a number, got {shown(v, 40)}")
            count = []
        if isinstance(v, (list, tuple)):
            if count and not _count_ok(len(v), count[0]):
                raise FieldlocError(f"conf '{path}' must be a list of {_count_text(count[0])},"
                                    f" got {shown(v, 40)}")
            items = [(f"{path}[{i}]", x) for i, x in enumerate(v)]
        elif count:
            raise FieldlocError(f"conf '{path}' must be a list of {_count_text(count[0])}, got"
                                f" {shown(v, 40)}")
        else:
            items = [(path, v)]
        for name, x in items:
            if not _is_number(x):
                raise FieldlocError(f"conf '{name}' must be a number, got {shown(x, 40)}")
            user_number(x, f"conf '{name}'")  # within the float range, finite
            if _beyond(x, low, 1) or _beyond(x, high, -1):
                parts = [_bound_text(low, ">"), _bound_text(high, "<")]
                raise FieldlocError(f"conf '{name}' must be"
                                    f" {' and '.join(p for p in parts if p)}, got {shown(x, 40)}")
        if count and count[0] == PAIR and v[0] > v[1]:
            raise FieldlocError(f"conf '{path}' must be a range [low, high] with low <= high,"
                                f" got {shown(v, 40)}")


def _count_ok(n: int, count) -> bool:
    if count == PAIR:
        return n == 2
    if isinstance(count, tuple):
        return count[0] <= n and (count[1] is None or n <= count[1])
    return n == count


def _count_text(count) -> str:
    """'2 numbers', 'at least 1 number', '1 to 8 numbers', '2 numbers [low, high]'."""
    if count == PAIR:
        return "2 numbers [low, high]"
    if not isinstance(count, tuple):
        return f"{count} number{'s' if count != 1 else ''}"
    if count[1] is None:
        return f"at least {count[0]} number{'s' if count[0] != 1 else ''}"
    return f"{count[0]} to {count[1]} numbers"


def _beyond(v, bound, side: int) -> bool:
    """Whether ``v`` lies beyond ``bound`` (side 1: below a low bound, -1: above a high one)."""
    if bound is None:
        return False
    if isinstance(bound, tuple):
        return (v - bound[0]) * side <= 0
    return (v - bound) * side < 0


def _bound_text(bound, sign: str) -> str:
    if bound is None:
        return ""
    if isinstance(bound, tuple):
        return f"{sign} {bound[0]:g}"
    return f"{sign}= {bound:g}"
