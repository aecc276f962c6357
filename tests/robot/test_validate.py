"""The validation layer's pieces: sizes before reading, nesting before parsing, numbers with messages that
name the key (robot/validate.py)."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.validate import (Range, check_number, check_numbers, check_size, check_table,
                                         load_json_bounded, nesting_depth)


def test_nesting_depth_counts_brackets_outside_strings():
    assert nesting_depth('{"a": [1, [2, {"b": "[[[["}]]}') == 4
    assert nesting_depth("x = ['[', \"]\\\"[\"]") == 1
    assert nesting_depth("") == 0


@given(st.recursive(st.none() | st.integers() | st.text(max_size=4), lambda c: st.lists(c, max_size=3)
                    | st.dictionaries(st.text(max_size=3), c, max_size=3), max_leaves=20))
def test_nesting_depth_matches_the_structure(obj):
    def depth(o):
        if isinstance(o, list):
            return 1 + max((depth(v) for v in o), default=0)
        if isinstance(o, dict):
            return 1 + max((depth(v) for v in o.values()), default=0)
        return 0

    assert nesting_depth(json.dumps(obj)) == depth(obj)


@pytest.mark.parametrize("value, r, msg", [
    (math.nan, Range(lo=0.0), r"k must be a finite number in \[0, inf\]; got nan"),
    ("10", Range(), r"k must be a finite number in \[-inf, inf\]; got '10'"),
    (True, Range(), r"got True"),
    (0.0, Range(lo=0.0, lo_open=True), r"in \(0, inf\]; got 0.0"),
    (2.5, Range(lo=0, hi=9, integer=True), r"k must be an integer in \[0, 9\]; got 2.5"),
    (300, Range(lo=1, hi=255, integer=True), r"k must be an integer in \[1, 255\]; got 300"),
])
def test_check_number_refuses_precisely(value, r, msg):
    with pytest.raises(ConfigError, match=msg):
        check_number(value, "k", r)


def test_check_number_and_numbers_accept():
    assert check_number(3, "k", Range(lo=1, hi=5, integer=True)) == 3
    assert check_numbers([1, 2.5], "k", Range(n=2)) == (1.0, 2.5)
    with pytest.raises(ConfigError, match=r"k must be 2 numbers, each a finite number"):
        check_numbers([1.0], "k", Range(n=2))
    assert check_table({"a": [1, 2], "b": None, "c": "x"}, {"a": Range(n=2), "b": Range(optional=True)}, "t") == \
        {"a": (1.0, 2.0), "b": None, "c": "x"}


def test_files_are_measured_before_reading(tmp_path):
    with pytest.raises(ConfigError, match=r"no such prefilter file \(a directory\)"):
        check_size(tmp_path, 10, "prefilter")
    big = tmp_path / "big.json"
    big.write_text(" " * 2000 + "{}")
    with pytest.raises(ConfigError, match=r"big.json: 2002 bytes, more than a prefilter file may have \(1000 bytes\)"):
        load_json_bounded(big, "prefilter", limit=1000)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ConfigError, match=r"deep.json: nested 100000 levels deep, more than a prefilter file may be"):
        load_json_bounded(deep, "prefilter")
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(ConfigError, match=r"bad.json: not a prefilter JSON file \(JSONDecodeError"):
        load_json_bounded(bad, "prefilter")
