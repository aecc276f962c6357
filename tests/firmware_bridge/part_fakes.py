"""Stand-ins for the companion loop's unit tests: a MAVLink link without a socket, and messages as a vehicle
sends them (packed, so they carry their sender)."""

from __future__ import annotations

from firmware_bridge.events import EventLog
from firmware_bridge.link import mavlink
from firmware_bridge.plausibility import TIMELINE_SAMPLES
from firmware_bridge.profiles import make_profile
from firmware_bridge.telemetry import TelemetryState
from firmware_bridge.vehicle_link import VehicleLink

_VEHICLE = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
OFFBOARD = 6 << 16  # PX4 main mode OFFBOARD in HEARTBEAT.custom_mode


class FakeLink:
    """The :class:`~firmware_bridge.link.MavLink` interface the loop uses, in memory: ``inbox`` is what the
    vehicle sent (drained by the loop), ``sent`` what the loop sent, ``commands`` its COMMAND_LONGs."""

    def __init__(self) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.inbox: list[tuple[object, float]] = []
        self.sent: list[object] = []
        self.commands: list[tuple[int, tuple]] = []
        self.heartbeats = 0
        self.target_system, self.target_component = 1, 1
        self.endpoint = "fake"
        self.stats: dict = {}
        self.foreign_systems: set = set()
        self.closed = False

    def send(self, msg) -> bool:
        self.sent.append(msg)
        return True

    def drain(self):
        out, self.inbox = self.inbox, []
        return out

    def wait(self, timeout: float) -> bool:
        return bool(self.inbox)

    def poll(self, now: float | None = None) -> bool:
        return False

    def send_heartbeat(self) -> None:
        self.heartbeats += 1

    def command_long(self, command: int, params, confirmation: int = 0, target=None) -> bool:
        self.commands.append((command, tuple(params)))
        return True

    def close(self) -> None:
        self.closed = True


def from_vehicle(msg):
    """``msg`` as received from system 1."""
    msg.pack(_VEHICLE)
    return msg


def heartbeat(armed: bool = True, offboard: bool = True):
    base = ARMED if armed else mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    return from_vehicle(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
                                                          base, OFFBOARD if offboard else 4 << 16, 0, 3))


def telemetry(t: float, z: float = 1.0):
    """An ATTITUDE_QUATERNION and a LOCAL_POSITION_NED sample stamped ``t`` [s] at height ``z`` [m]."""
    ms = int(round(t * 1000))
    return (from_vehicle(mavlink.MAVLink_attitude_quaternion_message(ms, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                                                     [0.0, 0.0, 0.0, 0.0])),
            from_vehicle(mavlink.MAVLink_local_position_ned_message(ms, 0.0, 0.0, -z, 0.0, 0.0, 0.0)))


def line(t: float, z: float = 1.0, n: int = TIMELINE_SAMPLES, dt: float = 0.005):
    """``n`` :func:`telemetry` pairs ``dt`` [s] apart up to ``t`` [s]: a time line the bridge uses (a stream's stamps
    are the vehicle's once ``TIMELINE_SAMPLES`` samples advanced on it; one pair alone is no reference yet)."""
    return [m for k in range(n) for m in telemetry(t - (n - 1 - k) * dt, z)]


def ack(command: int, result: int = mavlink.MAV_RESULT_ACCEPTED):
    return from_vehicle(mavlink.MAVLink_command_ack_message(command, result, 0, 0, 255, 190))


def vehicle(link: FakeLink | None = None, events: EventLog | None = None, **kw) -> VehicleLink:
    """A PX4 :class:`VehicleLink` on a fake link (no prestream: a mode request may follow the first setpoint)."""
    kw = {"rate_hz": 200.0, "link_timeout": 0.5, **kw}
    return VehicleLink(link or FakeLink(), make_profile("px4", prestream=0.0), TelemetryState(),
                       events or EventLog(t0=0.0), **kw)
