"""Online predictor updates in numpy (design/adapter.py) against the batch fit and numpy's QR."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ddpc_codegen.design.hankel import channel_stats
from ddpc_codegen.design.predictor import FitLayout, _solve_r, channel_scale, hankel_r_factor
from ddpc_codegen.errors import DataError
from ddpc_codegen.design.adapt_qp import QPModel
from ddpc_codegen.values.adapt import AdaptSettings, SampleWindow
from ddpc_codegen.design.adapter import (AdaptLayout, Adapter, excitation_ratio, givens_update,
                                             solve_g)
from support.lti import random_lti


def _data(seed: int, T: int = 400, m: int = 2, p: int = 1, noise: float = 1e-3):
    sys_ = random_lti(4, m, p, seed)
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((T, m))
    y, _ = sys_.simulate(u, np.zeros(4))
    return u, y + noise * rng.standard_normal(y.shape)


def _windows(u, y, depth):
    w = np.hstack([u, y])
    return [w[j : j + depth] for j in range(w.shape[0] - depth + 1)]


@given(n=st.integers(1, 12), k=st.integers(1, 30), f=st.floats(0.5, 1.0), seed=st.integers(0, 10**6))
@settings(max_examples=40, deadline=None)
def test_givens_update_is_the_qr_of_the_stacked_rows(n, k, f, seed):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((k, n))
    R = np.zeros((n, n))
    for j, x in enumerate(X):
        givens_update(R, x.copy(), f)
    weights = np.sqrt(f) ** np.arange(k - 1, -1, -1)  # the newest row has weight 1
    ref = np.linalg.qr(weights[:, None] * X, mode="r")
    # R factors are unique up to the sign of each row: compare R^T R and the row magnitudes
    np.testing.assert_allclose(R.T @ R, ref.T @ ref, atol=1e-10 * max(1.0, np.abs(ref).max() ** 2))
    assert np.all(np.diag(R) >= 0)
    assert np.allclose(np.tril(R, -1), 0.0)


def _ridges(trace0: float, cols: np.ndarray, r: int, ridge: float, f: float) -> np.ndarray:
    """The ridge each ridge row carries after the columns (k, width) were folded, from the rule alone: every row
    lam0 = ridge trace0 / r at first; after column j row j mod r is set to the lam of the data then; every
    ridge forgotten by f per column."""
    lam = np.full(r, ridge * trace0 / r)
    trace = trace0
    for j, x in enumerate(cols):
        trace = f * trace + float(x[:r] @ x[:r])
        lam *= f
        lam[j % r] = max(lam[j % r], ridge * trace / r)
    return lam


@pytest.mark.parametrize("method, ridge", [("lsq", 1e-6), ("lsq", 0.0), ("pem", 1e-4), ("pem", 0.0)])
def test_columns_fed_one_by_one_equal_the_batch_refit_of_the_data_before_the_held_out_window(method, ridge):
    """f = 1: R holds the shipped data, every column but the window's and the ridge rows as they stand; G equals
    the batch fit (design/predictor.py's solve, no ridge of its own) of the QR of all of them stacked."""
    u, y = _data(3)
    lay = AdaptLayout(2, 1, 4, 3, method)
    flay = FitLayout(2, 1, 4, 3, method)
    scale, _ = channel_scale(*channel_stats([np.hstack([u, y])]), ("u0", "u1", "y0"))
    half = 150
    R0 = hankel_r_factor([(u[:half], y[:half])], flay, scale)  # the shipped factor: the first part
    ad = Adapter(lay, R0, scale, AdaptSettings(forgetting=1.0, window=30), ridge=ridge)
    wins = _windows(u, y, lay.depth)[half - lay.depth + 1 :]
    for w in wins:
        assert ad.push(w)
    assert ad.recent().shape[0] == 30 and ad.counts["folded"] == ad.counts["updates"] - 30
    # R holds every column but the window's 30 newest: the batch fit of the samples that end before them
    keep = len(u) - 30
    folded = np.array([lay.column(w, scale) for w in wins[:-30]])
    lam = _ridges(float(np.sum(R0[:, : lay.r] ** 2)), folded, lay.r, ridge, 1.0)
    rows = np.zeros((lay.r, lay.width))
    rows[:, : lay.r] = np.diag(np.sqrt(lam))
    Rb = np.linalg.qr(np.vstack([hankel_r_factor([(u[:keep], y[:keep])], flay, scale), rows]), mode="r")
    batch = _solve_r(Rb, flay, 1.0, 0.0, 1e-10)["G"]
    G, _ = solve_g(ad.R, lay, 1.0, 1e-10)
    assert np.abs(G - batch).max() <= 1e-9 * max(1.0, np.abs(batch).max())
    if ridge:  # the ridge tracks the data: every row renewed in the last r columns
        assert np.all(lam >= ridge * ad.trace / lay.r * (1 - lay.r * 1e-2)) and np.allclose(ad.ridge_k, lam)


@given(f=st.floats(0.9, 1.0), seed=st.integers(0, 10**6), gain=st.floats(0.1, 10.0))
@settings(max_examples=15, deadline=None)
def test_ridge_rows_stay_within_one_renewal_of_the_relative_ridge(f, seed, gain):
    """Any forgetting, data whose scale changes (``gain``) after the shipped part: each ridge row lies between
    f^(r-1) times the smallest and the largest ridge * trace / r of the last r columns, as the rule alone
    predicts; the factor is the QR of the forgotten data and those rows (numpy's QR)."""
    u, y = _data(seed % 1000, T=300)
    u[100:], y[100:] = gain * u[100:], gain * y[100:]
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    R0 = hankel_r_factor([(u[:100], y[:100])], FitLayout(2, 1, 4, 3, "lsq"), np.ones(3))
    ad = Adapter(lay, R0, np.ones(3), AdaptSettings(forgetting=f, window=20), ridge=1e-3)
    wins = _windows(u[100:], y[100:], lay.depth)
    for w in wins:
        ad.push(w)
    folded = np.array([lay.column(w, np.ones(3)) for w in wins[:-20]])
    lam = _ridges(float(np.sum(R0[:, : lay.r] ** 2)), folded, lay.r, 1e-3, f)
    np.testing.assert_allclose(ad.ridge_k, lam, rtol=1e-12)
    # within one renewal: at least f^(r-1) times the smallest lam of the last r columns, at most the largest
    r, trace, hist = lay.r, float(np.sum(R0[:, : lay.r] ** 2)), []
    for x in folded:
        trace = f * trace + float(x[:r] @ x[:r])
        hist.append(1e-3 * trace / r)
    last = np.array(hist[-lay.r :])
    assert np.all(lam >= f ** (lay.r - 1) * last.min() * (1 - 1e-12)) and np.all(lam <= last.max() * (1 + 1e-12))
    X = np.vstack([_aged(np.vstack([R0, folded]), len(folded), f),
                   np.hstack([np.diag(np.sqrt(lam)), np.zeros((lay.r, lay.width - lay.r))])])
    ref = np.linalg.qr(X, mode="r")
    np.testing.assert_allclose(ad.R.T @ ad.R, ref.T @ ref, atol=1e-9 * np.abs(ref.T @ ref).max())


def test_layout_matches_the_design_fit_layout():
    u, y = _data(1, T=40)
    for method in ("lsq", "pem"):
        lay, flay = AdaptLayout(2, 1, 4, 3, method), FitLayout(2, 1, 4, 3, method)
        assert (lay.r, lay.q_y, lay.q_s, lay.width) == (flay.r, flay.q_y, flay.q_s, flay.width)
        np.testing.assert_array_equal(lay.u_rows, flay.u_rows)
        scale = np.array([1.0, 2.0, 3.0])
        w = np.hstack([u, y])[:7]
        np.testing.assert_array_equal(lay.column(w, scale), flay.data_rows((w / scale).reshape(1, -1))[0])


def test_window_of_the_wrong_shape_is_refused():
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    with pytest.raises(DataError, match=r"^an adaptation window must have shape \(7, 3\) \(depth Tini\+Tf, "
                                        r"channels u then y\); got \(6, 3\)$"):
        lay.column(np.zeros((6, 3)), np.ones(3))


def _aged(X, n_new, f):
    """Rows of X weighted by their age: the last n_new rows f^(age/2), the rows before them f^(n_new/2)."""
    age = np.concatenate([np.full(X.shape[0] - n_new, n_new), np.arange(n_new - 1, -1, -1)])
    return np.sqrt(f) ** age[:, None] * X


def test_forgetting_weights_old_columns_down():
    """With forgetting f the statistic is that of the columns weighted f^(age/2) (numpy's QR as reference)."""
    u, y = _data(5, T=120)
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    R0 = 0.1 * np.eye(lay.width)
    ad = Adapter(lay, R0, np.ones(3), AdaptSettings(forgetting=0.97, window=30))
    wins = _windows(u, y, lay.depth)
    for w in wins:
        ad.push(w)
    fitted = wins[:-30]  # the window's 30 newest are held out of R
    X = np.vstack([R0, np.array([lay.column(w, np.ones(3)) for w in fitted])])
    ref = np.linalg.qr(_aged(X, len(fitted), 0.97), mode="r")
    np.testing.assert_allclose(ad.R.T @ ad.R, ref.T @ ref, atol=1e-9 * np.abs(ref.T @ ref).max())


def test_a_better_predictor_is_accepted_and_swapped_a_worse_window_is_rejected():
    """Shipped R from one system; the data change to another: the re-solved G predicts the recent window
    better, is accepted (bounded step) and becomes current only on swap()."""
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    u0, y0 = _data(11)
    u1, y1 = _data(12)
    scale = np.ones(3)
    R0 = hankel_r_factor([(u0, y0)], FitLayout(2, 1, 4, 3, "lsq"), scale)
    ad = Adapter(lay, R0, scale, AdaptSettings(forgetting=0.98, window=60, max_change=0.5), ridge=1e-6)
    G_before = ad.G.copy()
    for w in _windows(u1, y1, lay.depth)[:200]:
        ad.push(w)
    assert ad.resolve() == "accepted"
    assert np.array_equal(ad.G, G_before)  # not yet swapped
    assert ad.swap() and not ad.swap()
    assert np.linalg.norm(ad.G - G_before) <= 0.5 * np.linalg.norm(G_before) * (1 + 1e-12)
    assert ad.counts["accepted"] == 1 and ad.counts["swaps"] == 1
    # a window of a constant input is not exciting: rejected, counted, nothing pending
    for _ in range(60):
        ad.push(np.hstack([np.ones((lay.depth, 2)), np.zeros((lay.depth, 1))]))
    assert ad.resolve() == "excitation" and ad.counts["rejected_excitation"] == 1 and not ad.swap()


@pytest.mark.parametrize("seed", range(40, 45))
def test_the_held_out_window_does_not_reward_fitting_its_noise(seed):
    """Nominal flight: the same system as the shipped data, noisy outputs, a short memory (f = 0.98). The
    candidate, fitted without the recent window, predicts it no better than the current G: rejected. Folded into
    the fit, the same window is predicted 10-25 % better by a candidate that only learnt its noise -- what a
    verification on in-sample data would have accepted."""
    from ddpc_codegen.design.adapter import _prediction_error

    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    u, y = _data(seed, T=1500, noise=0.05)
    R0 = hankel_r_factor([(u[:1000], y[:1000])], FitLayout(2, 1, 4, 3, "lsq"), np.ones(3))
    ad = Adapter(lay, R0, np.ones(3), AdaptSettings(forgetting=0.98, window=60, max_change=10.0), ridge=1e-6)
    for w in _windows(u[1000:], y[1000:], lay.depth):
        ad.push(w)
    assert ad.resolve() == "prediction" and not ad.swap()
    held_out = ad.counts["error_candidate"] / ad.counts["error_current"]
    R_in = ad.R.copy()
    for x in ad.recent():
        givens_update(R_in, x.copy(), 0.98)
    G_in, _ = solve_g(R_in, lay, 1.0, 1e-10)
    in_sample = _prediction_error(G_in, ad.recent(), lay) / _prediction_error(ad.G, ad.recent(), lay)
    assert in_sample < 1.0 - ad.settings.min_improvement <= held_out, (in_sample, held_out)


def test_no_improvement_on_the_recent_window_is_rejected():
    """R mostly learnt from another system, the recent window from the current one: the candidate
    predicts the recent window worse than the current G and is dropped."""
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    u, y = _data(21)
    u1, y1 = _data(22)
    R0 = hankel_r_factor([(u[:80], y[:80])], FitLayout(2, 1, 4, 3, "lsq"), np.ones(3))
    ad = Adapter(lay, R0, np.ones(3), AdaptSettings(forgetting=1.0, window=30, max_change=10.0), ridge=1e-6)
    for w in _windows(u1, y1, lay.depth)[:300] + _windows(u, y, lay.depth)[100:130]:
        ad.push(w)
    assert ad.resolve() == "prediction" and ad.counts["rejected_prediction"] == 1 and not ad.swap()


def test_min_improvement_asks_the_candidate_to_cut_the_error_by_that_fraction():
    """The same re-solve accepted with no margin is refused once the margin exceeds its actual cut (and
    accepted again just below it); the errors of the check are in the counts."""
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    u0, y0 = _data(11)
    u1, y1 = _data(12)
    R0 = hankel_r_factor([(u0, y0)], FitLayout(2, 1, 4, 3, "lsq"), np.ones(3))

    def verdict(margin: float) -> tuple[str, dict]:
        ad = Adapter(lay, R0, np.ones(3), AdaptSettings(forgetting=0.98, window=60, max_change=0.5,
                                                        min_improvement=margin), ridge=1e-6)
        for w in _windows(u1, y1, lay.depth)[:200]:
            ad.push(w)
        return ad.resolve(), ad.counts

    v, c = verdict(0.0)
    cut = 1.0 - c["error_candidate"] / c["error_current"]
    assert v == "accepted" and 0.0 < cut < 1.0
    assert verdict(cut * 0.999)[0] == "accepted"
    v, c = verdict(min(1.0, cut * 1.001))
    assert v == "prediction" and c["rejected_prediction"] == 1 and c["accepted"] == 0


def _never_convex(lay: AdaptLayout) -> QPModel:
    """A QP model whose Hessian is -I whatever G is (data-unit predictor = G itself, no outputs weighted)."""
    n_o, n_f, n_th = lay.q_y, lay.m * lay.t_f, lay.r
    n_w = lay.r - n_f
    return QPModel(Lm=np.eye(n_o), Rm=np.eye(lay.r), C0=np.zeros((n_o, lay.r)), B=np.eye(n_f),
                   Wd=np.zeros((n_o, n_o)), P_fixed=-np.eye(n_f), F_fixed=np.zeros((n_f, n_th)),
                   y_rows=np.zeros(0, int), A_g0=np.zeros((0, n_f)), F_g0=np.zeros((0, n_th)), n_w=n_w, n_y=0)


def test_hessian_check_rejects_a_candidate_that_loses_definiteness():
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    u, y = _data(31)
    u1, y1 = _data(32)
    R0 = hankel_r_factor([(u, y)], FitLayout(2, 1, 4, 3, "lsq"), np.ones(3))
    ad = Adapter(lay, R0, np.ones(3), AdaptSettings(forgetting=0.98, window=60), ridge=1e-6, qp=_never_convex(lay))
    for w in _windows(u1, y1, lay.depth)[:100]:
        ad.push(w)
    assert ad.resolve() == "hessian" and ad.counts["rejected_hessian"] == 1
    assert not ad.swap() and ad.qp_data is None


@pytest.mark.parametrize("increments", [False, True])
def test_sample_window_is_the_last_depth_samples_or_their_increments(increments):
    rng = np.random.default_rng(4)
    u, y = rng.standard_normal((9, 2)), rng.standard_normal((9, 1))
    sw = SampleWindow(4, 2, 1, increments)
    need = 4 + increments
    out = [sw.push(u[k], y[k]) for k in range(9)]
    assert all(o is None for o in out[: need - 1])
    full = np.hstack([u, y])
    for k in range(need - 1, 9):
        ref = full[k - need + 1 : k + 1]
        np.testing.assert_array_equal(out[k], np.diff(ref, axis=0) if increments else ref)
    sw.clear()
    assert sw.push(u[0], y[0]) is None


def test_nonfinite_windows_are_skipped_and_counted():
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    ad = Adapter(lay, np.eye(lay.width), np.ones(3), AdaptSettings(window=30))
    w = np.zeros((lay.depth, 3))
    w[2, 1] = np.nan
    R = ad.R.copy()
    assert not ad.push(w)
    assert np.array_equal(ad.R, R) and ad.counts["skipped"] == 1 and ad.counts["updates"] == 0


def test_rank_deficient_shipped_factor_and_bad_settings_are_refused():
    lay = AdaptLayout(2, 1, 4, 3, "lsq")
    with pytest.raises(DataError, match=r"^the shipped R factor is rank deficient: the predictor cannot be re-solved from it \(fit it with "
                                        r"\[predictor\] ridge > 0\)$"):
        Adapter(lay, np.zeros((3, lay.width)), np.ones(3), AdaptSettings(window=30))
    with pytest.raises(DataError, match=r"^\[adapt\] window must be >= m \(Tini\+Tf\) = 14 columns"):
        Adapter(lay, np.eye(lay.width), np.ones(3), AdaptSettings(window=13))
    with pytest.raises(DataError, match=r"^\[adapt\] forgetting must be in \(0, 1\]; got 1.5$"):
        Adapter(lay, np.eye(lay.width), np.ones(3), AdaptSettings(forgetting=1.5, window=30))
    with pytest.raises(DataError, match=r"^the R factor must have 21 columns and at most 21 rows; got shape \(2, 5\)$"):
        Adapter(lay, np.eye(2, 5), np.ones(3), AdaptSettings(window=30))


def test_excitation_ratio_needs_enough_columns():
    lay = AdaptLayout(1, 1, 2, 2, "lsq")
    rng = np.random.default_rng(0)
    cols = rng.standard_normal((10, lay.width))
    assert excitation_ratio(cols[:3], lay) == 0.0  # 3 columns < 4 input rows
    assert excitation_ratio(cols, lay) > 1e-3
