"""The companion-computer tick loop: telemetry in, steering + height / leg-angle controller,
SET_ATTITUDE_TARGET out, at 200 Hz (``ddpc-bridge``).

One tick (on the bridge's own clock; lock-step: on every telemetry sample)::

    newest telemetry (NED/FRD -> ENU/FLU -> trajectory frame) -> MeasuredState (t = trajectory time)
    hopping: phase (contact estimate or the robot's contact flag) -> state.contact    (:mod:`.hopping_loop`)
    r_nom = controller.nominal_reference(state)             stage (a)
    u     = steer: ReferenceSteerer.step(y_des, u_nom)      the generated solver, with fallback
            passthrough: r_nom                              the model-based controller alone
            collect: r_nom + PRBS                           new data (hopping: in the air only)
            hopping steer: HoppingSteering.decide(phase, ...)  ground ticks r_nom, aerial windows completed
            prefilter: PrefilterPolicy(y_des ahead, r_nom)  the gain + offset + lead baseline
            feedforward: r_nom + delta[trajectory tick]     a learned (ILC) table  (:mod:`.baseline_modes`)
    sp    = controller.track(u, state)                      stage (b): quaternion + thrust
    clamp tilt / thrust, thrust field per autopilot profile, send SET_ATTITUDE_TARGET, log

Parts (owned, each with one job; see :mod:`firmware_bridge`): ``vehicle`` (:class:`.vehicle_link.VehicleLink`),
``modes`` (:class:`.mode_requests.ModeRequests`), ``stream`` / ``shaping`` (:mod:`.setpoints`), ``trigger``
(:class:`.clock.TickTrigger`), ``engagement`` (:class:`.engagement.Engagement`), ``stage``
(:class:`.reference_stage.ReferenceStage`, whose product is a :class:`.reference_stage.TickReference`), ``gate``
(:class:`.tick_gate.TickGate`), ``recorder`` (:class:`.report.FlightRecorder`), ``events``
(:class:`.events.EventLog`).

Timing. Real time: the bridge ticks on its own uniform grid at ``rate_hz`` (:mod:`.clock`);
between ticks it sleeps in ``select`` on the link and folds *every* pending message into the
telemetry state (each sample is also kept in the log: a burst of two is two samples). A tick uses
the newest sample of each stream, held, with its age (receive -> now); a late or missing sample
is just an older held sample -- it neither resets the steering history nor splits a dataset.
Telemetry older than ``max_age`` applies the stale action; the setpoint stream continues while
the vehicle is silent -- for ``stale_stream_limit`` seconds, after which the bridge goes quiet and
lets the autopilot's own off-board-loss failsafe (PX4 COM_OF_LOSS_T) take over. Latency (per
tick) is from the kernel receive time of the newest telemetry sample to the return of the send
call. In ``lockstep`` (with ``ddpc-vehicle --lockstep``) only telemetry drives ticks and the
controller's time is the vehicle's time stamp (a lost sample there is a ``gap``, bridged in the
history for up to ``max_gap_fill`` ticks).

Before the first tick (:mod:`.preflight`): the heartbeat's autopilot must match ``autopilot`` (no
mode command otherwise), parameters are read (hover thrust, GUID_OPTIONS: the thrust semantics),
the trajectory must lie inside the solver's bounds (:mod:`.steering_setup`). Flight phases (:mod:`.engagement`): arming once
telemetry arrives, retried while refused; optional take-off ramp to the trajectory start (heights
from the take-off point); bumpless (re-)engagement; the trajectory's clock and frame are fixed at
its first start -- a stall never restarts or re-anchors it.

Safety:
* Steering only while the vehicle reports armed and off-board / guided, its heartbeat is
  recent and telemetry is fresh; the steering history is reset whenever that chain breaks.
* Solver failure, NaN, out-of-bounds or too large a step -> the unsteered reference for that
  tick (ReferenceSteerer), counted per reason.
* Attitude (roll, pitch) and thrust clamped to configured limits before sending.
* Only the configured vehicle's messages are used (other system ids counted and ignored;
  bytes that are not MAVLink are skipped per datagram).
* Arming and mode changes happen only with ``arm`` / ``offboard``; a vehicle that leaves
  off-board by itself (pilot, failsafe) is not pulled back.
* SIGINT / SIGTERM: stop, (with ``offboard``) ask for HOLD, write the log, print a summary.
"""

from __future__ import annotations

import dataclasses
import math
import signal
import time
from collections.abc import Sized

import numpy as np

from ddpc_codegen.robot.controller import HeightLegAngleController
from ddpc_codegen.robot.phases import ContactConfig
from ddpc_codegen.robot.profile import Envelope

from firmware_bridge.bridge_config import (BridgeConfig, FaultInjectingSolver, FlightError, NoVehicleError,
                                           default_controller_config)
from firmware_bridge.clock import TickTrigger
from firmware_bridge.engagement import Engagement
from firmware_bridge.events import EventLog
from firmware_bridge.gate import GATE_FLAGS
from firmware_bridge.gc_pacer import GcPacer
from firmware_bridge.hopping_loop import HoppingLoop
from firmware_bridge.link import MavLink
from firmware_bridge.mode_requests import ModeRequests
from firmware_bridge.preflight import PreflightError, VehicleInfo, check_vehicle_thrust, hover_param
from firmware_bridge.profiles import make_profile
from firmware_bridge.realtime import RealtimeSetup, setup_realtime
from firmware_bridge.reference_stage import TickReference
from firmware_bridge.report import FlightRecorder, gap_statistics, write_summary
from firmware_bridge.setpoints import AttitudeSetpoints, SetpointStream
from firmware_bridge.steering_setup import Steering, build_reference_stage, build_steering, loop_warnings
from firmware_bridge.plausibility import TelemetryLimits
from firmware_bridge.position_source import PositionSource
from firmware_bridge.telemetry import TelemetryState, TrajectoryFrame
from firmware_bridge.tick_gate import TickGate, make_gate
from firmware_bridge.ticklog import TickLog
from firmware_bridge.vehicle_link import VehicleLink

__all__ = ["BridgeConfig", "Bridge", "FaultInjectingSolver", "FlightError", "NoVehicleError",
           "default_controller_config", "gap_statistics"]

_NO_NOTES: list[str] = []


def _tick_gate(c: BridgeConfig, steering: Steering | None, hover_thrust: float, events: EventLog) -> TickGate:
    """The last gate of the bridge's ticks, from its config (and the steering's step guard)."""
    period = 1.0 / c.rate_hz
    return TickGate(make_gate(c, c.mode, period, steering.solver if steering is not None else None), events,
                    max_step=steering.steerer.max_step if steering is not None else None,
                    max_tilt=math.radians(c.max_tilt_deg), thrust_min=c.thrust_min, thrust_max=c.thrust_max,
                    hover_thrust=hover_thrust, max_age=None if c.lockstep else c.max_age, guard_hold=c.guard_hold,
                    ref_rate=(c.envelope or Envelope()).ref_rates(c.scenario), period=period)


def _engagement(c: BridgeConfig, events: EventLog, ctrl: HeightLegAngleController, frame: TrajectoryFrame,
                gate_rate: np.ndarray | None) -> Engagement:
    """The bridge's engagement, from its config (take-off to the trajectory's start height); its blend moves the
    reference no faster than the gate's rate bound (``gate_rate`` per tick, None: none)."""
    blend = c.blend_rates
    if blend and gate_rate is not None and len(blend) == len(gate_rate):
        blend = tuple(float(v) for v in np.minimum(blend, np.asarray(gate_rate) * c.rate_hz))
    return Engagement(events, blend_rates=blend, takeoff=c.takeoff,
                      start_height=lambda: ctrl.trajectory.start_point()[1], climb_rate=c.climb_rate,
                      tolerance=c.approach_tolerance, timeout=c.approach_timeout, max_age=c.max_age,
                      stale_action=c.stale_action, stale_stream_limit=c.stale_stream_limit,
                      describe=lambda: f"{c.mode}; {frame.describe()}")


class Bridge:
    """The tick loop, owning its parts (see the module docstring). ``run()`` returns the summary dict.

    Args:
        config: :class:`BridgeConfig`.
        link: an open :class:`MavLink` (default: opened from ``config.url``).
        solver: a loaded solver (default: ``load_solver(config.solver)`` in steer mode).
    """

    def __init__(self, config: BridgeConfig, link: MavLink | None = None, solver=None) -> None:
        self.cfg = c = config
        self.period = 1.0 / c.rate_hz
        ctrl_cfg = c.controller or default_controller_config()
        if abs(ctrl_cfg.dt - self.period) > 1e-9:
            raise ValueError(f"controller dt {ctrl_cfg.dt} s does not match the rate {c.rate_hz} Hz")
        self.ctrl = HeightLegAngleController(ctrl_cfg, c.trajectory)
        hopping = self.ctrl.mode == "hopping"
        contact = c.contact or ContactConfig(leg_length=ctrl_cfg.leg_length)
        self.events = EventLog(verbose=c.verbose)
        self.steering: Steering | None = build_steering(c, self.ctrl, solver) if c.mode == "steer" else None
        self.stage = build_reference_stage(c, self.ctrl, self.steering, contact)
        self.hop: HoppingLoop | None = self.stage.hop
        self.link = link or MavLink.for_bridge(c)
        profile = make_profile(c.autopilot, prestream=c.prestream)
        # Hopping: the contact flag is read (and logged) whenever the robot sends one; it drives the
        # phases only with source "signal".
        telem = TelemetryState(c.attitude_stream, c.position_stream, contact.signal_name if hopping else None,
                               limits=TelemetryLimits.from_envelope(c.envelope))
        self.vehicle = VehicleLink(self.link, profile, telem, self.events, rate_hz=c.rate_hz,
                                   link_timeout=c.link_timeout, arm_timeout=c.arm_timeout, verbose=c.verbose,
                                   on_reboot=lambda: self.trigger.restart_samples())
        self.frame = TrajectoryFrame(c.frame, anchor=(0.0, 0.0) if hopping else self.ctrl.trajectory.start_position()[:2])
        self.source = PositionSource.for_bridge(c, self.frame, self.events, telem.limits)  # the measured position
        hover = ctrl_cfg.model_mass * ctrl_cfg.g / ctrl_cfg.max_thrust
        self.shaping = AttitudeSetpoints(self.frame, profile, hover, c.thrust_min, c.thrust_max)
        self.gate = _tick_gate(c, self.steering, hover, self.events)
        self.trigger = TickTrigger(self.period, c.lockstep, c.max_gap_fill, c.tick_margin)
        self.vehicle_info: VehicleInfo | None = None  # known after the preflight (before the first tick)
        self._stop = False
        self.stop_reason = ""
        self.events.restart()  # the bridge's times count from here (the solver is loaded, the link open)
        self.recorder = FlightRecorder(self.ctrl.m, self.ctrl.p, self.period, self.events.t0, lockstep=c.lockstep,
                                       capacity=int(c.rate_hz * (c.duration or 60.0) * 1.5) + 1024)
        self._rt = RealtimeSetup()  # best effort until run() asks for more
        self._new_run()

    def _new_run(self) -> None:
        """Everything the loop keeps between ticks, fresh at every :meth:`run`."""
        c = self.cfg
        self.vehicle.reset()
        self.trigger.reset()
        self.gate.reset()
        self.stream = SetpointStream(self.vehicle, c.lockstep)
        self.modes = ModeRequests(self.vehicle, self.stream, arm=c.arm, offboard=c.offboard, land=c.land)
        self.engagement = _engagement(c, self.events, self.ctrl, self.frame, self.gate.gate.rate)
        self._tick_t = math.nan  # control clock of the last tick (grid time / stamp) [s]
        self.failure: str | None = None

    def stop(self, *_args) -> None:
        """Ask the loop to finish (signal handler)."""
        self._stop = True
        if not self.stop_reason:
            self.stop_reason = "signal"

    # ------------------------------------------------------------------ main loop
    def run(self, install_signals: bool = True, interrupted: Sized = ()) -> dict:
        """Connect, configure, run the tick loop until stopped; write the log; return the summary.
        ``interrupted``: the signals that arrived while the bridge was set up, a list the caller's handler
        fills (non-empty: stop before the first tick)."""
        c = self.cfg
        if install_signals:
            signal.signal(signal.SIGINT, self.stop)
            signal.signal(signal.SIGTERM, self.stop)
        self._rt = setup_realtime(c.rt_priority, cpus=c.cpus, cpu_latency_us=c.cpu_latency_us)
        if c.rt_priority or c.cpus:
            self.events(f"scheduling: {self._rt.describe()}")
        self._new_run()
        if len(interrupted):
            self.stop()
        pacer = GcPacer()
        try:
            self.vehicle.wait_for_heartbeat(c.wait_heartbeat, lambda: self._stop)
            if not self._stop:  # interrupted while waiting: straight to the log and the summary
                self._preflight()
                self.vehicle.request_streams()
            pacer.start()
            self._loop(pacer)
            self.modes.hand_back(self.period)
            self._stop = True
        except NoVehicleError:
            self.stop_reason = "no vehicle"
            raise
        except PreflightError as e:
            self.stop_reason = f"preflight: {e}"
            raise
        finally:
            self._rt.release()
            pacer.stop()
            self._finish()
        if self.failure:
            raise FlightError(self.failure)
        return self.summary()

    def _loop(self, pacer: GcPacer) -> None:
        """Wait, fold the messages in, tick when due; housekeeping after the tick (never delays a setpoint)."""
        link, tel = self.link, self.vehicle.telem
        next_hb = 0.0
        while not self._stop:
            timeout = self.trigger.wake_in(time.monotonic())
            if timeout > 0:
                link.wait(timeout)
            self.vehicle.pump()
            self.source.pump()
            now = time.monotonic()
            kind = self.trigger.due(now, tel)
            if kind:
                self._tick(kind, now)
                self.trigger.done(kind, time.monotonic())
            now = time.monotonic()
            beat = now >= next_hb
            if beat:
                next_hb = now + 1.0
            self.vehicle.housekeeping(now, heartbeat=beat)
            self._supervise(now)
            if now - self.stream.last_send < 0.5 * self.period:  # right after a tick: off the critical path
                pacer.idle(now)

    # ------------------------------------------------------------------ one tick
    def _tick(self, kind: str, now: float) -> None:
        """One control tick: newest telemetry (held, with its age) -> reference -> gate -> setpoint -> log."""
        c, tel, eng, st = self.cfg, self.vehicle.telem, self.engagement, self.vehicle.status
        event = kind == "event"
        age, t_ctrl, n_new = self.trigger.timing(now, tel)
        stalled = self.gate.stalled(now)  # first: a quiet tick is still a tick, and a pause is no vehicle silence
        if stalled:
            self.vehicle.bridge_paused(now, self.gate.stalls[-1]["gap_s"])
            self.stage.reset()
            eng.stalled()
        fresh = (tick_age := self.source.age(now, age)) <= c.max_age  # --position-source mocap: the pose's age too
        heard = self.vehicle.heard(now)
        engaged = st.armed and st.offboard and heard
        if not eng.telemetry(now, tick_age, fresh):
            if event:
                self.trigger.consumed(tel)
            self.stream.last_send = now  # quiet: the autopilot's own failsafe takes over
            return
        gap, fill = self._gap(t_ctrl) if event else (False, 0)
        state, y = self._measure(fresh)
        on = engaged and self.frame.captured and self.source.captured
        self._engage(on, t_ctrl, y, state)
        t_traj = eng.trajectory_time(t_ctrl)
        state = dataclasses.replace(state, t=t_traj)
        if self.hop is not None:
            state = self.hop.observe(state, tel)
        r_nom, hold = eng.reference(self.ctrl.nominal_reference(state), y, t_ctrl, self.period, heard=heard,
                                    engaged=on, fresh=fresh)
        ref = self.stage.step(r_nom, y, t_traj, hold, fill)                       # the mode's reference
        u, flags = self._gate(ref, stalled, now)                                  # the last gate
        eng.applied(u)  # what the vehicle is sent: a resume continues from it
        q, thrust, field, bad = self._setpoint(u, state, fresh)                   # controller, clamps
        self.gate.report(u, ref.r_nom, ref.reason, flags | bad, self.hop.notes if self.hop is not None else _NO_NOTES,
                         tel.dropped)
        t_vehicle = tel.newest_stamp() if event else self.vehicle.vehicle_now(now, c.lockstep)
        sent = self.stream.send(q, field, int(round(t_vehicle * 1000.0)) if math.isfinite(t_vehicle) else 0)
        t_sent = time.monotonic()
        self.recorder.record(
            ref, u, state, now=now, t_sent=t_sent, t_vehicle=t_vehicle,
            t_traj=t_traj if eng.traj_t0 is not None else math.nan, age=age, q=q, thrust=thrust, field=field,
            event=event or n_new > 0, engaged=engaged and ref.reason not in ("takeoff", "blend"), fresh=fresh,
            sent=sent, gap=gap, n_new=n_new, latency=(t_sent - tel.newest_rx()) * 1e6, gate=flags | bad,
            armed=st.armed, offboard=st.offboard, y_des=self.ctrl.y_des, phase=self.ctrl.phase,
            backdate=self.hop.backdate if self.hop is not None else 0, contact=tel.contact, truth=self.vehicle.truth)
        self.recorder.rows.set_last(self.source.columns(now))

    def _gap(self, stamp: float) -> tuple[bool, int]:
        """Lock-step: (a gap, ticks to bridge); a hole too long to bridge refills the steering history."""
        gap, fill, hole = self.trigger.gap(stamp, self.vehicle.telem)
        if hole:
            self.stage.reset()
        return gap, fill

    def _measure(self, fresh: bool):
        """The measured state in the trajectory frame and its outputs (p,). Before the trajectory first starts,
        the frame follows the vehicle (frozen from then on: no re-anchoring mid-air) and heights count from
        where it stood disarmed."""
        tel = self.vehicle.telem
        if fresh and not self.engagement.flown:
            self.frame.capture(tel.position, float(tel.euler[2]))
            self.source.capture(self.vehicle.status.armed)  # the mocap's frame at the same ticks
            if not self.vehicle.status.armed:
                self.frame.z0 = float(tel.position[2])
                self.vehicle.truth.capture_ground()
        state = self.source.measure(self.frame.to_trajectory(tel.measured_state(0.0)))
        return state, self.ctrl.outputs(state)

    def _engage(self, engaged: bool, t_ctrl: float, y: np.ndarray, state) -> None:
        """Engagement edges: each forgets the steering history; the first releases a hopping robot."""
        edge = self.engagement.update(engaged, t_ctrl, y, float(state.position[2]), self.vehicle.status.mode_name)
        if edge in ("first", "again", "resume"):
            self.stage.reset()
        if edge == "first" and self.hop is not None:
            self.hop.release(state)
        self._tick_t = t_ctrl

    def _gate(self, ref: TickReference, stalled: bool, now: float) -> tuple[np.ndarray, int]:
        """The applied reference (m,) and the gate flags; a guard saturation hands the steering back."""
        u, flags = self.gate.reference(ref, edge=self.engagement.edge)
        self.stage.applied(ref, u)
        flags |= GATE_FLAGS["stall"] if stalled else 0
        sat = self.gate.saturated(flags, now, self._tick_t)
        if sat:
            self.stage.reset()
        return u, flags | sat

    def _setpoint(self, u: np.ndarray, state, fresh: bool) -> tuple[tuple, float, float, int]:
        """Stage (b) and the clamps: (q NED/FRD, thrust, the thrust field, gate flags); stale: the stale action,
        disarmed before the first flight: the idle ground setpoint."""
        c = self.cfg
        if not fresh and c.stale_action != "reference":
            q, thrust, field = self.shaping.level()
            if c.stale_action == "land":
                self.modes.land_on_stale()
        elif not self.vehicle.status.armed and not self.engagement.flown:
            q, thrust, field = self.shaping.ground(float(state.position[2]))
        else:
            q_enu, thrust = self.gate.clamp(self.ctrl.track(u, state))
            q = self.shaping.to_vehicle(q_enu)
            field = self.vehicle.profile.thrust_field(thrust, float(u[0]), float(state.position[2]))
        return self.gate.setpoint(q, thrust, field, self.shaping.level)

    # ------------------------------------------------------------------ around the ticks
    def _preflight(self) -> None:
        """Before the first tick: the vehicle's preflight, then what the loop adds (solver, hopping timing)."""
        c, prof = self.cfg, self.vehicle.profile
        self.vehicle_info = info = self.vehicle.preflight(c.guid_options, c.force_guid_options, lambda: self._stop)
        check_vehicle_thrust(info, self.shaping.hover_thrust, c.thrust_min, c.thrust_max, prof, self.ctrl.config)
        for warning in loop_warnings(self.steering, self.hop, prof, c.rate_hz):
            self.events(f"warning: {warning}")
        self.events(f"vehicle: {prof.name}, hover thrust {hover_param(prof)}="
                    + ("?" if info.hover_thrust is None else f"{info.hover_thrust:.3f}")
                    + f", controller model hover thrust {self.shaping.hover_thrust:.3f}")

    def _supervise(self, now: float) -> None:
        """Off the tick path: arming and modes, and when to stop (duration flown, timeout, vehicle lost)."""
        c, eng = self.cfg, self.engagement
        if not self.vehicle.status.seen:
            return
        failure = self.modes.supervise(now, eng.engaged_before)
        if failure:
            self.failure, self.stop_reason, self._stop = failure, "arming failed", True
        if c.duration is not None and eng.engaged and eng.traj_t0 is not None:
            if self._tick_t - eng.traj_t0 >= c.duration - 1e-9:
                self.stop_reason = f"duration {c.duration:g} s flown"
                self._stop = True
        if c.timeout is not None and now - self.events.t0 > c.timeout:
            self.stop_reason = self.stop_reason or f"timeout {c.timeout:g} s"
            self._stop = True
        if self.vehicle.watch(now, c.vehicle_lost_timeout):
            # Waiting on for --timeout would hide it: the flight is over, and the exit code says so (7).
            self.events(f"vehicle lost: nothing heard for {now - self.vehicle.status.last_heard:.1f} s: stopping")
            self.stop_reason = "vehicle lost"
            self._stop = True

    def _finish(self) -> None:
        c = self.cfg
        if c.log:  # always, even without a tick (interrupted, vehicle lost): the log says what happened
            self.log_path = self.ticklog().save(c.log)
        s = self.summary()
        if c.summary:
            write_summary(s, c.summary)
        for part in (self.vehicle, self.source):
            part.close()

    # ------------------------------------------------------------------ results
    def ticklog(self) -> TickLog:
        """The tick log with its metadata (config, controller, trajectory, frame, events, solver)."""
        return self.source.annotate(self.recorder.ticklog(self.cfg, self.ctrl, self.vehicle, self.frame, self.events,
                                    self.gate, self.steering.solver if self.steering else None), self.recorder.t0)

    def summary(self) -> dict:
        """The run's summary (what the summary file holds)."""
        head = {"mode": self.cfg.mode, "autopilot": self.vehicle.profile.name, "stop_reason": self.stop_reason}
        out = self.recorder.summary(
            head, self.cfg, vehicle=self.vehicle, vehicle_info=self.vehicle_info, stream=self.stream,
            trigger=self.trigger, engagement=self.engagement, gate=self.gate, frame=self.frame, events=self.events,
            scheduling=self._rt.describe())
        out.update(self.stage.summary(), position_source=self.source.summary())
        if "feedforward" in out:
            out["feedforward"] = {"file": str(self.cfg.feedforward), **out["feedforward"]}
        return out
