"""The simulator's true state, when the vehicle is a SITL that sends it: ArduPilot's SIM_STATE.

Kept in the tick log beside the EKF telemetry (``truth_*`` columns, nan without it) so that a
flight's error can be measured against the truth as well as against the autopilot's estimate;
never used for control. ArduCopter SITL sends SIM_STATE (id 108) only when asked
(SET_MESSAGE_INTERVAL; measured: 200/s when asked for 200 Hz, none otherwise).

SIM_STATE has no time stamp (ArduPilot sends it from the same loop as ATTITUDE / LOCAL_POSITION_NED):
a tick holds the newest one, like the telemetry, and logs its age. Its fields: ``lat`` / ``lon``
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.robot.frames import euler_enu_from_ned

__all__ = ["SimTruth", "EARTH_RADIUS_M"]

EARTH_RADIUS_M = 6378137.0  # WGS-84 equatorial radius (what ArduPilot's flat-earth offsets use)


@dataclass
class SimTruth:
    """The newest SIM_STATE in local ENU (nan until one arrives).

    Attributes:
        position: east, north, up [m] from (lat0, lon0) and the take-off altitude alt0.
        velocity: ENU [m/s]; euler: roll, pitch, yaw ENU / FLU [rad].
        rx: receive time of the newest sample [s, bridge clock]; seq: samples received.
        lat0, lon0: horizontal origin [deg] (first sample); alt0: take-off altitude [m AMSL].
    """

    position: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    velocity: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    euler: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    rx: float = -math.inf
    seq: int = 0
    lat0: float = math.nan
    lon0: float = math.nan
    alt0: float = math.nan
    _alt: float = math.nan

    @property
    def present(self) -> bool:
        return self.seq > 0

    def update(self, msg, rx: float) -> None:
        """Fold in one SIM_STATE message received at ``rx`` [s]."""
        lat, lon = _degrees(msg)
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(msg.alt)):
            return
        if not math.isfinite(self.lat0):
            self.lat0, self.lon0 = lat, lon
        if not math.isfinite(self.alt0):
            self.alt0 = float(msg.alt)  # until the take-off point is captured: the first sample
        self._alt = float(msg.alt)
        north = math.radians(lat - self.lat0) * EARTH_RADIUS_M
        east = math.radians(lon - self.lon0) * EARTH_RADIUS_M * math.cos(math.radians(self.lat0))
        self.position[:] = (east, north, self._alt - self.alt0)
        self.velocity[:] = (msg.ve, msg.vn, -msg.vd)
        self.euler[:] = euler_enu_from_ned((msg.roll, msg.pitch, msg.yaw))
        self.rx, self.seq = rx, self.seq + 1

    def capture_ground(self) -> None:
        """Heights count from where the vehicle is now (call while it stands disarmed)."""
        if math.isfinite(self._alt):
            self.alt0 = self._alt
            self.position[2] = 0.0

    def age(self, now: float) -> float:
        """Seconds since the newest sample arrived (inf before any)."""
        return now - self.rx

    def as_dict(self) -> dict | None:
        """For the tick log's metadata: the source and origin (None when nothing arrived)."""
        if not self.present:
            return None
        return {"source": "SIM_STATE", "samples": self.seq, "lat0_deg": self.lat0, "lon0_deg": self.lon0,
                "alt0_m": self.alt0, "frame": "local ENU from (lat0, lon0); up from the take-off altitude alt0"}


def _degrees(msg) -> tuple[float, float]:
    """Latitude, longitude [deg]: the degE7 integers when the message carries them (more exact)."""
    lat_i, lon_i = getattr(msg, "lat_int", 0), getattr(msg, "lon_int", 0)
    if lat_i or lon_i:
        return lat_i * 1e-7, lon_i * 1e-7
    return float(msg.lat), float(msg.lon)
