"""The predictor's step response, dead time and 90 % settling time against LTI systems whose responses are known
exactly, and the horizon check on them and on the demo's flying loop."""

import math
from pathlib import Path

import numpy as np
import pytest

from support.lti import LTI, random_lti
from ddpc_codegen import IODataset, fit_predictor
from ddpc_codegen.design.fit import fit_configured
from ddpc_codegen.design.step_response import dead_index, settling_index, settling_report, settling_summary, step_response
from ddpc_codegen.sim import simulate
from ddpc_codegen.values.config import SteeringConfig

ROOT = Path(__file__).resolve().parents[2]


def _lags(a: list[float]) -> LTI:
    """Decoupled first-order lags y[k+1] = a y[k] + (1 - a) u[k]: unit steps give y[k] = 1 - a^k exactly."""
    a = np.asarray(a)
    return LTI(np.diag(a), np.diag(1 - a), np.eye(len(a)), np.zeros((len(a), len(a))))


def _delayed_lags(a: list[float], delay: list[int]) -> LTI:
    """As :func:`_lags`, each input first delayed by ``delay`` samples (a shift register of that many states):
    a unit step gives y[k] = 0 up to k = delay, then 1 - a^(k - delay)."""
    n = [d + 1 for d in delay]
    A, B, C = np.zeros((sum(n), sum(n))), np.zeros((sum(n), len(a))), np.zeros((len(a), sum(n)))
    for j, (aj, d) in enumerate(zip(a, delay)):
        o = sum(n[:j])  # states o .. o + d - 1: the shift register, o + d: the lag
        B[o, j] = 1.0 if d else 1 - aj
        for i in range(1, d):
            A[o + i, o + i - 1] = 1.0
        if d:
            A[o + d, o + d - 1] = 1 - aj
        A[o + d, o + d], C[j, o + d] = aj, 1.0
    return LTI(A, B, C, np.zeros((len(a), len(a))))


def _fit(sys_: LTI, t_ini: int, t_f: int, dt: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((1500, sys_.B.shape[1]))
    y, _ = sys_.simulate(u, np.zeros(sys_.n))
    return fit_predictor(IODataset(u, y, dt, input_names=("u_a", "u_b"), output_names=("y_a", "y_b")),
                         t_ini, t_f, "lsq")


def test_chained_prediction_is_the_exact_step_response_beyond_tf():
    sys_ = random_lti(4, 2, 2, 3)
    pred = _fit(sys_, 8, 10, 0.005)
    for j in range(2):
        u = np.zeros((60, 2))
        u[:, j] = 1.0
        exact, _ = sys_.simulate(u, np.zeros(4))
        np.testing.assert_allclose(step_response(pred, j, 60), exact, atol=1e-8 * max(1.0, np.abs(exact).max()))


def test_settling_time_of_first_order_lags_is_analytic():
    a = [0.97, 0.9]
    pred = _fit(_lags(a), 4, 10, 0.01)
    got = settling_summary(pred, span_s=10.0)
    for s, ai, name in zip(got, a, ("y_a", "y_b")):
        k = math.ceil(math.log(0.1) / math.log(ai))  # 1 - a^k within 10 % of 1 from k on
        assert (s.output, s.ticks) == (name, k) and s.seconds == pytest.approx(k * 0.01)
        assert s.gain == pytest.approx(1.0, abs=1e-8)
    assert [s.input for s in got] == ["u_a", "u_b"]  # each output's strongest input


def test_a_loop_that_answers_within_the_horizon_is_not_warned_however_slowly_it_settles():
    pred = _fit(_lags([0.97, 0.5]), 4, 10, 0.01)
    lines, warnings = settling_report(pred, span_s=10.0)
    # y = 1 - a^k, largest change 1: 1 - a at k = 1 (>= 1 %), 1 - a^9 by the horizon's last sample (24 %, 99.8 %)
    assert lines == ["step response u_a -> y_a: gain 1, dead time 0.01 s (1 ticks), 90 % settling time 0.76 s "
                     "(76 ticks); the horizon (0.1 s) sees 24 % of the response",
                     "step response u_b -> y_b: gain 1, dead time 0.01 s (1 ticks), 90 % settling time 0.04 s "
                     "(4 ticks); the horizon (0.1 s) sees 99.8 % of the response"]
    assert warnings == []


def test_a_dead_time_longer_than_the_horizon_is_warned():
    pred = _fit(_delayed_lags([0.5, 0.5], [14, 0]), 16, 10, 0.01)
    got = settling_summary(pred, span_s=1.0)
    assert [(s.dead_ticks, s.ticks) for s in got] == [(15, 18), (1, 4)]  # y_a: 0 up to k = 14, then 1 - 0.5^(k - 14)
    assert got[0].seen == pytest.approx(0.0, abs=1e-8)
    _, warnings = settling_report(pred, span_s=1.0)
    assert warnings == ["warning: y_a has not begun to answer a u_a step when the horizon (10 x 0.01 s = 0.1 s) ends "
                        "(dead time 0.15 s: below 1 % of its largest change for 15 ticks): the steering cannot act on "
                        "that loop; raise [horizon] t_f above 15 (with [horizon] knots to keep the QP small)"]


def test_the_demos_flying_loop_answers_within_its_75_ms_horizon():
    # configs/flying.toml on the simulator's excited flight: the height loop settles long after the horizon
    # (the steering still cuts its error many times in make demo), but answers within it: no warning
    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying.toml")
    pred = fit_configured(cfg, simulate("flying", 15.0, excitation=True, seed=3, noise=True).to_dataset())
    z, pitch = settling_summary(pred)
    assert z.output == "z" and z.ticks > 5 * cfg.t_f and z.dead_ticks < cfg.t_f and z.seen > 0.02
    assert pitch.dead_ticks < cfg.t_f
    assert settling_report(pred)[1] == []


def test_settling_index_edge_cases():
    assert settling_index(np.ones(10)) == 0
    assert settling_index(np.zeros(10)) is None  # no change: nothing to settle
    assert settling_index(np.r_[np.zeros(95), np.ones(5)]) is None  # still moving at the end
    assert settling_index(np.array([0.0, 0.5, 0.95, 1.05, 1.0])) == 2
    assert dead_index(np.r_[np.zeros(5), 0.009, 0.5, 1.0]) == 6  # 1 % of the largest change
    assert dead_index(np.r_[0.0, -0.02, -2.0, -1.0]) == 1  # either sign
    assert dead_index(np.zeros(4)) is None and dead_index(np.r_[0.0, np.nan]) is None
    with pytest.raises(ValueError, match=r"^input_index must be in 0..1; got 2$"):
        step_response(_fit(_lags([0.9, 0.9]), 4, 10, 0.01), 2, 5)
