"""Baselines identification: the prefilter recovers a known gain / offset / dead time; ILC
converges on a known LTI plant with a periodic reference; the lifted FIR model is exact."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.design.baselines import (
    PrefilterModel,
    fit_impulse_response,
    fit_prefilter,
    ilc_update_norm_optimal,
    ilc_update_p,
    lifted_matrix,
    shift_ahead,
)
from ddpc_codegen.design.data import prbs
from ddpc_codegen.errors import ConfigError, DataError
from support.lti import random_lti

GAIN, OFFSET, LEAD = (0.95, 1.1), (-0.057, 0.002), (7, 3)


def _static_loop(u: np.ndarray, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """y_i[k] = g_i u_i[k - d_i] + c_i (the first d_i samples from u_i[0]), plus white noise."""
    y = np.empty_like(u)
    for i, (g, c, d) in enumerate(zip(GAIN, OFFSET, LEAD)):
        delayed = np.concatenate([np.full(d, u[0, i]), u[: u.shape[0] - d, i]])
        y[:, i] = g * delayed + c
    return y + noise * np.random.default_rng(seed).standard_normal(y.shape)


def _inputs(n: int = 3000, seed: int = 1) -> np.ndarray:
    t = np.arange(n) * 0.005
    slow = np.column_stack([1.0 + 0.2 * np.sin(0.7 * t), 0.05 * np.sin(1.3 * t + 1.0)])
    return slow + prbs(n, 2, amplitude=(0.05, 0.03), min_hold=4, seed=seed)


def test_prefilter_recovers_gain_offset_and_lead_exactly_without_noise():
    u = _inputs()
    pf = fit_prefilter(u, _static_loop(u), max_lead=20, dt=0.005)
    np.testing.assert_allclose(pf.gain, GAIN, rtol=0, atol=1e-10)
    np.testing.assert_allclose(pf.offset, OFFSET, rtol=0, atol=1e-10)
    assert pf.lead == LEAD
    assert max(pf.residual_rms) < 1e-10 and min(pf.r2) > 1 - 1e-12


def test_prefilter_with_noise_within_stated_tolerance():
    """Noise 5 mm / 5 mrad (about 1/4 of the PRBS amplitude): gain within 2 %, offset within 2 mm /
    2 mrad, lead exact -- over several noise seeds and two trajectories."""
    u = [_inputs(3000, 1), _inputs(2000, 2)]
    y = [_static_loop(a, noise=0.005, seed=s) for s, a in enumerate(u)]
    pf = fit_prefilter(u, y, max_lead=20, dt=0.005)
    np.testing.assert_allclose(pf.gain, GAIN, rtol=0.02)
    np.testing.assert_allclose(pf.offset, OFFSET, atol=0.002)
    assert pf.lead == LEAD


def test_prefilter_skips_trajectories_shorter_than_the_largest_lead():
    """A log split by stale stretches has short pieces: they carry no sample every lead can use."""
    u = _inputs()
    short = _inputs(15, seed=3)
    pf = fit_prefilter([u, short], [_static_loop(u), _static_loop(short)], max_lead=20, dt=0.005)
    ref = fit_prefilter(u, _static_loop(u), max_lead=20, dt=0.005)
    np.testing.assert_array_equal(pf.gain, ref.gain)
    assert pf.lead == ref.lead == LEAD


def test_prefilter_smoothing_keeps_the_static_model():
    """A unity-DC low-pass commutes with y = g u[k-d] + c: the same model, to the filter's edge
    effects at the ends of the record (0.5 % in gain, 2 mm in offset here)."""
    u = _inputs()
    pf = fit_prefilter(u, _static_loop(u), max_lead=20, dt=0.005, smooth_hz=2.0)
    np.testing.assert_allclose(pf.gain, GAIN, rtol=5e-3)
    np.testing.assert_allclose(pf.offset, OFFSET, atol=2e-3)
    assert pf.lead == LEAD


def test_prefilter_inverse_makes_the_static_loop_track():
    pf = PrefilterModel(GAIN, OFFSET, LEAD, 0.005)
    t = np.arange(400) * 0.005
    y_des = np.column_stack([1.0 + 0.1 * np.sin(2 * t), 0.02 * np.cos(3 * t)])
    H = max(LEAD) + 1
    u = np.array([pf.inverse(y_des[k : k + H], y_des[k]) for k in range(len(t) - H)])
    y = _static_loop(u)
    k = np.arange(max(LEAD), len(u))
    np.testing.assert_allclose(y[k], y_des[k], atol=1e-12)
    # A short horizon clips the lead instead of failing.
    assert np.all(np.isfinite(pf.inverse(y_des[:2], y_des[0])))


def test_prefilter_json_round_trip_and_bad_files(tmp_path):
    pf = fit_prefilter(_inputs(), _static_loop(_inputs()), max_lead=20, dt=0.005, names=("z_ref", "pitch_ref"))
    assert PrefilterModel.load(pf.save(tmp_path / "pf.json")) == pf
    (tmp_path / "bad.json").write_text('{"prefilter": {"gain": [0.0], "offset": [0.0], "lead": [1], "dt": 0.005}}')
    with pytest.raises(ConfigError, match="nonzero gain"):
        PrefilterModel.load(tmp_path / "bad.json")
    (tmp_path / "junk.json").write_text("not json")
    with pytest.raises(ConfigError, match="junk.json: prefilter: is not valid JSON"):
        PrefilterModel.load(tmp_path / "junk.json")


def test_prefilter_refuses_short_or_unresponsive_data():
    u = _inputs(50)
    with pytest.raises(DataError, match="too few samples"):
        fit_prefilter(u, _static_loop(u), max_lead=20)
    u = _inputs()
    with pytest.raises(DataError, match="does not respond"):
        fit_prefilter(u, np.ones_like(u), max_lead=5)


# ----------------------------------------------------------------------------- ILC
N = 200  # one trial: two periods of the reference


def _markov(sys_, n: int) -> np.ndarray:
    """Impulse response h[0..n-1] of a SISO LTI (h[0] = D = 0)."""
    return np.array([0.0] + [(sys_.C @ np.linalg.matrix_power(sys_.A, k) @ sys_.B).item() for k in range(n - 1)])


def _trials(sys_, update, iterations: int) -> list[float]:
    """||e|| per iteration: each trial starts at rest and runs r + delta; r = a periodic sine."""
    r = np.sin(2 * np.pi * np.arange(N) / 100)[:, None]
    delta = np.zeros((N, 1))
    norms = []
    for _ in range(iterations):
        y, _ = sys_.simulate(r + delta, np.zeros(sys_.n))
        e = y - r
        norms.append(float(np.linalg.norm(e)))
        delta = update(delta, e)
    return norms


def test_norm_optimal_ilc_converges_monotonically_to_the_floor():
    """Exact lifted model, weight 1e-3: ||e|| falls every iteration; on a minimum-phase plant
    (seed 1) to round-off (< 1e-12 of the first trial) within 15 iterations; on plants with
    directions G barely moves (seeds 0, 2: sigma^2 << weight) it still falls monotonically, to < 10 %."""
    for seed, floor in ((1, 1e-12), (0, 0.1), (2, 0.1)):
        sys_ = random_lti(4, 1, 1, seed=seed, radius=0.8)
        G = lifted_matrix(_markov(sys_, N), N)
        norms = _trials(sys_, lambda d, e: ilc_update_norm_optimal(d, e, G, 1e-3), 15)
        assert all(b <= a * (1 + 1e-9) + 1e-14 for a, b in zip(norms, norms[1:])), (seed, norms)
        assert norms[-1] < floor * norms[0], (seed, norms)


def test_p_type_ilc_converges_on_a_known_plant():
    """P-type with lead 1 (relative degree 1) and gain 0.5 / CB on seed 1 (|1 - gamma CB| = 0.5):
    the error falls every iteration, to < 1 % of the first trial in 15 iterations."""
    sys_ = random_lti(4, 1, 1, seed=1, radius=0.8)
    cb = _markov(sys_, 2)[1]
    norms = _trials(sys_, lambda d, e: ilc_update_p(d, e, 0.5 / cb, 1), 15)
    assert all(b < a for a, b in zip(norms, norms[1:])), norms
    assert norms[-1] < 0.01 * norms[0], norms


def test_p_type_q_filter_and_mask():
    delta = np.zeros((100, 1))
    e = np.ones((100, 1))
    mask = np.arange(100) < 50
    out = ilc_update_p(delta, e, 0.5, 0, cutoff_hz=5.0, dt=0.005, mask=mask)
    np.testing.assert_allclose(out[50:], 0.0)
    np.testing.assert_allclose(out[10:40], -0.5, atol=1e-6)  # the Q-filter passes a constant


def test_shift_ahead_holds_the_last_sample():
    np.testing.assert_array_equal(shift_ahead(np.arange(5.0), 2), [2, 3, 4, 4, 4])
    np.testing.assert_array_equal(shift_ahead(np.arange(3.0), 0), [0, 1, 2])


def test_fir_fit_recovers_the_impulse_response_of_an_lti_plant():
    sys_ = random_lti(3, 1, 1, seed=4, radius=0.7)
    u = prbs(3000, 1, seed=3)
    y, _ = sys_.simulate(u, np.zeros(3))
    h, c = fit_impulse_response(u, y + 0.25, n_taps=80)
    np.testing.assert_allclose(h[:, 0], _markov(sys_, 80), atol=1e-8)
    assert abs(c[0] - 0.25) < 1e-8
    with pytest.raises(ConfigError, match="weight > 0"):
        ilc_update_norm_optimal(np.zeros(3), np.zeros(3), np.eye(3), 0.0)
