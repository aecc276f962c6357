"""The telemetry's time line (firmware_bridge/telemetry.py): a stream's stamps are the vehicle's clock only once
TIMELINE_SAMPLES samples advanced on its line, so no stray or forged first sample becomes the reference of the good
ones (it is re-lined onto them, with an event); a confirmed line leaves only on a reboot's evidence, as before.

Found by make fuzz's start-up stamp attack: samples stamped 2**32 - 1 ms before the vehicle's first real one kept
every real sample "back in time" (exit 8), and a first tick on that stamp kept the setpoint stream's length in
vehicle time negative (no OFFBOARD request) even once the line was re-lined. The same length across a genuine reboot
in lock-step (firmware_bridge/setpoints.py): the stream never pauses there, so it restarts on the reboot itself."""

from __future__ import annotations

import math
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge.clock import TickTrigger
from firmware_bridge.plausibility import TIMELINE_SAMPLES
from firmware_bridge.setpoints import SetpointStream
from firmware_bridge.telemetry import TelemetryState
from part_fakes import heartbeat, line, telemetry, vehicle

DT = 0.005
T0, RX0 = 10.0, 100.0  # the vehicle's clock at its first real sample [s], the bridge's receive clock then [s]
FAR_MS = 2**32 - 1     # the largest stamp a MAVLink time_boot_ms carries
Q = (1.0, 0.0, 0.0, 0.0)


def _real(k: int, z: float = 1.0):
    """The vehicle's k-th sample pair at 200 Hz and its receive time."""
    return telemetry(T0 + DT * k, z), RX0 + DT * k


# A forged or stray stamp [ms] at least 10 s off the vehicle's clock (ahead or behind), and its height [m].
_stray = st.tuples(st.one_of(st.integers(0, int((T0 - 10.0) * 1000)), st.integers(int((T0 + 10.0) * 1000), FAR_MS)),
                   st.floats(0.5, 3.0))


@settings(max_examples=60, deadline=None)
@given(strays=st.lists(st.tuples(st.integers(0, TIMELINE_SAMPLES + 2), _stray), min_size=1,
                       max_size=TIMELINE_SAMPLES - 1))
def test_stray_stamps_at_start_up_never_become_the_reference_of_the_good_samples(strays):
    """Up to TIMELINE_SAMPLES - 1 samples off the vehicle's clock, before or among its first real samples: the
    stamps in use are only ever the vehicle's, its samples end up used on their own line (at most one re-line per
    stream, said in a note), and a tick never happens on a stray stamp."""
    tel, trigger = TelemetryState(), TickTrigger(DT, lockstep=True, max_gap_fill=3)
    real = {round(T0 + DT * k, 3) for k in range(40)}
    for k in range(40):
        for _, (ms, z) in (s for s in strays if s[0] == k):
            for m in telemetry(ms / 1000.0, z):
                tel.update(m, RX0 + DT * k)
        msgs, rx = _real(k)
        for m in msgs:
            tel.update(m, rx)
        if tel.has_data:  # a stamp the bridge may use (the tick clock, the vehicle clock)
            assert round(tel.newest_stamp(), 3) in real and round(tel.oldest_stamp(), 3) in real
        assert trigger.due(rx, tel) in ("", "event")
        if trigger.due(rx, tel):
            assert round(trigger.timing(rx, tel)[1], 3) in real
            trigger.consumed(tel)
    assert tel.has_data and math.isclose(tel.newest_stamp(), T0 + DT * 39) and tel.position[2] == 1.0
    assert tel.relines <= 2 and len(tel.take_notes()) == tel.relines and not tel.new_timeline()


@settings(max_examples=40, deadline=None)
@given(t_back=st.floats(0.0, T0 - 0.1), n_stray=st.integers(1, TIMELINE_SAMPLES - 1))
def test_a_confirmed_time_line_is_never_re_lined_and_stamps_going_back_for_good_wait_for_a_reboot(t_back, n_stray):
    """Stamps that go back and stay consistent after the line was confirmed are a reboot's business (a heartbeat's
    evidence in the vehicle link): dropped, never re-lined; fewer than TIMELINE_SAMPLES of them are no new line."""
    tel = TelemetryState()
    for k in range(TIMELINE_SAMPLES):
        msgs, rx = _real(k)
        for m in msgs:
            assert tel.update(m, rx)
    assert tel.has_data and tel.att.confirmed and tel.pos.confirmed
    for j in range(n_stray):
        for m in telemetry(t_back + DT * j):
            assert not tel.update(m, RX0 + 1.0 + DT * j)
    assert not tel.new_timeline()
    for j in range(n_stray, TIMELINE_SAMPLES):
        for m in telemetry(t_back + DT * j):
            assert not tel.update(m, RX0 + 1.0 + DT * j)
    assert tel.new_timeline() and tel.relines == 0 and tel.newest_stamp() == T0 + DT * (TIMELINE_SAMPLES - 1)


def test_no_tick_and_no_vehicle_clock_before_the_line_is_confirmed():
    tel, trigger = TelemetryState(), TickTrigger(DT, lockstep=False, max_gap_fill=3)
    for k in range(TIMELINE_SAMPLES - 1):
        msgs, rx = _real(k)
        for m in msgs:
            assert tel.update(m, rx)  # used (the newest sample), but its stamp is no one's reference yet
        assert not tel.has_data and math.isnan(tel.newest_stamp()) and trigger.due(rx, tel) == ""
    msgs, rx = _real(TIMELINE_SAMPLES - 1)
    for m in msgs:
        tel.update(m, rx)
    assert tel.has_data and trigger.due(rx, tel) == "grid"


def test_the_fuzzers_far_stamps_at_start_up_are_re_lined_with_one_event_and_the_clock_is_the_vehicles():
    """make fuzz's start-up attack through the vehicle link: three pairs stamped 2**32 - 1 ms around the first real
    samples. The vehicle's samples are used after five, each stream re-lined once with an event; no reboot, no
    "left its time line" event; the vehicle clock estimate and the lock-step clock are the vehicle's stamps."""
    v = vehicle()
    v.on_message(heartbeat(), RX0 - 0.01)
    for k in range(12):
        if k < 3:
            for m in telemetry(FAR_MS / 1000.0, z=0.9):
                v.on_message(m, RX0 + DT * k - 0.001)
        msgs, rx = _real(k)
        for m in msgs:
            v.on_message(m, rx + 0.002)
    tel = v.telem
    assert tel.has_data and tel.newest_stamp() == T0 + DT * 11 and tel.position[2] == 1.0
    assert v.counts["reboots"] == 0 and tel.relines == 2 and tel.rejected["stamp"] == 2 * (TIMELINE_SAMPLES - 1)
    said = [e for _, e in v.events.events]
    assert sum("telemetry re-lined from 4294967.295 s to 10.020 s" in e for e in said) == 2, said
    assert not any("left its time line" in e for e in said)
    assert math.isclose(v.t_offset, RX0 + 0.002 - T0, abs_tol=1e-9)
    assert math.isclose(v.vehicle_now(RX0 + 1.0, lockstep=False), T0 + 1.0 - 0.002, abs_tol=1e-9)
    assert v.vehicle_now(0.0, lockstep=True) == T0 + DT * 11


def test_a_reboot_with_heartbeat_evidence_starts_on_a_confirmed_line():
    """The reboot keeps its rule (five samples on a new time line and a heartbeat's evidence) and its new line is
    the vehicle's at once: what its samples agreed on counts, no second confirmation."""
    v = vehicle()
    v.on_message(heartbeat(), RX0)
    for m in line(T0 + 0.1, n=20):
        v.on_message(m, RX0 + 0.1)
    v.on_message(heartbeat(), RX0 + 1.0)  # silent past the link timeout: a reboot's evidence
    for k in range(TIMELINE_SAMPLES):
        for m in telemetry(0.2 + DT * k):
            v.on_message(m, RX0 + 1.0 + DT * k)
    assert v.counts["reboots"] == 1 and v.telem.relines == 0 and v.telem.has_data
    assert v.telem.newest_stamp() == 0.2 + DT * (TIMELINE_SAMPLES - 1)


# The vehicle's clock before a reboot [ms] and after it: back (a fresh boot) or far ahead of what the receive clock
# allows; both off the old time line.
_reboot_clocks = st.integers(1000, 4_000_000).flatmap(
    lambda pre: st.tuples(st.just(pre), st.one_of(st.integers(0, pre - 500), st.integers(pre + 60_000, FAR_MS - 1000))))


@settings(max_examples=60, deadline=None)
@given(clocks=_reboot_clocks, evidence=st.sampled_from(["silence", "state"]),
       n_before=st.integers(TIMELINE_SAMPLES, 40), n_after=st.integers(0, 40))
def test_a_reboot_in_lockstep_restarts_the_setpoint_streams_length_on_the_new_time_line(clocks, evidence, n_before,
                                                                                        n_after):
    """Lock-step (the stream's length counts in vehicle time): a setpoint goes out on every tick, so the stream never
    pauses on the wall clock, across a genuine reboot (a new time line and the heartbeat's evidence). Its length is
    then the new line's, from the first setpoint on it: never a difference across the two lines (negative after a
    fresh boot: no OFFBOARD request; huge after a jump ahead: an OFFBOARD request before the vehicle had a stream)."""
    t_pre, t_new = clocks[0] / 1000.0, clocks[1] / 1000.0
    trigger = TickTrigger(DT, lockstep=True, max_gap_fill=3)
    v = vehicle(on_reboot=trigger.restart_samples)
    stream, tel = SetpointStream(v, lockstep=True), v.telem
    v.on_message(heartbeat(), RX0)

    def sample(t: float, rx: float) -> None:
        for m in telemetry(t):
            v.on_message(m, rx)
        if trigger.due(rx, tel):  # the bridge's lock-step tick: a setpoint stamped with the newest sample
            trigger.consumed(tel)
            stream.send(Q, 0.5, int(round(tel.newest_stamp() * 1000)))

    for k in range(n_before):
        sample(t_pre - DT * (n_before - 1 - k), RX0 + DT * k)
    rx = RX0 + DT * n_before
    before = DT * (n_before - TIMELINE_SAMPLES)  # from the first tick on the confirmed line
    assert stream.streamed(time.monotonic()) == pytest.approx(before)
    if evidence == "silence":
        rx += 1.0  # silent past the link timeout
        v.on_message(heartbeat(), rx)
    else:
        v.on_message(heartbeat(armed=False), rx)  # a fresh boot comes back disarmed
    for k in range(TIMELINE_SAMPLES + n_after):
        sample(t_new + DT * k, rx + DT * (k + 1))
        done = k - (TIMELINE_SAMPLES - 1)  # ticks on the new line since its first (the sample that completed it)
        assert stream.streamed(time.monotonic()) == pytest.approx(before if done < 0 else DT * done, abs=1e-9)
    assert v.counts["reboots"] == 1 and tel.newest_stamp() == pytest.approx(t_new + DT * (TIMELINE_SAMPLES - 1 + n_after))
