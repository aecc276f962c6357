"""A MAVLink telemetry-log writer for tests: records of an 8-byte big-endian µs timestamp
followed by one raw MAVLink packet, packets encoded by pymavlink (the format QGroundControl,
MAVProxy and mavutil's logfile write)."""

from __future__ import annotations

import struct

import numpy as np
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

UNIX_T0_US = 1_700_000_000_000_000  # a plausible wall-clock start (tlog stamps are Unix µs)


class TlogWriter:
    """Collect (timestamp, packet) records; ``encoder(sysid, compid)`` gives a pymavlink
    MAVLink object whose ``*_encode`` methods build messages."""

    def __init__(self) -> None:
        self.records: list[tuple[int, bytes]] = []
        self._mavs: dict[tuple[int, int], mavlink2.MAVLink] = {}

    def encoder(self, sysid: int = 1, compid: int = 1) -> mavlink2.MAVLink:
        key = (sysid, compid)
        if key not in self._mavs:
            self._mavs[key] = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        return self._mavs[key]

    def add(self, t_us: int, msg, sysid: int = 1, compid: int = 1, mavlink1: bool = False) -> None:
        """Append one message received at ``t_us`` (µs since the Unix epoch)."""
        mav = self.encoder(sysid, compid)
        buf = msg.pack(mav, force_mavlink1=mavlink1)
        mav.seq = (mav.seq + 1) % 256
        self.records.append((int(t_us), bytes(buf)))

    def add_raw(self, raw: bytes) -> None:
        """Append raw bytes (to corrupt a log on purpose)."""
        self.records.append((-1, raw))

    def to_bytes(self, sort: bool = True) -> bytes:
        """The file; ``sort`` orders records by timestamp (raw inserts need ``sort=False``)."""
        recs = self.records
        if sort:
            if any(t < 0 for t, _ in recs):
                raise ValueError("raw byte inserts have no timestamp: write with sort=False")
            recs = sorted(recs, key=lambda r: r[0])
        return b"".join(b if t < 0 else struct.pack(">Q", t) + b for t, b in recs)

    def write(self, path: str | Path, sort: bool = True) -> Path:
        path = Path(path)
        path.write_bytes(self.to_bytes(sort))
        return path


# ------------------------------------------------------------------ a synthetic MAVLink flight
class SyntheticMavlinkFlight:
    """Known signals on a MAVLink link (times in µs since the first record, stamped as Unix µs).

    Vehicle (sys 1, comp 1): HEARTBEAT 1 Hz (PX4 offboard 0..5 s, posctl 6..7 s, offboard
    8..10 s, armed), ATTITUDE 100 Hz (pitch piecewise linear, knots every 0.2 s),
    LOCAL_POSITION_NED 50 Hz (height piecewise linear, knots every 0.1 s).
    Companion (sys 1, comp 191): SET_ATTITUDE_TARGET 50 Hz (pitch_ref steps every 0.1 s),
    SET_POSITION_TARGET_LOCAL_NED 50 Hz (z_ref steps every 0.2 s, only position used).
    """

    t1 = 10_000_000
    vehicle_boot_us = 30_000_000  # vehicle booted 30 s before the log starts
    companion_boot_us = 7_000_000
    pos_mask = 0b1101_1111_1000  # ignore velocity, acceleration, yaw, yaw rate

    def __init__(self, seed: int = 1) -> None:
        rng = np.random.default_rng(seed)
        n = self.t1 // 100_000 + 2
        self.z_levels = 1.0 + 0.25 * rng.integers(0, 2, n)
        self.pitch_levels = 0.1 * rng.standard_normal(n)
        self.h_knots = 1.0 + 0.2 * rng.standard_normal(n)
        self.p_knots = 0.1 * rng.standard_normal(n)

    def z_ref(self, t):
        return self.z_levels[np.asarray(t) // 200_000]

    def pitch_ref(self, t):
        return self.pitch_levels[np.asarray(t) // 100_000]

    def z(self, t):
        return np.interp(np.asarray(t, dtype=float), np.arange(self.h_knots.size) * 100_000, self.h_knots)

    def pitch(self, t):
        return np.interp(np.asarray(t, dtype=float), np.arange(self.p_knots.size) * 200_000, self.p_knots)

    def writer(self, *, mavlink1_attitude: bool = False, ignore_position_at=(), vehicle_type: int = 2) -> TlogWriter:
        from ddpc_codegen.robot.frames import quat_from_euler_array

        w = TlogWriter()
        veh, comp = w.encoder(1, 1), w.encoder(1, 191)
        for s in range(0, self.t1 // 1_000_000 + 1):
            t = s * 1_000_000
            main = 3 if s in (6, 7) else 6
            w.add(UNIX_T0_US + t, veh.heartbeat_encode(vehicle_type, 12, 1 | 128, main << 16, 4), 1, 1)
            w.add(UNIX_T0_US + t + 1, comp.heartbeat_encode(18, 8, 0, 0, 4), 1, 191)
        for t in range(0, self.t1 + 1, 10_000):
            ms = (t + self.vehicle_boot_us) // 1000
            w.add(UNIX_T0_US + t, veh.attitude_encode(ms, 0.01, float(self.pitch(t)), 0.3, 0, 0, 0), 1, 1,
                  mavlink1=mavlink1_attitude)
        for t in range(0, self.t1 + 1, 20_000):
            ms = (t + self.vehicle_boot_us) // 1000
            w.add(UNIX_T0_US + t, veh.local_position_ned_encode(ms, 0, 0, -float(self.z(t)), 0, 0, 0), 1, 1)
            cms = (t + self.companion_boot_us) // 1000
            q = quat_from_euler_array(0.0, float(self.pitch_ref(t)), 0.3).tolist()
            w.add(UNIX_T0_US + t, comp.set_attitude_target_encode(cms, 1, 1, 0b111, q, 0, 0, 0, 0.55), 1, 191)
            mask = self.pos_mask | (0b111 if t in ignore_position_at else 0)
            w.add(UNIX_T0_US + t, comp.set_position_target_local_ned_encode(
                cms, 1, 1, 1, mask, 0, 0, -float(self.z_ref(t)), 0, 0, 0, 0, 0, 0, 0, 0), 1, 191)
        return w
