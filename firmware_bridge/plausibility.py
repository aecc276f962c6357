"""Is a telemetry sample physically plausible? Bounds, jumps from the last accepted sample, and the
vehicle clock's progress; the rules :class:`.telemetry.TelemetryState` applies before a sample is used.

A sample that fails is dropped and counted by reason (it never reaches the frames or the setpoints);
the stream's last accepted sample ages instead, so a run of them is stale telemetry. A sample whose
stamp leaves the stream's time line (back in time, or ahead of what the receive clock allows) starts
or extends a *candidate* time line. A line is the vehicle's once ``TIMELINE_SAMPLES`` samples advanced on it;
until then a candidate that advanced as often replaces it (one forged or stray first sample never anchors the
good ones), after it :class:`.vehicle_link.VehicleLink` takes a candidate that ``TIMELINE_SAMPLES`` samples agree
on as a reboot only with a heartbeat's evidence as well.

The bounds are not the reference envelope: a vehicle outside its envelope must still be seen. They
are what no multicopter's estimator reports, with room for its resets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MAX_POSITION_M", "MAX_SPEED_MPS", "MAX_ACCEL_MPS2", "MAX_BODY_RATE_RADPS", "MAX_CLOCK_RATE",
           "CLOCK_SLACK_S", "TIMELINE_SAMPLES", "TelemetryLimits", "on_timeline"]

# EKF local frames (PX4, ArduPilot) stay within tens of km of their origin over any flight a
# companion link reaches; a position beyond 100 km is a corrupt or forged sample.
MAX_POSITION_M = 1e5
# Above the fastest multicopters' top speed with margin; a forged 1e30 m/s fails it.
MAX_SPEED_MPS = 100.0
# About 10 g: beyond any multicopter's thrust-to-weight and its estimator's velocity resets per second.
MAX_ACCEL_MPS2 = 100.0
# About 2900 deg/s: beyond a racing quadrotor's flip rates.
MAX_BODY_RATE_RADPS = 50.0
# An estimator reset (GPS switch, origin reset) may step the position a few metres and the velocity a
# few m/s at once; larger steps wait until the time since the last sample allows them.
JUMP_MARGIN_M = 2.0
SPEED_JUMP_MARGIN_MPS = 5.0
# A lock-step simulator may run faster than real time; four times is beyond what the bridge follows.
MAX_CLOCK_RATE = 4.0
# Samples delivered together (a burst, a queue) lead the receive clock by the stamp step between two of them
# (ArduPilot's bursts 5 ms, PX4 SIH's steps up to 16 ms); a stamp may lead by this much more. Below the bridge's
# default max_age (50 ms): a sample forged a little ahead makes the genuine ones "back in time" for less than
# that, never stale telemetry (at 0.5 s, stamps 0.4 s ahead from the vehicle's address kept the telemetry stale
# and the vehicle, flown on held measurements, left its envelope: found by make fuzz).
CLOCK_SLACK_S = 0.04
# A time line is the vehicle's once this many samples advanced on it (before that its stamps are nobody's
# reference, and a run that advanced as often off it replaces it); a reboot needs as many samples that agree on a
# new time line (and a heartbeat's evidence).
TIMELINE_SAMPLES = 5
# With a profile's speed / acceleration limit: the vehicle may exceed its path's limits (wind, a push,
# its own overshoot) by this factor plus the margins above, never more than the absolute bounds.
PROFILE_LIMIT_FACTOR = 3.0


@dataclass(frozen=True)
class TelemetryLimits:
    """What a plausible sample satisfies (SI units: m, m/s, m/s^2, rad/s, s)."""

    max_position: float = MAX_POSITION_M
    max_speed: float = MAX_SPEED_MPS
    max_accel: float = MAX_ACCEL_MPS2
    max_rate: float = MAX_BODY_RATE_RADPS
    jump_margin: float = JUMP_MARGIN_M
    speed_margin: float = SPEED_JUMP_MARGIN_MPS
    clock_rate: float = MAX_CLOCK_RATE
    clock_slack: float = CLOCK_SLACK_S

    @classmethod
    def from_envelope(cls, envelope) -> TelemetryLimits:
        """Speed and acceleration bounds from a profile's envelope (its ``max_speed`` / ``max_accel`` where it
        has them, times :data:`PROFILE_LIMIT_FACTOR` plus the margins), else the defaults."""
        speed = _finite_positive(getattr(envelope, "max_speed", None))
        accel = _finite_positive(getattr(envelope, "max_accel", getattr(envelope, "max_acceleration", None)))
        return cls(max_speed=min(MAX_SPEED_MPS, PROFILE_LIMIT_FACTOR * speed + SPEED_JUMP_MARGIN_MPS)
                   if speed else MAX_SPEED_MPS,
                   max_accel=min(MAX_ACCEL_MPS2, PROFILE_LIMIT_FACTOR * accel) if accel else MAX_ACCEL_MPS2)

    def state_fault(self, position, velocity, last: tuple | None, dt: float) -> str | None:
        """Why a position sample is implausible (None: plausible).

        Args:
            position, velocity: the sample, (3,) each [m, m/s]. last: the last accepted (position, velocity)
                of the stream, or None. dt: time since that sample [s, >= 0].
        """
        if max(abs(v) for v in position) > self.max_position:
            return "position_bounds"
        if math.sqrt(sum(v * v for v in velocity)) > self.max_speed:
            return "velocity_bounds"
        if last is None:
            return None
        p0, v0 = last
        if _dist(position, p0) > self.max_speed * dt + self.jump_margin:
            return "position_jump"
        if _dist(velocity, v0) > self.max_accel * dt + self.speed_margin:
            return "velocity_jump"
        return None

    def rates_fault(self, rates) -> str | None:
        """Why body rates (3,) [rad/s] are implausible (None: plausible)."""
        return "rate_bounds" if max(abs(v) for v in rates) > self.max_rate else None


def on_timeline(limits: TelemetryLimits, stamp0: float, rx0: float, stamp: float, rx: float) -> bool:
    """The stamp [s] received at ``rx`` [s] continues a time line whose last sample was (``stamp0``, ``rx0``):
    never back in time, never further ahead than the receive clock allows."""
    if not math.isfinite(stamp0):
        return True
    step = stamp - stamp0
    return 0.0 <= step <= max(rx - rx0, 0.0) * limits.clock_rate + limits.clock_slack


def _dist(a, b) -> float:
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b)))


def _finite_positive(v) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) and f > 0 else None
