"""Flight phases a real vehicle needs around the steered flight, each a small piece of state the
bridge's tick and supervisor consult.

* :class:`ArmingRetry` -- arm once the vehicle can be armed: not before both telemetry streams
  arrive (ArduCopter accepts arming well before it sends any LOCAL_POSITION_NED, and a
  setpoint computed without a position is garbage), then retry every ``interval`` while refused
  (each refusal reported with the autopilot's words), give up after ``timeout``.
* :class:`Approach` -- take-off / approach: the height reference ramps at ``climb_rate`` from
  where the vehicle is to the trajectory's start height (heights from the take-off point), then is
  trimmed while the vehicle hovers off it; the trajectory clock waits; done once the vehicle holds
  the start height (or the wait timed out: the trajectory then starts off its start, and says so).
* :class:`RefBlend` -- bumpless (re-)engagement: the applied reference starts at the measured
  output and moves toward the nominal one at bounded rates, then hands over exactly.
* :class:`Engagement` -- the loop's engagement as a whole: its edges (the first starts the trajectory
  clock or the take-off ramp; later ones, and a resume after stale telemetry or a stall, continue the same
  clock with a blend: a (re-)engagement's from the measured outputs, a resume's from the reference last
  applied, which the vehicle flew on meanwhile), staleness, and why the nominal reference passes untouched
  on a tick.

After boot the SITLs refuse arming for a while: ArduCopter with a reason ("Arm: Gyros
inconsistent", MAV_RESULT_FAILED), before its first local position; PX4 SIH with
TEMPORARILY_REJECTED and no text (PX4 reports through EVENT messages).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from firmware_bridge.events import EventLog

__all__ = ["ArmingRetry", "Approach", "RefBlend", "Engagement"]


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
    """Height-reference ramp from the engagement height to the trajectory start, then a trim until the vehicle is
    there.

    The bridge's height controller has no integrator, so a vehicle heavier (or weaker) than its model hovers below
    the reference it is given (a 35 % heavier PX4 SIH ended its take-off 0.3-0.4 m low) and would start the
    trajectory, and the steering, that far off. From ``trim_after`` s after the ramp ended, while the height error
    is larger than half the tolerance, the reference is trimmed by ``trim_gain`` times the error per second (at
    most ``climb_rate``, within ``max_trim``), so the vehicle reaches the start; the engagement then hands the
    trimmed reference back to the trajectory's at the blend's rates. A vehicle that holds the start unaided is
    never trimmed (its error stays within half the tolerance).

    Attributes:
        target: start height of the trajectory [m, from the take-off point].
        climb_rate: ramp rate [m/s]; tolerance: |z - target| counted as there [m];
        hold: seconds within tolerance before the trajectory starts; max_extra: give up waiting
            this long after the ramp ended [s] (the trajectory starts anyway, off its start, and ``timed_out``
            says so with ``last_error``, the height error [m] of the last tick: the vehicle, or its height
            estimate, did not settle); ``t_done``: when it ended.
        trim_gain: [1/s], trim_after: [s], max_trim: [m] (0: no trim); ``trim``: the trim now [m].
    """

    target: float
    climb_rate: float = 0.5
    tolerance: float = 0.05
    hold: float = 1.0
    max_extra: float = 5.0
    trim_gain: float = 1.0
    trim_after: float = 1.5
    max_trim: float = 1.0
    z_ref: float = math.nan
    z_ramp: float = math.nan
    trim: float = 0.0
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
        self.z_ref = self.z_ramp = float(z)

    def step(self, t: float, dt: float, z: float) -> float:
        """The height reference for this tick at time t [s] (the ramp plus the trim); advances by one tick."""
        gap = self.target - self.z_ramp
        self.z_ramp += math.copysign(min(abs(gap), self.climb_rate * dt), gap)
        if self.z_ramp == self.target and not math.isfinite(self.t_ramp_end):
            self.t_ramp_end = t
        if math.isfinite(self.t_ramp_end):
            err = self.target - float(z)
            if t - self.t_ramp_end >= self.trim_after and abs(err) > 0.5 * self.tolerance:
                step = max(-self.climb_rate * dt, min(self.climb_rate * dt, self.trim_gain * err * dt))
                self.trim = max(-self.max_trim, min(self.max_trim, self.trim + step))
            if abs(err) <= self.tolerance:
                self.t_in = t if not math.isfinite(self.t_in) else self.t_in
            else:
                self.t_in = math.nan
            self.held = math.isfinite(self.t_in) and t - self.t_in >= self.hold
            self.timed_out = not self.held and t - self.t_ramp_end >= self.max_extra
        self.last_error = float(z) - self.target
        if self.done and not math.isfinite(self.t_done):
            self.t_done = t
        self.z_ref = self.z_ramp + self.trim
        return self.z_ref

    def outcome(self) -> dict:
        """How the approach ended (the bridge summary's ``approach``): held or not, whether the trajectory started
        off its start (``off_start``: the wait timed out), the start height and the height error then [m], the
        wait after the ramp [s], the trim the reference needed [m], the tolerance [m] and timeout [s]."""
        return {"held": self.held, "off_start": not self.held, "target_m": self.target,
                "error_at_start_m": self.last_error, "waited_s": self.t_done - self.t_ramp_end, "trim_m": self.trim,
                "tolerance_m": self.tolerance, "timeout_s": self.max_extra}


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


class Engagement:
    """The loop's engagement and its trajectory clock.

    Args:
        events: where events go.
        blend_rates: the bumpless blend's rates per reference (empty: no blend).
        takeoff: ramp the height reference to ``start_height()`` [m] at the first engagement (``climb_rate``
            [m/s], done within ``tolerance`` [m], giving up ``timeout`` s after the ramp).
        max_age, stale_action, stale_stream_limit: the staleness limit [s], its fallback (for the events) and
            how long the setpoints go on while stale [s] (0: for ever).
        describe: the first engagement's event text after "trajectory starts, " (mode, frame).
    """

    def __init__(self, events: EventLog, *, blend_rates=(), takeoff: bool = False,
                 start_height: Callable[[], float] | None = None, climb_rate: float = 0.5,
                 tolerance: float = 0.05, timeout: float = 5.0, max_age: float = math.inf,
                 stale_action: str = "reference", stale_stream_limit: float = 0.0,
                 describe: Callable[[], str] = lambda: "") -> None:
        self.events = events
        self.blend_rates = tuple(blend_rates or ())
        self.takeoff, self.start_height = takeoff, start_height
        self.climb_rate, self.tolerance, self.timeout = climb_rate, tolerance, timeout
        self.max_age, self.stale_action, self.stale_stream_limit = max_age, stale_action, stale_stream_limit
        self.describe = describe
        self.engaged = False
        self.flown = False                    # the trajectory has started once: frame and clock are fixed
        self.engaged_before = False
        self.activations = 0
        self.traj_t0: float | None = None     # control-clock time at which the trajectory started [s]
        self.resume_pending = ""              # what a pending bumpless resume follows (staleness, a stall); "": none
        self.last_applied: np.ndarray | None = None  # the reference the last tick applied (a resume starts there)
        self.edge = ""                        # the last tick's edge (see :meth:`update`)
        self.stale_since: float | None = None
        self.left_mode = ""                   # the vehicle's mode while out after an engagement ("": engaged / never)
        self.t_last = math.nan                # control-clock time of the last tick [s]
        self.approach: Approach | None = None
        self.approach_result: dict | None = None  # how the take-off approach ended (the summary's "approach")
        self.blend = RefBlend(self.blend_rates)

    def trajectory_time(self, t: float) -> float:
        """Trajectory time [s] at control-clock time ``t`` (0 before the trajectory starts)."""
        return t - self.traj_t0 if self.traj_t0 is not None else 0.0

    def flown_s(self) -> float:
        """Trajectory time flown by the last tick [s] (0 before the trajectory starts)."""
        return self.trajectory_time(self.t_last) if math.isfinite(self.t_last) else 0.0

    def telemetry(self, now: float, age: float, fresh: bool) -> bool:
        """Staleness bookkeeping; False when the stream limit says to go quiet (no setpoint)."""
        if fresh:
            if self.stale_since is not None:
                self.events(f"telemetry fresh again after {now - self.stale_since:.3f} s")
                self.resume_pending = "stale telemetry"
            self.stale_since = None
            return True
        if self.stale_since is None:
            self.stale_since = now
            self.events(f"telemetry stale (age {age * 1e3:.1f} ms > {self.max_age * 1e3:.0f} ms): fallback "
                        f"'{self.stale_action}'")
        return not (self.stale_stream_limit > 0 and now - self.stale_since > self.stale_stream_limit)

    def stalled(self) -> None:
        """The loop's own clock stalled: resume bumplessly (as after stale telemetry) once flying."""
        if self.flown:
            self.resume_pending = "a stall of the bridge"

    def update(self, engaged: bool, t: float, y: np.ndarray, z: float, vehicle_mode: str) -> str:
        """Engagement edges at control-clock time ``t`` [s] with the measured outputs ``y`` (p,) and height
        ``z`` [m]: "first" (the trajectory, or the take-off ramp, starts), "again" (a re-engagement: same
        clock and frame), "resume" (fresh again after a stale stretch or a stall), "lost" or "". On "first",
        "again" and "resume" the owner forgets the steering history; each starts a bumpless blend."""
        edge = ""
        if engaged and not self.engaged:
            edge = "again" if self.flown else "first"
            self.activations += 1
            self.engaged_before = True
            self.left_mode = ""
            if self.blend_rates:
                self.blend.start(y)
            if edge == "first":
                self._first(t, z, vehicle_mode)
            else:
                self.events(f"re-engaged ({vehicle_mode}): trajectory continues at t = {t - self.traj_t0:.3f} s, "
                            "same frame")
        elif engaged and self.resume_pending and self.flown:
            # Still engaged, but the telemetry was stale or the bridge stalled: the vehicle flew on what it
            # was last sent while the trajectory clock ran on. Resume as at a re-engagement (same clock and
            # frame), the reference rate-limited from that last applied reference: never re-anchored to the
            # measured outputs, which moved meanwhile (a step of the vehicle's drift in one tick).
            edge = "resume"
            if self.blend_rates and self.approach is None:
                self.blend.start(y if self.last_applied is None else self.last_applied)
            self.events(f"resumed after {self.resume_pending}: trajectory continues at t = {t - self.traj_t0:.3f} s, "
                        "same frame")
        elif not engaged and self.engaged:
            edge = "lost"
            self.events("disengaged: vehicle no longer armed + off-board (or link lost)")
        self.resume_pending = ""
        self.engaged, self.t_last, self.edge = engaged, t, edge
        if not engaged and self.engaged_before:
            self.left_mode = vehicle_mode or "?"  # the vehicle's newest mode while it is out (its failsafe's)
        if engaged and self.approach is not None:
            self.traj_t0 = t  # the trajectory clock waits at its start until the vehicle is there
        return edge

    def _first(self, t: float, z: float, vehicle_mode: str) -> None:
        self.flown = True
        self.traj_t0 = t
        if self.takeoff:
            self.approach = Approach(self.start_height(), climb_rate=self.climb_rate, tolerance=self.tolerance,
                                     max_extra=self.timeout)
            self.approach.start(z)
        self.events(f"engaged ({vehicle_mode}, armed): "
                    + (f"take-off to z = {self.approach.target:.2f} m at {self.climb_rate:g} m/s, then "
                       if self.approach else "")
                    + f"trajectory starts, {self.describe()}")

    def reference(self, r_nom: np.ndarray, y: np.ndarray, t: float, dt: float, *, heard: bool, engaged: bool,
                  fresh: bool) -> tuple[np.ndarray, str]:
        """(the nominal reference (m,) after the take-off ramp and the blend, why it passes untouched or "")
        for this tick at control-clock time ``t`` [s] (``dt``: the tick [s])."""
        ramping = engaged and fresh and self.approach is not None
        if ramping:
            r_nom[0] = self.approach.step(t, dt, float(y[0]))
        blending = engaged and self.blend.active
        if blending:
            r_nom = self.blend.apply(r_nom, dt)
        if ramping:
            if self.approach.done:
                self._approached(r_nom)
            return r_nom, "takeoff"
        if not heard:
            return r_nom, "no_heartbeat"
        if not engaged:
            return r_nom, "inactive"
        if not fresh:
            return r_nom, "stale"
        return r_nom, "blend" if blending else ""

    def _approached(self, r_last: np.ndarray) -> None:
        """The approach ended on this tick, whose reference was ``r_last`` (m,): the trajectory starts; a trimmed
        reference is handed back to the trajectory's at the blend's rates (bumpless, as a resume)."""
        ap, self.approach = self.approach, None
        self.approach_result = ap.outcome()
        if ap.trim and self.blend_rates:
            self.blend.start(r_last)
        if ap.trim:
            self.events(f"take-off: the reference trimmed {ap.trim:+.3f} m to reach the start height (the vehicle "
                        "hovers off its model), handed back to the trajectory's at the blend's rates")
        if ap.timed_out:  # say so: the steering then starts against that error (the line ends as readers expect)
            self.events(f"WARNING: OFF ITS START: did not hold the start height within {ap.tolerance:g} m for "
                        f"{ap.hold:g} s in {ap.max_extra:g} s (height error now {ap.last_error:+.3f} m: the vehicle "
                        "or its height estimate did not settle): trajectory starts anyway")
        else:
            self.events("at the trajectory's start height: trajectory starts")

    def applied(self, u: np.ndarray) -> None:
        """This tick applied the reference ``u`` (m,): a resume starts from there."""
        self.last_applied = np.array(u, dtype=float)
