"""The simulator's true state, when the vehicle is a SITL that sends it: ArduPilot's SIM_STATE,
PX4 SIH's HIL_STATE_QUATERNION.

Kept in the tick log beside the EKF telemetry (``truth_*`` columns, nan without it) so that a
flight's error can be measured against the truth as well as against the autopilot's estimate;
never used for control. Both are sent only when asked (SET_MESSAGE_INTERVAL):

* ArduCopter SITL: SIM_STATE (id 108); measured: 200/s when asked for 200 Hz, none otherwise.
* PX4 SIH: HIL_STATE_QUATERNION (id 115), which PX4's mavlink module fills from SIH's ground-truth
  topics (``vehicle_global_position_groundtruth``, ``vehicle_attitude_groundtruth``); measured on
  the shared SIH build: none unless asked, ~50/s when asked for 50 Hz; ``time_usec`` 0. Its fields:
  ``lat`` / ``lon`` [degE7], ``alt`` [mm AMSL], ``vx`` / ``vy`` / ``vz`` [cm/s, NED],
  ``attitude_quaternion`` (w, x, y, z; body FRD -> NED). A real PX4 has no ground truth and
  does not send it.

Neither has a usable time stamp (each is sent from the same loop as the attitude / position
telemetry): a tick holds the newest one, like the telemetry, and logs its age. SIM_STATE's fields: ``lat`` / ``lon``
[deg] (``lat_int`` / ``lon_int`` [degE7] when the extension is present: float32 degrees resolve
only ~0.4 m of latitude and ~1.4 m of longitude at ArduPilot's test site, -35 / 149 deg), ``alt`` [m above mean sea level], ``vn`` / ``ve`` / ``vd`` [m/s, NED],
``roll`` / ``pitch`` / ``yaw`` [rad, body FRD w.r.t. NED]. Here they become local ENU like the
bridge's telemetry (:mod:`.telemetry`):

* east / north [m] from the first sample's latitude / longitude (flat earth, WGS-84 equatorial
  radius: < 1 mm error over the metres flown);
* up [m] = ``alt`` minus the take-off altitude ``alt0``, captured the way the trajectory frame
  captures the EKF's ``z0`` (while the vehicle is disarmed: where it stands), so the true height
  and the trajectory's heights count from the same ground;
* velocity ENU = (ve, vn, -vd); attitude as ENU / FLU Euler angles (``euler_enu_from_ned``).

The position is refined below the message's grid with the velocity (:class:`.truth_refine.Dequantizer`: SIM_STATE's
altitude comes in whole centimetres, truncated), and, given a ``partner`` (a stream with the autopilot's
``time_boot_ms`` sent from the truth's loop at its rate: ArduCopter's), each sample is placed on the autopilot's
clock, not on its arrival (:class:`.truth_refine.LinkClock`), the way the test bed's observer and motion-capture
stand-in read it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.robot.frames import euler_enu_from_ned, euler_from_quat
from firmware_bridge.truth_refine import DEG7_M, EARTH_RADIUS_M, TRUTH_GRID, Dequantizer, LinkClock

__all__ = ["SimTruth", "EARTH_RADIUS_M", "TRUTH_MESSAGES", "CLOCK_PARTNER"]

# The ground-truth message of each SITL (MAVLink id), by autopilot profile name.
TRUTH_MESSAGES = {"ardupilot": ("SIM_STATE", 108), "px4": ("HIL_STATE_QUATERNION", 115)}

# The stream that places ArduCopter's truth on its clock (sent from the same loop when asked at the same rate).
CLOCK_PARTNER = "LOCAL_POSITION_NED"


@dataclass
class SimTruth:
    """The newest SIM_STATE / HIL_STATE_QUATERNION in local ENU (nan until one arrives), refined below its grid.

    Attributes:
        position: east, north, up [m] from (lat0, lon0) and the take-off altitude alt0.
        velocity: ENU [m/s]; euler: roll, pitch, yaw ENU / FLU [rad].
        rx: time of the newest sample [s, receiver clock]: its loop's time on the autopilot's clock when a
            ``partner`` places it, else its arrival; seq: samples folded in.
        lat0, lon0: horizontal origin [deg] (first sample); alt0: take-off altitude [m AMSL] (the first
            sample's reported altitude until :meth:`capture_ground`, then the refined one there).
        partner: the message type whose ``time_boot_ms`` places the truth ("": arrival times).
    """

    position: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    velocity: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    euler: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    rx: float = -math.inf
    seq: int = 0
    lat0: float = math.nan
    lon0: float = math.nan
    alt0: float = math.nan
    source: str = ""
    partner: str = ""
    _alt: float = math.nan
    _fine: list[Dequantizer] = field(default_factory=list)  # east, north, altitude
    clock: LinkClock | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.partner and self.clock is None:
            self.clock = LinkClock()

    @classmethod
    def for_link(cls, autopilot: str, streams: Iterable[str]) -> SimTruth:
        """The truth as read beside the telemetry ``streams`` (asked at the truth's rate) from ``autopilot``
        ("ardupilot", "px4"): on ArduCopter's clock when LOCAL_POSITION_NED is one of them."""
        return cls(partner=CLOCK_PARTNER if autopilot == "ardupilot" and CLOCK_PARTNER in set(streams) else "")

    @property
    def present(self) -> bool:
        return self.seq > 0

    def update(self, msg, rx: float) -> None:
        """Fold in one message received at ``rx`` [s]: a SIM_STATE or HIL_STATE_QUATERNION, or the ``partner``
        (a truth sample waits up to the clock's pairing window for it)."""
        for m, t in [(msg, rx)] if self.clock is None else self.clock.place(msg, rx, self.partner):
            self._fold(m, t)

    def _fold(self, msg, t: float) -> None:
        """One truth sample at ``t`` [s] into the state (any other message: ignored)."""
        typ = msg.get_type()
        if typ not in TRUTH_GRID:
            return
        if typ == "HIL_STATE_QUATERNION":
            lat, lon, alt = msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3
            v_ned = (msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01)
            # the FRD -> NED quaternion's Euler angles are NED roll / pitch / yaw
            rpy = tuple(euler_from_quat(msg.attitude_quaternion))
        else:
            lat, lon = _degrees(msg)
            alt, v_ned, rpy = float(msg.alt), (msg.vn, msg.ve, msg.vd), (msg.roll, msg.pitch, msg.yaw)
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)) or (lat == 0 and lon == 0):
            return  # not yet valid (PX4 sends zeros before SIH has a position)
        if not math.isfinite(self.lat0):
            self.lat0, self.lon0 = lat, lon
            cos0 = math.cos(math.radians(lat))
            self._fine = [Dequantizer(DEG7_M * cos0, (-1.0, 1.0)), Dequantizer(DEG7_M, (-1.0, 1.0)),
                          Dequantizer(TRUTH_GRID[typ], (0.0, 1.0))]
        if not math.isfinite(self.alt0):
            self.alt0 = alt  # until the take-off point is captured: the first sample
        north = math.radians(lat - self.lat0) * EARTH_RADIUS_M
        east = math.radians(lon - self.lon0) * EARTH_RADIUS_M * math.cos(math.radians(self.lat0))
        self.velocity[:] = (v_ned[1], v_ned[0], -v_ned[2])
        east, north, self._alt = (f.update(q, float(v), t) for f, q, v in zip(self._fine, (east, north, alt),
                                                                               self.velocity))
        self.position[:] = (east, north, self._alt - self.alt0)
        self.euler[:] = euler_enu_from_ned(rpy)
        self.rx, self.seq, self.source = t, self.seq + 1, typ

    def capture_ground(self) -> None:
        """Heights count from where the vehicle is now (call while it stands disarmed)."""
        if math.isfinite(self._alt):
            self.alt0 = self._alt
            self.position[2] = 0.0
            # standing still the refined altitude is its cell's middle, as the motion-capture stand-in's ground (and
            # the observer's): heights count from the ground the lab setup's estimate counts from

    def age(self, now: float) -> float:
        """Seconds since the newest sample (its placed time, :attr:`rx`; inf before any)."""
        return now - self.rx

    def as_dict(self) -> dict | None:
        """For the tick log's metadata: the source and origin (None when nothing arrived)."""
        if not self.present:
            return None
        return {"source": self.source, "samples": self.seq, "lat0_deg": self.lat0, "lon0_deg": self.lon0,
                "alt0_m": self.alt0, "frame": "local ENU from (lat0, lon0); up from the take-off altitude alt0"}


def _degrees(msg) -> tuple[float, float]:
    """Latitude, longitude [deg]: the degE7 integers when the message carries them (more exact)."""
    lat_i, lon_i = getattr(msg, "lat_int", 0), getattr(msg, "lon_int", 0)
    if lat_i or lon_i:
        return lat_i * 1e-7, lon_i * 1e-7
    return float(msg.lat), float(msg.lon)
