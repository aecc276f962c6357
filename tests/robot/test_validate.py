"""The validation layer's pieces: numbers with messages that name the key (robot/validate.py; the files'
sizes and nesting: tests/values/test_files.py)."""

from __future__ import annotations

import math

import pytest

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.validate import Range, check_number, check_numbers, check_table


@pytest.mark.parametrize("value, r, msg", [
    (math.nan, Range(lo=0.0), r"k must be a finite number in \[0, inf\]; got nan"),
    ("10", Range(), r"k must be a finite number in \[-inf, inf\]; got '10'"),
    (True, Range(), r"got True"),
    (0.0, Range(lo=0.0, lo_open=True), r"in \(0, inf\]; got 0.0"),
    (2.5, Range(lo=0, hi=9, integer=True), r"k must be an integer in \[0, 9\]; got 2.5"),
    (300, Range(lo=1, hi=255, integer=True), r"k must be an integer in \[1, 255\]; got 300"),
    (10**400, Range(lo=1e-3, hi=1e3), r"k must be a finite number in \[0.001, 1000\]; got 1000000"),  # no OverflowError
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
