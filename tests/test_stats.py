"""The one percentile summary and the tick-to-tick step rms (ddpc_codegen.stats)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ddpc_codegen.stats import limit_share, percentiles, step_rms


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


def test_limit_share_counts_clamped_samples_in_the_mask():
    thrust = np.array([0.0, 0.5, 1.0, 0.9999999, 1e-7, 0.3])
    assert limit_share(thrust, 0.0, 1.0) == pytest.approx(4 / 6)        # within 1e-6 of a limit counts
    assert limit_share(thrust, 0.0, 1.0, tol=0.0) == pytest.approx(2 / 6)
    keep = np.array([False, True, True, False, False, True])
    assert limit_share(thrust, 0.0, 1.0, keep) == pytest.approx(1 / 3)
    assert limit_share(thrust, 0.0, 1.0, np.zeros(6, bool)) is None        # nothing scored: null, not 0
    with pytest.raises(ValueError, match="mask has 5 samples, x has 6"):
        limit_share(thrust, 0.0, 1.0, np.ones(5, bool))


@given(arrays(np.float64, st.integers(1, 40), elements=st.floats(-0.5, 1.5)), st.data())
@settings(max_examples=60, deadline=None)
def test_limit_share_equals_counting_by_hand(x, data):
    keep = data.draw(arrays(np.bool_, x.shape[0]))
    got = limit_share(x, 0.0, 1.0, keep)
    picked = [v for v, k in zip(x, keep) if k]
    if not picked:
        assert got is None
    else:
        assert got == pytest.approx(sum(v <= 1e-6 or v >= 1 - 1e-6 for v in picked) / len(picked))
