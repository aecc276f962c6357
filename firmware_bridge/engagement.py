"""Flight phases a real vehicle needs around the steered flight, each a small piece of state the
bridge's tick and supervisor consult.

* :class:`ArmingRetry` -- arm once the vehicle can be armed: not before both telemetry streams
  arrive (ArduCopter accepts arming ~16 s before it sends any LOCAL_POSITION_NED, and a
  setpoint computed without a position is garbage), then retry every ``interval`` while refused
  (each refusal reported with the autopilot's words), give up after ``timeout``.
* :class:`Approach` -- take-off / approach: the height reference ramps at ``climb_rate`` from
  where the vehicle is to the trajectory's start height (heights from the take-off point), the
  trajectory clock waits; done once the vehicle holds the start height.
* :class:`RefBlend` -- bumpless (re-)engagement: the applied reference starts at the measured
  output and moves toward the nominal one at bounded rates, then hands over exactly.

Measured on the SITLs: ArduCopter refused arming ("Arm: Gyros inconsistent", MAV_RESULT_FAILED)
for 26 s after start and sent no local position before 42 s; PX4 SIH answered
TEMPORARILY_REJECTED (no text: PX4 reports through EVENT messages) for ~2.5 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["ArmingRetry", "Approach", "RefBlend"]


@dataclass
class ArmingRetry:
    """When to send the next ARM command and when to give up.

    Attributes:
        interval: seconds between attempts while refused.
        timeout: give up this long after the first attempt [s].
    """

    interval: float = 2.0
    timeout: float = 120.0
    attempts: int = 0
    first: float = math.nan
    next_try: float = 0.0
    refusals: list[str] = field(default_factory=list)

    def due(self, now: float, ready: bool) -> bool:
        """True when an ARM command should go out now (``ready``: telemetry present, nothing pending)."""
        return ready and now >= self.next_try and not self.gave_up(now)

    def sent(self, now: float) -> None:
        if not math.isfinite(self.first):
            self.first = now
        self.attempts += 1
        self.next_try = now + self.interval

    def refused(self, result: str, text: str) -> str:
        """Record a refusal; returns the line to report."""
        why = f"arming refused ({result})" + (f": {text}" if text else "")
        self.refusals.append(why)
        return f"{why} -- attempt {self.attempts}, retrying every {self.interval:g} s"

    def gave_up(self, now: float) -> bool:
        return math.isfinite(self.first) and now - self.first > self.timeout

    def failure(self) -> str:
        last = self.refusals[-1] if self.refusals else "no answer"
        return (f"could not arm: {self.attempts} attempts in {self.timeout:g} s, last: {last} "
                "(is the autopilot's EKF ready? check its pre-arm messages)")


@dataclass
class Approach:
    """Height-reference ramp from the engagement height to the trajectory start.

    Attributes:
        target: start height of the trajectory [m, from the take-off point].
        climb_rate: ramp rate [m/s]; tolerance: |z - target| counted as there [m];
        hold: seconds within tolerance before the trajectory starts; max_extra: give up waiting
            this long after the ramp ended [s] (the trajectory starts anyway, and ``timed_out`` says
            so with ``last_error``, the height error [m] of the last tick: the vehicle, or its height
            estimate, did not settle); ``t_done``: when it ended.
    """

    target: float
    climb_rate: float = 0.5
    tolerance: float = 0.05
    hold: float = 1.0
    max_extra: float = 5.0
    z_ref: float = math.nan
    t_ramp_end: float = math.nan
    t_in: float = math.nan
    held: bool = False
    timed_out: bool = False
    last_error: float = math.nan
    t_done: float = math.nan

    @property
    def done(self) -> bool:
        """The trajectory may start: the start height was held, or the wait timed out."""
        return self.held or self.timed_out

    def start(self, z: float) -> None:
        """Begin at the measured height z [m]."""
        self.z_ref = float(z)

    def step(self, t: float, dt: float, z: float) -> float:
        """The height reference for this tick at time t [s]; advances the ramp by one tick."""
        gap = self.target - self.z_ref
        self.z_ref += math.copysign(min(abs(gap), self.climb_rate * dt), gap)
        if self.z_ref == self.target and not math.isfinite(self.t_ramp_end):
            self.t_ramp_end = t
        if math.isfinite(self.t_ramp_end):
            if abs(z - self.target) <= self.tolerance:
                self.t_in = t if not math.isfinite(self.t_in) else self.t_in
            else:
                self.t_in = math.nan
            self.held = math.isfinite(self.t_in) and t - self.t_in >= self.hold
            self.timed_out = not self.held and t - self.t_ramp_end >= self.max_extra
        self.last_error = float(z) - self.target
        if self.done and not math.isfinite(self.t_done):
            self.t_done = t
        return self.z_ref

    def outcome(self) -> dict:
        """How the approach ended (the bridge summary's ``approach``): held or not, the start height and
        the height error then [m], the wait after the ramp [s], the tolerance [m] and timeout [s]."""
        return {"held": self.held, "target_m": self.target, "error_at_start_m": self.last_error,
                "waited_s": self.t_done - self.t_ramp_end, "tolerance_m": self.tolerance, "timeout_s": self.max_extra}


@dataclass
class RefBlend:
    """Rate-limited hand-over of the applied reference (bumpless engagement).

    The applied reference starts at the measured outputs and its offset to the nominal reference shrinks by at
    most ``rates`` per second: it moves with the path meanwhile, so the hand-over ends within |offset| / rate
    seconds however fast the path itself moves (a blend toward the moving reference would never catch a path
    faster than the rate).

    Attributes:
        rates: largest change per second of each reference channel's offset (z [m/s], pitch [rad/s], ...).
    """

    rates: tuple[float, ...]
    current: np.ndarray | None = None
    offset: np.ndarray | None = None
    active: bool = False

    def start(self, y_now: np.ndarray) -> None:
        """Begin at the measured outputs (the references are desired outputs: same channels)."""
        self.current = np.array(y_now, dtype=float)
        self.offset = None  # measured at the first apply, against that tick's nominal reference
        self.active = True

    def apply(self, r: np.ndarray, dt: float) -> np.ndarray:
        """The reference to apply this tick: ``r`` once the offset is gone, else ``r`` + the shrunk offset."""
        if not self.active or self.current is None:
            return r
        r = np.asarray(r, dtype=float)
        step = np.asarray(self.rates, dtype=float) * dt
        if self.offset is None:
            self.offset = self.current - r
        if np.all(np.abs(self.offset) <= step):
            self.active, self.current, self.offset = False, None, None
            return r
        self.offset = np.sign(self.offset) * np.maximum(np.abs(self.offset) - step, 0.0)
        self.current = r + self.offset
        return self.current.copy()
