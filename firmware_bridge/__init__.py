"""Companion-computer side: runs a generated steering solver in the loop over MAVLink.

* :mod:`.link` -- MAVLink I/O: connection strings, drain-everything receive path, system-id
  filtering, reply pinning, reconnects, COMMAND_LONG retries.
* :mod:`.profiles` -- PX4 / ArduPilot Copter mode encoding and SET_ATTITUDE_TARGET thrust semantics.
* :mod:`.telemetry` -- NED/FRD telemetry -> the controller's ENU/FLU state (newest sample, age).
* :mod:`.bridge` -- the 200 Hz tick loop (``ddpc-bridge``): steer / passthrough / collect, safety.
* :mod:`.vehicle` -- the simulator behind a PX4-like MAVLink endpoint (``ddpc-vehicle``).
* :mod:`.realtime` -- SCHED_FIFO, mlockall, PM QoS for the loop; wake-up latency probe (``ddpc-rtcheck``).
* :mod:`.ticklog` -- the per-tick log, an IODataset ``.npz`` (collect -> dataset -> codegen -> steer).
* :mod:`.cli`, :mod:`.demo` -- console entry points and ``make bridge-demo``.
"""

from .bridge import Bridge, BridgeConfig, FaultInjectingSolver, NoVehicleError
from .link import CommandTracker, LinkError, MavLink, parse_url
from .profiles import ArduPilotProfile, PX4Profile, make_profile
from .telemetry import TelemetryState
from .ticklog import TickLog, load_ticklog
from .vehicle import SimVehicle, VehicleConfig

__all__ = [
    "Bridge",
    "BridgeConfig",
    "FaultInjectingSolver",
    "NoVehicleError",
    "MavLink",
    "LinkError",
    "CommandTracker",
    "parse_url",
    "PX4Profile",
    "ArduPilotProfile",
    "make_profile",
    "TelemetryState",
    "TickLog",
    "load_ticklog",
    "SimVehicle",
    "VehicleConfig",
]
