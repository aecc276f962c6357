"""Hopping phase detection (robot/phases.py) against the simulator's true touchdown and liftoff
times, with and without sensor noise, and on synthetic chatter."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.values.phases import ASCENT, DESCENT, GROUND
from ddpc_codegen.robot.phases import ContactConfig, PhaseEstimator


def _hop(noise: bool, seed: int, duration: float = 8.0):
    from ddpc_codegen.sim import simulate

    states = []
    res = simulate("hopping", duration, seed=seed, noise=noise,
                   reference_hook=lambda ctx: states.append(ctx.state))  # observes, changes nothing
    return res, states


def _delays(events, kind: str, times: np.ndarray, dt: float) -> list[int | None]:
    """Detection tick minus the first tick at or after each true event (None: not detected)."""
    ks = [k for k, e in events if e == kind]
    out = []
    for te in times:
        k0 = int(np.ceil(te / dt - 1e-9))
        near = [k - k0 for k in ks if -3 <= k - k0 <= 10]
        out.append(near[0] if near else None)
    return out


@pytest.mark.parametrize("noise, seed", [(False, 0), (True, 1)])
def test_estimate_from_telemetry_within_two_ticks(noise, seed):
    res, states = _hop(noise, seed)
    est = PhaseEstimator(ContactConfig(leg_length=res.config.leg_length))
    sig = PhaseEstimator(ContactConfig(source="signal"))
    for s in states:
        est.update(s.position[2], s.velocity[2], s.euler[0], s.euler[1])
        sig.update(0.0, 0.0, 0.0, 0.0, signal=s.contact)
    n_td, n_lo = len(res.touchdowns), len(res.liftoffs)
    assert n_td >= 8
    for e in (est, sig):  # one event per true event: no chatter, none missed
        assert sum(1 for _, k in e.events if k == "touchdown") == n_td
        assert sum(1 for _, k in e.events if k == "liftoff") == n_lo
    d = _delays(est.events, "touchdown", res.touchdowns, res.dt) + _delays(est.events, "liftoff", res.liftoffs, res.dt)
    within = np.mean([x is not None and 0 <= x <= 2 for x in d])
    assert within >= (1.0 if not noise else 0.9), d
    # the robot's own contact flag arrives with the one-tick measurement delay, never later
    ds = _delays(sig.events, "touchdown", res.touchdowns, res.dt) + _delays(sig.events, "liftoff", res.liftoffs, res.dt)
    assert set(ds) == {1}


@pytest.mark.parametrize("noise, seed", [(False, 0), (True, 1), (True, 2)])
def test_profile_thresholds_detect_on_the_sensors_sample(noise, seed):
    """pogox_hopping's [contact] thresholds sit where the foot meets (h = 0) and leaves (h = -3.7 mm,
    the leg still extending) the ground: noise-free, every touchdown and liftoff from telemetry alone
    on the sample the contact flag reports it (1 tick, the measurement delay) or one after; with
    sensor noise >= 95 % within 2 ticks, none spurious or missed."""
    from ddpc_codegen.robot.profile import load_profile

    res, states = _hop(noise, seed)
    est = PhaseEstimator(load_profile("pogox_hopping").contact)
    for s in states:
        est.update(s.position[2], s.velocity[2], s.euler[0], s.euler[1])
    assert sum(1 for _, k in est.events if k == "touchdown") == len(res.touchdowns)
    assert sum(1 for _, k in est.events if k == "liftoff") == len(res.liftoffs)
    d = _delays(est.events, "touchdown", res.touchdowns, res.dt) + _delays(est.events, "liftoff", res.liftoffs, res.dt)
    if noise:
        assert np.mean([x is not None and 0 <= x <= 2 for x in d]) >= 0.95, d
    else:
        assert set(d) <= {1, 2} and np.mean([x == 1 for x in d]) >= 0.75, d


def test_profile_thresholds_resting_on_the_leg_do_not_chatter():
    """Standing on the compressed leg (h = -7 mm, half the weight on the spring), noisy: no liftoff."""
    from ddpc_codegen.robot.profile import load_profile

    rng = np.random.default_rng(0)
    est = PhaseEstimator(load_profile("pogox_hopping").contact, phase=GROUND)
    for _ in range(2000):
        est.update(0.4 - 0.007 + rng.normal(0, 0.002), rng.normal(0, 0.02), 0.0, 0.0)
    assert est.events == []


def test_noise_around_the_contact_plane_does_not_chatter():
    rng = np.random.default_rng(0)
    est = PhaseEstimator(ContactConfig(leg_length=0.4), phase=DESCENT)
    for _ in range(2000):  # foot hovering at the plane, sigma 2 mm, vz noise 0.02 m/s
        est.update(0.4 + rng.normal(0, 0.002), rng.normal(0, 0.02), 0.0, 0.0)
    assert len(est.events) <= 2


def test_apex_switches_ascent_to_descent_once():
    est = PhaseEstimator(ContactConfig(leg_length=0.4), phase=ASCENT)
    phases = [est.update(0.7, vz, 0.0, 0.0) for vz in (1.0, 0.5, 0.0, -0.2, 0.2, -0.5)]
    assert phases == [ASCENT, ASCENT, ASCENT, DESCENT, DESCENT, DESCENT]


def test_tilted_leg_reaches_the_ground_later():
    est = PhaseEstimator(ContactConfig(leg_length=0.4))
    assert est.foot_height(0.4, 0.0, 0.0) == pytest.approx(0.0)
    assert est.foot_height(0.4, 0.0, 0.3) == pytest.approx(0.4 * (1 - np.cos(0.3)))
    est.update(0.38, -1.0, 0.0, 0.0)
    assert est.phase == GROUND


@pytest.mark.parametrize("kw, match", [
    ({"source": "sensor"}, "source must be one of"),
    ({"leg_length": 0.0}, "leg_length must be > 0"),
    ({"touchdown_margin": -0.001}, "touchdown_margin must be a number >= 0"),
    ({"liftoff_margin": -0.5}, "liftoff_margin must be > -leg_length"),
    ({"liftoff_margin": float("nan")}, "liftoff_margin must be a number"),
    ({"min_air_ticks": 0}, "min_air_ticks must be an integer >= 1"),
])
def test_bad_contact_config(kw, match):
    with pytest.raises(ValueError, match=match):
        ContactConfig(**kw)


def test_signal_source_needs_the_signal():
    with pytest.raises(ValueError, match="needs the robot's contact flag"):
        PhaseEstimator(ContactConfig(source="signal")).update(0.5, 0.0, 0.0, 0.0)


def _fall(est, v: float, dt: float = 0.005, z0: float = 0.46, n: int = 40):
    """Foot falling onto the plane at v [m/s] then compressing; returns the heights fed."""
    zs = []
    for k in range(n):
        z = z0 - v * dt * k
        zs.append(z)
        est.update(z, -v, 0.0, 0.0, signal=(z < 0.4) if est.config.source == "signal" else None)
        if est.phase == GROUND:
            return zs, k
    raise AssertionError("no touchdown")


@pytest.mark.parametrize("v, margin", [(1.7, 0.004), (0.5, 0.004), (1.7, 0.02)])
def test_touchdown_backdates_the_samples_already_below_the_plane(v, margin):
    est = PhaseEstimator(ContactConfig(leg_length=0.4, touchdown_margin=margin), phase=DESCENT)
    zs, k = _fall(est, v)
    below = [i for i, z in enumerate(zs) if z < 0.4]
    # every sample below the plane before the confirming one is handed back, up to the cap
    assert est.backdate == min(k - below[0], est.config.backdate_ticks)
    est.update(0.39, -v, 0.0, 0.0)
    assert est.backdate == 0  # only on the confirming tick


def test_contact_signal_is_never_backdated():
    est = PhaseEstimator(ContactConfig(source="signal"), phase=DESCENT)
    _fall(est, 1.7)
    assert est.backdate == 0 and est.events[-1][1] == "touchdown"
