"""Numbers a user wrote: one strict reading for every reader of a user's file or option (conf
overrides and presets, calib.yaml, simulation.yaml, teams' field files, CSV cells).

    parse_number(text) -> float              a number written as text (ValueError otherwise)
    user_number(value, name, ...) -> float | int
    user_numbers(values, name, ...) -> list  a list of them, each named name[i]

What a reader is handed (YAML, JSON, text) is not yet a number: ``yes`` is a YAML boolean (a bool
is an int to Python: float(True) is 1.0), a JSON or YAML integer has no size limit (float() of
one of 400 digits raises OverflowError), and text may say ``nan`` or ``1_000``. ``user_number``
takes an int, a float or numeric text and refuses everything else with one message naming the
value's key, as the caller's error class (DatasetError for a dataset's file, ...).
"""

from __future__ import annotations

import math
import numbers
import re

import numpy as np

from .errors import FieldlocError, shown

# a number as a CSV holds one: ASCII decimal or scientific notation, or a spelling of NaN or
# infinity (refused below, with a message of its own, except where NaN is allowed). Python's
# float() also takes "1_000" and non-ASCII digits ("٣" is 3), which no logger writes: such a
# cell is a damaged one, not a number
NUMBER = re.compile(r"[+-]?(?:(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
                    r"|(?i:nan|inf|infinity))")


def parse_number(text: str) -> float:
    """The number a file's cell or value holds (``NUMBER``: ASCII decimal or scientific
    notation, or a spelling of NaN or infinity), for every reader of numbers a user gives;
    ValueError otherwise, as float() raises (which also took "1_000" and "٣")."""
    if not NUMBER.fullmatch(text.strip()):
        raise ValueError(f"not a number: {text[:20]!r}")
    return float(text)


def user_number(value, name: str, *, whole: bool = False, finite: bool = True,
                error: type[FieldlocError] = FieldlocError) -> float | int:
    """``value`` as a float (an int when ``whole``), or ``error`` with one line
    ``"{name} must be ..., got ..."``: ``name`` says where the value stands (e.g.
    ``"conf 'hypotheses'"``, ``"calib.yaml: 'height'"``). Taken: an int, a float, or text
    that ``parse_number`` reads (YAML 1.1 reads ``1e-4`` as text). Refused: a bool (YAML's
    ``yes``), anything else that is no number, an integer beyond the float range (its
    digits are not quoted), NaN and infinity (unless ``finite`` is False), and with
    ``whole`` a number with a fraction."""
    want = "a whole number" if whole else "a number"
    v = value
    if isinstance(v, str):
        try:
            v = parse_number(v)
        except ValueError:
            raise error(f"{name} must be {want}, got {shown(value, 40)}") from None
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
        raise error(f"{name} must be {want}, got {shown(value, 40)}")
    try:
        f = float(v)
    except OverflowError:  # an int beyond 1.8e308 (not quoted: it has hundreds of digits)
        raise error(f"{name} must be {want} within the float range, got an integer too large"
                    " for it (beyond 1.8e308)") from None
    if finite and not math.isfinite(f):
        raise error(f"{name} must be a finite number, got {shown(value, 40)}")
    if whole:
        if not math.isfinite(f) or f != int(f):
            raise error(f"{name} must be a whole number, got {shown(value, 40)}")
        return int(v) if isinstance(v, numbers.Integral) else int(f)
    return f


def user_numbers(values, name: str, *, count: int | tuple[int, ...] | None = None,
                 **kwargs) -> list:
    """A list of numbers (``user_number`` each, named ``name[i]``, inside the quotes that end
    ``name``, ``kwargs`` passed on), or
    the error class ``kwargs`` name with one line when ``values`` is no list or tuple, or not
    of ``count`` elements (one count, or a tuple of the counts taken)."""
    error = kwargs.get("error", FieldlocError)
    if isinstance(values, np.ndarray) and values.ndim == 1:  # a preset's array
        values = values.tolist()
    counts = (count,) if isinstance(count, int) else count
    if not isinstance(values, (list, tuple)) or (counts and len(values) not in counts):
        what = "a list of " + (" or ".join(map(str, counts)) + " numbers" if counts
                               else "numbers")
        raise error(f"{name} must be {what}, got {shown(values, 40)}")
    quote = "'" if name.endswith("'") else ""  # "calib.yaml: 'centre'" -> "... 'centre[0]'"
    stem = name[:len(name) - len(quote)]
    return [user_number(v, f"{stem}[{i}]{quote}", **kwargs) for i, v in enumerate(values)]


def json_float(value) -> float | None:
    """``value`` as a float where it is a JSON number (not a boolean) a float holds finitely;
    None otherwise (text, NaN, inf, or an integer of 400 digits, whose float() overflows:
    trial Z1-1)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        v = float(value)
    except OverflowError:
        return None
    return v if math.isfinite(v) else None
