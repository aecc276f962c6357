"""ddpc_codegen.runtime.prediction_watch.PredictionWatch: the predictor's error on the flight against its held-out
error, on a plant whose response is known exactly (a FIR filter: the output is the inputs' window alone), and the
steerer's "model_mismatch" fallback it drives."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ddpc_codegen.runtime.prediction_watch import PredictionWatch
from ddpc_codegen.runtime.steerer import ReferenceSteerer
from ddpc_codegen.values.solve_result import SteeringResult

T_INI, T_F = 6, 10
H = np.array([0.0, 0.3, 0.4, 0.2, 0.1])  # the plant's impulse response (one tick of delay)


def fir(u: np.ndarray, h: np.ndarray) -> np.ndarray:
    """y[k] = sum_i h[i] u[k - i], u (T, 1) -> (T, 1), zero before the start."""
    return np.convolve(u[:, 0], h)[: len(u), None]


class FirSolver:
    """A generated solver's predict of the FIR plant ``h`` (the window's inputs make the output exactly), and a
    solve that answers the nominal reference plus 0.01."""

    has_nominal = True

    def __init__(self, h: np.ndarray, holdout=(0.01,)) -> None:
        self.h = h
        self.manifest = {"dims": {"t_ini": T_INI, "t_f": T_F, "m": 1, "p": 1},
                         "dataset": {"holdout": {"rmse": list(holdout)}}}
        self.predictions = 0

    def predict(self, u_ini, y_ini, u_f):
        self.predictions += 1
        return fir(np.vstack([u_ini, u_f]), self.h)[T_INI:]

    def solve(self, u_ini, y_ini, y_des, u_nom=None):
        return SteeringResult(np.asarray(u_nom) + 0.01, status="solved")


def fly(watch: PredictionWatch, gains: np.ndarray, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """Push a PRBS-like input through the plant scaled by ``gains`` (one per tick); the watch's verdict per tick."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-0.1, 0.1], size=len(gains) // 3 + 1), 3)[: len(gains), None]
    y = fir(u, H) * gains[:, None] + noise * rng.standard_normal((len(gains), 1))
    ok = []
    for k in range(len(gains)):
        watch.push(u[k], y[k])
        watch.poll()
        ok.append(watch.ok)
    return np.array(ok)


def test_the_right_predictor_stays_trusted_and_a_wrong_loop_trips_it_until_the_loop_is_back():
    said = []
    watch = PredictionWatch(FirSolver(H), [0.01], ratio=3.0, every=2, span=4, resume=4,
                            on_change=lambda ok, score: said.append((ok, score)))
    gains = np.r_[np.ones(200), 3.0 * np.ones(200), np.ones(200)]  # the loop's gain triples for 200 ticks
    ok = fly(watch, gains, noise=0.005)
    assert ok[:200].all()  # noise at half the held-out error: never tripped
    first_bad = 200 + int(np.argmin(ok[200:]))
    assert 200 < first_bad < 200 + T_INI + T_F + 2 * 4  # within the check's window and its span
    assert not ok[first_bad:400].any()
    assert ok[-50:].all() and watch.counts["trips"] == 1 and watch.counts["resumes"] == 1
    assert watch.worst > 3.0 and watch.summary()["ok"]
    assert [ok for ok, _ in said] == [False, True] and said[0][1] > 3.0 >= said[1][1]


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(0.2, 5.0), ratio=st.floats(1.5, 6.0))
def test_the_score_is_the_error_in_held_out_units(scale, ratio):
    """A predictor off by a fixed factor of the plant: the score is the RMS of (1 - scale) * y over the held-out
    error, whatever the units; it trips exactly when that exceeds the ratio."""
    watch = PredictionWatch(FirSolver(H * scale), [0.02], ratio=ratio, every=1, span=1, resume=1)
    ok = fly(watch, np.ones(80))
    u = np.repeat(np.random.default_rng(0).choice([-0.1, 0.1], size=80 // 3 + 1), 3)[:80, None]
    y = fir(u, H)
    expected = np.sqrt(np.mean(((scale - 1.0) * y[-T_F:]) ** 2)) / 0.02
    assert watch.score == pytest.approx(expected, rel=1e-9)
    assert ok[-1] == (expected <= ratio)


def test_a_reset_forgets_the_history_but_not_the_verdict_and_checks_wait_for_a_full_window():
    solver = FirSolver(H * 4.0)
    watch = PredictionWatch(solver, [0.01], ratio=2.0, every=1, span=1, resume=3)
    fly(watch, np.ones(T_INI + T_F - 1))
    assert solver.predictions == 0 and watch.ok  # not a full window yet
    fly(watch, np.ones(30))
    assert not watch.ok
    watch.reset()
    assert not watch.ok and watch.score > 2.0
    watch.push(np.zeros(1), np.zeros(1))
    watch.poll()
    assert not watch.ok  # one sample after a reset: no check, the verdict stands


def test_a_manifest_without_a_held_out_error_has_no_watch_and_bad_settings_are_refused():
    assert PredictionWatch.for_solver(FirSolver(H, holdout=())) is None
    assert PredictionWatch.for_solver(FirSolver(H)).ratio == 8.0
    with pytest.raises(ValueError, match="reference_rmse"):
        PredictionWatch(FirSolver(H), [0.0])
    with pytest.raises(ValueError, match="ratio > 1"):
        PredictionWatch(FirSolver(H), [0.01], ratio=1.0)


def test_the_steerer_falls_back_while_the_watch_distrusts_the_predictor():
    solver = FirSolver(H * 4.0)
    watch = PredictionWatch(solver, [0.01], ratio=2.0, every=1, span=1, resume=1)
    st = ReferenceSteerer(solver, T_INI, T_F, 1, 1, watch=watch)
    y_des, u_nom = np.zeros((T_F, 1)), np.ones((T_F, 1))
    rng = np.random.default_rng(1)
    u = rng.choice([-0.1, 0.1], size=(T_INI + T_F + 5, 1))
    y = fir(u, H)
    for k in range(len(u)):
        st.observe(u[k], y[k])
    out = st.step(y_des, u_nom)
    assert out.reason == "model_mismatch" and not out.steered and out.u[0] == 1.0
    assert st.summary()["fallback_reasons"] == {"model_mismatch": 1}
    assert st.summary()["prediction_watch"]["trips"] == 1
    solver.h = H  # the predictor now is the plant
    for k in range(len(u)):
        st.observe(u[k], y[k])
    out = st.step(y_des, u_nom)
    assert out.steered and out.u[0] == pytest.approx(1.01)
