"""The last gate (firmware_bridge/gate.py): whatever a mode proposes -- NaN, 1e6, a step of the whole
steering offset -- what leaves is finite, inside the envelope and moves the correction at most ``rate``
per tick from where it stood."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge.gate import GATE_FLAGS, SetpointGate

LO, HI = np.array([-1.0, -0.5]), np.array([20.0, 0.5])
RATE = np.array([0.005, 0.002])

_u = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-2.0, 3.0))
_r = st.floats(0.0, 2.0)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(_u, _u, _r, st.floats(-0.3, 0.3)), min_size=2, max_size=60))
def test_every_applied_reference_is_finite_inside_and_rate_limited(ticks):
    gate = SetpointGate(LO, HI, RATE)
    prev_u = prev_r = None
    for u0, u1, r0, r1 in ticks:
        r = np.array([r0, r1])
        out, _ = gate.apply(np.array([u0, u1]), r)
        assert np.all(np.isfinite(out)) and np.all(out >= LO) and np.all(out <= HI)
        if prev_u is not None:
            assert np.all(np.abs(out - prev_u) <= RATE + np.abs(r - prev_r) + 1e-12)
        prev_u, prev_r = out, r


def test_a_fallback_blends_back_at_the_rate_and_is_flagged():
    gate = SetpointGate(LO, HI, RATE)
    r = np.array([1.0, 0.0])
    out, flags = gate.apply(r + [0.3, 0.1], r)  # the first tick: nothing to limit from
    assert flags == 0 and out.tolist() == [1.3, 0.1]
    out, flags = gate.apply(r, r)  # the steering hands back (step_too_large, solver failure, ...)
    assert flags == GATE_FLAGS["rate_limited"]
    assert out == pytest.approx([1.3 - 0.005, 0.1 - 0.002])
    n = 1
    while not np.array_equal(out, r):
        out, flags = gate.apply(r, r)
        n += 1
    assert n == 60  # 0.3 m at 5 mm per tick (the pitch offset was back after 50)
    assert gate.counts["rate_limited"] == 59


def test_nonfinite_and_out_of_envelope_proposals():
    gate = SetpointGate(LO, HI, None)
    r = np.array([1.0, 0.0])
    out, flags = gate.apply(np.array([np.nan, 1e6]), r)
    assert out.tolist() == [1.0, 0.5] and flags == GATE_FLAGS["nonfinite_reference"] | GATE_FLAGS["envelope"]
    out, flags = gate.apply(r, np.array([np.nan, 0.0]))  # no nominal to hand back to: hold
    assert out.tolist() == [1.0, 0.5] and flags == GATE_FLAGS["nonfinite_reference"]


def test_bad_bounds_are_refused():
    with pytest.raises(ValueError, match=r"the envelope needs lo < hi per reference; got \[1.0\], \[0.0\]"):
        SetpointGate(np.array([1.0]), np.array([0.0]))
    with pytest.raises(ValueError, match=r"rate must be > 0 per reference; got \[0.0, 1.0\]"):
        SetpointGate(LO, HI, np.array([0.0, 1.0]))
