"""A minimal PX4 ULog writer for tests, following the documented file format
(https://docs.px4.io/main/en/dev_log/ulog_file_format.html), independent of pyulog's writer.

File = 16-byte header (magic ``ULog\\x01\\x12\\x35``, version 1, uint64 start timestamp µs),
definitions section (flag bits 'B' first, then formats 'F', info 'I', parameters 'P'),
data section (subscriptions 'A', data 'D', logging 'L', dropouts 'O', sync 'S').
Every message is ``uint16 msg_size, uint8 msg_type`` + payload, little-endian.
"""

from __future__ import annotations

import heapq
import struct
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
SYNC_MAGIC = b"\x2f\x73\x13\x20\x25\x0c\xbb\x12"
_CODES = {
    "int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H", "int32_t": "i", "uint32_t": "I",
    "int64_t": "q", "uint64_t": "Q", "float": "f", "double": "d", "bool": "?", "char": "c",
}

# Formats as PX4 v1.14 logs them (trimmed to the fields the importer and tests use, with
# PX4's explicit trailing padding so pyulog's padding handling is exercised).
PX4_FORMATS: dict[str, list[tuple[str, str]]] = {
    "vehicle_attitude": [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("float[4]", "q"),
                         ("float[4]", "delta_q_reset"), ("uint8_t", "quat_reset_counter"),
                         ("uint8_t[7]", "_padding0")],
    "vehicle_attitude_setpoint": [("uint64_t", "timestamp"), ("float", "yaw_sp_move_rate"), ("float[4]", "q_d"),
                                  ("float[3]", "thrust_body"), ("bool", "reset_integral"),
                                  ("bool", "fw_control_yaw_wheel"), ("uint8_t[2]", "_padding0")],
    "trajectory_setpoint": [("uint64_t", "timestamp"), ("float[3]", "position"), ("float[3]", "velocity"),
                            ("float[3]", "acceleration"), ("float[3]", "jerk"), ("float", "yaw"),
                            ("float", "yawspeed")],
    "vehicle_local_position": [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("bool", "xy_valid"),
                               ("bool", "z_valid"), ("uint8_t[2]", "_padding0"), ("float", "x"), ("float", "y"),
                               ("float", "z"), ("float", "vx"), ("float", "vy"), ("float", "vz"),
                               ("float", "heading"), ("uint8_t[4]", "_padding1")],
    "vehicle_status": [("uint64_t", "timestamp"), ("uint64_t", "armed_time"), ("uint8_t", "arming_state"),
                       ("uint8_t", "nav_state"), ("uint8_t[6]", "_padding0")],
    "offboard_control_mode": [("uint64_t", "timestamp"), ("bool", "position"), ("bool", "velocity"),
                              ("bool", "acceleration"), ("bool", "attitude"), ("bool", "body_rate"),
                              ("bool", "thrust_and_torque"), ("bool", "direct_actuator"), ("uint8_t[1]", "_padding0")],
}


def _split_type(t: str) -> tuple[str, int]:
    if "[" in t:
        base, n = t[:-1].split("[")
        return base, int(n)
    return t, 0


class ULogWriter:
    """Build a ULog file in memory: formats, info, parameters, subscriptions, data, logging."""

    def __init__(self, start_timestamp_us: int = 0, *, compat_flags: Sequence[int] = (0,) * 8,
                 incompat_flags: Sequence[int] = (0,) * 8) -> None:
        self.start = int(start_timestamp_us)
        self.compat = list(compat_flags)
        self.incompat = list(incompat_flags)
        self.formats: dict[str, list[tuple[str, int, str]]] = {}
        self.definitions: list[bytes] = []
        self.subscriptions: list[bytes] = []
        self.streams: dict[int, list[tuple[int, bytes]]] = {}  # msg_id -> [(timestamp, message)]
        self.extra: list[tuple[int, bytes]] = []  # logging / dropouts, by timestamp
        self._sub_format: dict[int, str] = {}

    @staticmethod
    def message(msg_type: str, payload: bytes) -> bytes:
        """One ULog message: uint16 size, uint8 type, payload."""
        return struct.pack("<HB", len(payload), ord(msg_type)) + payload

    # -------------------------------------------------------------- definitions
    def add_format(self, name: str, fields: Sequence[tuple[str, str]]) -> None:
        """'F': ``name:type field;type field;...`` (types like ``float[4]``)."""
        self.formats[name] = [(*_split_type(t), f) for t, f in fields]
        text = name + ":" + "".join(f"{t} {f};" for t, f in fields)
        self.definitions.append(self.message("F", text.encode()))

    def add_px4_format(self, name: str) -> None:
        self.add_format(name, PX4_FORMATS[name])

    @staticmethod
    def _key_value(key: str, value) -> bytes:
        if isinstance(value, str):
            raw = value.encode()
            kt = f"char[{len(raw)}] {key}".encode()
        elif isinstance(value, bool) or isinstance(value, (int, np.integer)):
            raw = struct.pack("<i", int(value))
            kt = f"int32_t {key}".encode()
        else:
            raw = struct.pack("<f", float(value))
            kt = f"float {key}".encode()
        return struct.pack("<B", len(kt)) + kt + raw

    def add_info(self, key: str, value: str | int | float) -> None:
        """'I': information message (``char[n]``, ``int32_t`` or ``float`` value)."""
        self.definitions.append(self.message("I", self._key_value(key, value)))

    def add_parameter(self, name: str, value: int | float) -> None:
        """'P': initial parameter value (``int32_t`` or ``float``)."""
        self.definitions.append(self.message("P", self._key_value(name, value)))

    # -------------------------------------------------------------- data section
    def add_subscription(self, name: str, multi_id: int = 0) -> int:
        """'A': subscribe a topic instance; returns its msg_id for data messages."""
        if name not in self.formats:
            self.add_px4_format(name)
        msg_id = len(self._sub_format)
        self._sub_format[msg_id] = name
        self.subscriptions.append(self.message("A", struct.pack("<BH", multi_id, msg_id) + name.encode()))
        self.streams[msg_id] = []
        return msg_id

    def pack(self, name: str, values: Mapping[str, object]) -> bytes:
        """Payload of one sample of topic ``name``; missing fields (and padding) are zero.

        Trailing padding fields are not written: PX4's logger writes ``o_size_no_padding``
        bytes, and readers reject data messages longer than that.
        """
        fields = list(self.formats[name])
        while fields and fields[-1][2].startswith("_padding"):
            fields.pop()
        out = b""
        for base, n, fname in fields:
            code = _CODES[base]
            v = values.get(fname, 0)
            if n:
                arr = list(np.broadcast_to(np.asarray(v), (n,)).tolist())
                out += struct.pack("<" + code * n, *([bytes([0])] * n if code == "c" else arr))
            else:
                out += struct.pack("<" + code, v.item() if isinstance(v, np.generic) else v)
        return out

    def add_data(self, msg_id: int, values: Mapping[str, object]) -> None:
        """'D': one sample; ``values['timestamp']`` (µs) is required."""
        name = self._sub_format[msg_id]
        payload = struct.pack("<H", msg_id) + self.pack(name, values)
        self.streams[msg_id].append((int(values["timestamp"]), self.message("D", payload)))

    def add_series(self, msg_id: int, timestamps: Sequence[int], **fields) -> None:
        """Many samples: each keyword is an array of (N,) or (N, k) values for a field."""
        for i, t in enumerate(timestamps):
            self.add_data(msg_id, {"timestamp": int(t), **{k: np.asarray(v)[i] for k, v in fields.items()}})

    def add_logging(self, timestamp: int, text: str, level: int = ord("6")) -> None:
        """'L': a logged string (level '0'..'7' as ASCII, '6' = INFO)."""
        self.extra.append((int(timestamp), self.message("L", struct.pack("<BQ", level, timestamp) + text.encode())))

    def add_dropout(self, timestamp: int, duration_ms: int) -> None:
        """'O': the logger lost ``duration_ms`` of data (placed at ``timestamp`` in the stream)."""
        self.extra.append((int(timestamp), self.message("O", struct.pack("<H", duration_ms))))

    # -------------------------------------------------------------- output
    def to_bytes(self) -> bytes:
        """The file. Data of all topics is interleaved by timestamp like a real logger's
        output, keeping each topic's own order (so a test can log a non-monotonic topic)."""
        head = MAGIC + struct.pack("<BQ", 1, self.start)
        flags = self.message("B", struct.pack("<8B8B3Q", *self.compat, *self.incompat, 0, 0, 0))
        body = b"".join(self.definitions) + b"".join(self.subscriptions)
        body += self.message("S", SYNC_MAGIC)
        streams = list(self.streams.values()) + [sorted(self.extra, key=lambda r: r[0])]
        body += b"".join(m for _, m in heapq.merge(*streams, key=lambda r: r[0]))
        return head + flags + body

    def write(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_bytes(self.to_bytes())
        return path


# ------------------------------------------------------------------ a synthetic PX4 flight
class SyntheticFlight:
    """Known signals, in µs since boot, logged the way PX4 would log them.

    Setpoints are piecewise constant (z_ref changes every 0.2 s, pitch_ref every 0.1 s), the
    states piecewise linear between knots that fall on logged samples (height knots every
    0.1 s, pitch knots every 0.2 s), yaw a ramp through +π. So the importer's rule (hold for
    setpoints, linear interpolation for states) must reproduce them exactly, up to float32.
    Offboard (nav_state 14) from t0 to 7 s, posctl 7..9 s, offboard again from 9 s.
    """

    start_us = 1_000_000
    t0 = 2_000_000
    t1 = 12_000_000
    roll_ = 0.01

    def __init__(self, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        n = (self.t1 - self.t0) // 100_000 + 2
        self.z_levels = 1.0 + 0.25 * rng.integers(0, 2, n)
        self.pitch_levels = 0.1 * rng.standard_normal(n)
        self.h_knots = 1.0 + 0.2 * rng.standard_normal(n)
        self.p_knots = 0.1 * rng.standard_normal(n)

    # truth
    def z_ref(self, t):
        return self.z_levels[(np.asarray(t) - self.t0) // 200_000]

    def pitch_ref(self, t):
        return self.pitch_levels[(np.asarray(t) - self.t0) // 100_000]

    def z(self, t):
        k = np.arange(self.h_knots.size) * 100_000 + self.t0
        return np.interp(np.asarray(t, dtype=float), k, self.h_knots)

    def pitch(self, t):
        k = np.arange(self.p_knots.size) * 200_000 + self.t0
        return np.interp(np.asarray(t, dtype=float), k, self.p_knots)

    def yaw(self, t):
        return 3.0 + 0.05 * (np.asarray(t, dtype=float) - self.t0) / 1e6  # crosses π at ~2.8 s

    # logged topics: name -> {"timestamp": (N,), field: (N,) or (N, k)}
    def topics(self) -> dict[str, dict[str, np.ndarray]]:
        from ddpc_codegen.robot.frames import quat_from_euler_array

        def ts(period):
            return np.arange(self.t0, self.t1 + 1, period, dtype=np.int64)

        t_sp, t_att_sp, t_lp, t_att = ts(20_000), ts(10_000), ts(10_000), ts(4_000)
        pos = np.zeros((t_sp.size, 3))
        pos[:, 2] = -self.z_ref(t_sp)  # NED: down
        t_st = np.array([self.t0, 4_500_000, 7_000_000, 8_000_000, 9_000_000, 10_500_000], dtype=np.int64)
        return {
            "trajectory_setpoint": {"timestamp": t_sp, "position": pos, "velocity": np.full((t_sp.size, 3), np.nan)},
            "vehicle_attitude_setpoint": {
                "timestamp": t_att_sp,
                "q_d": quat_from_euler_array(0.0, self.pitch_ref(t_att_sp), 0.3),
                "thrust_body": np.tile([0.0, 0.0, -0.55], (t_att_sp.size, 1)),
            },
            "vehicle_local_position": {"timestamp": t_lp, "timestamp_sample": t_lp - 1000, "z": -self.z(t_lp),
                                       "xy_valid": np.ones(t_lp.size, bool), "z_valid": np.ones(t_lp.size, bool)},
            "vehicle_attitude": {"timestamp": t_att, "timestamp_sample": t_att - 500,
                                 "q": quat_from_euler_array(self.roll_, self.pitch(t_att), self.yaw(t_att))},
            "vehicle_status": {"timestamp": t_st, "nav_state": np.array([14, 14, 2, 2, 14, 14]),
                               "arming_state": np.full(t_st.size, 2)},
        }


def write_ulog(path, topics: Mapping[str, Mapping[str, np.ndarray]], start_us: int = SyntheticFlight.start_us) -> Path:
    """Write topics (as returned by :meth:`SyntheticFlight.topics`; ``name@N`` = instance N)."""
    w = ULogWriter(start_us)
    w.add_info("sys_name", "PX4")
    w.add_info("ver_sw", "0123456789abcdef")
    w.add_parameter("MPC_THR_HOVER", 0.5)
    w.add_parameter("SDLOG_PROFILE", 1)
    for name, fields in topics.items():
        base = name.split("@")[0]
        mid = w.add_subscription(base, multi_id=int(name.split("@")[1]) if "@" in name else 0)
        t = fields["timestamp"]
        w.add_series(mid, t, **{k: v for k, v in fields.items() if k != "timestamp"})
    w.add_logging(SyntheticFlight.t0, "[commander] Armed by external command")
    return w.write(path)
