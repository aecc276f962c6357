import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import DataError, ExcitationError, IODataset, fit_predictor, prbs

TI, TF = 8, 10


def _data(n, seed, T=400, m=2, p=2, feedthrough=False):
    sys_ = random_lti(n, m, p, seed, feedthrough=feedthrough)
    rng = np.random.default_rng(seed + 100)
    u = rng.standard_normal((T, m))
    y, _ = sys_.simulate(u, rng.standard_normal(n))
    return sys_, IODataset(u, y, 0.005)


def _test_window(sys_, seed, m=2):
    rng = np.random.default_rng(seed + 200)
    u = rng.standard_normal((TI + TF, m))
    y, _ = sys_.simulate(u, rng.standard_normal(sys_.n))
    return u[:TI], y[:TI], u[TI:], y[TI:]


def _rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


@pytest.mark.parametrize("n", [4, 5, 6])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lsq_is_exact_on_noise_free_lti(n, seed):
    sys_, ds = _data(n, seed, feedthrough=seed == 2)
    pred = fit_predictor(ds, TI, TF, "lsq")
    ui, yi, uf, yf = _test_window(sys_, seed)
    y, sigma = pred.predict(ui, yi, uf)
    assert y.shape == (TF, 2) and sigma.shape == (TI, 2)
    assert _rel(y, yf) <= 1e-8
    assert np.all(sigma == 0)


@pytest.mark.parametrize("n", [4, 6])
def test_pem_with_heavy_slack_weight_is_exact(n):
    sys_, ds = _data(n, 3)
    pred = fit_predictor(ds, TI, TF, "pem", slack_weight=1e12)
    ui, yi, uf, yf = _test_window(sys_, 3)
    y, sigma = pred.predict(ui, yi, uf)
    assert _rel(y, yf) <= 1e-8
    assert np.abs(sigma).max() <= 1e-8 * np.abs(yi).max()


def test_pem_paper_weighting_is_biased_and_documented():
    """Equal weighting of ||g|| and ||sigma|| (the paper's pinv) trades prediction accuracy for
    a nonzero slack even on noise-free data: the bias is real, bounded, and shrinks with rho."""
    sys_, ds = _data(4, 0)
    ui, yi, uf, yf = _test_window(sys_, 0)
    errs = []
    for rho in (1.0, 1e2, 1e4, 1e6):
        y, sigma = fit_predictor(ds, TI, TF, "pem", slack_weight=rho).predict(ui, yi, uf)
        errs.append(_rel(y, yf))
        if rho == 1.0:
            assert np.abs(sigma).max() > 1e-6
    assert 1e-7 < errs[0] < 1e-1
    assert all(b < a for a, b in zip(errs, errs[1:]))


def test_streaming_equals_direct_build():
    sys_, ds = _data(5, 4, T=3000)
    for method, kw in (("lsq", {}), ("pem", {}), ("pem", {"slack_weight": 10.0, "ridge": 1e-3})):
        a = fit_predictor(ds, 20, 15, method, block_columns=257, **kw)
        b = fit_predictor(ds, 20, 15, method, streaming=False, **kw)
        for x, y in ((a.Gy_w, b.Gy_w), (a.Gy_u, b.Gy_u), (a.Gs_w, b.Gs_w), (a.Gs_u, b.Gs_u)):
            assert np.abs(x - y).max() <= 1e-9 * max(1.0, np.abs(y).max())


def test_mosaic_of_trajectories_predicts_exactly():
    sys_ = random_lti(4, 2, 2, 7)
    rng = np.random.default_rng(7)
    us = [rng.standard_normal((150, 2)) for _ in range(4)]
    ys = [sys_.simulate(u, rng.standard_normal(4))[0] for u in us]
    pred = fit_predictor(IODataset(us, ys, 0.005), TI, TF, "lsq")
    ui, yi, uf, yf = _test_window(sys_, 7)
    assert _rel(pred.predict(ui, yi, uf)[0], yf) <= 1e-8


def test_ridge_changes_prediction_and_digest():
    _, ds = _data(4, 0)
    a = fit_predictor(ds, TI, TF, "lsq")
    b = fit_predictor(ds, TI, TF, "lsq", ridge=1.0)
    assert a.digest != b.digest
    assert np.abs(a.Gy_u - b.Gy_u).max() > 1e-6


def test_too_short_data_message():
    u = prbs(80, 2, seed=0)
    ds = IODataset(u, u.copy(), 0.005)
    with pytest.raises(DataError) as e:
        fit_predictor(ds, 20, 15)
    assert str(e.value).startswith("need at least 104 samples for Tini=20, Tf=15, m=2; got 80")


def test_not_exciting_data_raises_with_report():
    T = 400
    u = np.column_stack([np.sin(np.arange(T) * 0.1), np.ones(T)])
    ds = IODataset(u, u.copy(), 0.005)
    with pytest.raises(ExcitationError) as e:
        fit_predictor(ds, TI, TF)
    assert "not persistently exciting enough for Tini=8, Tf=10" in str(e.value)
    assert "rank" in str(e.value)
    pred = fit_predictor(ds, TI, TF, check_excitation=False)
    assert not pred.excitation().ok


def test_bad_arguments():
    _, ds = _data(4, 0)
    with pytest.raises(DataError, match="unknown predictor method 'dmd'"):
        fit_predictor(ds, TI, TF, "dmd")
    with pytest.raises(DataError, match="slack_weight must be a positive number; got 0"):
        fit_predictor(ds, TI, TF, slack_weight=0)
    with pytest.raises(DataError, match="horizons must be >= 1"):
        fit_predictor(ds, 0, TF)
    pred = fit_predictor(ds, TI, TF)
    with pytest.raises(DataError, match=r"u_ini must have 16 entries \(stacked time-major\); got shape \(7, 2\)"):
        pred.predict(np.zeros((7, 2)), np.zeros((TI, 2)), np.zeros((TF, 2)))
    with pytest.raises(DataError, match="y_ini contains NaN"):
        pred.predict(np.zeros((TI, 2)), np.full((TI, 2), np.nan), np.zeros((TF, 2)))


def test_streaming_memory_does_not_grow_with_samples():
    """Peak allocation during the fit is set by the block size, not by T (beyond the data itself)."""
    import tracemalloc

    peaks = []
    # 5 and 20 blocks of 2048 columns: a fit that held the whole Hankel (140 rows x 8 B per column) would
    # grow by ~34 MB between the two, far past the 4 MB allowed
    for T in (10_000, 40_000):
        u = prbs(T, 2, amplitude=1.0, min_hold=2, seed=1)
        y = np.cumsum(u, axis=0) * 0.01
        ds = IODataset(u, y, 0.005)
        tracemalloc.start()
        fit_predictor(ds, 20, 15, "pem", block_columns=2048)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < peaks[0] + 4e6  # 4x the samples, < 4 MB more peak
    assert peaks[1] < 60e6
