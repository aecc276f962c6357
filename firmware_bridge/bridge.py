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
import gc
import math
import signal
import sys
import time
from collections.abc import Sized

import numpy as np

from ddpc_codegen.robot.controller import HeightLegAngleController
from ddpc_codegen.robot.phases import ContactConfig
from ddpc_codegen.runtime.adapt_loop import adapt_code
from ddpc_codegen.runtime.steerer import ReferenceSteerer

from firmware_bridge.baseline_modes import BASELINE_MODES, baseline_policy, feedforward_row
from firmware_bridge.clock import TickClock
from firmware_bridge.bridge_config import (BridgeConfig, FaultInjectingSolver, FlightError, NoVehicleError,
                                    default_controller_config)
from firmware_bridge.hopping_loop import HoppingLoop, hopping_window
from firmware_bridge.link import CommandTracker, MavLink
from firmware_bridge.engagement import Approach, ArmingRetry, RefBlend
from firmware_bridge.gate import GATE_FLAGS
from firmware_bridge.preflight import PreflightError, VehicleInfo
from firmware_bridge.profiles import Profile, make_profile
from firmware_bridge.realtime import RealtimeSetup, setup_realtime
from firmware_bridge.report import Reporting, gap_statistics
from firmware_bridge.safety import TickSafety, make_gate
from firmware_bridge.setpoints import SetpointShaping
from firmware_bridge.steering_setup import SteeringSetup
from firmware_bridge.supervisor import Supervisor
from firmware_bridge.telemetry import TelemetryState, TrajectoryFrame
from firmware_bridge.ticklog import TickRecorder
from firmware_bridge.truth import SimTruth

__all__ = ["BridgeConfig", "Bridge", "FaultInjectingSolver", "FlightError", "NoVehicleError",
           "default_controller_config", "gap_statistics"]

class Bridge(Supervisor, Reporting, SetpointShaping, TickSafety, SteeringSetup):
    """The tick loop (see the module docstring). ``run()`` returns the summary dict.

    Args:
        config: :class:`BridgeConfig`.
        link: an open :class:`MavLink` (default: opened from ``config.url``).
        solver: a loaded solver (default: ``load_solver(config.solver)`` in steer mode).
    """

    def __init__(self, config: BridgeConfig, link: MavLink | None = None, solver=None) -> None:
        self.cfg = c = config
        self.period = 1.0 / c.rate_hz
        self.ctrl_cfg = c.controller or default_controller_config()
        if abs(self.ctrl_cfg.dt - self.period) > 1e-9:
            raise ValueError(f"controller dt {self.ctrl_cfg.dt} s does not match the rate {c.rate_hz} Hz")
        self.ctrl = HeightLegAngleController(self.ctrl_cfg, c.trajectory)
        self.hopping = self.ctrl.mode == "hopping"
        contact = c.contact or ContactConfig(leg_length=self.ctrl_cfg.leg_length)
        self.hop: HoppingLoop | None = None
        self.m, self.p = self.ctrl.m, self.ctrl.p
        self.hover_thrust = self.ctrl_cfg.model_mass * self.ctrl_cfg.g / self.ctrl_cfg.max_thrust
        self.profile: Profile = make_profile(c.autopilot, prestream=c.prestream)
        self.vehicle: VehicleInfo | None = None  # known after the preflight (before the first tick)
        self.steerer: ReferenceSteerer | None = None
        self.solver = None
        if c.mode == "steer":
            self._setup_solver(solver)
        elif c.mode in BASELINE_MODES:  # a baseline behind the steering's interface
            lo, hi = c.reference_bounds()
            self.policy, self._ahead = baseline_policy(c.mode, getattr(c, c.mode, None), c.rate_hz, self.m, self.hopping,
                                                       hi - lo)
        self.gate = make_gate(c, c.mode, self.period, self.solver)  # the last gate on every applied reference
        if self.hopping:
            window = hopping_window(self.solver, self.steerer.t_ini) if self.steerer is not None else None
            self.hop = HoppingLoop(self.ctrl, contact, self.policy if self.steerer is not None else None, window)
        self.link = link or MavLink(c.url, baud=c.baud, source_system=c.sysid, source_component=c.compid,
                                    target_system=c.target_system, target_component=c.target_component)
        self.tracker = CommandTracker(self.link)
        # Hopping: the contact flag is read (and logged) whenever the robot sends one; it drives the
        # phases only with source "signal".
        self.telem = TelemetryState(c.attitude_stream, c.position_stream, contact.signal_name if self.hopping else None)
        xy0 = (0.0, 0.0) if self.hopping else self.ctrl.trajectory.start_position()[:2]
        self.frame = TrajectoryFrame(c.frame, anchor=xy0)
        self.rec = TickRecorder(self.m, self.p, capacity=int(c.rate_hz * (c.duration or 60.0) * 1.5) + 1024)
        self.tilt_max = math.radians(c.max_tilt_deg)
        self._exc = None
        if c.mode == "collect":
            self._exc_amp = np.broadcast_to(np.asarray(c.excitation, dtype=float), (self.m,)).copy()
            self.prepare_excitation()
        self._stop = False
        self.stop_reason = ""
        self.events: list[tuple[float, str]] = []
        self.params: dict[str, float] = {}
        self.counts: dict[str, int] = {"tilt_clamped": 0, "thrust_clamped": 0, "telemetry_gaps": 0,
                                       "reboots": 0, "stream_requests": 0, "link_losses": 0}
        self.t0 = time.monotonic()
        self._send_times: list[float] = []
        self._send_stamps: list[float] = []  # vehicle time of each send (the clock that counts in lock-step)
        self.scheduling = "best effort"
        self._rt = RealtimeSetup()
        self._init_run_state()

    def _reset_steering(self) -> None:
        """Forget the steering history (hopping: its own (u, y, phase) history too)."""
        if self.hop is not None:
            self.hop.reset()
        elif self.steerer is not None:
            self.policy.reset()

    def stop(self, *_args) -> None:
        """Ask the loop to finish (signal handler)."""
        self._stop = True
        if not self.stop_reason:
            self.stop_reason = "signal"

    def _event(self, what: str) -> None:
        t = time.monotonic() - self.t0
        self.events.append((round(t, 4), what))
        if self.cfg.verbose:
            print(f"[bridge {t:8.3f}] {what}", file=sys.stderr, flush=True)

    # ------------------------------------------------------------------ vehicle state
    def _init_run_state(self) -> None:
        """Everything the loop keeps between ticks (fresh at every :meth:`run`)."""
        self.armed = False
        self.offboard = False
        self.mode_name = "?"
        self.hb_autopilot: int | None = None
        self.hb_type = 0
        self.last_hb = -math.inf
        self.last_heard = -math.inf        # last heartbeat or telemetry sample from the vehicle [s]
        self.hb_seen = False
        self._link_lost = False
        self._t_offset = math.inf          # receive time - vehicle time stamp (clock sync estimate) [s]
        self._last_seq = (0, 0)            # telemetry sample counts used by the last event tick
        self.clock = TickClock(self.period)  # real time: the uniform tick grid
        self._seen_total = 0               # telemetry samples (both streams) up to the last tick
        self._tick_t = math.nan            # trajectory clock of the last tick (grid time / stamp) [s]
        self._last_send = -math.inf
        self._last_msg = None              # last SET_ATTITUDE_TARGET (repeated by hold ticks)
        self._stream_since = math.inf      # start of the current uninterrupted setpoint stream [s]
        self._stream_since_stamp = math.nan
        self._prev_stream_t = -math.inf
        self._stale_since: float | None = None
        self._fresh_again = False          # telemetry fresh after a stale stretch: resume bumplessly
        self._ref_offset = None            # u - y at the last fresh engaged tick
        self._engaged = False
        self._traj_t0: float | None = None  # vehicle time at which the trajectory started [s]
        self._last_stamp = math.nan
        self._n_activations = 0
        self._offboard_attempts = 0
        self._next_offboard_try = 0.0
        self.arming = ArmingRetry(timeout=self.cfg.arm_timeout)
        self.approach: Approach | None = None
        self.approach_result: dict | None = None  # how the take-off approach ended (the summary's "approach")
        self.blend = RefBlend(tuple(self.cfg.blend_rates or ()))
        self._flown = False                # the trajectory has started once: frame and clock are fixed
        self.failure: str | None = None
        self._last_text = ""
        self._was_engaged_ever = False
        self._stale_mode_sent = False
        self._k_exc = 0
        self.truth = SimTruth()            # the SITL's true state, when it sends one (logged, not used)
        self._init_safety()

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
        self.scheduling = self._rt.describe()
        if c.rt_priority or c.cpus:
            self._event(f"scheduling: {self.scheduling}")
        self._init_run_state()
        if len(interrupted):
            self.stop()
        next_hb = 0.0
        gc_was = gc.isenabled()
        try:
            self._wait_for_vehicle()
            if not self._stop:  # interrupted while waiting: straight to the log and the summary
                self._preflight()
                self._request_streams()
            gc.collect()
            gc.freeze()  # keep the collector's full passes off the tick path (objects made so far are immortal)
            gc.disable()
            last_gc = time.monotonic()
            n_gc = 0
            while not self._stop:
                now = time.monotonic()
                timeout = self._wake_in(now)
                if timeout > 0:
                    self.link.wait(timeout)
                for msg, rx in self.link.drain():
                    self._on_message(msg, rx)
                now = time.monotonic()
                kind = self._tick_kind(now)
                if kind:
                    self._tick(kind, now)
                    if kind == "grid":
                        self.clock.advance(time.monotonic())
                # ---- housekeeping, after the tick (never delays a setpoint)
                now = time.monotonic()
                if now >= next_hb:
                    next_hb = now + 1.0
                    self.link.send_heartbeat()
                self.tracker.poll(now)
                if self.link.poll(now):
                    self._event(f"link reopened ({self.link.endpoint})")
                    self._request_streams()
                self._supervise(now)
                if now - last_gc > 1.0 and now - self._last_send < 0.5 * self.period:
                    # Right after a tick, off the critical path: young generations only (the setup objects
                    # are frozen), the middle one every ~30 s.
                    n_gc += 1
                    gc.collect(1 if n_gc % 30 == 0 else 0)
                    last_gc = now
            self._shutdown()
        except NoVehicleError:
            self.stop_reason = "no vehicle"
            raise
        except PreflightError as e:
            self.stop_reason = f"preflight: {e}"
            raise
        finally:
            self._rt.release()
            if gc_was:
                gc.enable()
            gc.unfreeze()
            self._finish()
        if self.failure:
            raise FlightError(self.failure)
        return self.summary()

    def _wake_in(self, now: float) -> float:
        if self.cfg.lockstep or not self.clock.started:
            return 0.05
        return self.clock.wait_time(now)

    def _tick_kind(self, now: float) -> str:
        """"event" (lock-step: every stream advanced), "grid" (real time: the clock's deadline), or ""."""
        t = self.telem
        if not t.has_data:
            return ""
        if self.cfg.lockstep:
            return "event" if t.att.seq > self._last_seq[0] and t.pos.seq > self._last_seq[1] else ""
        if not self.clock.started:
            self.clock.start(now)  # the grid starts with the first complete telemetry
        return "grid" if self.clock.due(now) else ""

    def _vehicle_now(self, now: float) -> float:
        """Vehicle time [s] now: the newest stamp in lockstep, else the clock estimate."""
        if self.cfg.lockstep or not math.isfinite(self._t_offset):
            return self.telem.newest_stamp()
        return now - self._t_offset

    # ------------------------------------------------------------------ one tick
    def _tick(self, kind: str, now: float) -> None:
        """One control tick: newest telemetry (held, with its age) -> reference -> setpoint -> log."""
        c = self.cfg
        tel = self.telem
        event = kind == "event"
        if c.lockstep:
            age, tclk = tel.newest_stamp() - tel.oldest_stamp(), tel.newest_stamp()
        else:
            age, tclk = now - tel.oldest_rx(), self.clock.time()  # grid time: uniform, no jitter
        fresh = age <= c.max_age
        hb_ok = self.hb_seen and now - self.last_heard <= c.link_timeout
        engaged = self.armed and self.offboard and hb_ok
        n_new = max(tel.seq_total - self._seen_total, 0)
        self._seen_total = tel.seq_total
        stalled = self._check_stall(now)  # before the staleness: a quiet tick is still a tick of the clock
        if not self._check_staleness(now, age, fresh, event):
            return
        gap, fill = self._lockstep_gap(tclk) if event else (False, 0)
        if fresh and not self._flown:
            # Before the trajectory first starts, the frame follows the vehicle (frozen from then
            # on: no re-anchoring mid-air) and heights count from where it stood disarmed.
            self.frame.capture(tel.position, float(tel.euler[2]))
            if not self.armed:
                self.frame.z0 = float(tel.position[2])
                self.truth.capture_ground()
        state = self.frame.to_trajectory(tel.measured_state(0.0))
        self._update_engagement(engaged and self.frame.captured, tclk, state)
        self._tick_t = tclk
        t_traj = tclk - self._traj_t0 if self._traj_t0 is not None else 0.0
        state = dataclasses.replace(state, t=t_traj)
        if self.hop is not None:
            state = self.hop.observe(state, tel)
        ref = self._reference(state, t_traj, hb_ok, engaged and self.frame.captured, fresh, fill)
        flags = self._gate_reference(ref) | (GATE_FLAGS["stall"] if stalled else 0)  # the last gate
        flags |= self._check_guard_saturation(flags, now)
        if fresh and engaged:
            self._ref_offset = ref["u"] - ref["y"]  # applied reference - measured output (a stall resumes here)
        if not fresh and c.stale_action != "reference":
            q, thrust, field = self._level_setpoint()
            if c.stale_action == "land":
                self._request_land()
        elif not self.armed and not self._flown:
            q, thrust, field = self._ground_setpoint(float(state.position[2]))
        else:
            q, thrust, _ = self._clamp(self.ctrl.track(ref["u"], state))
            field = self.profile.thrust_field(thrust, float(ref["u"][0]), float(state.position[2]))
        q, thrust, field, bad = self._gate_setpoint(q, thrust, field)
        self._safety_events(ref, flags | bad)
        t_vehicle = tel.newest_stamp() if event else self._vehicle_now(now)
        sent = self._send_setpoint(q, field, int(round(t_vehicle * 1000.0)) if math.isfinite(t_vehicle) else 0)
        t_sent = time.monotonic()
        self._record(ref, state, now=now, t_sent=t_sent, t_vehicle=t_vehicle,
                     t_traj=t_traj if self._traj_t0 is not None else math.nan, age=age, q=q, thrust=thrust,
                     field=field, event=event or n_new > 0, engaged=engaged and ref["reason"] not in ("takeoff", "blend"),
                     fresh=fresh, sent=sent, gap=gap,
                     n_new=n_new, latency=(t_sent - tel.newest_rx()) * 1e6, gate=flags | bad)

    def _reference(self, state, t_traj: float, hb_ok: bool, engaged: bool, fresh: bool, fill: int) -> dict:
        """Stage (a) and the mode's reference: steered / passthrough / collect, or why not."""
        ctrl = self.ctrl
        r_nom = ctrl.nominal_reference(state)
        y = ctrl.outputs(state)
        if engaged and fresh and self.approach is not None:
            r_nom[0] = self.approach.step(self._tick_t, self.period, float(y[0]))
        blending = engaged and self.blend.active
        if blending:
            r_nom = self.blend.apply(r_nom, self.period)
        ref = {"r_nom": r_nom, "y": y, "u": r_nom, "u_st": None, "exc": None, "solve_us": math.nan}
        if engaged and fresh and self.approach is not None:
            ref["reason"] = "takeoff"
            if self.approach.done:
                ap, self.approach = self.approach, None
                self.approach_result = ap.outcome()
                if ap.timed_out:  # say so: the steering then starts against that error
                    self._event(f"WARNING: did not hold the start height within {ap.tolerance:g} m for {ap.hold:g} s "
                                f"in {ap.max_extra:g} s (height error now {ap.last_error:+.3f} m: the vehicle or its "
                                "height estimate did not settle): trajectory starts anyway")
                else:
                    self._event("at the trajectory's start height: trajectory starts")
            return ref
        if not hb_ok:
            ref["reason"] = "no_heartbeat"
        elif not engaged:
            ref["reason"] = "inactive"
        elif not fresh:
            ref["reason"] = "stale"
            if self.hop is not None:
                self.hop.reset()
            elif self.steerer is not None:
                self.steerer.reset()
        elif blending:
            # The hand-over is the controller's alone: the solver would pull the reference back to the
            # trajectory faster than the blend allows. The history fills meanwhile (no extra warm-up).
            ref["reason"] = "blend"
            if self.steerer is not None:
                self.policy.observe(r_nom, y)
                ref["observed"] = True
        elif self.cfg.mode == "steer" and self.hop is not None:
            self.hop.lost(fill)
            ref.update(self.hop.steer(y, r_nom, t_traj, self._ahead))
        elif self.cfg.mode == "steer":
            self.policy.lost(fill, y)
            out = self.policy.decide(y, r_nom, ctrl.desired_outputs(t_traj + self._ahead))
            ref.update(u=out.u, reason=out.reason, solve_us=out.solve_us, u_st=out.u if out.steered else None,
                       observed=True)
            if self.policy.adaptation is not None:
                ref["adapt"] = adapt_code(self.policy.adaptation.last)
                ref["adapt_offset"] = self.policy.adaptation.offset_norm
                ref["adapt_snap"] = self.policy.adaptation.last_snap
            if out.reason == "step_too_large" and out.result is not None:  # clamped to the guard by the gate
                ref["candidate"] = np.asarray(out.result.u[0], dtype=float)
        elif self.cfg.mode in BASELINE_MODES:
            if self.cfg.mode == "feedforward":  # the row of this trajectory tick (a re-engagement continues it)
                self.policy.seek(feedforward_row(t_traj, self.period))
            out = self.policy.decide(y, r_nom, ctrl.desired_outputs(t_traj + self._ahead))
            ref.update(u=out.u, reason=out.reason)
        else:  # collect
            ref["exc"] = self._excitation() if self.hop is None else self.hop.excitation(self._excitation())
            ref.update(u=r_nom + ref["exc"], reason="collect")
        return ref
