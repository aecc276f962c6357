"""The one percentile summary (ddpc_codegen.stats)."""

import numpy as np

from ddpc_codegen.stats import percentiles


def test_percentiles_keys_values_and_empty_input():
    a = np.arange(101.0)
    assert percentiles(a) == {"p50": 50.0, "p99": 99.0, "max": 100.0, "n": 101}
    assert percentiles([1.0, np.nan, np.inf, 3.0]) == {"p50": 2.0, "p99": 2.98, "max": 3.0, "n": 2}
    assert percentiles([], qs=(50, 99.99)) == {"p50": None, "p99.99": None, "max": None, "n": 0}
    assert percentiles(np.ones((2, 3)), qs=(10,))["n"] == 6
