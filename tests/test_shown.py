"""twin.errors.shown: a user's value quoted in a one-line message (the one helper the
scenario schema, the plugin registry and the sweep store share)."""
from __future__ import annotations

import numpy as np

from twin.errors import QUOTE_LIMIT, shown


class _BadRepr:
    def __repr__(self):
        raise RuntimeError("no repr")


class _Layout:
    def __repr__(self):
        return "Layout(\n    a=1,\n\tb='\x1b[31m')"


def test_control_characters_are_escaped_and_the_message_stays_one_line():
    assert shown("a\nb\x00c\u2028") == r"'a\nb\x00c\u2028'"
    assert shown("a  b") == "'a  b'"  # a str's own spaces are its value
    assert shown(np.eye(2)) == "array([[1., 0.], [0., 1.]])"  # a multi-line repr's layout: one space
    assert shown(_Layout()) == r"Layout( a=1, b='\x1b[31m')"
    for v in ("x\r\ny", np.zeros((3, 3)), _Layout(), {"k": "\x85\t"}):
        assert shown(v).isprintable(), shown(v)


def test_long_values_are_cut_at_the_limit():
    assert len(shown("x" * 10**6)) == QUOTE_LIMIT and shown("x" * 10**6).endswith("…")
    assert shown("x" * 100, 20) == "'" + "x" * 18 + "…"
    assert shown("abc", 5) == "'abc'"


def test_what_cannot_be_shown_is_named_by_its_type():
    assert shown(_BadRepr()) == "<a _BadRepr>"
    assert shown(10 ** 5000) == "<a int>"  # beyond Python's 4300-digit conversion
    assert shown(object(), as_json=True) == "<a object>"


def test_values_read_from_json_are_shown_as_json():
    assert [shown(v, as_json=True) for v in (None, True, [1, "x"], {"a": 1.5})] == \
        ["null", "true", '[1, "x"]', '{"a": 1.5}']
    assert shown("a\nb\x7f\u2028é", as_json=True) == r'"a\nb\x7f\u2028é"'


def test_the_old_names_still_work():
    from twin import protocols
    from twin.scenarios import schema

    assert protocols.shown is shown and schema.shown is shown
