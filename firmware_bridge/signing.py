"""MAVLink 2 message signing for the bridge's link: the key file and pymavlink's signing state.

A signing key is 32 bytes shared by the vehicle and the bridge (ArduPilot: set with MAVProxy's
``signing setkey`` or a GCS; PX4: the ``SETUP_SIGNING`` message stores it on the vehicle and
``MAV_SIGN_CFG`` turns checking on). With a key every packet we send is signed, and every packet
received without a valid signature (unsigned, MAVLink 1, wrong key, replayed time stamp) is dropped
by the parser and counted.
"""

from __future__ import annotations

import time
from pathlib import Path

__all__ = ["KEY_BYTES", "SigningError", "load_signing_key", "enable_signing", "signing_timestamp"]

KEY_BYTES = 32
_MAX_KEY_FILE = 4096  # a key file is 32 raw bytes or 64 hex digits; anything larger is the wrong file
_EPOCH_2015 = 1420070400  # MAVLink signing time stamps count 10 us units from 2015-01-01 UTC


class SigningError(ValueError):
    """A signing key file that is not a 32-byte key."""


def load_signing_key(path: str | Path) -> bytes:
    """The 32-byte key in ``path``: 32 raw bytes, or 64 hex digits (surrounding white space ignored).

    Raises:
        SigningError: missing, not a regular file, too large, or not a 32-byte key (one line naming the file).
    """
    p = Path(path)
    if not p.is_file():
        raise SigningError(f"{p}: signing key is not a regular file")
    with open(p, "rb") as f:
        data = f.read(_MAX_KEY_FILE + 1)
    if len(data) > _MAX_KEY_FILE:
        raise SigningError(f"{p}: signing key file over {_MAX_KEY_FILE} bytes; expected 32 raw bytes or 64 hex digits")
    text = data.strip()
    if len(text) == 2 * KEY_BYTES:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if len(data) == KEY_BYTES:
        return data
    raise SigningError(f"{p}: signing key must be 32 raw bytes or 64 hex digits; got {len(data)} bytes")


def signing_timestamp(now: float | None = None) -> int:
    """The MAVLink signing time stamp for the wall-clock time ``now`` [s since the epoch]."""
    return int(((time.time() if now is None else now) - _EPOCH_2015) * 100_000)


def enable_signing(mav, key: bytes, link_id: int = 0, sign_outgoing: bool = True) -> None:
    """Sign what ``mav`` (a pymavlink ``MAVLink``) packs and refuse every unsigned packet it parses."""
    if len(key) != KEY_BYTES:
        raise SigningError(f"signing key must be {KEY_BYTES} bytes; got {len(key)}")
    s = mav.signing
    s.secret_key = bytes(key)
    s.link_id = int(link_id)
    s.sign_outgoing = sign_outgoing
    s.timestamp = max(s.timestamp, signing_timestamp())
    s.allow_unsigned_callback = _refuse_unsigned


def _refuse_unsigned(_mav, _msg_id: int) -> bool:
    return False  # with a key, nothing unsigned is accepted (not even a heartbeat or RADIO_STATUS)
