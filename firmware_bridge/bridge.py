"""The companion-computer tick loop: telemetry in, steering + height / leg-angle controller,
SET_ATTITUDE_TARGET out, at 200 Hz (``ddpc-bridge``).

One tick (on the bridge's own clock; lock-step: on every telemetry sample)::

    newest telemetry (NED/FRD -> ENU/FLU -> trajectory frame) -> MeasuredState (t = trajectory time)
    r_nom = controller.nominal_reference(state)             stage (a)
    u     = steer: ReferenceSteerer.step(y_des, u_nom)      the generated solver, with fallback
            passthrough: r_nom                              the model-based controller alone
            collect: r_nom + PRBS                           new data
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
the trajectory must lie inside the solver's bounds. Flight phases (:mod:`.phases`): arming once
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
import json
import math
import signal
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.robot.controller import ControllerConfig, HeightLegAngleController
from ddpc_codegen.robot.profile import load_profile
from ddpc_codegen.robot.trajectory import EllipseTrajectory
from ddpc_codegen.robot.frames import quat_from_euler
from ddpc_codegen.design.result import SteeringResult
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer, solver_input_bounds

from firmware_bridge.clock import TickClock
from firmware_bridge.link import CommandTracker, MavLink, mavlink
from firmware_bridge.phases import Approach, ArmingRetry, RefBlend
from firmware_bridge.preflight import (PreflightError, VehicleInfo, check_autopilot, check_trajectory_bounds,
                                       decode_param_value, hover_param, params_to_read, resolve_guid_options)
from firmware_bridge.realtime import RealtimeSetup, setup_realtime
from firmware_bridge.profiles import ArduPilotProfile, Profile, make_profile
from firmware_bridge.telemetry import TelemetryState, TrajectoryFrame, swap_frames
from firmware_bridge.ticklog import FALLBACK_REASONS, REASONS, TickLog, TickRecorder, _json_default, reason_code

__all__ = ["BridgeConfig", "Bridge", "FaultInjectingSolver", "FlightError", "NoVehicleError",
           "default_controller_config", "gap_statistics"]

_MSG_IDS = {
    "ATTITUDE": mavlink.MAVLINK_MSG_ID_ATTITUDE,
    "ATTITUDE_QUATERNION": mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    "LOCAL_POSITION_NED": mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "ODOMETRY": mavlink.MAVLINK_MSG_ID_ODOMETRY,
}
# Body rates ignored: attitude + thrust (= 7).
_TYPE_MASK = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
              | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
              | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)


class NoVehicleError(RuntimeError):
    """No heartbeat from the target vehicle within the wait time."""


class FlightError(RuntimeError):
    """A flight phase could not be completed (e.g. the vehicle refused arming until the timeout)."""


def default_controller_config() -> ControllerConfig:
    """The flying controller of the shipped ``pogox`` profile (what ``ddpc-vehicle`` flies)."""
    return load_profile("pogox").controller


@dataclass
class BridgeConfig:
    """Options of the bridge (CLI flags of ``ddpc-bridge`` map 1:1; units SI unless named).

    Attributes:
        url, baud: MAVLink connection (see :func:`firmware_bridge.link.parse_url`).
        mode: "steer" (DDPC on; needs ``solver``), "passthrough" (baseline), "collect" (PRBS).
        solver: folder of a generated solver (``ddpc-codegen codegen``), steer mode.
        autopilot: "px4" or "ardupilot" (checked against the vehicle's heartbeat before anything is sent).
        guid_options: ArduPilot GUID_OPTIONS expected (None: the vehicle's value, read before engaging);
            force_guid_options: encode for ``guid_options`` even if the vehicle disagrees.
        sysid, compid: our identity; target_system / target_component: the vehicle (0: first seen).
        rate_hz: control rate (must match the solver's dt and the controller's dt).
        attitude_stream / position_stream: telemetry messages to request.
        max_age: telemetry older than this [s] -> stop steering, stale action.
        stale_action: "reference" (controller on the newest telemetry, unsteered), "hover"
            (level, hover thrust / climb rate 0), "land" (like hover and, with ``offboard``,
            request the autopilot's LAND mode).
        stale_stream_limit: stop streaming after telemetry has been stale this long [s] so the
            autopilot's off-board-loss failsafe takes over (0: never stop).
        link_timeout: no vehicle heartbeat for this long [s] -> link lost.
        max_tilt_deg, thrust_min, thrust_max: clamps on the sent setpoint.
        max_step: (m,) largest |u_steered - u_nom| accepted per channel (None: no guard).
        max_gap_fill: up to this many lost telemetry samples in a row are bridged in the steering
            history (reference held, outputs interpolated; :meth:`ReferenceSteerer.fill_gap`)
            instead of resetting it (a reset costs Tini unsteered ticks); 0: always reset.
        arm, offboard: explicitly allowed actions: arm the vehicle (once both telemetry streams
            arrive; retried every 2 s while refused, each refusal reported, :class:`FlightError`
            after ``arm_timeout`` s); switch it to OFFBOARD / GUIDED after ``prestream`` seconds of
            setpoints (and HOLD at exit / LAND if stale).
        takeoff: at the first engagement, ramp the height reference at ``climb_rate`` [m/s] from
            where the vehicle is to the trajectory's start height, then start the trajectory.
        land: at exit hand the vehicle back with LAND (and wait up to 60 s for it to disarm)
            instead of HOLD.
        blend_rates: bumpless (re-)engagement: the applied references start at the measured
            outputs and approach the nominal ones at most this fast per channel ((m/s, rad/s) for
            flying); None: no blending.
        duration: stop after this long in off-board [s] (None: until signalled).
        timeout: overall wall-clock limit [s] (None: none). wait_heartbeat: give up if no vehicle [s].
        lockstep: tick only on telemetry, controller time = vehicle time stamps.
        log: tick log path (.npz; an IODataset). summary: JSON summary path.
        dataset_skip: seconds after each activation left out of the dataset part of the log.
        settle: seconds after activation excluded from the RMSE in the summary.
        excitation, excitation_hold, seed: collect-mode PRBS amplitude per channel, hold [ticks], seed.
        inject_solver_failure: (first solve index, count[, "fail" | "nan"]) fault injection for tests.
        controller: ControllerConfig (default: :func:`default_controller_config`).
        trajectory: EllipseTrajectory (default: the controller's default ellipse).
        frame: "start" (default: the trajectory starts where the robot is, along its heading, when
            it enters off-board; no turn, no jump) or "world" (trajectory coordinates are the
            autopilot's local ENU, commanded heading east). See :class:`.telemetry.TrajectoryFrame`.
        rt_priority: >0: run the loop SCHED_FIFO at this priority, with memory locked and a
            ``cpu_latency_us`` PM QoS request held (each if permitted; see :mod:`.realtime`).
        cpu_latency_us: PM QoS CPU wake-up latency bound [us] while real time (None: no request).
        cpus: pin the loop to these CPUs (None: any).
    """

    url: str = "udpin:127.0.0.1:14540"
    baud: int | None = None
    mode: str = "steer"
    solver: str | None = None
    autopilot: str = "px4"
    guid_options: int | None = None
    force_guid_options: bool = False
    sysid: int = 1
    compid: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
    target_system: int = 1
    target_component: int = 1
    rate_hz: float = 200.0
    attitude_stream: str = "ATTITUDE_QUATERNION"
    position_stream: str = "LOCAL_POSITION_NED"
    max_age: float = 0.050
    stale_action: str = "reference"
    stale_stream_limit: float = 1.0
    link_timeout: float = 3.0
    max_tilt_deg: float = 30.0
    thrust_min: float = 0.0
    thrust_max: float = 1.0
    max_step: tuple | None = (0.3, 0.5)
    max_gap_fill: int = 3
    arm: bool = False
    offboard: bool = False
    arm_timeout: float = 120.0
    takeoff: bool = False
    climb_rate: float = 0.5
    land: bool = False
    blend_rates: tuple | None = (0.5, 0.5)
    prestream: float = 1.0
    duration: float | None = None
    timeout: float | None = None
    wait_heartbeat: float = 30.0
    lockstep: bool = False
    log: str | None = None
    summary: str | None = None
    dataset_skip: float = 0.0
    settle: float = 3.0
    excitation: tuple = (0.05, 0.03)
    excitation_hold: int = 4
    seed: int = 0
    inject_solver_failure: tuple | None = None
    controller: ControllerConfig | None = None
    trajectory: EllipseTrajectory | None = None
    frame: str = "start"
    rt_priority: int = 0
    cpu_latency_us: int | None = 0
    cpus: tuple | None = None
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.mode not in ("steer", "passthrough", "collect"):
            raise ValueError(f"mode must be steer, passthrough or collect; got {self.mode!r}")
        if self.mode == "steer" and not self.solver:
            raise ValueError("steer mode needs a generated solver folder (--solver generated/<name>)")
        if self.stale_action not in ("reference", "hover", "land"):
            raise ValueError(f"stale_action must be reference, hover or land; got {self.stale_action!r}")
        if not (self.rate_hz > 0 and self.max_age > 0):
            raise ValueError("rate_hz and max_age must be positive")
        if not 0.0 <= self.thrust_min < self.thrust_max <= 1.0:
            raise ValueError("need 0 <= thrust_min < thrust_max <= 1")
        if not isinstance(self.max_gap_fill, int) or self.max_gap_fill < 0:
            raise ValueError(f"max_gap_fill must be an integer >= 0; got {self.max_gap_fill!r}")
        if self.frame not in ("start", "world"):
            raise ValueError(f"frame must be 'start' or 'world'; got {self.frame!r}")


class FaultInjectingSolver:
    """Wraps a solver; solve calls number ``start`` .. ``start+count-1`` fail (test hook).

    kind "fail": status "injected_failure" (not ok); "nan": a NaN solution with status "solved".
    """

    def __init__(self, solver, start: int, count: int, kind: str = "fail") -> None:
        self._solver, self.start, self.count, self.kind = solver, int(start), int(count), kind
        self.calls = 0
        self.injected = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self._solver, name)

    def solve(self, u_ini, y_ini, y_des, u_nom=None) -> SteeringResult:
        i = self.calls
        self.calls += 1
        if self.start <= i < self.start + self.count:
            self.injected += 1
            if self.kind == "nan":
                res = self._solver.solve(u_ini, y_ini, y_des, u_nom)
                res.u = np.full_like(res.u, np.nan)
                return res
            d = self._solver.manifest["dims"]
            return SteeringResult(np.full((d["t_f"], d["m"]), np.nan), status="injected_failure")
        return self._solver.solve(u_ini, y_ini, y_des, u_nom)


def gap_statistics(send_times: np.ndarray, period: float) -> dict:
    """Missed ticks from setpoint send times [s]: a gap of g seconds between two setpoints
    misses round(g / period) - 1 ticks once g >= 1.5 periods (jitter below that is not a miss)."""
    t = np.asarray(send_times, dtype=float)
    if t.size < 2:
        return {"missed_ticks": 0, "max_gap_ms": math.nan, "rate_hz": math.nan, "duration_s": 0.0}
    g = np.diff(t)
    miss = np.where(g >= 1.5 * period, np.rint(g / period) - 1, 0).astype(int)
    dur = float(t[-1] - t[0])
    return {"missed_ticks": int(miss.sum()), "max_gap_ms": float(g.max() * 1e3),
            "rate_hz": float((t.size - 1) / dur) if dur > 0 else math.nan, "duration_s": dur}


def _pct(a: np.ndarray) -> dict:
    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max()),
            "n": int(a.size)}


class Bridge:
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
        if self.ctrl_cfg.mode != "flying":
            raise ValueError("the bridge flies the 'flying' controller (hopping needs a contact estimate "
                             "that MAVLink telemetry does not carry)")
        self.ctrl = HeightLegAngleController(self.ctrl_cfg, c.trajectory)
        self.m, self.p = self.ctrl.m, self.ctrl.p
        self.hover_thrust = self.ctrl_cfg.model_mass * self.ctrl_cfg.g / self.ctrl_cfg.max_thrust
        self.profile: Profile = make_profile(c.autopilot, prestream=c.prestream)
        self.vehicle: VehicleInfo | None = None  # known after the preflight (before the first tick)
        self.steerer: ReferenceSteerer | None = None
        self.solver = None
        if c.mode == "steer":
            self._setup_solver(solver)
        self.link = link or MavLink(c.url, baud=c.baud, source_system=c.sysid, source_component=c.compid,
                                    target_system=c.target_system, target_component=c.target_component)
        self.tracker = CommandTracker(self.link)
        self.telem = TelemetryState(c.attitude_stream, c.position_stream)
        self.frame = TrajectoryFrame(c.frame, anchor=(self.ctrl.trajectory.start_point()[0], 0.0))
        self.rec = TickRecorder(self.m, self.p, capacity=int(c.rate_hz * (c.duration or 60.0) * 1.5) + 1024)
        self.tilt_max = math.radians(c.max_tilt_deg)
        self._exc = None
        if c.mode == "collect":
            self._exc_amp = np.broadcast_to(np.asarray(c.excitation, dtype=float), (self.m,)).copy()
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

    # ------------------------------------------------------------------ setup
    def _setup_solver(self, solver) -> None:
        from ddpc_codegen.runtime.loader import load_solver

        c = self.cfg
        solver = solver if solver is not None else load_solver(c.solver)
        man = solver.manifest
        d = man["dims"]
        if (d["m"], d["p"]) != (self.m, self.p):
            raise ValueError(f"solver has m={d['m']}, p={d['p']} but the flying loop has m={self.m}, p={self.p}")
        sig = man.get("signals", {})
        if sig.get("inputs") and tuple(sig["inputs"]) != self.ctrl.input_names:
            raise ValueError(f"solver inputs {sig['inputs']} != controller references {list(self.ctrl.input_names)}")
        if sig.get("outputs") and tuple(sig["outputs"]) != self.ctrl.output_names:
            raise ValueError(f"solver outputs {sig['outputs']} != controller outputs {list(self.ctrl.output_names)}")
        if sig.get("dt") and abs(float(sig["dt"]) - self.period) > 1e-9:
            raise ValueError(f"solver dt {sig['dt']} s does not match the bridge rate {c.rate_hz} Hz")
        if c.inject_solver_failure:
            start, count, *kind = c.inject_solver_failure
            solver = FaultInjectingSolver(solver, int(start), int(count), kind[0] if kind else "fail")
        self.solver = solver
        self.steerer = ReferenceSteerer.for_solver(
            solver, max_step=None if c.max_step is None else np.asarray(c.max_step, float))
        self.policy = SteeringPolicy(self.steerer, max_gap_fill=c.max_gap_fill)
        traj = self.ctrl.trajectory
        t = np.linspace(0.0, traj.t_start + 5 * traj.spin_up + traj.period, 2000)
        lo, hi = solver_input_bounds(solver)
        check_trajectory_bounds(traj.sample(t)["z"], float(lo[0]), float(hi[0]))
        self.t_f = d["t_f"]
        self._ahead = self.period * np.arange(self.t_f)

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
        self._engaged = False
        self._traj_t0: float | None = None  # vehicle time at which the trajectory started [s]
        self._last_stamp = math.nan
        self._n_activations = 0
        self._offboard_attempts = 0
        self._next_offboard_try = 0.0
        self.arming = ArmingRetry(timeout=self.cfg.arm_timeout)
        self.approach: Approach | None = None
        self.blend = RefBlend(tuple(self.cfg.blend_rates or ()))
        self._flown = False                # the trajectory has started once: frame and clock are fixed
        self.failure: str | None = None
        self._last_text = ""
        self._was_engaged_ever = False
        self._stale_mode_sent = False
        self._k_exc = 0

    def _on_message(self, msg, rx: float) -> None:
        typ = msg.get_type()
        if typ in self.telem.wanted:
            tel = self.telem
            before = (tel.att.stamp, tel.pos.stamp)
            tel.update(msg, rx)
            if before[0] - tel.att.stamp > 1.0 or before[1] - tel.pos.stamp > 1.0:
                # Vehicle clock went back: it rebooted. Forget its state and ask for the streams again.
                self.counts["reboots"] += 1
                self._event(f"vehicle time went back ({max(before):.3f} s -> {tel.newest_stamp():.3f} s): "
                            "reboot, re-requesting streams")
                self.telem.reset()
                self.telem.update(msg, rx)
                self._last_seq = (0, 0)
                self._t_offset = math.inf
                self._request_streams()
            new = self.telem.newest_stamp()
            off = rx - new
            # Vehicle clock estimate: minimum of (receive - stamp), slowly forgetting (clock drift).
            self._t_offset = min(self._t_offset + 1e-5, off) if math.isfinite(self._t_offset) else off
        elif typ == "HEARTBEAT":
            vm = self.profile.decode(msg.base_mode, msg.custom_mode)
            if not self.hb_seen:
                self.hb_autopilot, self.hb_type = int(msg.autopilot), int(msg.type)
                self._event(f"vehicle heartbeat: sysid {msg.get_srcSystem()}, autopilot {msg.autopilot}, "
                            f"{vm.name}, armed={vm.armed}")
            elif rx - self.last_hb > self.cfg.link_timeout:
                self._event("vehicle heartbeat back: link restored, re-requesting streams")
                self._request_streams()
            if self.hb_seen and (vm.armed != self.armed or vm.name != self.mode_name):
                self._event(f"vehicle {vm.name}, armed={vm.armed}")
            self.hb_seen = True
            self.last_hb = rx
            self.armed, self.offboard, self.mode_name = vm.armed, vm.offboard, vm.name
        elif typ == "COMMAND_ACK":
            pc = self.tracker.on_ack(msg)
            if pc is not None and pc.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and not pc.accepted:
                self._event(self.arming.refused(mavlink.enums["MAV_RESULT"][pc.result].name, self._last_text))
            elif pc is not None and (self.cfg.verbose or not pc.accepted):
                self._event(f"{pc.label}: {mavlink.enums['MAV_RESULT'][pc.result].name}")
        elif typ == "PARAM_VALUE":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="ignore")
            name = name.rstrip("\x00")
            self.params[name] = decode_param_value(msg.param_value, msg.param_type, self.hb_autopilot or 0)
            if name == "COM_OF_LOSS_T":
                self.profile.offboard_loss_timeout = float(msg.param_value)
        elif typ == "STATUSTEXT":
            self._last_text = str(msg.text).rstrip("\x00")  # the autopilot's reason for a refusal
            if self.cfg.verbose:
                self._event(f"vehicle says: {msg.text}")

    def _request_streams(self) -> None:
        us = int(round(1e6 / self.cfg.rate_hz))
        for name in sorted({self.cfg.attitude_stream, self.cfg.position_stream}):
            self.tracker.submit(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(_MSG_IDS[name]), float(us)),
                                f"SET_MESSAGE_INTERVAL {name} {self.cfg.rate_hz:g} Hz")
        self.counts["stream_requests"] += 1

    def _preflight(self, timeout: float = 3.0) -> None:
        """Before the first tick: the heartbeat's autopilot, the parameters, the thrust semantics.

        Raises:
            PreflightError: wrong autopilot, or a required parameter / a consistent GUID_OPTIONS missing.
        """
        c = self.cfg
        check_autopilot(self.hb_autopilot, self.profile)
        wanted = params_to_read(self.profile)
        t_end = time.monotonic() + timeout
        next_ask = 0.0
        while not self._stop and time.monotonic() < t_end and any(n not in self.params for n in wanted):
            if time.monotonic() >= next_ask:
                next_ask = time.monotonic() + 0.5
                for n in wanted:
                    if n not in self.params:
                        self._request_param(n)
            self.link.wait(0.05)
            for msg, rx in self.link.drain():
                self._on_message(msg, rx)
        missing = [n for n, req in wanted.items() if n not in self.params and not req]
        if missing:
            self._event(f"parameters not answered within {timeout:g} s: {', '.join(missing)} (not needed)")
        hover = self.params.get(hover_param(self.profile))
        self.vehicle = VehicleInfo(self.hb_autopilot, self.hb_type, dict(self.params), hover)
        if isinstance(self.profile, ArduPilotProfile):
            opt = resolve_guid_options(self.params.get("GUID_OPTIONS"), c.guid_options, c.force_guid_options)
            self.profile.guid_options = opt
            self._event(f"GUID_OPTIONS={opt}: thrust field is a "
                        + ("climb rate" if self.profile.climb_rate_thrust else "thrust"))
        self._event(f"vehicle: {self.profile.name}, hover thrust {hover_param(self.profile)}="
                    + ("?" if hover is None else f"{hover:.3f}")
                    + f", controller model hover thrust {self.hover_thrust:.3f}")

    def _request_param(self, name: str) -> None:
        self.link.send(self.link.mav.param_request_read_encode(self.link.target_system or 0,
                                                               self.link.target_component or 0, name.encode(), -1))

    # ------------------------------------------------------------------ main loop
    def run(self, install_signals: bool = True) -> dict:
        """Connect, configure, run the tick loop until stopped; write the log; return the summary."""
        c = self.cfg
        if install_signals:
            signal.signal(signal.SIGINT, self.stop)
            signal.signal(signal.SIGTERM, self.stop)
        self._rt = setup_realtime(c.rt_priority, cpus=c.cpus, cpu_latency_us=c.cpu_latency_us)
        self.scheduling = self._rt.describe()
        if c.rt_priority or c.cpus:
            self._event(f"scheduling: {self.scheduling}")
        self._init_run_state()
        next_hb = 0.0
        gc_was = gc.isenabled()
        try:
            self._wait_for_vehicle()
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

    def _wait_for_vehicle(self) -> None:
        c = self.cfg
        t_end = time.monotonic() + c.wait_heartbeat
        next_hb = 0.0
        while not self.hb_seen and not self._stop:
            now = time.monotonic()
            if now > t_end:
                raise NoVehicleError(f"no heartbeat from system {c.target_system} on {self.link.endpoint} "
                                     f"within {c.wait_heartbeat:g} s")
            if now >= next_hb:
                next_hb = now + 1.0
                self.link.send_heartbeat()  # udpout: lets a udpin vehicle learn our address
            self.link.poll(now)
            self.link.wait(0.05)
            for msg, rx in self.link.drain():
                self._on_message(msg, rx)

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
        hb_ok = now - self.last_hb <= c.link_timeout
        engaged = self.armed and self.offboard and hb_ok
        n_new = max(tel.seq_total - self._seen_total, 0)
        self._seen_total = tel.seq_total
        if not self._check_staleness(now, age, fresh, event):
            return
        gap, fill = self._lockstep_gap(tclk) if event else (False, 0)
        if fresh and not self._flown:
            # Before the trajectory first starts, the frame follows the vehicle (frozen from then
            # on: no re-anchoring mid-air) and heights count from where it stood disarmed.
            self.frame.capture(tel.position, float(tel.euler[2]))
            if not self.armed:
                self.frame.z0 = float(tel.position[2])
        state = self.frame.to_trajectory(tel.measured_state(0.0))
        self._update_engagement(engaged and self.frame.captured, tclk, state)
        self._tick_t = tclk
        t_traj = tclk - self._traj_t0 if self._traj_t0 is not None else 0.0
        state = dataclasses.replace(state, t=t_traj)
        ref = self._reference(state, t_traj, hb_ok, engaged and self.frame.captured, fresh, fill)
        if not fresh and c.stale_action != "reference":
            q, thrust, field = self._level_setpoint()
            if c.stale_action == "land":
                self._request_land()
        else:
            q, thrust, _ = self._clamp(self.ctrl.track(ref["u"], state))
            field = self.profile.thrust_field(thrust, float(ref["u"][0]), float(state.position[2]))
        t_vehicle = tel.newest_stamp() if event else self._vehicle_now(now)
        sent = self._send_setpoint(q, field, int(round(t_vehicle * 1000.0)) if math.isfinite(t_vehicle) else 0)
        t_sent = time.monotonic()
        self._record(ref, state, now=now, t_sent=t_sent, t_vehicle=t_vehicle,
                     t_traj=t_traj if self._traj_t0 is not None else math.nan, age=age, q=q, thrust=thrust,
                     field=field, event=event or n_new > 0, engaged=engaged and ref["reason"] not in ("takeoff", "blend"),
                     fresh=fresh, sent=sent, gap=gap,
                     n_new=n_new, latency=(t_sent - tel.newest_rx()) * 1e6)

    def _check_staleness(self, now: float, age: float, fresh: bool, event: bool) -> bool:
        """Staleness bookkeeping; False when the stream limit says to go quiet (no setpoint)."""
        c = self.cfg
        if fresh:
            if self._stale_since is not None:
                self._event(f"telemetry fresh again after {now - self._stale_since:.3f} s")
            self._stale_since = None
            return True
        if self._stale_since is None:
            self._stale_since = now
            self._event(f"telemetry stale (age {age * 1e3:.1f} ms > {c.max_age * 1e3:.0f} ms): fallback "
                        f"'{c.stale_action}'")
        if c.stale_stream_limit > 0 and now - self._stale_since > c.stale_stream_limit:
            if event:
                self._last_seq = (self.telem.att.seq, self.telem.pos.seq)
            self._last_send = now  # quiet: the autopilot's own failsafe takes over
            return False
        return True

    def _lockstep_gap(self, stamp: float) -> tuple[bool, int]:
        """Lock-step only (stamps are the tick clock there): (gap, ticks to bridge in the history)."""
        tel = self.telem
        self._last_seq = (tel.att.seq, tel.pos.seq)
        step = stamp - self._last_stamp
        self._last_stamp = stamp
        if not (math.isfinite(step) and abs(step - self.period) > 0.4 * self.period):
            return False, 0
        self.counts["telemetry_gaps"] += 1
        r = step / self.period
        n = int(round(r)) - 1
        if 1 <= n <= self.cfg.max_gap_fill and abs(r - round(r)) < 0.4:
            return True, n  # a few samples lost: bridged once this tick's y is known
        if self.steerer is not None:
            self.policy.reset()  # a long hole, or time went backwards: refill before steering again
        return True, 0

    def _update_engagement(self, engaged: bool, tclk: float, state) -> None:
        """Engagement edges. The first one starts the trajectory (or the take-off ramp); later ones
        continue the same trajectory, clock and frame. Each starts a bumpless blend."""
        c = self.cfg
        if engaged and not self._engaged:
            self._n_activations += 1
            self._was_engaged_ever = True
            if self.steerer is not None:
                self.policy.reset()
            if c.blend_rates:
                self.blend.start(self.ctrl.outputs(state))
            if not self._flown:
                self._flown = True
                self._traj_t0 = tclk
                if c.takeoff:
                    self.approach = Approach(self.ctrl.trajectory.start_point()[1], climb_rate=c.climb_rate)
                    self.approach.start(float(state.position[2]))
                self._event(f"engaged ({self.mode_name}, armed): "
                            + (f"take-off to z = {self.approach.target:.2f} m at {c.climb_rate:g} m/s, then "
                               if self.approach else "")
                            + f"trajectory starts, {c.mode}; {self.frame.describe()}")
            else:
                self._event(f"re-engaged ({self.mode_name}): trajectory continues at t = "
                            f"{tclk - self._traj_t0:.3f} s, same frame")
        elif not engaged and self._engaged:
            self._event("disengaged: vehicle no longer armed + off-board (or link lost)")
        self._engaged = engaged
        if engaged and self.approach is not None:
            self._traj_t0 = tclk  # the trajectory clock waits at its start until the vehicle is there

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
                self.approach = None
                self._event("at the trajectory's start height: trajectory starts")
            return ref
        if not hb_ok:
            ref["reason"] = "no_heartbeat"
        elif not engaged:
            ref["reason"] = "inactive"
        elif not fresh:
            ref["reason"] = "stale"
            if self.steerer is not None:
                self.steerer.reset()
        elif blending:
            # The hand-over is the controller's alone: the solver would pull the reference back to the
            # trajectory faster than the blend allows. The history fills meanwhile (no extra warm-up).
            ref["reason"] = "blend"
            if self.steerer is not None:
                self.policy.observe(r_nom, y)
        elif self.cfg.mode == "steer":
            self.policy.lost(fill, y)
            out = self.policy.decide(y, r_nom, ctrl.desired_outputs(t_traj + self._ahead))
            ref.update(u=out.u, reason=out.reason, solve_us=out.solve_us, u_st=out.u if out.steered else None)
        elif self.cfg.mode == "collect":
            ref["exc"] = self._excitation()
            ref.update(u=r_nom + ref["exc"], reason="collect")
        else:
            ref["reason"] = "passthrough"
        return ref

    def _record(self, ref: dict, state, *, now: float, t_sent: float, t_vehicle: float, t_traj: float, age: float,
                q, thrust: float, field: float, event: bool, engaged: bool, fresh: bool, sent: bool, gap: bool,
                n_new: int, latency: float) -> None:
        """One row of the tick log (see :mod:`.ticklog` for the fields)."""
        i = self.rec.new_row()
        A = self.rec.arrays
        A["t_wall"][i] = now - self.t0
        A["t_vehicle"][i] = t_vehicle
        A["t_traj"][i] = t_traj
        A["age_ms"][i] = age * 1e3
        A["position"][i] = state.position
        A["velocity"][i] = state.velocity
        A["euler"][i] = state.euler
        A["rates"][i] = state.body_rates
        A["y"][i] = ref["y"]
        A["y_des"][i] = self.ctrl.y_des
        A["r_nom"][i] = ref["r_nom"]
        A["u"][i] = ref["u"]
        if ref["u_st"] is not None:
            A["u_steered"][i] = ref["u_st"]
        A["excitation"][i] = ref["exc"] if ref["exc"] is not None else 0.0
        A["sp_q"][i] = q
        A["sp_thrust"][i] = thrust
        A["sp_field"][i] = field
        A["reason"][i] = reason_code(ref["reason"])
        A["solve_us"][i] = ref["solve_us"]
        A["latency_us"][i] = latency
        A["compute_us"][i] = (t_sent - now) * 1e6
        A["event"][i] = event
        A["new_samples"][i] = min(n_new, 127)
        A["armed"][i] = self.armed
        A["offboard"][i] = self.offboard
        A["active"][i] = engaged and fresh
        A["fresh"][i] = fresh
        A["sent"][i] = sent
        A["valid"][i] = event and engaged and fresh if self.cfg.lockstep else engaged and fresh
        A["gap"][i] = gap

    def _excitation(self) -> np.ndarray:
        from ddpc_codegen.design.data import prbs

        block = 12000
        j = self._k_exc % block
        if self._exc is None or j == 0:
            seed = self.cfg.seed * 1009 + self._k_exc // block
            self._exc = prbs(block, self.m, amplitude=self._exc_amp, min_hold=self.cfg.excitation_hold, seed=seed)
        self._k_exc += 1
        return self._exc[j]

    def _level_setpoint(self) -> tuple[tuple, float, float]:
        """Level attitude at the trajectory frame's heading and hover thrust / zero climb rate."""
        q = swap_frames(*self.frame.to_world((1.0, 0.0, 0.0, 0.0)))
        thrust = min(max(self.hover_thrust, self.cfg.thrust_min), self.cfg.thrust_max)
        return q, thrust, self.profile.hover_field(thrust)

    def _clamp(self, sp) -> tuple[tuple, float, tuple]:
        roll, pitch, yaw = (float(v) for v in sp.euler)
        lim = self.tilt_max
        q_enu = tuple(float(v) for v in sp.q)
        if abs(roll) > lim or abs(pitch) > lim or not (math.isfinite(roll) and math.isfinite(pitch)):
            self.counts["tilt_clamped"] += 1
            roll = max(-lim, min(lim, roll)) if math.isfinite(roll) else 0.0
            pitch = max(-lim, min(lim, pitch)) if math.isfinite(pitch) else 0.0
            q_enu = tuple(float(v) for v in quat_from_euler(roll, pitch, yaw if math.isfinite(yaw) else 0.0))
        thrust = float(sp.thrust)
        lo, hi = self.cfg.thrust_min, self.cfg.thrust_max
        if not math.isfinite(thrust):
            thrust = self.hover_thrust
            self.counts["thrust_clamped"] += 1
        if thrust < lo or thrust > hi:
            self.counts["thrust_clamped"] += 1
            thrust = min(max(thrust, lo), hi)
        return swap_frames(*self.frame.to_world(q_enu)), thrust, (roll, pitch, yaw)

    def _send_setpoint(self, q_ned: tuple, field: float, stamp_ms: int) -> bool:
        lk = self.link
        msg = lk.mav.set_attitude_target_encode(
            stamp_ms & 0xFFFFFFFF, lk.target_system or 0, lk.target_component or 0, _TYPE_MASK,
            list(q_ned), 0.0, 0.0, 0.0, float(field))
        ok = lk.send(msg)
        self._last_msg = msg
        self._last_send = time.monotonic()
        if ok:
            self._send_times.append(self._last_send)
            self._send_stamps.append(self._vehicle_now(self._last_send))
            self._stream_mark(self._last_send)
        return ok

    def _stream_mark(self, t: float) -> None:
        # Continuous streaming since when (PX4 wants a live stream before it accepts OFFBOARD).
        if not math.isfinite(self._stream_since) or t - self._prev_stream_t > 0.5:
            self._stream_since = t
            self._stream_since_stamp = self.telem.newest_stamp()
        self._prev_stream_t = t


    # ------------------------------------------------------------------ arming / modes
    def _supervise(self, now: float) -> None:
        c = self.cfg
        if not self.hb_seen:
            return
        self._supervise_arming(now)
        streaming = math.isfinite(self._stream_since) and now - self._prev_stream_t < 0.1
        # Lockstep: "1 s of setpoints" in vehicle time (wall time runs much faster or slower there).
        streamed = (self.telem.newest_stamp() - self._stream_since_stamp) if c.lockstep else now - self._stream_since
        if (c.offboard and not self.offboard and not self._was_engaged_ever and streaming
                and streamed >= self.profile.prestream and (self.armed or not c.arm or not self.profile.arm_first)
                and now >= self._next_offboard_try and self._offboard_attempts < 5
                and not self.tracker.queues.get(mavlink.MAV_CMD_DO_SET_MODE)):
            self._offboard_attempts += 1
            self._next_offboard_try = now + 1.0
            params = self.profile.offboard_command()
            self._event(f"requesting {self.profile.mode_command_name(params)} after "
                        f"{streamed:.2f} s of setpoints (--offboard)")
            self.tracker.submit(mavlink.MAV_CMD_DO_SET_MODE, params, f"DO_SET_MODE {self.profile.mode_command_name(params)}")
        if c.duration is not None and self._engaged and self._traj_t0 is not None:
            if self._tick_t - self._traj_t0 >= c.duration - 1e-9:
                self.stop_reason = f"duration {c.duration:g} s flown"
                self._stop = True
        if c.timeout is not None and now - self.t0 > c.timeout:
            self.stop_reason = self.stop_reason or f"timeout {c.timeout:g} s"
            self._stop = True
        if self.hb_seen and now - self.last_hb > c.link_timeout and not self._link_lost:
            self._link_lost = True
            self.counts["link_losses"] += 1
            self._event(f"no vehicle heartbeat for {c.link_timeout:g} s: link lost")
        elif now - self.last_hb <= c.link_timeout:
            self._link_lost = False

    def _supervise_arming(self, now: float) -> None:
        """--arm: once both telemetry streams arrive (and, for ArduPilot, in the guided mode), arm;
        retry while refused; give up with :class:`FlightError` after ``arm_timeout``."""
        c = self.cfg
        if not c.arm or self.armed or self._was_engaged_ever:
            return
        if self.arming.gave_up(now):
            self.failure = self.arming.failure()
            self.stop_reason = "arming failed"
            self._stop = True
            return
        ready = (self.telem.has_data and (self.profile.arm_first or self.offboard)
                 and not self.tracker.queues.get(mavlink.MAV_CMD_COMPONENT_ARM_DISARM))
        if self.arming.due(now, ready):
            self.arming.sent(now)
            self._event(f"arming (--arm), attempt {self.arming.attempts}")
            self.tracker.submit(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), "ARM")

    def _request_land(self) -> None:
        if self.cfg.offboard and not self._stale_mode_sent:
            self._stale_mode_sent = True
            params = self.profile.land_command()
            self._event(f"stale telemetry: requesting {self.profile.mode_command_name(params)}")
            self.tracker.submit(mavlink.MAV_CMD_DO_SET_MODE, params, f"DO_SET_MODE {self.profile.mode_command_name(params)}")

    def _shutdown(self) -> None:
        """With --offboard: hand the vehicle to HOLD before going quiet (setpoints keep flowing meanwhile)."""
        c = self.cfg
        if not (c.offboard and self.offboard and self.armed):
            return
        params = self.profile.land_command() if c.land else self.profile.hold_command()
        self._event(f"exit: requesting {self.profile.mode_command_name(params)}")
        pc = self.tracker.submit(mavlink.MAV_CMD_DO_SET_MODE, params, f"DO_SET_MODE {self.profile.mode_command_name(params)}")
        t_end = time.monotonic() + (60.0 if c.land else 1.5)
        self._stop = False
        # LAND: until the vehicle has landed and disarmed itself; HOLD: until acknowledged.
        while time.monotonic() < t_end and not ((not self.armed) if c.land else pc.done):
            now = time.monotonic()
            self.link.wait(max(0.0, min(0.05, self._last_send + self.period - now)))
            for msg, rx in self.link.drain():
                self._on_message(msg, rx)
            now = time.monotonic()
            if now - self._last_send >= self.period and self._last_msg is not None:
                self.link.send(self._last_msg)
                self._last_send = now
            self.tracker.poll(now)
        if c.land:
            self._event("landed and disarmed" if not self.armed else "LAND: still armed after 60 s")
        self._stop = True

    # ------------------------------------------------------------------ results
    def ticklog(self) -> TickLog:
        c = self.cfg
        meta = {"bridge": {k: v for k, v in asdict(c).items() if k not in ("controller", "trajectory")},
                "controller": asdict(self.ctrl_cfg), "trajectory": asdict(self.ctrl.trajectory),
                "autopilot": self.profile.name, "dataset_skip": c.dataset_skip, "min_segment": 50,
                # tick_position / velocity / euler are in this frame (last capture: the latest engagement)
                "frame": self.frame.as_dict(),
                "solver": None if self.solver is None else {"folder": str(getattr(self.solver, "folder", "")),
                                                           "config_hash": self.solver.manifest.get("config_hash"),
                                                           "predictor_hash": self.solver.manifest.get("predictor_hash")}}
        samples = {name: np.array(s.history, dtype=float).reshape(-1, 2) - np.array([0.0, self.t0])
                   for name, s in (("attitude", self.telem.att), ("position", self.telem.pos))}
        return self.rec.to_log(dt=self.period, input_names=self.ctrl.input_names, output_names=self.ctrl.output_names,
                               input_units=self.ctrl.input_units, output_units=self.ctrl.output_units, metadata=meta,
                               samples=samples)

    def summary(self) -> dict:
        c = self.cfg
        v = self.rec.view()
        n = self.rec.n
        reasons = v["reason"]
        names = np.array(REASONS)
        counts = {str(names[i]): int((reasons == i).sum()) for i in np.unique(reasons)} if n else {}
        fb = {k: cnt for k, cnt in counts.items() if k in FALLBACK_REASONS}
        # In lock-step the vehicle's clock is the one that matters: wall-clock gaps only say the
        # machine was busy, not that a tick of the (paused) vehicle went without a setpoint.
        gaps = gap_statistics(np.asarray(self._send_stamps if c.lockstep else self._send_times), self.period)
        eng = v["event"] & v["active"] & (np.nan_to_num(v["t_traj"], nan=-1.0) >= c.settle)
        ez = v["y"][eng, 0] - v["y_des"][eng, 0] if n else np.zeros(0)
        out = {
            "mode": c.mode, "autopilot": self.profile.name, "stop_reason": self.stop_reason, "ticks": n,
            "setpoints_sent": len(self._send_times), "rate_hz": gaps["rate_hz"], "duration_s": gaps["duration_s"],
            "latency_us": _pct(v["latency_us"]) if n else _pct(np.zeros(0)),
            "missed_ticks": gaps["missed_ticks"], "max_gap_ms": gaps["max_gap_ms"],
            "fallbacks": int(sum(fb.values())), "fallback_reasons": fb, "reasons": counts,
            "event_ticks": int(v["event"].sum()) if n else 0, "activations": self._n_activations,
            "grid_skipped": self.clock.skipped, "telemetry": self._telemetry_summary(),
            "arming": {"attempts": self.arming.attempts, "refusals": self.arming.refusals[-5:]},
            "vehicle": None if self.vehicle is None else asdict(self.vehicle),
            "rmse_z_measured": float(np.sqrt(np.mean(ez ** 2))) if ez.size else None,
            "rmse_samples": int(ez.size), **self.counts,
            "link": {**dict(self.link.stats), "foreign_systems": sorted(self.link.foreign_systems)},
            "params": self.params, "scheduling": self.scheduling, "frame": self.frame.as_dict(),
            "events": self.events,
        }
        if self.steerer is not None:
            out["steering"] = self.steerer.summary()
            if isinstance(self.solver, FaultInjectingSolver):
                out["steering"]["injected_failures"] = self.solver.injected
        return out

    def _telemetry_summary(self) -> dict:
        """Per stream: samples received (every one is kept in the log), distinct stamps per second,
        the most common stamp steps [ms: count] -- what the autopilot really delivers."""
        out = {}
        for name, s in (("attitude", self.telem.att), ("position", self.telem.pos)):
            h = np.array(s.history, dtype=float).reshape(-1, 2)
            st = np.unique(h[:, 0])
            span = st[-1] - st[0] if st.size > 1 else 0.0
            steps, cnt = np.unique(np.round(np.diff(h[:, 0]) * 1e3).astype(int), return_counts=True)
            top = sorted(zip(cnt.tolist(), steps.tolist()), reverse=True)[:4]
            out[name] = {"samples": int(h.shape[0]), "distinct_per_s": float((st.size - 1) / span) if span > 0 else None,
                         "step_ms": {str(k): c for c, k in top}}
        return out

    def _finish(self) -> None:
        c = self.cfg
        if c.log and self.rec.n:
            self.log_path = self.ticklog().save(c.log)
        s = self.summary()
        if c.summary:
            Path(c.summary).parent.mkdir(parents=True, exist_ok=True)
            Path(c.summary).write_text(json.dumps(s, indent=2, default=_json_default) + "\n")
        self.link.close()
