"""The predictor's step response and 90 % settling time against LTI systems whose responses are known exactly."""

import math

import numpy as np
import pytest

from support.lti import LTI, random_lti
from ddpc_codegen import IODataset, fit_predictor
from ddpc_codegen.design.step_response import settling_index, settling_report, settling_summary, step_response


def _lags(a: list[float]) -> LTI:
    """Decoupled first-order lags y[k+1] = a y[k] + (1 - a) u[k]: unit steps give y[k] = 1 - a^k exactly."""
    a = np.asarray(a)
    return LTI(np.diag(a), np.diag(1 - a), np.eye(len(a)), np.zeros((len(a), len(a))))


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


def test_horizon_shorter_than_settling_is_warned():
    pred = _fit(_lags([0.97, 0.5]), 4, 10, 0.01)
    lines, warnings = settling_report(pred, span_s=10.0)
    assert lines == ["step response u_a -> y_a: gain 1, 90 % settling time 0.76 s (76 ticks)",
                     "step response u_b -> y_b: gain 1, 90 % settling time 0.04 s (4 ticks)"]
    assert warnings == ["warning: the horizon (10 x 0.01 s = 0.1 s) covers less than the 90 % settling time of y_a "
                        "(0.76 s): the steering cannot lead that loop; raise [horizon] t_f to at least 76 (with "
                        "[horizon] knots to keep the QP small)"]


def test_settling_index_edge_cases():
    assert settling_index(np.ones(10)) == 0
    assert settling_index(np.zeros(10)) is None  # no change: nothing to settle
    assert settling_index(np.r_[np.zeros(95), np.ones(5)]) is None  # still moving at the end
    assert settling_index(np.array([0.0, 0.5, 0.95, 1.05, 1.0])) == 2
    with pytest.raises(ValueError, match=r"^input_index must be in 0..1; got 2$"):
        step_response(_fit(_lags([0.9, 0.9]), 4, 10, 0.01), 2, 5)
