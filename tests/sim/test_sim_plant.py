"""Plant physics: free fall, hover, passive bounces against closed forms, impact map."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddpc_codegen.robot.frames import quat_from_euler
from ddpc_codegen.sim.params import PogoXParams
from ddpc_codegen.sim.plant import AIR, STANCE, PogoXPlant

# Conservative test robot: no drag, no leg damping, no foot mass, motors can be fully off.
PASSIVE = dict(drag=0.0, leg_damping=0.0, foot_mass=0.0, idle_fraction=0.0)


def _run(plant: PogoXPlant, duration: float, cmd=(0.0,) * 4, h: float = 0.001):
    events = []
    for _ in range(int(round(duration / h))):
        events += plant.step(h, cmd)
    return events


def _spring_mass_times(z0: float, p: PogoXParams) -> tuple[float, float]:
    """Touchdown and stance duration of a vertical undamped drop from rest at z0 (closed form)."""
    g, L0, m, k = p.g, p.leg_rest_length, p.mass, p.leg_stiffness
    t_td = math.sqrt(2 * (z0 - L0) / g)
    w = math.sqrt(k / m)
    delta = math.atan2(-g * t_td / w, m * g / k)
    return t_td, (2 * math.pi + 2 * delta) / w


def test_free_fall_is_exact():
    p = PogoXParams(**PASSIVE)
    pl = PogoXPlant(p)
    pl.reset([0.3, -0.2, 5.0], velocity=[1.0, 0.5, 2.0], rotor_speeds=0.0)
    _run(pl, 0.5)
    t = 0.5
    np.testing.assert_allclose(pl.position, [0.3 + t, -0.2 + 0.5 * t, 5.0 + 2.0 * t - 0.5 * p.g * t * t], atol=1e-12)
    np.testing.assert_allclose(pl.velocity, [1.0, 0.5, 2.0 - p.g * t], atol=1e-12)
    assert pl.mode == AIR


def test_hover_equilibrium():
    p = PogoXParams(drag=0.0)
    pl = PogoXPlant(p)
    pl.reset([0.0, 0.0, 1.0])  # rotors at the hover speed of the true mass
    w = p.hover_omega
    _run(pl, 2.0, cmd=(w,) * 4)
    np.testing.assert_allclose(pl.position, [0, 0, 1.0], atol=1e-9)
    np.testing.assert_allclose(pl.velocity, 0.0, atol=1e-9)
    np.testing.assert_allclose(pl.rates, 0.0, atol=1e-9)  # yaw torques of the X layout cancel
    assert 4 * p.k_f * w * w == pytest.approx(p.mass * p.g)
    assert p.max_thrust == pytest.approx(p.thrust_to_weight * p.mass * p.g)


def test_touchdown_and_liftoff_times_match_closed_form():
    p = PogoXParams(**PASSIVE)
    pl = PogoXPlant(p)
    z0 = 0.6
    pl.reset([0, 0, z0], rotor_speeds=0.0)
    ev = _run(pl, 0.9)
    kinds = [e.kind for e in ev]
    assert kinds[:3] == ["touchdown", "liftoff", "touchdown"]
    t_td, t_st = _spring_mass_times(z0, p)
    assert abs(ev[0].t - t_td) < 1e-6
    assert abs(ev[1].t - (t_td + t_st)) < 1e-6
    # Undamped: lifts off with the touchdown speed, next touchdown is symmetric.
    assert abs(ev[2].t - (t_td + t_st + 2 * t_td)) < 1e-6


def test_stance_duration_of_pure_spring_mass():
    # No gravity: the stance is exactly half a period of the spring-mass, pi sqrt(m/k).
    p = PogoXParams(g=0.0, **PASSIVE)
    pl = PogoXPlant(p)
    pl.reset([0, 0, p.leg_rest_length + 0.1], velocity=[0, 0, -1.0], rotor_speeds=0.0)
    ev = _run(pl, 0.4)
    assert [e.kind for e in ev[:2]] == ["touchdown", "liftoff"]
    assert abs(ev[0].t - 0.1) < 1e-9
    assert abs((ev[1].t - ev[0].t) - math.pi * math.sqrt(p.mass / p.leg_stiffness)) < 1e-6
    assert pl.velocity[2] == pytest.approx(1.0, abs=1e-6)


def test_energy_is_conserved_in_undamped_passive_bounce():
    p = PogoXParams(**PASSIVE)
    pl = PogoXPlant(p)
    pl.reset([0, 0, 0.6], rotor_speeds=0.0)
    e0 = pl.energy()
    worst = 0.0
    modes = set()
    for _ in range(2500):  # ~3 bounces
        pl.step(0.001, (0.0,) * 4)
        worst = max(worst, abs(pl.energy() - e0))
        modes.add(pl.mode)
    assert modes == {AIR, STANCE}
    assert worst / e0 < 1e-7


def test_tilted_bounce_conserves_energy_within_phases_and_stays_pinned():
    p = PogoXParams(**PASSIVE)
    pl = PogoXPlant(p)
    pl.reset([0, 0, 0.55], velocity=[0.3, 0, 0], quaternion=quat_from_euler(0.0, -0.08, 0.0), rotor_speeds=0.0)
    energies, modes, foot = [], [], []
    for _ in range(450):
        ev = pl.step(0.001, (0.0,) * 4)
        energies.append(pl.energy())
        modes.append(pl.mode)
        foot.append(pl.foot_position())
        if ev and ev[0].kind == "liftoff":
            break
    modes = np.array(modes)
    energies = np.array(energies)
    st = np.flatnonzero(modes == STANCE)
    assert st.size > 50
    # Energy is constant inside the stance (the touchdown impulse is the only loss).
    seg = energies[st[0] : st[-1] + 1]
    assert np.ptp(seg) / seg[0] < 1e-7
    assert seg[0] <= energies[0] + 1e-9
    # The foot does not move while in contact.
    f = np.array(foot)[st]
    assert np.max(np.abs(f - f[0])) < 1e-12
    assert f[0][2] == 0.0


def test_touchdown_map_zeroes_lateral_foot_velocity_and_drops_foot_momentum():
    p = PogoXParams(drag=0.0, leg_damping=0.0, idle_fraction=0.0, foot_mass=0.2)
    pl = PogoXPlant(p)
    q = quat_from_euler(0.05, -0.1, 0.2)
    pl.reset([0, 0, 0.7], velocity=[0.4, -0.2, -1.0], quaternion=q, rates=[0.3, -0.2, 0.1], rotor_speeds=0.0)
    s = pl.state.tolist()
    R = np.array([[1 - 2 * (s[8] ** 2 + s[9] ** 2), 2 * (s[7] * s[8] - s[6] * s[9]), 2 * (s[7] * s[9] + s[6] * s[8])],
                  [2 * (s[7] * s[8] + s[6] * s[9]), 1 - 2 * (s[7] ** 2 + s[9] ** 2), 2 * (s[8] * s[9] - s[6] * s[7])],
                  [2 * (s[7] * s[9] - s[6] * s[8]), 2 * (s[8] * s[9] + s[6] * s[7]), 1 - 2 * (s[7] ** 2 + s[8] ** 2)]])
    L = s[13]

    def foot_vel_body(st):
        vb = R.T @ np.array(st[3:6])
        w = np.array(st[10:13])
        return vb + np.cross(w, [0, 0, -L])

    before = foot_vel_body(s)
    after_state = pl._touchdown_map(s)
    after = foot_vel_body(after_state)
    np.testing.assert_allclose(after[:2], 0.0, atol=1e-12)
    assert after[2] == pytest.approx(before[2] * (1 - p.foot_mass / p.mass))
    assert after_state[14] == pytest.approx(after[2])  # leg rate = axial velocity


def test_bump_stop_counts_bottom_out():
    p = PogoXParams(**PASSIVE)
    pl = PogoXPlant(p)
    pl.reset([0, 0, 1.2], rotor_speeds=0.0)
    _run(pl, 0.7)
    assert pl.n_bottom_outs == 1
