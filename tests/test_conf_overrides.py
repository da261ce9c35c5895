"""A conf key given twice in ``key=value`` overrides: on the command line (``-c``) the last
wins, as a wrapper or alias appending its own ``-c`` to a user's expects; in a file's list (a
batch SPEC's ``conf: [...]``) it is refused, as a YAML key given twice is: one value would win
silently (trial M4)."""

from __future__ import annotations

import pytest

from stages.common.conf import parse_overrides
from stages.common.errors import FieldlocError


def test_a_repeated_command_line_override_keeps_the_last():
    assert parse_overrides(["min_confidence=0.5", "min_confidence=0.9"]) == {
        "min_confidence": 0.9}
    assert parse_overrides(["a.b=1", "a . b=2"]) == {"a": {"b": 2}}


@pytest.mark.parametrize("items,key", [
    (["min_confidence=0.5", "min_confidence=0.9"], "'min_confidence'"),
    (["a.b=1", "a.c=2", " a . b =3"], "'a.b'"),
])
def test_a_repeated_override_in_a_file_is_refused(items, key):
    with pytest.raises(FieldlocError, match=f"^the key {key} is given twice$"):
        parse_overrides(items, once=True)
    assert parse_overrides(items[:-1], once=True)  # each key once: read
