"""Companion-computer side: runs a generated steering solver in the loop over MAVLink.

Everything here runs on the companion computer (no CasADi, no simulator); the simulated vehicle,
the SITL harness and the demos live in :mod:`ddpc_codegen.testbed`.

* :mod:`.transports` -- connection strings; UDP / TCP / serial byte transports with receive times.
* :mod:`.link` -- MAVLink I/O: drain-everything receive path, system-id
  filtering, reply pinning, reconnects, COMMAND_LONG retries.
* :mod:`.profiles` -- PX4 / ArduPilot Copter mode encoding and SET_ATTITUDE_TARGET thrust semantics.
* :mod:`.telemetry` -- NED/FRD telemetry -> the controller's ENU/FLU state (newest sample, age).
* :mod:`.truth` -- the simulators' ground truth (ArduCopter SIM_STATE) beside the estimate.
* :mod:`.clock` -- the bridge's own control clock: a uniform tick grid whatever the telemetry does.
* :mod:`.preflight` -- before the first tick: the heartbeat's autopilot, parameters, thrust semantics.
* :mod:`.engagement` -- arming retries, take-off ramp, bumpless (re-)engagement.
* :mod:`.supervisor` -- modes, arming, failsafe, fallbacks and hand-backs.
* :mod:`.setpoints` -- setpoint shaping: PRBS in collect mode, clamps, the SET_ATTITUDE_TARGET send.
* :mod:`.bridge_config` -- the bridge's settings (``BridgeConfig``), checked on construction.
* :mod:`.bridge` -- the 200 Hz tick loop (``ddpc-bridge``): steer / passthrough / collect, safety.
* :mod:`.baseline_modes` -- the prefilter and feedforward (ILC table) modes, checked before flying.
* :mod:`.hopping_loop` -- hopping: phases from telemetry or a contact signal, the hopping steering tick.
* :mod:`.realtime` -- SCHED_FIFO, mlockall, PM QoS for the loop; wake-up latency probe (``ddpc-rtcheck``).
* :mod:`.ticklog` -- the per-tick log, an IODataset ``.npz`` (collect -> dataset -> codegen -> steer).
* :mod:`.report` -- the flight summary.
* :mod:`.cli`, :mod:`.cli_args` -- the ``ddpc-bridge`` console entry point and its value types.
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
