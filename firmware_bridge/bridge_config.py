"""The bridge's options (:class:`BridgeConfig`; ``ddpc-bridge`` flags map 1:1), its error types and
the solver fault-injection wrapper used by the tests."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.values.files import checked_output_file
from ddpc_codegen.values.solve_result import SteeringResult
from ddpc_codegen.robot.controller import ControllerConfig
from ddpc_codegen.robot.signals import check_per_reference
from ddpc_codegen.robot.phases import ContactConfig
from ddpc_codegen.robot.profile import Envelope, default_envelope, load_profile
from ddpc_codegen.robot.trajectory import EllipseTrajectory

from firmware_bridge.link import mavlink, parse_url
from firmware_bridge.arg_checks import check_bridge_values
from firmware_bridge.path_checks import check_flight_paths
from firmware_bridge.position_source import POSITION_SOURCES
from firmware_bridge.ticklog import log_file

BRIDGE_MODES = ("steer", "passthrough", "collect", "prefilter", "feedforward")


def check_output_paths(log: str | None, summary: str | None, overwrite: bool,
                       inputs: dict[str, str | None] | None = None) -> None:
    """Before anything connects: the files the run writes -- the tick log where it is saved (``.npz``
    normalised: ``--log X.log`` writes ``X.npz``) and the summary -- each absent or (with ``overwrite``) a
    regular file, in a folder that takes new files, not the same file and none of the run's ``inputs`` (flag ->
    path); ValueError (one line naming the flag) otherwise: a flight log is never replaced silently, nor
    discovered unwritable after the flight."""
    written = {}
    for flag, given, path in (("--log", log, log_file(log) if log else None), ("--summary", summary, summary)):
        if not given:
            continue
        what = flag if str(path) == str(given) else f"{flag} {given}"
        written[flag] = checked_output_file(path, what, overwrite=overwrite, error=ValueError)
    if len(written) == 2 and written["--log"] == written["--summary"]:
        raise ValueError(f"{summary}: --summary: the same file as --log {log} (it would replace the tick log)")
    for flag, path in written.items():
        for source, given in (inputs or {}).items():
            if given and Path(given).resolve() == path:
                raise ValueError(f"{path}: {flag}: the {source} file (the run's input would be replaced)")


__all__ = ["BridgeConfig", "FaultInjectingSolver", "FlightError", "NoVehicleError", "default_controller_config"]


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
        mode: "steer" (DDPC on; needs ``solver``), "passthrough" (baseline), "collect" (PRBS),
            "prefilter" (the static gain + offset + lead baseline; needs ``prefilter``),
            "feedforward" (r_nom + a learned table indexed by trajectory tick; needs ``feedforward``).
        solver: folder of a generated solver (``ddpc-codegen codegen``), steer mode.
        prefilter: prefilter JSON file (:meth:`ddpc_codegen.design.baselines.PrefilterModel.save`),
            prefilter mode.
        feedforward: feed-forward table npz (:meth:`ddpc_codegen.runtime.baselines.FeedforwardPolicy.save`,
            clock "trajectory", dt = 1 / rate_hz, one column per reference), feedforward mode.
        autopilot: "px4" or "ardupilot" (checked against the vehicle's heartbeat before anything is sent).
        guid_options: ArduPilot GUID_OPTIONS expected (None: the vehicle's value, read before engaging);
            force_guid_options: encode for ``guid_options`` even if the vehicle disagrees.
        sysid, compid: our identity; target_system / target_component: the vehicle (0: first seen).
        vehicle_address: udpin: the vehicle's (IPv4 address, port); None: pinned to its first heartbeat.
        signing_key: a 32-byte MAVLink 2 signing key (None: unsigned link).
        rate_hz: control rate (must match the solver's dt and the controller's dt).
        attitude_stream / position_stream: telemetry messages to request.
        position_source: the measured position: "autopilot" (its estimate, from ``position_stream``) or "mocap"
            (the motion-capture poses received on ``mocap``; :mod:`.position_source`).
        mocap: the link the motion-capture poses arrive on (``udpin:HOST:PORT``; None: none); with source
            "autopilot" they are logged beside the estimate.
        max_age: telemetry older than this [s] -> stop steering, stale action.
        stale_action: "reference" (controller on the newest telemetry, unsteered), "hover"
            (level, hover thrust / climb rate 0), "land" (like hover and, with ``offboard``,
            request the autopilot's LAND mode).
        stale_stream_limit: stop streaming after telemetry has been stale this long [s] so the
            autopilot's off-board-loss failsafe takes over (0: never stop).
        link_timeout: nothing heard from the vehicle (heartbeat or telemetry) for this long [s] -> link lost.
        vehicle_lost_timeout: the link lost this long [s] -> the flight ends ("vehicle lost", exit 7).
        max_tilt_deg, thrust_min, thrust_max: clamps on the sent setpoint.
        max_step: (m,) largest |u_steered - u_nom| accepted per channel (None: no guard; hopping's
            default, as in the simulator's loop).
        guard_hold: steer: the steering's correction clamped at the ``max_step`` guard on every tick for this
            long [s] means the predictor no longer explains the vehicle (an unseen change it cannot absorb, a
            vehicle that stopped following its references): the steering is forgotten and refilled and the
            reference handed back toward the nominal one at the rate bound, an event and an entry of
            ``summary["guard_saturations"]``; 0: never (the clamp may then hold indefinitely).
        max_gap_fill: up to this many lost telemetry samples in a row are bridged in the steering
            history (reference held, outputs interpolated; :meth:`ReferenceSteerer.fill_gap`)
            instead of resetting it (a reset costs Tini unsteered ticks); 0: always reset.
        adapt: steer mode: online predictor updates from steered ticks (engaged, fresh, not a fallback) with
            the solver's [adapt] settings (a solver generated with [adapt] enabled); the tick log's ``adapt``
            column records every update and re-solve verdict.
        arm, offboard: explicitly allowed actions: arm the vehicle (once both telemetry streams
            arrive; retried every 2 s while refused, each refusal reported, :class:`FlightError`
            after ``arm_timeout`` s); switch it to OFFBOARD / GUIDED after ``prestream`` seconds of
            setpoints (and HOLD at exit / LAND if stale).
        takeoff: at the first engagement, ramp the height reference at ``climb_rate`` [m/s] from
            where the vehicle is to the trajectory's start height, then start the trajectory once the
            height held within ``approach_tolerance`` [m] for 1 s, or ``approach_timeout`` s after the
            ramp ended (then with a warning: the vehicle, or its height estimate, did not settle).
            The default tolerance, 0.1 m, is above the passthrough controller's steady-state height
            error at the start on the SITLs, so a hovering vehicle starts after its 1 s hold instead
            of on the timeout.
        land: at exit hand the vehicle back with LAND (and wait up to 60 s for it to disarm)
            instead of HOLD.
        blend_rates: bumpless (re-)engagement: the applied references start at the measured
            outputs and approach the nominal ones at most this fast per channel ((m/s, rad/s) for
            flying); None: no blending (hopping: the policy's fade-in is the bumpless transfer, a
            blend toward an arc or a stance reference would fight the hop).
        duration: stop after this long in off-board [s] (None: until signalled).
        timeout: overall wall-clock limit [s] (None: none). wait_heartbeat: give up if no vehicle [s].
        lockstep: tick only on telemetry, controller time = vehicle time stamps.
        tick_margin: real time: the tick grid's phase locks to this long after the position sample's
            typical arrival (its late edge: the median plus three half interquartile ranges) [s] (None: the grid runs free at its first tick's phase; see :mod:`.phase_lock`).
        log: tick log path (.npz; an IODataset; another suffix is replaced by ``.npz``).
        summary: JSON summary path. An existing log or summary file is refused unless ``overwrite``.
        dataset_skip: seconds after each activation left out of the dataset part of the log.
        settle: seconds after activation excluded from the RMSE in the summary.
        excitation, excitation_hold, seed: collect-mode PRBS amplitude per channel, hold [ticks], seed
            (hopping: in the air only; default (0.01, 0.02, 0.02) m, rad as in the simulator).
        inject_solver_failure: (first solve index, count[, "fail" | "nan"]) fault injection for tests.
        controller: ControllerConfig (default: :func:`default_controller_config`); ``mode =
            "hopping"`` makes the bridge hop (:mod:`.hopping`; profile ``pogox_hopping``).
        contact: hopping phase detection (the profile's ``[contact]``; default: estimated from
            telemetry with the controller's leg length).
        trajectory: EllipseTrajectory (default: the controller's default ellipse).
        frame: "start" (default: the trajectory starts where the robot is, along its heading, when
            it enters off-board; no turn, no jump) or "world" (trajectory coordinates are the
            autopilot's local ENU, commanded heading east). See :class:`.telemetry.TrajectoryFrame`.
        rt_priority: >0: run the loop SCHED_FIFO at this priority, with memory locked and a
            ``cpu_latency_us`` PM QoS request held (each if permitted; see :mod:`.realtime`).
        cpu_latency_us: PM QoS CPU wake-up latency bound [us] while real time (None: no request).
        cpus: pin the loop to these CPUs (None: any).
        envelope: what the last gate lets reach the vehicle (the profile's ``[envelope]``; None: defaults).
    """

    url: str = "udpin:127.0.0.1:14540"
    baud: int | None = None
    mode: str = "steer"
    solver: str | None = None
    prefilter: str | None = None
    feedforward: str | None = None
    autopilot: str = "px4"
    guid_options: int | None = None
    force_guid_options: bool = False
    sysid: int = 1
    compid: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
    target_system: int = 1
    target_component: int = 1
    vehicle_address: tuple[str, int] | None = None
    signing_key: bytes | None = field(default=None, repr=False)
    rate_hz: float = 200.0
    attitude_stream: str = "ATTITUDE_QUATERNION"
    position_stream: str = "LOCAL_POSITION_NED"
    position_source: str = "autopilot"
    mocap: str | None = None
    max_age: float = 0.050
    stale_action: str = "reference"
    stale_stream_limit: float = 1.0
    link_timeout: float = 3.0
    vehicle_lost_timeout: float = 10.0
    max_tilt_deg: float = 30.0
    thrust_min: float = 0.0
    thrust_max: float = 1.0
    max_step: tuple | None = (0.3, 0.5)
    guard_hold: float = 1.0
    max_gap_fill: int = 3
    adapt: bool = False
    arm: bool = False
    offboard: bool = False
    arm_timeout: float = 120.0
    takeoff: bool = False
    climb_rate: float = 0.5
    approach_timeout: float = 5.0
    approach_tolerance: float = 0.1
    land: bool = False
    blend_rates: tuple | None = (0.5, 0.5)
    prestream: float = 1.0
    duration: float | None = None
    timeout: float | None = None
    wait_heartbeat: float = 30.0
    lockstep: bool = False
    tick_margin: float | None = 200e-6
    log: str | None = None
    overwrite: bool = False
    summary: str | None = None
    dataset_skip: float = 0.0
    settle: float = 3.0
    excitation: tuple = (0.05, 0.03)
    excitation_hold: int = 4
    seed: int = 0
    inject_solver_failure: tuple | None = None
    controller: ControllerConfig | None = None
    contact: ContactConfig | None = None
    trajectory: EllipseTrajectory | None = None
    frame: str = "start"
    rt_priority: int = 0
    cpu_latency_us: int | None = 0
    cpus: tuple | None = None
    verbose: bool = False
    envelope: Envelope | None = None

    def __post_init__(self) -> None:
        check_bridge_values(self)
        check_output_paths(self.log, self.summary, self.overwrite,
                           {"--prefilter": self.prefilter, "--feedforward": self.feedforward})
        if self.mode not in BRIDGE_MODES:
            raise ValueError(f"mode must be one of {', '.join(BRIDGE_MODES)}; got {self.mode!r}")
        if self.mode == "steer" and not self.solver:
            raise ValueError("steer mode needs a generated solver folder (--solver generated/<name>)")
        if self.mode == "prefilter" and not self.prefilter:
            raise ValueError("prefilter mode needs a prefilter JSON file (--prefilter prefilter.json)")
        if self.mode == "feedforward":
            if not self.feedforward:
                raise ValueError("feedforward mode needs a feed-forward table (--feedforward table.npz)")
            if self.scenario != "flying":
                raise ValueError("feedforward mode flies the flying scenario (the hopping ILC runs in-process)")
        if self.stale_action not in ("reference", "hover", "land"):
            raise ValueError(f"stale_action must be reference, hover or land; got {self.stale_action!r}")
        if not (self.rate_hz > 0 and self.max_age > 0):
            raise ValueError("rate_hz and max_age must be positive")
        for key in ("climb_rate", "approach_timeout", "approach_tolerance"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key} must be positive; got {getattr(self, key)!r}")
        if not 0.0 <= self.thrust_min < self.thrust_max <= 1.0:
            raise ValueError("need 0 <= thrust_min < thrust_max <= 1")
        if self.tick_margin is not None and not 0.0 <= self.tick_margin < 0.5 / self.rate_hz:
            raise ValueError(f"tick_margin must be in [0, half the period); got {self.tick_margin!r} s")
        if not isinstance(self.max_gap_fill, int) or self.max_gap_fill < 0:
            raise ValueError(f"max_gap_fill must be an integer >= 0; got {self.max_gap_fill!r}")
        if self.frame not in ("start", "world"):
            raise ValueError(f"frame must be 'start' or 'world'; got {self.frame!r}")
        self._check_position_source()
        if self.scenario == "hopping":
            self._hopping_defaults()
        self._check_channel_values()
        # Before anything connects: every input that defines the path, as a path (the feed-forward table's
        # clock, tick and columns too), against the envelope (the profile's, else the shipped one's).
        if self.envelope is None:
            self.envelope = default_envelope(self.scenario)
        check_flight_paths(self, self.controller or default_controller_config(),
                           (self.trajectory or EllipseTrajectory()) if self.scenario == "flying" else None)

    def reference_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of each applied reference: the envelope's height range, angles within the controller's
        ``max_tilt`` (the last gate's bounds)."""
        ctrl = self.controller or default_controller_config()
        return (self.envelope or Envelope()).reference_bounds(self.scenario, ctrl.max_tilt)

    @property
    def scenario(self) -> str:
        """"flying" or "hopping" (the controller's mode)."""
        return self.controller.mode if self.controller is not None else "flying"

    def _hopping_defaults(self) -> None:
        """The flying defaults have two channels; on the three-channel hopping loop they can only be
        defaults, replaced by hopping's (no step guard, no blend, the simulator's PRBS)."""
        for key, hop in (("max_step", None), ("blend_rates", None), ("excitation", _HOP_EXCITATION)):
            if getattr(self, key) == _FLYING_DEFAULTS[key]:
                setattr(self, key, hop)
        if self.takeoff:
            raise ValueError("takeoff is for flying: hopping is released from where the robot hovers")

    def _check_position_source(self) -> None:
        """The position source and the mocap link: one line naming the flag when they cannot work."""
        if self.position_source not in POSITION_SOURCES:
            raise ValueError(f"--position-source must be one of {', '.join(POSITION_SOURCES)}; got {self.position_source!r}")
        if self.position_source == "mocap" and not self.mocap:
            raise ValueError("--position-source mocap needs the link the poses arrive on (--mocap udpin:HOST:PORT)")
        if self.mocap:
            try:
                parse_url(self.mocap)
            except ValueError as e:
                raise ValueError(f"--mocap: {e}") from None
            if self.mocap == self.url:
                raise ValueError(f"--mocap {self.mocap}: the vehicle's link (the poses need a port of their own)")
        if self.position_source == "mocap" and self.lockstep:
            raise ValueError("--position-source mocap runs on the wall clock; --lockstep ticks on the vehicle's stamps")

    def _check_channel_values(self) -> None:
        """One value per reference channel, finite; a step guard or blend rate of 0 or below would
        refuse every steered tick (NaN: never), an excitation below 0 has no meaning."""
        for key, zero_ok in (("max_step", False), ("blend_rates", False), ("excitation", True)):
            setattr(self, key, check_per_reference(key, getattr(self, key), self.scenario, zero_ok=zero_ok))


_FLYING_DEFAULTS = {"max_step": (0.3, 0.5), "blend_rates": (0.5, 0.5), "excitation": (0.05, 0.03)}
_HOP_EXCITATION = (0.01, 0.02, 0.02)


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
