"""ddpc_codegen.runtime.steerer.ReferenceSteerer: history bookkeeping, gap bridging, fallbacks."""

import numpy as np
import pytest

from ddpc_codegen.values.solve_result import SteeringResult
from ddpc_codegen.runtime.steerer import ReferenceSteerer


class _EchoSolver:
    """Returns u = u_nom + 0.01 and remembers the window it was given."""

    has_nominal = True

    def solve(self, u_ini, y_ini, y_des, u_nom=None):
        self.window = (np.array(u_ini), np.array(y_ini))
        return SteeringResult(np.asarray(u_nom) + 0.01, status="solved")


def _steerer(**kw) -> ReferenceSteerer:
    return ReferenceSteerer(_EchoSolver(), t_ini=4, t_f=3, m=2, p=1, **kw)


def test_fill_gap_holds_u_and_interpolates_y():
    st = _steerer()
    for k in range(4):
        st.observe([k, -k], [10.0 * k])
    st.fill_gap(2, np.array([60.0]))  # ticks 4 and 5 lost; tick 6 measured y = 60
    u, y = st.window()
    np.testing.assert_array_equal(u, [[2, -2], [3, -3], [3, -3], [3, -3]])  # zero-order hold of u_3
    np.testing.assert_allclose(y[:, 0], [20.0, 30.0, 40.0, 50.0])           # y_3 -> y_6 linearly
    assert st.summary()["gap_filled_ticks"] == 2


def test_fill_gap_is_exact_for_a_ramp_and_a_noop_without_history():
    st = _steerer()
    st.fill_gap(3, np.array([1.0]))          # nothing observed yet: nothing to bridge from
    assert not st.ready and st.summary()["gap_filled_ticks"] == 0
    for k in range(3):
        st.observe([0.5, 0.5], [0.25 * k])
    st.fill_gap(1, np.array([0.25 * 4]))     # tick 3 lost on a ramp: the fill is the true sample
    u, y = st.window()
    np.testing.assert_allclose(y[:, 0], [0.0, 0.25, 0.5, 0.75])
    assert st.ready


def test_steer_uses_the_bridged_window_and_fallbacks_are_counted():
    st = _steerer(max_step=[0.005, 0.005])
    y_des, u_nom = np.zeros((3, 1)), np.ones((3, 2))
    assert st.step(y_des, u_nom).reason == "warmup"
    for k in range(3):
        st.observe([1.0, 1.0], [float(k)])
    st.fill_gap(1, np.array([4.0]))
    out = st.step(y_des, u_nom)
    assert out.reason == "step_too_large" and not out.steered  # +0.01 > 0.005: the nominal reference
    np.testing.assert_allclose(st.solver.window[1][:, 0], [0.0, 1.0, 2.0, 3.0])
    st.max_step = None
    out = st.step(y_des, u_nom)
    assert out.steered and np.allclose(out.u, 1.01)
    s = st.summary()
    assert (s["steered"], s["fallbacks"], s["warmup"]) == (1, 1, 1)
    assert s["fallback_reasons"] == {"step_too_large": 1}


@pytest.mark.parametrize("n", [0, -1])
def test_fill_gap_ignores_nonpositive_counts(n):
    st = _steerer()
    st.observe([1.0, 1.0], [1.0])
    st.fill_gap(n, np.array([2.0]))
    assert st.summary()["gap_filled_ticks"] == 0


def test_a_pause_falls_back_without_a_solve_until_it_is_lifted():
    st = _steerer()
    y_des, u_nom = np.zeros((3, 1)), np.ones((3, 2))
    for k in range(4):
        st.observe([1.0, 1.0], [float(k)])
    st.solver.window = None
    st.pause = "beyond_jerk"
    out = st.step(y_des, u_nom)
    assert (out.reason, out.steered, st.solver.window) == ("beyond_jerk", False, None)
    np.testing.assert_array_equal(out.u, [1.0, 1.0])
    st.pause = ""
    assert st.step(y_des, u_nom).steered and st.summary()["fallback_reasons"] == {"beyond_jerk": 1}
