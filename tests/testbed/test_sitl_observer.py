"""The SITL observer without a SITL: its true height refined below the centimetres ArduCopter reports, the frames'
offset measured on the ground, the pairing of truth and estimate by arrival, and the lag it measures."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from ddpc_codegen.testbed.mocap import MocapConfig, MocapSampler
from ddpc_codegen.testbed.sitl_observer import HOME_ALT, Observer, estimate_lag

GROUND_UP = 0.0437  # the true height of the vehicle on the ground above home [m]: inside a centimetre cell


def sim_state(up: float, vu: float) -> SimpleNamespace:
    """ArduCopter's SIM_STATE at ``up`` [m] above home climbing at ``vu`` [m/s]: the altitude truncated to whole
    centimetres (as the simulator's Location reports it), the velocity exact."""
    alt = math.floor(round((HOME_ALT + up) * 100.0, 6)) / 100.0
    return SimpleNamespace(get_type=lambda: "SIM_STATE", alt=alt, vd=-vu, lat=-35.363261, lon=149.16523, lat_int=0,
                           lon_int=0, vn=0.0, ve=0.0, roll=0.0, pitch=0.0, yaw=0.0)


def lpos(up: float, boot_s: float) -> SimpleNamespace:
    return SimpleNamespace(get_type=lambda: "LOCAL_POSITION_NED", z=-up, time_boot_ms=int(round(boot_s * 1e3)))


def flight(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """On the ground for 5 s, then a climb to 1 m and a 0.5 m/s-class vertical wander [m, m/s] at the times ``t``."""
    s = np.clip(t - 5.0, 0.0, None)
    climb = 0.5 - 0.5 * np.cos(np.pi * np.minimum(s, 2.0) / 2.0)
    up = GROUND_UP + climb + 0.3 * np.sin(2 * np.pi * s / 4.3) + 0.2 * np.sin(2 * np.pi * s / 6.1)
    return up, np.gradient(up, t)


def fly_observer(estimate_at, t: np.ndarray, burst: np.ndarray | None = None) -> Observer:
    """An observer fed the flight's SIM_STATE and LOCAL_POSITION_NED (``estimate_at(i)``: the estimate sent with
    the i-th sample, stamped with its time ``t``) at 50 Hz, both delayed on arrival by ``burst`` [s] (n,) (the
    link's common bursts)."""
    obs = Observer("", connect=False)
    up, vu = flight(t)
    late = np.zeros_like(t) if burst is None else burst
    for i, ti in enumerate(t):
        obs.record(sim_state(up[i], vu[i]), ti + late[i])
        obs.record(lpos(estimate_at(i), ti), ti + late[i] + 1e-4)
    return obs


def test_the_true_height_is_refined_below_the_centimetre_grid():
    t = np.arange(0.0, 30.0, 0.02)
    up, _ = flight(t)
    obs = fly_observer(lambda i: 0.0, t)
    truth, _ = obs.heights(t[300:-1])
    raw = np.array([sim_state(u, 0.0).alt - HOME_ALT for u in up[300:-1]])
    assert np.sqrt(np.mean((raw - up[300:-1]) ** 2)) > 0.004  # the message alone: centimetre steps, ~5 mm off
    assert np.sqrt(np.mean((truth - up[300:-1]) ** 2)) < 0.0005


def test_an_exact_estimate_on_the_mocap_is_within_a_millimetre_on_the_ground_and_in_flight():
    """The EKF follows the stand-in, whose origin is its first (refined) sample on the ground: the observer's ground
    offset and refined truth put such an estimate on the truth, with no hover offset from the grid."""
    t = np.arange(0.0, 30.0, 0.02)
    up, vu = flight(t)
    mocap = MocapSampler(MocapConfig(latency_s=0.0, pos_noise_m=0.0, att_noise_rad=0.0, vel_noise_mps=0.0))
    est = []
    for ti, u, v in zip(t, up, vu):
        mocap.feed(sim_state(u, v), ti)
        est.append(-float(mocap.sample(ti).position[2]))
    obs = fly_observer(lambda i: est[i], t)
    k = t < 4.5  # what Observer.ground() takes before a take-off
    ground = float(np.median(np.array(obs.sim)[k, 1] - np.array(obs.lpos)[k, 1]))
    truth, e = obs.heights(t[1:-1])
    err = e - (truth - ground)
    assert np.sqrt(np.mean(err[t[1:-1] < 4.5] ** 2)) < 0.0005   # on the ground
    assert np.sqrt(np.mean(err[t[1:-1] > 8.0] ** 2)) < 0.001    # in flight


def test_truth_and_estimate_on_the_autopilots_clock_through_the_links_bursts():
    """Both streams leave the autopilot's same loop and arrive in the same bursts, 0-20 ms late (as measured on
    ArduCopter's TCP link): placed on the estimate's time_boot_ms, the truth is where it was when sent (on arrival
    it would be off by its speed times the burst), an exact estimate stays on it and no lag appears."""
    t = np.arange(0.0, 30.0, 0.02)
    up, _ = flight(t)
    rng = np.random.default_rng(3)
    burst = np.repeat(rng.uniform(0.0, 0.02, len(t) // 4 + 1), 4)[:len(t)]
    obs = fly_observer(lambda i: up[i], t, burst)
    k = (t > 8.0) & (t < 29.0)
    truth, e = obs.heights(t[k])
    assert np.sqrt(np.mean((e - truth) ** 2)) < 0.001
    assert np.sqrt(np.mean((truth - up[k]) ** 2)) < 0.001
    lag, spread = obs.estimate_lag(8.0, 29.0)
    assert abs(lag) <= 0.002 and spread < 0.001
    px4 = Observer("", autopilot="px4", connect=False)  # PX4 sends them apart: on arrival
    px4.record(lpos(1.0, 100.0), 5.0)
    assert px4.clock is None and px4.lpos == [(5.0, 1.0)]


@pytest.mark.parametrize("late", [0.03, -0.02])
def test_estimate_lag_finds_an_estimate_late_or_early(late):
    t = np.arange(0.0, 20.0, 0.005)
    truth = 0.4 * np.sin(2 * np.pi * t / 4.3) + 0.3 * np.sin(2 * np.pi * t / 6.1)
    est = np.interp(t - late, t, truth)
    lag, spread = estimate_lag(np.arange(2.0, 18.0, 0.005), (t, truth), (t, est))
    assert lag == pytest.approx(late, abs=0.0011) and spread < 0.001
    assert math.isnan(estimate_lag(np.array([1.0]), (t, truth), (t, est))[0])
    still = np.full_like(t, 1.0) + 0.001 * np.sin(t)  # a hover's millimetres: no lag to see
    assert math.isnan(estimate_lag(np.arange(2.0, 18.0, 0.005), (t, still), (t, still))[0])
