"""One config value (values/config_values.py): weights become symmetric PSD matrices, bounds per-channel arrays,
and every other value is refused naming the file and the key."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ddpc_codegen.values.config_values import channel_bounds, is_number, weight_matrix
from ddpc_codegen.errors import ConfigError

finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=100, deadline=None)
@given(arrays(float, st.integers(1, 6), elements=st.floats(0.0, 1e6)))
def test_a_diagonal_of_non_negative_entries_is_its_matrix(d):
    np.testing.assert_array_equal(weight_matrix(d.tolist(), d.size, "[cost] Q", "c.toml"), np.diag(d))


@settings(max_examples=100, deadline=None)
@given(arrays(float, (3, 3), elements=finite))
def test_a_full_matrix_is_accepted_exactly_when_symmetric_psd(a):
    """Gram matrices of entries up to 1e3 (eigenvalues to ~1e7): their round-off below zero is not a refusal."""
    sym = a @ a.T  # PSD by construction
    np.testing.assert_array_equal(weight_matrix(sym.tolist(), 3, "[cost] R", "c.toml"), sym)
    skew = a - a.T
    if np.any(np.abs(2 * skew) > 1e-4 * (np.abs(sym) + 1.0)):  # beyond any rounding: not symmetric
        with pytest.raises(ConfigError, match=r"^c.toml: \[cost\] R must be a finite symmetric matrix$"):
            weight_matrix((sym + skew).tolist(), 3, "[cost] R", "c.toml")


@pytest.mark.parametrize("value, msg", [
    ([1.0, -1.0], r"diagonal entries must be finite and >= 0; got \[1.0, -1.0\]"),
    ([1.0], r"must have 2 entries \(one per channel\) or be a 2x2 matrix; got 1 entries \[1.0\]"),
    ("big", r"must be a list of numbers or a matrix; got 'big'"),
    ([[1.0, 0.0], [0.0, -1.0]], r"must be positive semidefinite; smallest eigenvalue -1"),
])
def test_bad_weights_are_refused_naming_file_and_key(value, msg):
    with pytest.raises(ConfigError, match=r"^c.toml: \[cost\] Q " + msg):
        weight_matrix(value, 2, "[cost] Q", "c.toml")


@given(x=finite, n=st.integers(1, 5))
def test_a_bound_number_is_every_channels_bound(x, n):
    np.testing.assert_array_equal(channel_bounds(x, n, "[bounds] u_min", "c.toml", -np.inf), np.full(n, x))
    np.testing.assert_array_equal(channel_bounds(None, n, "[bounds] u_min", "c.toml", -np.inf), np.full(n, -np.inf))


def test_bad_bounds_are_refused():
    with pytest.raises(ConfigError, match=r"^c.toml: \[bounds\] y_max must not contain NaN"):
        channel_bounds([1.0, float("nan")], 2, "[bounds] y_max", "c.toml", np.inf)
    with pytest.raises(ConfigError, match=r"^c.toml: \[bounds\] y_max must have 2 entries \(one per channel\); got 3"):
        channel_bounds([1, 2, 3], 2, "[bounds] y_max", "c.toml", np.inf)
    with pytest.raises(ConfigError, match=r"must be a number or a list of 2 numbers; got True"):
        channel_bounds(True, 2, "[bounds] y_max", "c.toml", np.inf)


def test_a_number_is_a_real_number_not_a_bool():
    assert is_number(1) and is_number(2.5) and is_number(np.float32(1.0))
    assert not is_number(True) and not is_number("1") and not is_number(None)
