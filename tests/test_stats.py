"""The one percentile summary and the tick-to-tick step rms (ddpc_codegen.stats)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ddpc_codegen.stats import percentiles, step_rms


def test_percentiles_keys_values_and_empty_input():
    a = np.arange(101.0)
    assert percentiles(a) == {"p50": 50.0, "p99": 99.0, "max": 100.0, "n": 101}
    assert percentiles([1.0, np.nan, np.inf, 3.0]) == {"p50": 2.0, "p99": 2.98, "max": 3.0, "n": 2}
    assert percentiles([], qs=(50, 99.99)) == {"p50": None, "p99.99": None, "max": None, "n": 0}
    assert percentiles(np.ones((2, 3)), qs=(10,))["n"] == 6


def test_step_rms_of_a_ramp_a_constant_and_a_broken_mask():
    t = np.arange(10.0)
    x = np.c_[0.5 * t, np.full(10, 3.0)]  # 0.5 per tick, constant
    assert step_rms(x) == [0.5, 0.0]
    mask = np.ones(10, bool)
    mask[4] = False  # pairs (3, 4) and (4, 5) drop out, (5, 6) counts
    x2 = x.copy()
    x2[4, 0] = 100.0  # a jump only through the masked tick
    assert step_rms(x2, mask)[0] == pytest.approx(0.5)
    assert step_rms(np.zeros((5, 2)), np.zeros(5, bool)) == [None, None]  # no pair: null, not NaN
    assert step_rms(np.arange(4.0)) == [1.0]  # a 1-D series is one column
    with pytest.raises(ValueError, match="mask has 3 ticks, x has 4"):
        step_rms(np.arange(4.0), np.ones(3, bool))


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 30), st.integers(1, 3)), elements=st.floats(-1e3, 1e3)),
       st.data())
def test_step_rms_equals_the_pairwise_definition(x, data):
    mask = np.array(data.draw(st.lists(st.booleans(), min_size=x.shape[0], max_size=x.shape[0])))
    got = step_rms(x, mask)
    for j in range(x.shape[1]):
        d = [x[k + 1, j] - x[k, j] for k in range(x.shape[0] - 1) if mask[k] and mask[k + 1]]
        if not d:
            assert got[j] is None
        else:
            assert got[j] == pytest.approx(math.sqrt(sum(v * v for v in d) / len(d)), rel=1e-12, abs=1e-12)
