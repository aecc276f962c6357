"""Unit-free predictors (issue 12): channel scaling inside the fit, a ridge relative to the data,
near-constant channels named by the PE check."""

import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import ExcitationError, IODataset, fit_predictor, persistency_of_excitation
from ddpc_codegen.design.hankel import NEAR_CONSTANT_RTOL

TI, TF, M, P = 6, 8, 2, 2
FITS = {"pem": dict(method="pem"), "lsq": dict(method="lsq"), "lsq+ridge": dict(method="lsq", ridge=1e-2)}


@pytest.fixture(scope="module")
def data():
    sys_ = random_lti(4, M, P, 3)
    rng = np.random.default_rng(3)
    u = rng.standard_normal((600, M))
    y, _ = sys_.simulate(u, rng.standard_normal(4))
    y = y + 0.01 * rng.standard_normal(y.shape)  # noisy: the ridge and pem's slack matter
    uq = rng.standard_normal((TI + TF, M))
    yq, _ = sys_.simulate(uq, rng.standard_normal(4))
    return u, y, (uq[:TI], yq[:TI], uq[TI:])


def _predict(u, y, query, fit):
    pr = fit_predictor(IODataset(u, y, 0.01), TI, TF, **fit)
    return pr.predict(*query)


@pytest.mark.parametrize("fit", list(FITS))
@pytest.mark.parametrize("factor", [1e-3, 1e3])
@pytest.mark.parametrize("channel", ["u0", "u1", "y0", "y1"])
def test_predictions_do_not_depend_on_units(data, fit, factor, channel):
    u, y, (ui, yi, uf) = data
    y_ref, s_ref = _predict(u, y, (ui, yi, uf), FITS[fit])
    k = np.ones(M + P)
    k[int(channel[1]) + (M if channel[0] == "y" else 0)] = factor
    ku, ky = k[:M], k[M:]
    y2, s2 = _predict(u * ku, y * ky, (ui * ku, yi * ky, uf * ku), FITS[fit])
    rel = np.abs(y2 / ky - y_ref).max() / np.abs(y_ref).max()
    assert rel <= 1e-9, rel
    if fit == "pem":  # the slack is an output quantity: it rescales with y
        assert np.abs(s2 / ky - s_ref).max() <= 1e-9 * max(np.abs(s_ref).max(), 1e-12)


def test_ridge_is_relative_to_the_amount_of_data(data):
    # The same trajectory twice doubles the Gram matrix; a relative ridge doubles with it: same G.
    u, y, q = data
    one = fit_predictor(IODataset(u, y, 0.01), TI, TF, "lsq", ridge=1e-2)
    two = fit_predictor(IODataset([u, u], [y, y], 0.01), TI, TF, "lsq", ridge=1e-2)
    assert two.n_columns == 2 * one.n_columns
    assert two.options["ridge_effective"] == pytest.approx(2 * one.options["ridge_effective"], rel=1e-12)
    np.testing.assert_allclose(two.Gy_w, one.Gy_w, rtol=0, atol=1e-10 * np.abs(one.Gy_w).max())
    np.testing.assert_allclose(two.Gy_u, one.Gy_u, rtol=0, atol=1e-10 * np.abs(one.Gy_u).max())


def test_effective_ridge_is_ridge_times_mean_gram_eigenvalue(data):
    u, y, _ = data
    ds = IODataset(u, y, 0.01)
    pr = fit_predictor(ds, TI, TF, "lsq", ridge=0.1)
    ref = fit_predictor(ds, TI, TF, "lsq", ridge=0.1, streaming=False)
    scale = np.std(np.hstack([u, y]), axis=0)
    from ddpc_codegen.design.hankel import block_hankel  # rows of Z: the first Tini + Tf - ... blocks

    H = block_hankel(np.hstack([u, y]) / scale, TI + TF)
    d = M + P
    z_rows = [t * d + c for t in range(TI) for c in range(d)] + [t * d + c for t in range(TI, TI + TF) for c in range(M)]
    Z = H[z_rows]
    lam = 0.1 * np.sum(Z**2) / Z.shape[0]
    assert pr.options["ridge_effective"] == pytest.approx(lam, rel=1e-10)
    assert ref.options["ridge_effective"] == pytest.approx(lam, rel=1e-10)
    np.testing.assert_allclose(pr.Gy_u, ref.Gy_u, atol=1e-9 * np.abs(ref.Gy_u).max())


def test_near_constant_input_channel_is_named(data):
    u, y, _ = data
    u2 = u.copy()
    u2[:, 1] = 5.6e-10 * np.sign(u[:, 1])  # a channel at 5.6e-10 rad: scaled, it would look exciting
    ds = IODataset(u2, y, 0.01, input_names=["z_ref", "pitch_ref"], output_names=["z", "pitch"])
    with pytest.raises(ExcitationError) as e:
        fit_predictor(ds, TI, TF, "lsq")
    msg = str(e.value)
    assert "NOT persistently exciting" in msg and "near-constant input channel(s): pitch_ref (std 5.6e-10)" in msg
    assert f"{NEAR_CONSTANT_RTOL:g} x the largest channel std" in msg
    rep = persistency_of_excitation(u2, TI + TF, names=["z_ref", "pitch_ref"])
    assert not rep.ok and rep.near_constant_inputs == ("pitch_ref",)
    # A constant at an offset (varying at rounding level) is named too.
    u3 = u.copy()
    u3[:, 0] = 1.0 + 1e-13 * np.sign(u[:, 0])
    assert persistency_of_excitation(u3, TI + TF).near_constant_inputs == ("u0",)


def test_near_constant_output_is_named_but_fits(data):
    u, y, q = data
    y2 = y.copy()
    y2[:, 0] = 3.0  # e.g. a held output channel
    pr = fit_predictor(IODataset(u, y2, 0.01, output_names=["z", "roll"]), TI, TF, "lsq")
    pe = pr.excitation()
    assert pe.ok and pe.near_constant_outputs == ("z",)
    assert "near-constant output channel(s): z (std 0)" in pe.summary()


def test_pe_verdict_does_not_depend_on_units(data):
    u, _, _ = data
    a = persistency_of_excitation(u, TI + TF)
    for k in ([1e-3, 1.0], [1.0, 1e3]):  # one channel in other units (the near-constant rule compares channels)
        b = persistency_of_excitation(u * k, TI + TF)
        assert a.ok and b.ok and a.rank == b.rank
        np.testing.assert_allclose(a.singular_values, b.singular_values, rtol=1e-9)
