"""A simulated PX4-like vehicle behind a MAVLink endpoint (``ddpc-vehicle``).

Three parts: the physics is the simulator's robot below the companion computer,
:class:`ddpc_codegen.sim.Stepper` (PogoX plant at 1 kHz, PX4-like attitude loop 250 Hz and
rate loop 1 kHz, measurement delay and sensor noise, pushes) -- the same object
:func:`ddpc_codegen.sim.simulate` steps; the autopilot's behaviour in off-board (modes, arming,
parameters, setpoints, failsafe) is :mod:`ddpc_codegen.testbed.vehicle_autopilot`, with its position
controller (HOLD, LAND, SET_POSITION_TARGET_LOCAL_NED) in :mod:`ddpc_codegen.testbed.vehicle_position`; the telemetry
streams and real autopilots' sample patterns are :mod:`ddpc_codegen.testbed.vehicle_telemetry`. The
companion computer's part is *not* here, it comes over the link. A disarmed vehicle is parked:
its state is frozen (no physics). A stuck hybrid integration (foot chattering) freezes it too,
with an event saying why.

Timing: real time by default. The vehicle wakes once per 5 ms tick: at the boundary it
simulates the elapsed 5 ms in 1 ms physics steps, each received setpoint taking effect from the
first step that starts after its (kernel) receive time -- i.e. within 1 ms of arrival, like
PX4's 1 kHz rate loop -- and then publishes the telemetry of the new tick. ``lockstep``: after
publishing telemetry the vehicle waits for the setpoint (SET_ATTITUDE_TARGET or
SET_POSITION_TARGET_LOCAL_NED) stamped with the newest
sample's time (``time_boot_ms``; with the regular pattern: tick k's time) before simulating
the next 5 ms (at most ``lockstep_timeout`` seconds of wall time, then it goes on with the
setpoint it has) -- fast, deterministic tests that reproduce :func:`ddpc_codegen.sim.simulate`
over the link.
"""

from __future__ import annotations

import gc
import logging
import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ddpc_codegen.robot.state import MeasuredState
from ddpc_codegen.robot.frames import quat_from_euler
from ddpc_codegen.sim.params import PogoXParams
from ddpc_codegen.sim.plant import STANCE, event_root_finder
from ddpc_codegen.sim.scenarios import get_scenario
from ddpc_codegen.sim.stepper import Stepper

from firmware_bridge.link import MavLink
from firmware_bridge.realtime import setup_realtime
from ddpc_codegen.testbed.vehicle_autopilot import AutopilotEmulator
from ddpc_codegen.testbed.vehicle_config import MODE_HOLD, MODE_LAND, MODE_OFFBOARD, VehicleConfig
from ddpc_codegen.testbed.vehicle_telemetry import SamplePattern, TelemetryPublisher

__all__ = ["VehicleConfig", "SimVehicle", "StepperBody", "MODE_OFFBOARD", "MODE_HOLD", "MODE_LAND"]

log = logging.getLogger("ddpc_codegen.testbed.vehicle")

# Measurement history kept for samples older than the tick (px4-sih: < 16 ms; ardupilot bursts).
_HISTORY = 0.05


class StepperBody:
    """The autopilot's view of the simulated robot (:class:`~ddpc_codegen.testbed.vehicle_autopilot.Body`)."""

    def __init__(self, stepper: Stepper) -> None:
        self.stepper = stepper
        p = stepper.params
        self.g, self.mass, self.max_thrust = p.g, p.mass, p.max_thrust
        self.tilt_max = p.fc.tilt_max
        self._leg = p.leg_rest_length

    def state(self) -> np.ndarray:
        return self.stepper.plant.state

    def in_contact(self) -> bool:
        return self.stepper.plant.mode == STANCE

    def airborne(self) -> bool:
        s = self.stepper.plant.state
        return self.stepper.plant.mode != STANCE and s[2] > self._leg + 0.05

    def set_attitude_target(self, q_enu: Any, thrust: float) -> None:
        self.stepper.set_setpoint(q_enu, thrust)


class SimVehicle:
    """The simulated PX4-like vehicle. ``run()`` serves until stopped / ``duration``."""

    def __init__(self, config: VehicleConfig, link: MavLink | None = None) -> None:
        self.cfg = c = config
        self.params = p = c.params or PogoXParams()
        self.link = link or MavLink(c.url, baud=c.baud, source_system=c.sysid, source_component=c.compid,
                                    target_system=None)
        if c.verbose and not log.handlers:
            _stderr_events()
        self.dt = p.control_dt
        self.h = p.physics_dt
        self.nsub = p.substeps
        sc = get_scenario(c.scenario)
        if c.scenario == "hopping":
            event_root_finder()  # its import now, not at the first touchdown of the real-time loop
        self.start_position = np.array(sc.initial_position(p), dtype=float)
        self.start_position[:2] += np.asarray(c.start_offset, dtype=float)
        self.stepper = Stepper(p, self.start_position, quaternion=quat_from_euler(0.0, 0.0, float(c.start_yaw)),
                               noise=c.noise, seed=c.seed, pushes=c.pushes, history=_HISTORY)
        self.telemetry = TelemetryPublisher(self.link, c.default_rates,
                                            SamplePattern(c.telemetry_pattern, c.telemetry_seed), c.contact_signal)
        self.autopilot = AutopilotEmulator(c, self.link, StepperBody(self.stepper), lambda: self.t,
                                           self.telemetry, (self.start_position, float(c.start_yaw)), self.dt)
        self.k = 0
        self._stop = False
        self.stats = {"overruns": 0, "lockstep_timeouts": 0}
        self._truth = np.empty((4096, 27))
        self._truth_n = 0
        self._published: list[int] = []  # sample stamps [ms] sent at this tick
        self.contact_events: dict[str, list[float]] = {"touchdown": [], "liftoff": []}  # true, vehicle time [s]
        self._hb_wall = -float("inf")

    # ------------------------------------------------------------------ views
    @property
    def t(self) -> float:
        """Vehicle (simulated) time of the current tick [s]."""
        return self.k * self.dt

    @property
    def plant(self):
        """The true robot (:class:`ddpc_codegen.sim.PogoXPlant`)."""
        return self.stepper.plant

    @property
    def armed(self) -> bool:
        return self.autopilot.armed

    @property
    def mode(self) -> str:
        return self.autopilot.mode

    @property
    def events(self) -> list[tuple[float, str]]:
        return self.autopilot.events

    def mode_name(self) -> str:
        return self.autopilot.mode_name()

    def stop(self, *_args) -> None:
        self._stop = True

    # ------------------------------------------------------------------ physics
    def _advance(self, before_substep: Callable[[int], None] | None = None) -> None:
        """The physics of the current tick (parked when disarmed; frozen once stuck)."""
        st = self.stepper
        if self.autopilot.armed and not st.stuck:
            # Plant time stands still while parked: the true contact events are kept in vehicle time.
            off, n_td, n_lo = self.t - st.plant.t, len(st.touchdowns), len(st.liftoffs)
            st.advance(before_substep=before_substep)
            self.contact_events["touchdown"] += [t + off for t in st.touchdowns[n_td:]]
            self.contact_events["liftoff"] += [t + off for t in st.liftoffs[n_lo:]]
            if st.stuck:
                self.autopilot.event(f"physics stopped: {st.stuck}")
        elif before_substep is not None:
            for j in range(self.nsub):
                before_substep(j)  # parked: setpoints still arrive (and are held)

    def _measure(self) -> Callable[[float], MeasuredState]:
        """The measured state of a sample ``age`` seconds old, for the telemetry publisher."""
        st, t = self.stepper, self.t
        if self.telemetry.pattern.kind == "regular":
            # One measurement per tick whether or not a stream is due (the noise sequence of
            # simulate(): a lock-step run over the link reproduces it).
            meas = st.measure(t)
            return lambda age: meas
        return lambda age: st.measure(t - age, age)

    def _log_truth(self) -> None:
        if not self.cfg.truth_log:
            return
        # Preallocated float rows (doubling): a growing list of tuples would make the garbage
        # collector's full passes longer and longer -- multi-ms stalls of the real-time loop.
        if self._truth_n == self._truth.shape[0]:
            self._truth = np.concatenate([self._truth, np.empty_like(self._truth)])
        row = self._truth[self._truth_n]
        fc = self.stepper.fc
        row[0] = self.t
        row[1:20] = self.plant.state
        row[20] = self.autopilot.armed
        row[21] = self.autopilot.mode == MODE_OFFBOARD
        row[22:26] = fc.q_sp
        row[26] = fc.thrust_sp
        self._truth_n += 1

    # ------------------------------------------------------------------ main loop
    def run(self, install_signals: bool = True) -> dict:
        """Serve until stopped (signal, :meth:`stop`) or ``duration``; returns a summary."""
        if install_signals:
            signal.signal(signal.SIGINT, self.stop)
            signal.signal(signal.SIGTERM, self.stop)
        rt = setup_realtime(self.cfg.rt_priority, cpus=self.cfg.cpus, cpu_latency_us=self.cfg.cpu_latency_us)
        self.scheduling = rt.describe()
        # The loop allocates short-lived objects only; collect the young generation often (cheap)
        # and never let a full collection land in the middle of a tick.
        gc.collect()
        gc.freeze()
        gc.set_threshold(5000, 1000, 1_000_000)
        try:
            if self.cfg.lockstep:
                self._run_lockstep()
            else:
                self._run_realtime()
        finally:
            rt.release()
            gc.set_threshold(700, 10, 10)
            gc.unfreeze()
            self._write_truth()
            self.autopilot.save_setpoint_log()
            self.link.close()
        return self.summary()

    def _tick_start(self, now: float) -> None:
        """At a tick boundary: heartbeat, failsafe, position control, log, measure and publish."""
        ap = self.autopilot
        if now - self._hb_wall >= 1.0:
            # 1 Hz of wall time: the companion's link monitor runs on wall time.
            self._hb_wall = now
            ap.send_heartbeat()
        ap.failsafe_check()
        if ap.armed:
            ap.control_tick()
        measure = self._measure()
        self._log_truth()
        self._published = [] if ap.silent() else self.telemetry.publish(self.t, measure)

    def _done(self) -> bool:
        d = self.cfg.duration
        return self._stop or (d is not None and self.t >= d - 1e-9)

    def _run_lockstep(self) -> None:
        regular = self.telemetry.pattern.kind == "regular"
        while not self._done():
            self.autopilot.process()
            self._tick_start(time.monotonic())
            if regular:
                self._wait_lockstep(int(round(self.t * 1000.0)))
            elif self._published:
                # The bridge ticks on new telemetry and stamps its setpoint with the newest sample.
                self._wait_lockstep(self._published[-1])
            self._advance()
            self.k += 1

    def _run_realtime(self) -> None:
        """One wake-up per 5 ms tick. At the boundary W_(k+1) the physics of tick k is simulated
        (1 ms steps), each setpoint taking effect at the first step that starts after its kernel
        receive time, and then the telemetry of tick k+1 goes out. So the vehicle never computes
        while the bridge does, and the physics never runs ahead of the wall clock."""
        ap = self.autopilot
        wall0 = time.monotonic()
        lag = 0.0  # added after a stall: real time resumes, it never races to catch up
        ap.process()
        self._tick_start(wall0)
        while not self._done():
            w_k = wall0 + lag + self.k * self.dt
            target = w_k + self.dt
            now = time.monotonic()
            if now - target > 0.05:
                # More than 50 ms late (machine stalled): resume real time from here.
                lag += now - target
                self.stats["overruns"] += 1
                w_k, target = now - self.dt, now
            elif target > now:
                time.sleep(target - now)
            ap.process()
            queue = ap.sp_queue

            def arrivals(j: int, w_k: float = w_k) -> None:
                t_j = w_k + j * self.h
                while queue and queue[0][0] <= t_j:
                    _rx, q, f = queue.popleft()
                    ap.take_setpoint(q, f)

            self._advance(arrivals)
            self.k += 1
            self._tick_start(time.monotonic())

    def _wait_lockstep(self, stamp_ms: int) -> None:
        """Wait (<= lockstep_timeout of wall time) for the setpoint stamped ``stamp_ms``."""
        ap = self.autopilot
        ap.expect_stamp_ms = stamp_ms
        deadline = time.monotonic() + self.cfg.lockstep_timeout
        if ap.process():
            return
        while not self._stop:
            rem = deadline - time.monotonic()
            if rem <= 0:
                self.stats["lockstep_timeouts"] += 1
                self._check_peer_gone()
                return
            if self.link.wait(min(rem, 0.05)) and ap.process():
                return

    def _check_peer_gone(self) -> None:
        """Lockstep waits for the companion: once it has been heard, its silence ends the run."""
        rx, now = self.link.stats["rx"], time.monotonic()
        if rx != getattr(self, "_rx_count", 0):
            self._rx_count, self._rx_time = rx, now
        elif rx and self.cfg.peer_timeout > 0 and now - self._rx_time > self.cfg.peer_timeout:
            self.autopilot.event(f"nothing from the companion for {self.cfg.peer_timeout:g} s: it is gone, stopping")
            self._stop = True

    def summary(self) -> dict:
        """JSON-friendly: simulated time, ticks, mode, arming, events, counters, link statistics."""
        ap = self.autopilot
        return {"sim_time": self.t, "ticks": self.k, "mode": ap.mode_name(), "armed": ap.armed,
                "scenario": self.cfg.scenario, "touchdowns": len(self.contact_events["touchdown"]),
                "liftoffs": len(self.contact_events["liftoff"]),
                "scheduling": getattr(self, "scheduling", ""), "telemetry_pattern": self.telemetry.pattern.kind,
                "events": [[round(t, 3), e] for t, e in ap.events], **self.stats, **ap.stats,
                "link": dict(self.link.stats)}

    def _write_truth(self) -> None:
        if not self.cfg.truth_log or not self._truth_n:
            return
        a = self._truth[: self._truth_n]
        path = Path(self.cfg.truth_log)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, t=a[:, 0], state=a[:, 1:20], armed=a[:, 20].astype(bool),
                            offboard=a[:, 21].astype(bool), fc_q_sp=a[:, 22:26], fc_thrust_sp=a[:, 26],
                            dt=self.dt, touchdowns=np.array(self.contact_events["touchdown"]),
                            liftoffs=np.array(self.contact_events["liftoff"]))


def _stderr_events() -> None:
    """``verbose``: the vehicle's events on stderr, one line each (the CLI's readable output)."""
    h = logging.StreamHandler(sys.stderr)
    h.setFormatter(logging.Formatter("%(message)s"))
    log.addHandler(h)
    log.setLevel(logging.INFO)
    log.propagate = False
