"""The time line a telemetry stamp must continue (plausibility.on_timeline): never back in time, never further
ahead than the receive clock allows -- a burst's steps pass, a stamp forged a few hundred ms ahead does not
(make fuzz's same-address stamp attack: at a 0.5 s slack it kept the genuine samples "back in time", the
telemetry stale, and the vehicle, flown on held measurements, left its envelope)."""

from __future__ import annotations

from firmware_bridge.plausibility import CLOCK_SLACK_S, MAX_CLOCK_RATE, TelemetryLimits, on_timeline

LIM = TelemetryLimits()


def test_bursts_and_fast_simulators_stay_on_the_time_line():
    assert on_timeline(LIM, float("nan"), 0.0, 123.0, 0.0)            # the first sample starts it
    assert on_timeline(LIM, 10.000, 5.0, 10.005, 5.0)                # ArduPilot: two samples in one datagram
    assert on_timeline(LIM, 10.000, 5.0, 10.016, 5.0)                # PX4 SIH's longest step, delivered together
    assert on_timeline(LIM, 10.000, 5.0, 10.005, 5.0005)             # a lock-step simulator, 10x real time
    assert on_timeline(LIM, 10.000, 5.0, 10.400, 5.1)                # 0.1 s received: 0.4 s of a 4x simulator
    assert on_timeline(LIM, 10.000, 5.0, 12.000, 7.0)                # a link dropout: stamp and receive clock alike


def test_a_stamp_ahead_of_the_receive_clock_or_back_in_time_leaves_it():
    assert CLOCK_SLACK_S < 0.05  # below the bridge's default max_age: a forged lead never makes the telemetry stale
    assert not on_timeline(LIM, 10.000, 5.0, 10.400, 5.0)            # 0.4 s ahead in the same instant
    assert not on_timeline(LIM, 10.000, 5.0, 10.000 + CLOCK_SLACK_S + 0.001, 5.0)
    assert not on_timeline(LIM, 10.000, 5.0, 70.000, 5.01)           # 60 s ahead
    assert not on_timeline(LIM, 10.000, 5.0, 9.990, 5.01)            # back in time
    assert on_timeline(LIM, 10.0, 5.0, 10.0 + 0.01 * MAX_CLOCK_RATE + CLOCK_SLACK_S, 5.01)
