"""Setpoint shaping of the bridge's tick: collect-mode PRBS on the references, the level hover
setpoint of the stale action, tilt / thrust clamps, and the SET_ATTITUDE_TARGET send (which also
marks the continuous stream PX4 wants before it accepts OFFBOARD). A mixin of :class:`Bridge`:
it reads the bridge's config, frame, profile and link."""

from __future__ import annotations

import math
import time

import numpy as np

from ddpc_codegen.robot.frames import quat_from_euler, quat_ned_frd_from_enu_flu

from firmware_bridge.link import mavlink

__all__ = ["SetpointShaping"]

# Body rates ignored: attitude + thrust (= 7).
_TYPE_MASK = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
              | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
              | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)


class SetpointShaping:
    """What goes out each tick, after the controller: excitation, clamps, the message."""

    _EXC_BLOCK = 12000  # samples of PRBS made at once (60 s at 200 Hz)

    def _excitation_block(self, index: int) -> np.ndarray:
        """Block ``index`` of the collect flight's PRBS, (block, m). The first is made before the tick loop
        starts (:meth:`prepare_excitation`): making it imports scipy.signal (~1 s), a stall on a tick."""
        from ddpc_codegen.design.data import prbs

        return prbs(self._EXC_BLOCK, self.m, amplitude=self._exc_amp, min_hold=self.cfg.excitation_hold,
                    seed=self.cfg.seed * 1009 + index)

    def prepare_excitation(self) -> None:
        """Make the first PRBS block now (collect mode), off the tick path."""
        self._exc = self._excitation_block(0)

    def _excitation(self) -> np.ndarray:
        j = self._k_exc % self._EXC_BLOCK
        if self._exc is None or (j == 0 and self._k_exc > 0):
            self._exc = self._excitation_block(self._k_exc // self._EXC_BLOCK)
        self._k_exc += 1
        return self._exc[j]

    def _level_setpoint(self) -> tuple[tuple, float, float]:
        """Level attitude at the trajectory frame's heading and hover thrust / zero climb rate."""
        q = quat_ned_frd_from_enu_flu(self.frame.to_world((1.0, 0.0, 0.0, 0.0)))
        thrust = min(max(self.hover_thrust, self.cfg.thrust_min), self.cfg.thrust_max)
        return q, thrust, self.profile.hover_field(thrust)

    def _ground_setpoint(self, z: float) -> tuple[tuple, float, float]:
        """Level, idle thrust (the lower clamp) / zero climb rate: what a disarmed vehicle is sent.
        A vehicle left in OFFBOARD by the previous flight (PX4 returns to it after LAND and disarm)
        flies the streamed setpoint the moment our ARM is accepted, up to a heartbeat (1 s) before
        we know it is armed; the controller's thrust toward the trajectory start then throws it up
        (measured on PX4 SIH: 1.5 m/s, the heights' origin captured 1.2 m in the air)."""
        q = quat_ned_frd_from_enu_flu(self.frame.to_world((1.0, 0.0, 0.0, 0.0)))
        thrust = self.cfg.thrust_min
        return q, thrust, self.profile.thrust_field(thrust, z, z)

    def _clamp(self, sp) -> tuple[tuple, float, tuple]:
        roll, pitch, yaw = (float(v) for v in sp.euler)
        lim = self.tilt_max
        q_enu = tuple(float(v) for v in sp.q)
        if abs(roll) > lim or abs(pitch) > lim or not (math.isfinite(roll) and math.isfinite(pitch)):
            self.counts["tilt_clamped"] += 1
            roll = max(-lim, min(lim, roll)) if math.isfinite(roll) else 0.0
            pitch = max(-lim, min(lim, pitch)) if math.isfinite(pitch) else 0.0
            q_enu = tuple(float(v) for v in quat_from_euler(roll, pitch, yaw if math.isfinite(yaw) else 0.0))
        thrust = float(sp.thrust)
        lo, hi = self.cfg.thrust_min, self.cfg.thrust_max
        if not math.isfinite(thrust):
            thrust = self.hover_thrust
            self.counts["thrust_clamped"] += 1
        if thrust < lo or thrust > hi:
            self.counts["thrust_clamped"] += 1
            thrust = min(max(thrust, lo), hi)
        return quat_ned_frd_from_enu_flu(self.frame.to_world(q_enu)), thrust, (roll, pitch, yaw)

    def _send_setpoint(self, q_ned: tuple, field: float, stamp_ms: int) -> bool:
        lk = self.link
        msg = lk.mav.set_attitude_target_encode(
            stamp_ms & 0xFFFFFFFF, lk.target_system or 0, lk.target_component or 0, _TYPE_MASK,
            list(q_ned), 0.0, 0.0, 0.0, float(field))
        ok = lk.send(msg)
        self._last_msg = msg
        self._last_send = time.monotonic()
        if ok:
            self._send_times.append(self._last_send)
            self._send_stamps.append(self._vehicle_now(self._last_send))
            self._stream_mark(self._last_send)
        return ok

    def _stream_mark(self, t: float) -> None:
        # Continuous streaming since when (PX4 wants a live stream before it accepts OFFBOARD).
        if not math.isfinite(self._stream_since) or t - self._prev_stream_t > 0.5:
            self._stream_since = t
            self._stream_since_stamp = self.telem.newest_stamp()
        self._prev_stream_t = t
