"""stages.common.user_numbers: the one reading of a number a user wrote (conf overrides, calib.yaml,
simulation.yaml, teams' field files). The commands that read them are held to it by the cases
of tests/test_faults.py (group "s54 group H1: numbers")."""

from __future__ import annotations

import pytest

from stages.common.errors import DatasetError, FieldlocError
from stages.common.user_numbers import user_number, user_numbers

HUGE = int("9" * 400)  # beyond the float range: float() of it raises OverflowError


@pytest.mark.parametrize("value,kwargs,expected", [
    (3, {}, 3.0), (2.5, {}, 2.5), ("1e-4", {}, 1e-4), (" -7 ", {}, -7.0),
    (4.0, {"whole": True}, 4), ("12", {"whole": True}, 12),
    (10**300, {"whole": True}, 10**300),  # within the float range: kept exact
    (float("inf"), {"finite": False}, float("inf")),
])
def test_numbers_taken(value, kwargs, expected):
    got = user_number(value, "k", **kwargs)
    assert got == expected and type(got) is type(expected)


@pytest.mark.parametrize("value,kwargs,message", [
    (True, {}, "k must be a number, got True"),  # YAML's yes
    (False, {"whole": True}, "k must be a whole number, got False"),
    ("yes", {}, "k must be a number, got 'yes'"),
    ("1_000", {}, "k must be a number, got '1_000'"),
    (None, {}, "k must be a number, got None"),
    ([1], {}, "k must be a number, got [1]"),
    (HUGE, {}, "k must be a number within the float range, got an integer too large"),
    (-HUGE, {"whole": True}, "k must be a whole number within the float range"),
    (float("nan"), {}, "k must be a finite number, got nan"),
    ("-inf", {}, "k must be a finite number, got '-inf'"),
    (2.5, {"whole": True}, "k must be a whole number, got 2.5"),
    ("x" * 500, {}, "got '" + "x" * 36 + "..."),  # a few dozen characters quoted
])
def test_numbers_refused_in_one_line(value, kwargs, message):
    with pytest.raises(FieldlocError) as err:
        user_number(value, "k", **kwargs)
    text = str(err.value)
    assert message in text and "\n" not in text and len(text) < 120


def test_lists_name_each_element_and_take_the_callers_error():
    assert user_numbers([1, "2.5"], "k", count=2) == [1.0, 2.5]
    with pytest.raises(DatasetError, match=r"k\[1\] must be a number, got True"):
        user_numbers([1, True], "k", error=DatasetError)
    with pytest.raises(DatasetError, match="k must be a list of 2 numbers, got"):
        user_numbers([1, 2, 3], "k", count=2, error=DatasetError)
    with pytest.raises(FieldlocError, match="k must be a list of numbers, got 'ab'"):
        user_numbers("ab", "k")
