"""Baseline policies behind the steering policy's per-tick interface (decide / reset / observe)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from ddpc_codegen.values.prefilter import PrefilterModel
from ddpc_codegen.errors import ConfigError
from ddpc_codegen.runtime.baselines import FeedforwardPolicy, PassthroughPolicy, PrefilterPolicy


def test_passthrough_sends_the_nominal_reference():
    out = PassthroughPolicy().decide(np.zeros(2), np.array([1.0, 0.1]), np.zeros((1, 2)))
    np.testing.assert_array_equal(out.u, [1.0, 0.1])
    assert not out.steered and out.reason == "passthrough"


def test_prefilter_policy_is_the_model_inverse_with_clipping(tmp_path):
    model = PrefilterModel((0.5, 1.0), (-0.1, 0.0), (2, 0), 0.005)
    pol = PrefilterPolicy(model)
    assert pol.horizon == 3
    y_des = np.array([[1.0, 0.2], [1.1, 0.3], [1.2, 0.4]])
    out = pol.decide(np.zeros(2), np.array([1.0, 0.25]), y_des)
    # z: r_nom + (y_des[2] - c) / g - y_des[0] = 1 + 2.6 - 1; pitch: r_nom (identity map).
    np.testing.assert_allclose(out.u, [2.6, 0.25])
    clipped = PrefilterPolicy(model, u_max=np.array([2.0, 1.0])).decide(np.zeros(2), np.array([1.0, 0.25]), y_des)
    assert clipped.reason == "prefilter_clipped" and clipped.u[0] == 2.0
    loaded = PrefilterPolicy.load(model.save(tmp_path / "pf.json"))
    np.testing.assert_array_equal(loaded.decide(np.zeros(2), np.array([1.0, 0.25]), y_des).u, out.u)


def test_feedforward_policy_table_clock(tmp_path):
    pol = FeedforwardPolicy(np.array([[0.1], [0.2], [0.3]]), 0.005, "liftoff")
    r = np.array([1.0])
    assert [pol.decide(r, r, r[None]).u[0] for _ in range(2)] == [1.1, 1.2]
    pol.observe(r, r)  # a tick decided elsewhere still advances the clock
    assert pol.decide(r, r, r[None]).u[0] == pytest.approx(1.3)  # beyond the table: the last row
    pol.reset()
    assert pol.decide(r, r, r[None]).u[0] == pytest.approx(1.1)
    again = FeedforwardPolicy.load(pol.save(tmp_path / "ilc.npz"))
    assert again.clock == "liftoff" and np.array_equal(again.delta, pol.delta)
    with pytest.raises(ConfigError, match="clock must be"):
        FeedforwardPolicy(np.zeros((2, 1)), clock="wall")
    with pytest.raises(ConfigError, match="finite"):
        FeedforwardPolicy(np.full((2, 1), np.nan))


def test_runtime_baselines_load_neither_casadi_nor_scipy():
    code = ("import sys, ddpc_codegen.runtime.baselines; "
            "print(sorted(m for m in ('casadi', 'scipy', 'ddpc_codegen.sim') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"
