"""Companion-side controller, frames, PX4-like flight controller pieces."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from ddpc_codegen.robot.controller import ControllerConfig, HeightLegAngleController, MeasuredState
from ddpc_codegen.robot.frames import euler_from_quat, quat_from_euler
from ddpc_codegen.sim.flight_controller import (
    PX4LikeFlightController,
    newton_to_normalized_thrust,
    normalized_thrust_to_newton,
)
from ddpc_codegen.sim.params import PogoXParams


def _state(t=0.0, pos=(0, 0, 1.0), vel=(0, 0, 0), eul=(0, 0, 0), contact=False):
    return MeasuredState(t, np.array(pos, float), np.array(vel, float), np.array(eul, float), np.zeros(3), contact)


def test_control_module_does_not_import_the_simulator():
    code = "import sys, ddpc_codegen.robot.controller; print(any(m.startswith('ddpc_codegen.sim') for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False"


def test_tracking_stage_is_pd_with_model_mass():
    cfg = ControllerConfig(mode="flying", model_mass=3.45, max_thrust=40.0, kp_z=10.0, kd_z=5.0)
    ctl = HeightLegAngleController(cfg)
    s = _state(pos=(0, 0, 1.0), vel=(0, 0, 0.2))
    sp = ctl.track([1.05, 0.0], s)
    expect = 3.45 * (9.81 + 10.0 * 0.05 - 5.0 * 0.2)
    assert sp.thrust_newton == pytest.approx(expect)
    assert sp.thrust == pytest.approx(expect / 40.0)
    np.testing.assert_allclose(sp.q, [1, 0, 0, 0], atol=1e-12)
    # Pitch reference goes straight to the attitude setpoint; thrust is tilt-compensated.
    sp = ctl.track([1.05, 0.1], s)
    np.testing.assert_allclose(euler_from_quat(sp.q), [0, 0.1, 0], atol=1e-12)
    assert sp.thrust_newton == pytest.approx(expect / math.cos(0.1))


def test_flying_nominal_reference_and_lookahead():
    ctl = HeightLegAngleController(ControllerConfig(mode="flying"))
    s = _state(t=4.0, pos=(0.1, 0.0, 1.0), vel=(0.2, 0, 0))
    r = ctl.nominal_reference(s)
    assert r.shape == (2,)
    np.testing.assert_allclose(ctl.desired_outputs(4.0), r)
    ahead = ctl.desired_outputs(4.0 + 0.005 * np.arange(15))
    assert ahead.shape == (15, 2)
    np.testing.assert_allclose(ahead[:, 0], ctl.trajectory.sample(4.0 + 0.005 * np.arange(15))["z"])


def test_hopping_stages_and_phases():
    cfg = ControllerConfig(mode="hopping", model_mass=3.45, apex_height=0.7, target_velocity=(0.0, 0.0))
    ctl = HeightLegAngleController(cfg)
    ctl.reset(0.0, 0.7)
    r = ctl.nominal_reference(_state(t=0.0, pos=(0, 0, 0.7)))
    assert r.shape == (3,) and r[0] == pytest.approx(0.7)
    # Stance: desired = measured.
    s = _state(t=0.4, pos=(0, 0, 0.37), vel=(0, 0, -1.0), eul=(0.01, 0.02, 0), contact=True)
    r = ctl.nominal_reference(s)
    np.testing.assert_allclose(r, [0.37, 0.01, 0.02])
    np.testing.assert_allclose(ctl.y_des, r)
    # Liftoff starts a ballistic (reduced gravity) arc that reaches the target apex.
    s = _state(t=0.55, pos=(0, 0, 0.40), vel=(0, 0, 1.5), contact=False)
    r = ctl.nominal_reference(s)
    assert r[0] == pytest.approx(0.40)
    ts = 0.55 + np.linspace(0, 1.2, 400)
    z = ctl.desired_outputs(ts)[:, 0]
    assert z.max() == pytest.approx(0.7, abs=1e-4)
    # Thrust in the air: the model weight share (1 - g_eff/g) when on the arc.
    sp = ctl.track(r, s)
    assert sp.thrust_newton >= 0.0


def test_thrust_mapping_and_tilt_limit():
    p = PogoXParams()
    assert normalized_thrust_to_newton(1.0, p) == pytest.approx(p.thrust_to_weight * p.mass * p.g)
    assert newton_to_normalized_thrust(normalized_thrust_to_newton(0.37, p), p) == pytest.approx(0.37)
    assert normalized_thrust_to_newton(2.0, p) == pytest.approx(p.max_thrust)
    fc = PX4LikeFlightController(p)
    fc.set_attitude_target(quat_from_euler(0.0, math.radians(60), 0.3), 0.5)
    b3z = 1 - 2 * (fc.q_sp[1] ** 2 + fc.q_sp[2] ** 2)
    assert math.acos(b3z) == pytest.approx(p.fc.tilt_max, abs=1e-9)
    rate = fc.attitude_update([1.0, 0.0, 0.0, 0.0])
    assert all(abs(r) <= m + 1e-12 for r, m in zip(rate, p.fc.rate_max))


def test_allocation_reproduces_collective_and_torque():
    p = PogoXParams()
    fc = PX4LikeFlightController(p)
    tau = (0.3, -0.2, 0.05)
    T = fc._allocate(0.8 * p.max_thrust, tau)
    d = p.arm_length / math.sqrt(2)
    xs, ys, sg = (d, -d, d, -d), (-d, d, d, -d), (-1, -1, 1, 1)
    assert sum(T) == pytest.approx(0.8 * p.max_thrust)
    assert sum(y * t for y, t in zip(ys, T)) == pytest.approx(tau[0])
    assert -sum(x * t for x, t in zip(xs, T)) == pytest.approx(tau[1])
    assert p.k_m_ratio * sum(s * t for s, t in zip(sg, T)) == pytest.approx(tau[2])
