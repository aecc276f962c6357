"""Companion-computer side: runs a generated steering solver in the loop over MAVLink.

Everything here runs on the companion computer (no CasADi, no simulator); the simulated vehicle,
the SITL harness and the demos live in :mod:`ddpc_codegen.testbed`.

* :mod:`.transports` -- connection strings; UDP / TCP / serial byte transports with receive times.
* :mod:`.link` -- MAVLink I/O: drain-everything receive path, system-id
  filtering, reply pinning, reconnects, COMMAND_LONG retries.
* :mod:`.profiles` -- PX4 / ArduPilot Copter mode encoding and SET_ATTITUDE_TARGET thrust semantics.
* :mod:`.telemetry` -- NED/FRD telemetry -> the controller's ENU/FLU state (newest sample, age).
* :mod:`.truth` -- the simulators' ground truth (ArduCopter SIM_STATE) beside the estimate;
  :mod:`.truth_refine` -- the truth below its message's grid and on the autopilot's clock.
* :mod:`.preflight` -- before the first tick: the heartbeat's autopilot, parameters, thrust semantics.
* :mod:`.bridge_config` -- the bridge's settings (``BridgeConfig``), checked on construction.
* :mod:`.baseline_modes` -- the prefilter and feedforward (ILC table) modes, checked before flying.
* :mod:`.steering_setup` -- the mode's set-up: the solver, its checks, the steering policy, the reference stage.
* :mod:`.realtime` -- SCHED_FIFO, mlockall, PM QoS for the loop; wake-up latency probe (``ddpc-rtcheck``).
* :mod:`.cli`, :mod:`.cli_args` -- the ``ddpc-bridge`` console entry point and its value types.

The companion loop's parts (each a class with one job, built and tested alone; a second front end composes
the same ones):

* :mod:`.vehicle_link` -- one vehicle as the loop sees it: messages in, heartbeats, streams, parameters,
  reboots, link loss; :mod:`.mode_requests` -- arming, the off-board mode, LAND, the hand-back at exit.
* :mod:`.clock` -- the loop's own tick grid, or lock-step on telemetry (:class:`~.clock.TickTrigger`);
  :mod:`.phase_lock` -- the grid's phase locked to the telemetry's arrivals (the period unchanged).
* :mod:`.engagement` -- engagement edges, the trajectory clock, take-off, bumpless blends, staleness.
* :mod:`.reference_stage` -- nominal reference -> the mode's reference (a frozen ``TickReference``);
  :mod:`.hopping_loop` -- hopping's phases and ground-phase windows; :mod:`.excitation` -- collect's PRBS.
* :mod:`.tick_gate` -- the last gate (over :mod:`.gate`): finite, rate-limited, in the envelope; guard
  clamp and saturation; stalls; tilt / thrust clamps.
* :mod:`.setpoints` -- the attitude setpoints besides the controller's and the SET_ATTITUDE_TARGET stream.
* :mod:`.report` -- the record: tick-log rows, the tick log (:mod:`.ticklog`, an IODataset ``.npz``), the
  summary; :mod:`.events` -- the timestamped events.
* :mod:`.bridge` -- the 200 Hz loop (``ddpc-bridge``) that owns them: steer / passthrough / collect / baselines.
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> module that defines it (imported on first use: ``import firmware_bridge`` stays
# light and never loads CasADi or the simulator)
_EXPORTS: dict[str, str] = {
    "Bridge": "firmware_bridge.bridge",
    "BridgeConfig": "firmware_bridge.bridge",
    "FaultInjectingSolver": "firmware_bridge.bridge",
    "NoVehicleError": "firmware_bridge.bridge",
    "CommandTracker": "firmware_bridge.link",
    "LinkError": "firmware_bridge.link",
    "MavLink": "firmware_bridge.link",
    "parse_url": "firmware_bridge.link",
    "ArduPilotProfile": "firmware_bridge.profiles",
    "PX4Profile": "firmware_bridge.profiles",
    "make_profile": "firmware_bridge.profiles",
    "HoppingLoop": "firmware_bridge.hopping_loop",
    "TelemetryState": "firmware_bridge.telemetry",
    "TickLog": "firmware_bridge.ticklog",
    "load_ticklog": "firmware_bridge.ticklog",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'firmware_bridge' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
