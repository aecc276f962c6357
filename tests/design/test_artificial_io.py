"""Artificial ground-phase IO: exactness on LTI data, bounds, the mosaic of hops (PE), steering in the loop."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen import IODataset
from ddpc_codegen.values.phases import GROUND
from ddpc_codegen.design.hopping_data import split_hopping
from ddpc_codegen.experiments.pipeline import CollectSpec, build_setup, collect
from ddpc_codegen.experiments.evaluate import run
from ddpc_codegen.design.artificial_io import ArtificialIO, ground_runs, hop_excitation
from ddpc_codegen.runtime.hopping import HoppingWindow
from ddpc_codegen.sim import simulate


def _lti_data(sys_, n_traj: int, T: int, seed: int, offset: float = 0.5) -> IODataset:
    """Noise-free trajectories of an LTI system with a constant output offset (an affine system)."""
    rng = np.random.default_rng(seed)
    us, ys = [], []
    for _ in range(n_traj):
        u = rng.standard_normal((T, sys_.B.shape[1]))
        y, _ = sys_.simulate(u, rng.standard_normal(sys_.n))
        us.append(u)
        ys.append(y + offset)
    return IODataset(us, ys, 0.005)


def _window(sys_, L: int, seed: int, offset: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((L, sys_.B.shape[1]))
    y, _ = sys_.simulate(u, rng.standard_normal(sys_.n))
    return u, y + offset


@pytest.mark.parametrize("what, n, m, p, t_g", [("all", 4, 1, 2, 4), ("outputs", 4, 2, 2, 12)])
def test_artificial_io_reproduces_the_removed_segment(lti_factory, what, n, m, p, t_g):
    # Unique cases: a whole gap with m*T_g <= n (the end states fix the inputs), or a gap of any
    # length whose inputs are known (only outputs missing).
    sys_ = lti_factory(n, m, p, seed=3)
    t_d = t_a = 6
    L = t_d + t_g + t_a
    art = ArtificialIO(_lti_data(sys_, 5, 300, seed=0), L)
    assert art.rank == m * L + n + 1  # + 1: the constant offset is one more (observable) state
    u, y = _window(sys_, L, seed=11)
    miss = np.zeros((L, m + p), dtype=bool)
    miss[t_d : t_d + t_g, (0 if what == "all" else m):] = True
    uu, yy = u.copy(), y.copy()
    uu[miss[:, :m]] = np.nan
    yy[miss[:, m:]] = np.nan
    c = art.complete(uu, yy, miss)
    np.testing.assert_allclose(c.u, u, atol=1e-8)
    np.testing.assert_allclose(c.y, y, atol=1e-8)
    assert c.residual < 1e-9 and not c.bounded


def test_non_unique_gap_is_still_a_trajectory_of_the_system(lti_factory):
    # m*T_g > n: the least-norm fill is one of many, but the whole window is an exact trajectory
    # (y = O x0 + T u + offset for some x0), so the state at the window's end is the true one.
    n, m, p, t_g = 4, 2, 2, 10
    sys_ = lti_factory(n, m, p, seed=3)
    L = 6 + t_g + 6
    art = ArtificialIO(_lti_data(sys_, 5, 300, seed=0), L)
    u, y = _window(sys_, L, seed=12)
    miss = np.zeros(L, dtype=bool)
    miss[6 : 6 + t_g] = True
    c = art.complete(np.where(miss[:, None], 0.0, u), np.where(miss[:, None], 0.0, y), miss)
    assert np.abs(c.u - u).max() > 1e-3  # not the recorded inputs ...
    # ... yet consistent: fit x0 (and the offset) to the completed window by least squares.
    O = np.vstack([sys_.C @ np.linalg.matrix_power(sys_.A, k) for k in range(L)])
    y0, _ = sys_.simulate(c.u, np.zeros(n))  # forced response
    A = np.hstack([O, np.tile(np.eye(p), (L, 1))])
    coef, *_ = np.linalg.lstsq(A, (c.y - y0).reshape(-1), rcond=None)
    assert np.abs(A @ coef - (c.y - y0).reshape(-1)).max() < 1e-8
    np.testing.assert_allclose(c.y[-6:], y[-6:], atol=1e-9)  # the known ascent is kept


def test_bounds_on_the_artificial_samples(lti_factory):
    sys_ = lti_factory(4, 2, 2, seed=3)
    L = 22
    data = _lti_data(sys_, 5, 300, seed=0)
    u, y = _window(sys_, L, seed=12)
    miss = np.zeros(L, dtype=bool)
    miss[6:16] = True
    free = ArtificialIO(data, L).complete(u, y, miss)
    hi = 0.5 * np.abs(free.u[miss]).max()
    art = ArtificialIO(data, L, u_min=[-hi, -hi], u_max=[hi, hi])
    c = art.complete(u, y, miss)
    assert c.bounded and c.status == "solved"
    assert np.abs(c.u[miss]).max() <= hi + 1e-7
    np.testing.assert_allclose(c.y[~miss], y[~miss], atol=1e-6)  # known samples still matched


def test_noise_level_keeps_the_fill_bounded_on_noisy_windows(lti_factory):
    sys_ = lti_factory(4, 2, 2, seed=3)
    L = 22
    data = _lti_data(sys_, 5, 300, seed=0)
    u, y = _window(sys_, L, seed=12)
    miss = np.zeros(L, dtype=bool)
    miss[6:16] = True
    y_noisy = y + np.random.default_rng(0).normal(0, 1e-3, y.shape)
    exact = ArtificialIO(data, L).complete(u, y_noisy, miss)
    reg = ArtificialIO(data, L, noise_level=1e-3).complete(u, y_noisy, miss, replace_known=True)
    assert reg.g_norm < exact.g_norm
    assert np.abs(reg.y[~miss] - y[~miss]).max() < 5e-3  # the fitted window stays near the data


# ---------------------------------------------------------------------------- simulator hops
@pytest.fixture(scope="module")
def hop_raw():
    return collect("hopping", CollectSpec(duration=60.0, seed=1, noise=False, amplitude=(0.01, 0.02, 0.02)))


@pytest.fixture(scope="module")
def hop_setup(hop_raw, tmp_path_factory):
    return build_setup("hopping", raw=hop_raw, generate_dir=None, save_data=False)


def test_split_into_aerial_segments_and_hops(hop_raw):
    aerial, hops = split_hopping(hop_raw.to_dataset("none"))
    assert all(not np.any(ph == GROUND) for ph in aerial.phases)
    assert all(len(ground_runs(ph)) == 1 for ph in hops.phases)
    assert hops.n_trajectories >= 60 and aerial.n_trajectories >= hops.n_trajectories


def test_mosaic_of_stitched_hops_is_persistently_exciting(hop_setup):
    ds = hop_setup.dataset  # the hops H_G1..H_Gn with artificial ground phases
    info = hop_setup.info["artificial_io"]
    assert info["hops"] == ds.n_trajectories and not info["skipped"]
    assert info["max_residual"] < 1e-6  # noise-free recording: the fills meet the real samples exactly
    L = hop_setup.config.t_ini + hop_setup.config.t_f
    pe = hop_excitation(ds, L + 10)  # order L + n with a generous state dimension
    assert pe.ok, pe.summary()
    assert pe.rank == ds.m * (L + 10) and pe.singular_values[-1] > 1e3 * pe.tol


def test_stitched_hops_keep_the_aerial_samples(hop_raw, hop_setup):
    _, hops = split_hopping(hop_raw.to_dataset("none"))
    ds = hop_setup.dataset
    for i in range(3):
        air = hops.phases[i] != GROUND
        np.testing.assert_array_equal(ds.y[i][air], hops.y[i][air])
        assert not np.allclose(ds.y[i][~air], hops.y[i][~air])  # the ground samples were replaced


def test_online_window_fills_ground_only_after_min_ascent(hop_raw, hop_setup):
    ds = hop_raw.to_dataset("none")
    u, y, ph = ds.u[0], ds.y[0], ds.phases[0]
    g0, g1 = ground_runs(ph)[5]
    win = HoppingWindow(hop_setup.art, 20, t_d=0, min_ascent=10, noise_level=0.0)
    assert win.window(u[: g0 - 30], y[: g0 - 30], ph[: g0 - 30]) is None  # clean aerial window
    assert win.window(u[: g1 + 3], y[: g1 + 3], ph[: g1 + 3]) == "early_ascent"  # too soon after liftoff
    w = win.window(u[: g1 + 12], y[: g1 + 12], ph[: g1 + 12])
    assert isinstance(w, tuple) and w[0].shape == (20, 3) and w[1].shape == (20, 3)
    np.testing.assert_allclose(w[1][-12:], y[g1 : g1 + 12], atol=1e-9)  # the real ascent is kept
    assert np.all(np.isfinite(w[0])) and np.abs(w[1][:8, 0] - 0.4).max() < 0.3  # plausible heights



def test_refit_since_the_liftoff_removes_more_sensor_noise(hop_setup):
    """refit_residual on PogoX hops with the sensor's white noise added (2 mm / 4 mrad): the last sample
    of the window refitted over every aerial sample since the liftoff is nearer the noise-free one than
    the 20-sample fit's (that sample is the state the prediction starts from); noise-free windows move
    by a fraction of the noise either way."""
    res = simulate("hopping", 6.0, seed=1)  # held out: no excitation, another seed
    u, y, ph = res.u, res.y, res.phase
    sig = np.array([2e-3, 4e-3, 4e-3])
    y_noisy = y + np.random.default_rng(0).normal(0.0, 1.0, y.shape) * sig
    kw = dict(t_d=0, min_ascent=10, noise_level=2e-3, denoise=True)
    short = HoppingWindow(hop_setup.art, 20, **kw)
    long = HoppingWindow(hop_setup.art, 20, refit_residual=1e-9, **kw)
    err, moved = [], []
    for k in range(200, len(ph), 7):
        if np.any(ph[k - 20 : k] == GROUND) or not np.any(ph[k - hop_setup.art.depth : k] == GROUND):
            continue
        ws = [w.window(u[:k], yy[:k], ph[:k]) for yy in (y_noisy, y) for w in (short, long)]
        if any(not isinstance(w, tuple) for w in ws):
            continue
        err.append([np.abs(w[1][-1] - y[k - 1]) / sig for w in ws[:2]])
        moved.append([np.abs(w[1][-1] - y[k - 1]) / sig for w in ws[2:]])
    err, moved = np.mean(err, axis=0), np.mean(moved, axis=0)
    assert "refit" not in short.counts and long.counts["refit"] >= 60, long.counts
    assert np.all(err[1] < 0.85 * err[0]), err  # measured: z 0.36 -> 0.27, roll 0.26 -> 0.19, pitch 0.33 -> 0.27
    assert moved.max() < 0.25, moved

def test_steering_cuts_the_apex_error_3x(hop_setup):
    base = run(None, "hopping", 8.0, steer=False)
    steered = run(hop_setup, "hopping", 8.0, interpreted=True)
    b, s = base.metrics["apex_error_mean_abs"], steered.metrics["apex_error_mean_abs"]
    assert b > 0.02  # the -200 g model mass error leaves ~3 cm
    assert s * 3 <= b, (b, s)
    assert not steered.metrics["crashed"]
    st = steered.steering
    assert st["fallbacks"] == 0 and st["artificial_io"]["filled"] > 0
    assert steered.metrics["rmse_pitch"] <= base.metrics["rmse_pitch"] * 1.05  # leg angles not worse


def test_bad_windows_are_refused_with_the_reason(lti_factory):
    sys_ = lti_factory(4, 1, 2, seed=3)
    art = ArtificialIO(_lti_data(sys_, 2, 200, seed=0), 12)
    u, y = _window(sys_, 12, seed=1)
    miss = np.zeros(12, dtype=bool)
    from ddpc_codegen.errors import DataError

    with pytest.raises(DataError, match="u has 12 samples but y has 11"):
        art.complete(u, y[:11], miss)
    with pytest.raises(DataError, match="window of 13 samples: the artificial-IO depth is 12"):
        art.complete(np.vstack([u, u[:1]]), np.vstack([y, y[:1]]), np.zeros(13, bool))
    with pytest.raises(DataError, match=r"missing must be \(12,\) or \(12, 3\); got \(12, 2\)"):
        art.complete(u, y, np.zeros((12, 2), bool))
    y_bad = y.copy()
    y_bad[3, 1] = np.nan
    with pytest.raises(DataError, match="known samples of the window contain NaN"):
        art.complete(u, y_bad, miss)
    miss[3] = True  # a missing sample may be NaN
    assert np.all(np.isfinite(art.complete(u, y_bad, miss).y))
