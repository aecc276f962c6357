"""Telemetry of the simulated vehicle: stream rates, message encoding, and real autopilots'
irregular sample patterns.

Streams (ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED, ODOMETRY; NED / FRD) go out at
the rates asked for with MAV_CMD_SET_MESSAGE_INTERVAL, all messages of one tick in one
datagram. Which *samples* exist is the pattern's business (stamps are whole milliseconds of
vehicle boot time; every sample is the measured state at its stamp, delayed and noisy):

``regular``
    one sample per 5 ms tick, stamped with the tick's time (the simulator's own loop).
``px4-sih``
    PX4 SITL with SIH, default settings: samples on a 4 ms grid, consecutive stamps 4, 8, 12 or
    16 ms apart (about 118 distinct samples per second, not 200); a stream asked for at 200 Hz
    sends each new sample once, so many ticks carry nothing new (and a few carry two).
``ardupilot``
    ArduCopter SITL: about 171 samples per second, i.e. one 5 ms sample in ~7 missing (every
    ~6th arrives after a gap), and now and then a TCP-like burst: a sample is held back and
    goes out together with the next one (two samples arriving < 0.5 ms apart).

This module does not import the simulator: it publishes whatever measured state it is given.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ddpc_codegen.robot.state import MeasuredState
from ddpc_codegen.robot.frames import (
    euler_ned_from_enu,
    frd_from_flu,
    ned_from_enu,
    quat_from_euler,
    quat_ned_frd_from_enu_flu,
    rotate_inverse,
)

from firmware_bridge.link import MavLink, mavlink

__all__ = ["STREAM_IDS", "TELEMETRY_PATTERNS", "SamplePattern", "TelemetryPublisher"]

STREAM_IDS = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: "ATTITUDE",
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: "ATTITUDE_QUATERNION",
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "LOCAL_POSITION_NED",
    mavlink.MAVLINK_MSG_ID_ODOMETRY: "ODOMETRY",
}
TELEMETRY_PATTERNS = ("regular", "px4-sih", "ardupilot")

# px4-sih: gaps of 1..4 grid steps of 4 ms; mean 8.4 ms -> ~119 samples/s (measured on PX4 SIH: ~118).
_PX4_GRID_MS = 4
_PX4_STEP_P = (0.3, 0.4, 0.2, 0.1)
# ardupilot: a 5 ms sample is missing with probability 1/7 (~171 Hz); a held-back sample (burst)
# with probability 0.05.
_ARDU_MISS_P = 1.0 / 7.0
_ARDU_BURST_P = 0.05


class SamplePattern:
    """Which telemetry samples exist at each tick (see the module docstring).

    Args:
        kind: one of :data:`TELEMETRY_PATTERNS`.
        seed: seeds the pattern's own generator (independent of the sensor noise).
    """

    def __init__(self, kind: str = "regular", seed: int = 0) -> None:
        if kind not in TELEMETRY_PATTERNS:
            raise ValueError(f"telemetry pattern must be one of {', '.join(TELEMETRY_PATTERNS)}; got {kind!r}")
        self.kind = kind
        self.rng = np.random.default_rng(seed)
        self._next_ms = 0  # px4-sih: stamp of the next sample on the 4 ms grid
        self._held: list[int] = []  # ardupilot: samples held back for a burst

    def samples(self, now_ms: int) -> list[int]:
        """Stamps [ms] of the samples to send at the tick at ``now_ms``, oldest first (may be empty)."""
        if self.kind == "regular":
            return [now_ms]
        if self.kind == "px4-sih":
            out = []
            while self._next_ms <= now_ms:  # every sample since the last tick (two 4 ms apart can share one)
                out.append(self._next_ms)
                self._next_ms += _PX4_GRID_MS * (1 + int(self.rng.choice(4, p=_PX4_STEP_P)))
            return out
        # ardupilot
        if self.rng.random() < _ARDU_MISS_P:
            return []
        if not self._held and self.rng.random() < _ARDU_BURST_P:
            self._held.append(now_ms)
            return []
        out, self._held = self._held + [now_ms], []
        return out


class TelemetryPublisher:
    """Stream intervals and message encoding of the simulated vehicle.

    Args:
        link: the vehicle's MAVLink endpoint.
        default_rates: message name -> rate [Hz] before anyone asks (and after interval 0).
        pattern: which samples exist (:class:`SamplePattern`).
        contact_name: also send each sample's foot-contact flag as a NAMED_VALUE_INT of this
            name, stamped like the sample, ahead of its state messages (None: not sent).
    """

    def __init__(self, link: MavLink, default_rates: dict[str, float], pattern: SamplePattern,
                 contact_name: str | None = None) -> None:
        self.link = link
        self.contact_name = contact_name
        self.default_rates = dict(default_rates)
        self.pattern = pattern
        self.intervals: dict[str, float] = {n: 0.0 for n in STREAM_IDS.values()}  # [s], 0 = off
        for name, hz in default_rates.items():
            self.intervals[name] = 1.0 / hz if hz > 0 else 0.0
        self._next_due: dict[str, float] = {n: 0.0 for n in self.intervals}
        self.last_stamp_ms = -1  # newest sample stamp sent

    def set_interval(self, msg_id: int, interval_us: float, t: float) -> bool:
        """MAV_CMD_SET_MESSAGE_INTERVAL (param2: -1 off, 0 default, else [us]) at vehicle time t [s].
        Returns False for a message this vehicle does not stream."""
        name = STREAM_IDS.get(int(msg_id))
        if name is None:
            return False
        if interval_us == -1:
            self.intervals[name] = 0.0
        elif interval_us == 0:
            hz = self.default_rates.get(name, 0.0)
            self.intervals[name] = 1.0 / hz if hz > 0 else 0.0
        else:
            self.intervals[name] = max(interval_us * 1e-6, 0.0)
        self._next_due[name] = t
        return True

    def publish(self, t: float, measure: Callable[[float], MeasuredState]) -> list[int]:
        """Send the due streams at vehicle time t [s]; ``measure(age)`` gives the measured state of
        a sample ``age`` seconds old. Returns the sample stamps sent [ms] (empty: nothing new)."""
        due = [name for name, iv in self.intervals.items() if iv > 0.0 and t + 1e-9 >= self._next_due[name]]
        if not due:
            return []
        now_ms = int(round(t * 1000.0))
        stamps = self.pattern.samples(now_ms)
        if not stamps:
            return []  # nothing new: the due streams stay due until a sample exists
        for name in due:
            iv = self.intervals[name]
            nd = self._next_due[name] + iv
            self._next_due[name] = nd if nd > t else t + iv
        out = []
        for ms in stamps:
            st = measure((now_ms - ms) * 1e-3)
            if self.contact_name:
                out.append(self.link.mav.named_value_int_encode(ms, self.contact_name.encode(), int(st.contact)))
            out += encode_state(self.link.mav, due, ms, st)
        self.link.send_many(out)  # one datagram per tick
        self.last_stamp_ms = stamps[-1]
        return stamps


def encode_state(mav, names: list[str], ms: int, st: MeasuredState) -> list:
    """MAVLink messages ``names`` (NED / FRD) of the measured state st (ENU / FLU) stamped ms."""
    p_ned = tuple(float(v) for v in ned_from_enu(st.position))
    v_ned = tuple(float(v) for v in ned_from_enu(st.velocity))
    w_frd = tuple(float(v) for v in frd_from_flu(st.body_rates))
    q_ned = None
    out = []
    for name in names:
        if name == "ATTITUDE":
            r, p, y = euler_ned_from_enu(st.euler)
            msg = mav.attitude_encode(ms, r, p, y, *w_frd)
        elif name in ("ATTITUDE_QUATERNION", "ODOMETRY"):
            if q_ned is None:
                q_ned = tuple(float(v) for v in quat_ned_frd_from_enu_flu(quat_from_euler(*st.euler)))
            if name == "ATTITUDE_QUATERNION":
                msg = mav.attitude_quaternion_encode(ms, *q_ned, *w_frd, (0.0, 0.0, 0.0, 0.0))
            else:
                v_body = rotate_inverse(q_ned, v_ned)
                nan21 = [math.nan] * 21
                msg = mav.odometry_encode(ms * 1000, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                                          *p_ned, list(q_ned), *v_body, *w_frd, nan21, nan21,
                                          0, mavlink.MAV_ESTIMATOR_TYPE_MOCAP, 100)
        else:
            msg = mav.local_position_ned_encode(ms, *p_ned, *v_ned)
        out.append(msg)
    return out

