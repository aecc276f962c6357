"""The rewrite hook: the one place where the proxy may change what the app sends.

The proxy calls a :class:`SetpointRewrite` for each ``SET_POSITION_TARGET_LOCAL_NED`` and
``SET_POSITION_TARGET_GLOBAL_INT`` (:data:`SETPOINT_MSGIDS`) from the app (the client whose setpoints it
follows) that has a position enabled (``type_mask`` does not ignore
all of x, y, z). The hook returns the replacement frame or None (pass the app's own frame). It is
only ever asked about a setpoint the app just sent, so it can replace one but never add one: the
proxy sends no setpoint the app did not cause. A hook that raises or returns anything but one valid
frame of the same message is ignored for that setpoint (the app's own frame goes out; counted).

Replacement frames carry the proxy's own component id (default :data:`PROXY_COMPONENT`) and its
own sequence numbers, on the app's system id: the autopilot and a ground station can tell them
from the app's, and the app's sequence stays gap-free for any other receiver.
"""

from __future__ import annotations

from typing import Protocol

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["SETPOINT_MSGID", "SETPOINT_MSGIDS", "PROXY_COMPONENT", "SetpointRewrite", "decode_frame", "has_position",
           "SetpointEncoder"]

SETPOINT_MSGID = mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
SETPOINT_MSGIDS = frozenset((SETPOINT_MSGID, mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT))
PROXY_COMPONENT = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER2  # 192: not the bridge's 191, nor a GCS's 190
_POSITION_IGNORE = (mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
                    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE)


class SetpointRewrite(Protocol):
    """``hook(msg, frame, t_rx) -> bytes | None``: ``msg`` the decoded setpoint, ``frame`` its bytes as
    received, ``t_rx`` its receive time [s, ``time.time()`` clock]."""

    def __call__(self, msg: mavlink.MAVLink_message, frame: bytes, t_rx: float) -> bytes | None: ...


_decoder = mavlink.MAVLink(None)


def decode_frame(frame: bytes) -> mavlink.MAVLink_message | None:
    """pymavlink's decode of one whole frame (a copy; the bytes are not touched); None when invalid."""
    try:
        return _decoder.decode(bytearray(frame))
    except Exception:  # MAVError, struct.error, ...: a frame the app sent malformed is not a setpoint
        return None


def has_position(msg: mavlink.MAVLink_message) -> bool:
    """Whether a SET_POSITION_TARGET_* message uses at least one of x, y, z."""
    return (msg.type_mask & _POSITION_IGNORE) != _POSITION_IGNORE


class SetpointEncoder:
    """Re-encodes an app's setpoint with a new position (everything else copied) under the proxy's
    own component id and sequence (see the module docstring)."""

    def __init__(self, component: int = PROXY_COMPONENT) -> None:
        self.component = component
        self._mav: dict[int, mavlink.MAVLink] = {}  # per source system: its own sequence counter

    def encode(self, msg: mavlink.MAVLink_message, position_ned: tuple[float, float, float] | None = None,
               **fields: float) -> bytes:
        """The replacement frame: ``msg`` (a SET_POSITION_TARGET_LOCAL_NED or _GLOBAL_INT) with x, y, z =
        ``position_ned`` [m, the message's frame; local only] and any other field given by name (e.g. ``alt=2.5``,
        ``vz=0.0``); every other field is the app's, as decoded."""
        sysid = msg.get_srcSystem()
        mav = self._mav.get(sysid)
        if mav is None:
            mav = self._mav[sysid] = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=self.component)
        cls = type(msg)
        values = {f: getattr(msg, f) for f in cls.fieldnames}
        if position_ned is not None:
            values["x"], values["y"], values["z"] = (float(v) for v in position_ned)
        values.update(fields)
        frame = bytes(cls(**values).pack(mav))
        mav.seq = (mav.seq + 1) % 256  # pymavlink counts on in send(), not in pack()
        return frame
