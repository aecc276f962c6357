"""The incremental (offset-free) predictor against independent references: a known LTI system's exact
response, the direct difference-predict-accumulate computation, and its invariances."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from support.lti import random_lti
from ddpc_codegen import ConfigError, DataError, IODataset, SteeringConfig, fit_predictor
from ddpc_codegen.design.fit import compose_increments, difference_dataset, fit_configured, fit_incremental

TI, TF = 8, 10


def _data(seed, n=4, T=500, offset=0.0):
    sys_ = random_lti(n, 2, 2, seed)
    rng = np.random.default_rng(seed + 100)
    u = rng.standard_normal((T, 2))
    y, _ = sys_.simulate(u, rng.standard_normal(n))
    return sys_, IODataset(u, y + offset, 0.005)


def _window(sys_, seed, offset=0.0):
    rng = np.random.default_rng(seed + 200)
    u = rng.standard_normal((TI + TF, 2))
    y, _ = sys_.simulate(u, rng.standard_normal(sys_.n))
    y = y + offset
    return u[:TI], y[:TI], u[TI:], y[TI:]


def _direct(inc, ui, yi, uf):
    """Difference the window, predict the increments, accumulate from y_ini[-1] (no composed matrices)."""
    dy, _ = inc.predict(np.diff(ui, axis=0), np.diff(yi, axis=0), np.diff(np.vstack([ui[-1:], uf]), axis=0))
    return yi[-1] + np.cumsum(dy, axis=0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_on_noise_free_lti(seed):
    sys_, ds = _data(seed)
    pred = fit_incremental(ds, TI, TF, "lsq")
    assert (pred.t_ini, pred.t_f, pred.method, pred.options["form"]) == (TI, TF, "lsq", "incremental")
    ui, yi, uf, yf = _window(sys_, seed)
    y, sigma = pred.predict(ui, yi, uf)
    assert np.linalg.norm(y - yf) <= 1e-8 * np.linalg.norm(yf)
    assert np.all(sigma == 0)


def test_offset_the_data_never_saw_is_carried_exactly():
    """An output offset (a mass error, a drifting height estimate) absent from the data: the incremental
    predictor stays exact, the absolute one (no constant in an LTI model) does not."""
    sys_, ds = _data(3)
    ui, yi, uf, yf = _window(sys_, 3, offset=0.7)
    inc = fit_incremental(ds, TI, TF, "lsq").predict(ui, yi, uf)[0]
    ab = fit_predictor(ds, TI, TF, "lsq").predict(ui, yi, uf)[0]
    assert np.abs(inc - yf).max() <= 1e-8
    assert np.abs(ab - yf).max() >= 1e-2


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), cu=st.floats(-5, 5), cy=st.floats(-5, 5), ridge=st.sampled_from([0.0, 1e-3, 1e-1]))
def test_composed_matrices_equal_the_direct_computation_and_are_offset_free(seed, cu, cy, ridge):
    _, ds = _data(7)
    inc = fit_predictor(difference_dataset(ds), TI - 1, TF, "lsq", ridge=ridge)
    pred = compose_increments(inc)
    rng = np.random.default_rng(seed)
    ui, yi, uf = rng.standard_normal((TI, 2)), rng.standard_normal((TI, 2)), rng.standard_normal((TF, 2))
    y = pred.predict(ui, yi, uf)[0]
    np.testing.assert_allclose(y, _direct(inc, ui, yi, uf), atol=1e-10 * max(1.0, np.abs(y).max()))
    # a constant on every output moves the prediction by that constant; one on every input changes nothing
    np.testing.assert_allclose(pred.predict(ui, yi + cy, uf)[0], y + cy, atol=1e-9 * (1 + abs(cy)))
    np.testing.assert_allclose(pred.predict(ui + cu, yi, uf + cu)[0], y, atol=1e-9 * (1 + abs(cu)))


def test_difference_dataset_drops_single_samples_and_keeps_labels():
    u = [np.arange(6.0).reshape(3, 2), np.ones((1, 2)), np.arange(8.0).reshape(4, 2) ** 2]
    y = [a[:, :1] * 2 for a in u]
    ph = [np.array([0, 1, 2]), np.array([1]), np.array([2, 2, 0, 1])]
    d = difference_dataset(IODataset(u, y, 0.01, phases=ph, input_names=["a", "b"], output_names=["c"]))
    assert d.lengths == (2, 3) and d.input_names == ("a", "b") and d.dt == 0.01
    np.testing.assert_array_equal(d.u[1], np.diff(u[2], axis=0))
    np.testing.assert_array_equal(d.y[0], np.diff(y[0], axis=0))
    np.testing.assert_array_equal(d.phases[1], [2, 0, 1])
    with pytest.raises(DataError, match="at least 2 samples"):
        difference_dataset(IODataset(np.ones((1, 2)), np.ones((1, 1)), 0.01))


def test_refused_for_pem_and_a_single_past_sample():
    _, ds = _data(0)
    with pytest.raises(ConfigError, match='needs method = "lsq"'):
        fit_incremental(ds, TI, TF, "pem")
    with pytest.raises(ConfigError, match="t_ini >= 2"):
        fit_incremental(ds, 1, TF, "lsq")


def _cfg(**pred):
    return SteeringConfig(t_ini=TI, t_f=TF, m=2, p=2, Q=[1.0, 1.0], R=[0.1, 0.1], predictor=pred)


def test_config_form_dispatch_and_validation():
    _, ds = _data(1)
    a = fit_configured(_cfg(method="lsq", ridge=1e-3), ds)
    b = fit_predictor(ds, TI, TF, "lsq", ridge=1e-3)
    assert a.digest == b.digest and "form" not in a.options
    c = fit_configured(_cfg(method="lsq", form="incremental", ridge=1e-3), ds)
    assert c.digest == fit_incremental(ds, TI, TF, "lsq", ridge=1e-3).digest != a.digest
    with pytest.raises(ConfigError, match=r"\[predictor\] form.*must be one of \['absolute', 'incremental'\]"):
        _cfg(method="lsq", form="delta")
    with pytest.raises(ConfigError, match=r"\[predictor\] form.*needs method"):
        _cfg(method="pem", form="incremental")
    with pytest.raises(ConfigError, match=r"\[predictor\] form.*needs t_ini >= 2 \(one increment\); got 1"):
        _cfg(method="lsq", form="incremental").replace(t_ini=1)
    assert dataclasses.asdict(_cfg(method="lsq"))["predictor"]["form"] == "absolute"
