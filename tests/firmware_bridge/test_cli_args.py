"""The command lines' value types: what each accepts, and the precise error for what it does not."""

from __future__ import annotations

import argparse
import re

import pytest

from firmware_bridge.cli_args import (
    cpu_list,
    fault_spec,
    floats,
    floats_or_none,
    margin_us,
    push_spec,
    qos_request,
    time_window,
)


def test_values_parse_to_their_tuples():
    assert floats("0.5,-1e-3") == (0.5, -0.001)
    assert floats_or_none("None") is None and floats_or_none("1,2") == (1.0, 2.0)
    assert time_window("2.5:4") == (2.5, 4.0)
    assert fault_spec("10:3") == (10, 3) and fault_spec("10:3:nan") == (10, 3, "nan")
    assert cpu_list("1,3") == (1, 3)
    assert push_spec("6:3,0,-8") == (6.0, (3.0, 0.0, -8.0), 0.1) and push_spec("1:0,0,5:0.3")[2] == 0.3
    assert qos_request(-1) is None and qos_request(0) == 0


@pytest.mark.parametrize("parse, text, message", [
    (floats, "1,x", "expected comma-separated numbers, got '1,x'"),
    (floats_or_none, "nan-ish", "expected comma-separated numbers, got 'nan-ish'"),
    (time_window, "3", "expected T0:T1 (seconds), got '3'"),
    (fault_spec, "10", "expected START:COUNT[:fail|nan], got '10'"),
    (fault_spec, "10:3:crash", "expected START:COUNT[:fail|nan], got '10:3:crash'"),
    (cpu_list, "1,two", "expected comma-separated CPU numbers, got '1,two'"),
    (cpu_list, "-1", "CPU numbers are >= 0, got '-1'"),
    (push_spec, "6:3,0", "expected T:FX,FY,FZ[:DUR] (s, N, s; DUR > 0), got '6:3,0'"),
    (push_spec, "6:3,0,1:0", "got '6:3,0,1:0'"),
    (push_spec, "inf:3,0,1", "got 'inf:3,0,1'"),
])
def test_bad_values_are_refused_with_the_expected_form(parse, text, message):
    with pytest.raises(argparse.ArgumentTypeError, match=re.escape(message)):
        parse(text)


def test_tick_margin_is_microseconds_or_free():
    assert margin_us("250") == 250.0 and margin_us("0") == 0.0 and margin_us(" Free ") is None
    for bad in ("-1", "nan", "inf", "soon"):
        with pytest.raises(argparse.ArgumentTypeError, match="microseconds"):
            margin_us(bad)
