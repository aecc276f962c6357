"""The simulated robot below the companion computer (sim.Stepper): measurement delay and history,
pushes, a stuck hybrid integration, and simulate() being exactly the stepper plus the controller."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.robot.frames import euler_from_quat
from ddpc_codegen.sim import PogoXParams, Push, Stepper, get_scenario, plant as plant_mod, simulate


@pytest.fixture
def params() -> PogoXParams:
    return PogoXParams()


def _hover(params: PogoXParams, **kw) -> Stepper:
    st = Stepper(params, [0.0, 0.0, 1.0], **kw)
    st.set_setpoint((1.0, 0.0, 0.0, 0.0), params.mass * params.g / params.max_thrust)
    return st


def test_measurement_is_the_state_meas_delay_ago_and_history_reaches_further(params):
    st = _hover(params, history=0.02, pushes=[Push(0.0, (0.0, 0.0, 20.0), 1.0)])
    z = [st.plant.state[2]]
    for _ in range(10):
        st.advance()
        z.append(st.plant.state[2])
    d = round(params.meas_delay / params.control_dt)  # delay in ticks (5 ms = 1 tick)
    assert st.measure(0.05).position[2] == z[-1 - d]
    assert st.measure(0.04, age=0.01).position[2] == z[-1 - d - 2]
    assert st.measure(0.0, age=1.0).position[2] == z[-1 - d - 4]  # the oldest kept: history is 20 ms
    assert z[-1] > z[0] + 0.005  # the push lifted it (20 N for 50 ms)


def test_noise_is_seeded_and_drawn_in_order(params):
    a, b = _hover(params, noise=True, seed=4), _hover(params, noise=True, seed=4)
    np.testing.assert_array_equal(a.measure(0.0).euler, b.measure(0.0).euler)
    clean = _hover(params).measure(0.0)
    assert not np.array_equal(a.measure(0.0).position, clean.position)


def test_a_stuck_integration_stops_the_stepping_without_raising(params, monkeypatch):
    st = _hover(params)

    def stuck(*_a, **_k):
        raise plant_mod.HybridEventError("chattering (test)")

    monkeypatch.setattr(st.plant, "step", stuck)
    st.advance()
    assert st.stuck == "chattering (test)" and st.step_count == 0
    st.advance()  # no-op from now on
    assert st.step_count == 0


def test_simulate_is_the_stepper_plus_the_controller(params):
    res = simulate("hopping", 1.0, params=params, seed=2, noise=True)
    sc = get_scenario("hopping")
    ctrl = sc.make_controller(params)
    x0, y0, z0 = sc.initial_position(params)
    st = Stepper(params, [x0, y0, z0], noise=True, seed=2)
    ctrl.reset(0.0, z0)
    for k in range(res.n):
        meas = st.measure(k * params.control_dt)
        np.testing.assert_array_equal(ctrl.outputs(meas), res.y[k])
        np.testing.assert_array_equal(st.plant.state, res.state[k])
        sp = ctrl.step(meas)
        st.advance((sp.q, sp.thrust))
    assert list(st.touchdowns) == list(res.touchdowns)
    assert euler_from_quat(st.plant.state[6:10]).shape == (3,)
