"""An autopilot's jerk limit and the app's stream (:mod:`firmware_bridge.proxy.jerk_bound`): the guard pauses the
steering around the acceleration jumps, from when they are known to the hold after they were sent; the spread is
the exact centred moving average of the app's own fields on ramps whose acceleration jumps (the steps app's), and
leaves smooth paths as sent."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from firmware_bridge.proxy.jerk_bound import FILL, SHAPED_S, JerkBound
from firmware_bridge.proxy.rewrite import mavlink

DT = 0.02
_POS_VEL_ACC = mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE


def _sp(z: float, vz: float, az: float, mask: int = _POS_VEL_ACC):
    return mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask, 0.0, 0.0, z, 0.0, 0.0, vz, 0.0, 0.0, az, 0.0, 0.0)


def _ramp(t: np.ndarray, rise: float, dur: float, start: float = 1.0) -> tuple[np.ndarray, ...]:
    """A cosine ramp of ``rise`` [m, up] over ``dur`` [s] from ``start``: (z, vz, az) NED; its acceleration jumps to
    rise (pi / dur)^2 / 2 at both ends."""
    s = np.clip((t - start) / dur, 0.0, 1.0)
    on = (t >= start) & (t <= start + dur)
    w = math.pi / dur
    h = rise * (0.5 - 0.5 * np.cos(math.pi * s))
    v = np.where(on, 0.5 * rise * w * np.sin(math.pi * s), 0.0)
    a = np.where(on, 0.5 * rise * w * w * np.cos(math.pi * s), 0.0)
    return -h, -v, -a


def _stream(z, vz, az, max_jerk: float, preview: float):
    """What the smoother gives each setpoint once the preview holds ``preview`` [s] beyond it: (sent afz, sent vz,
    the windows' widths in setpoints), the app's own where it gives none."""
    sm = JerkBound(max_jerk, preview)
    msgs = [_sp(*row) for row in zip(z, vz, az)]
    lag = int(round(preview / DT))
    out_a, out_v = [], []
    for k, m in enumerate(msgs):
        sm.push(k * DT, m)
        j = k - lag
        if j >= 0:
            f = sm.fields(msgs[j])
            out_a.append(f.get("afz", az[j]))
            out_v.append(f.get("vz", vz[j]))
    return np.array(out_a), np.array(out_v), sm


@settings(max_examples=40, deadline=None)
@given(rise=st.floats(0.2, 1.2), dur=st.floats(1.0, 2.5), max_jerk=st.floats(3.0, 20.0))
def test_a_ramps_acceleration_jumps_are_spread_to_the_jerk_limit(rise, dur, max_jerk):
    """The sent acceleration changes by at most the limit per second (a jump within the preview's reach, on a ramp
    whose own smooth jerk is within the share of the limit the rule leaves it), and it is the exact centred average
    of the app's own over the window the rule names."""
    assume(0.5 * rise * (math.pi / dur) ** 3 <= (1.0 - FILL) * max_jerk)
    t = np.arange(0.0, dur + 3.0, DT)
    z, vz, az = _ramp(t, rise, dur)
    jump = abs(az).max()
    width = jump / (FILL * max_jerk)
    preview = max(width, 0.2)  # enough preview for the spread
    sent_a, sent_v, sm = _stream(z, vz, az, max_jerk, preview)
    assert sm.counts["short"] == 0 and (sm.counts["smoothed"] > 0 or width < 1.5 * DT)
    assert (np.abs(np.diff(sent_a)) / DT).max() <= max_jerk * 1.05
    # the centred moving average (an independent computation: numpy's convolution) where a jump is in reach
    k = np.arange(len(sent_a))
    n_half = int(math.floor(0.5 * (width + DT) / DT + 1e-9))
    for j in k[n_half:len(sent_a) - n_half:7]:
        lo, hi = j - n_half, j + n_half + 1
        near = np.abs(np.diff(az[max(j - int(preview / DT), 0):j + int(preview / DT) + 1])).max() > 0.5 * jump
        if near and n_half >= 1:
            assert sent_a[j] == pytest.approx(np.convolve(az[lo:hi], np.ones(hi - lo) / (hi - lo), "valid")[0],
                                              abs=1e-12)
            assert sent_v[j] == pytest.approx(np.mean(vz[lo:hi]), abs=1e-12)


def test_the_spread_keeps_the_ramps_velocity_change():
    """Averaging is linear: the sent acceleration integrates to the same velocity change as the app's."""
    t = np.arange(0.0, 6.0, DT)
    z, vz, az = _ramp(t, 0.8, 1.5)
    sent_a, sent_v, _ = _stream(z, vz, az, 5.0, 0.5)
    assert np.sum(sent_a) * DT == pytest.approx(np.sum(az[:len(sent_a)]) * DT, abs=1e-9)
    assert np.abs(np.diff(sent_a)).max() / DT <= 5.0 * FILL * 1.1


def test_a_smooth_path_goes_out_as_the_app_sent_it():
    """A path whose own jerk is far within the limit has no jump to spread: the fields stay the app's."""
    t = np.arange(0.0, 10.0, DT)
    w = 2 * np.pi / 6.1
    z, vz, az = -0.5 * np.sin(w * t), -0.5 * w * np.cos(w * t), 0.5 * w * w * np.sin(w * t)
    sent_a, sent_v, sm = _stream(z, vz, az, 5.0, 0.5)
    assert sm.counts["smoothed"] == 0
    assert np.array_equal(sent_a, az[:len(sent_a)]) and np.array_equal(sent_v, vz[:len(sent_v)])


def test_a_jump_wider_than_the_preview_is_spread_as_far_as_it_reaches_and_counted():
    t = np.arange(0.0, 5.0, DT)
    z, vz, az = _ramp(t, 1.0, 1.0)  # a jump of ~4.9 m/s^2: 1.2 s at 5 m/s^3, the preview reaches 0.3 s
    _, _, sm = _stream(z, vz, az, 5.0, 0.3)
    assert sm.counts["short"] > 0 and sm.summary()["max_jerk"] == 5.0


def test_ignored_or_unknown_fields_are_left_alone():
    sm = JerkBound(5.0, 0.5)
    ignored = _sp(0.0, 0.0, 0.0, _POS_VEL_ACC | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE)
    sm.push(0.0, ignored)
    assert sm.fields(ignored) == {}
    assert sm.fields(_sp(0.0, 0.0, 0.0)) == {}  # never pushed (no longer held)
    nan = _sp(0.0, float("nan"), 1.0)
    for k, m in enumerate((_sp(0.0, 0.0, 0.0), nan, _sp(0.0, 0.0, 2.0))):
        sm.push(1.0 + k * DT, m)
    f = sm.fields(nan)  # its own non-finite field is not averaged in
    assert all(math.isfinite(v) for v in f.values())


@pytest.mark.parametrize("jerk, preview, match", [(0.0, 0.5, "max-jerk must be"), (float("nan"), 0.5, "max-jerk must"),
                                                  (5.0, -1.0, "finite times >= 0"), (5.0, math.inf, "finite times")])
def test_bad_settings_are_refused(jerk, preview, match):
    with pytest.raises(ValueError, match=match):
        JerkBound(jerk, preview)


@pytest.mark.parametrize("preview", [0.0, 0.5])
def test_the_guard_pauses_from_when_a_jump_is_known_to_the_hold_after_it_was_sent(preview):
    """The steps app's ramp (a jump at its start and end): paused for the setpoints sent from ``preview`` before the
    first jump until ``hold`` after the last one; never without a preview before the jump arrives."""
    t = np.arange(0.0, 8.0, DT)
    z, vz, az = _ramp(t, 0.8, 1.5, start=2.0)
    jb = JerkBound(5.0, preview, hold=2.0)
    lag = int(round(preview / DT))
    paused = {}
    for k, row in enumerate(zip(z, vz, az)):
        jb.push(k * DT, _sp(*row))
        if k >= lag:
            paused[round((k - lag) * DT, 6)] = jb.paused((k - lag) * DT)
    on = [ts for ts, p in paused.items() if p]
    assert jb.counts["jumps"] == 2 and min(on) == pytest.approx(2.0 - preview, abs=1.5 * DT)
    assert max(on) == pytest.approx(3.5 + 2.0, abs=1.5 * DT)
    assert all(paused[ts] for ts in paused if min(on) <= ts <= max(on))


def test_the_guard_lets_a_jump_the_autopilot_makes_at_once_and_a_smooth_path_pass():
    t = np.arange(0.0, 10.0, DT)
    small = 0.9 * 5.0 * SHAPED_S  # a jump made within SHAPED_S at the limit
    jb = JerkBound(5.0)
    for k, a in enumerate(np.where(t > 3.0, small, 0.0)):
        jb.push(k * DT, _sp(0.0, 0.0, float(a)))
    w = 2 * np.pi / 4.3
    for k, tk in enumerate(t):
        jb.push(10.0 + tk, _sp(-0.3 * np.sin(w * tk), -0.3 * w * np.cos(w * tk), 0.3 * w * w * np.sin(w * tk)))
    assert jb.counts["jumps"] == 0 and not jb.paused(5.0)
