"""The value types of the ``ddpc-bridge`` / ``ddpc-vehicle`` command lines (argparse ``type=`` callables
that raise ``ArgumentTypeError`` with the expected form) and the real-time flags both commands share."""

from __future__ import annotations

import argparse
import math

from firmware_bridge.signing import SigningError, load_signing_key
from firmware_bridge.transports import parse_address

__all__ = ["ATTITUDE_STREAMS", "POSITION_STREAMS", "floats", "floats_or_none", "time_window", "fault_spec", "cpu_list",
           "push_spec", "qos_request", "add_realtime_args", "host_port", "signing_key_file", "margin_us"]

ATTITUDE_STREAMS = {"attitude": "ATTITUDE", "quaternion": "ATTITUDE_QUATERNION", "odometry": "ODOMETRY"}
POSITION_STREAMS = {"local": "LOCAL_POSITION_NED", "odometry": "ODOMETRY"}


def floats(s: str) -> tuple[float, ...]:
    """Comma-separated numbers."""
    try:
        return tuple(float(v) for v in s.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {s!r}") from None


def floats_or_none(s: str) -> tuple[float, ...] | None:
    """``none`` (any case) or comma-separated numbers."""
    return None if str(s).strip().lower() == "none" else floats(s)


def host_port(s: str) -> tuple[str, int]:
    """HOST:PORT (``--vehicle-address``), resolved to an IPv4 address."""
    try:
        return parse_address(s)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def signing_key_file(s: str) -> bytes:
    """A file holding a 32-byte MAVLink signing key, raw or as 64 hex digits (``--signing-key``)."""
    try:
        return load_signing_key(s)
    except (SigningError, OSError) as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def time_window(s: str) -> tuple[float, float]:
    """T0:T1 [s]."""
    a, sep, b = s.partition(":")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected T0:T1 (seconds), got {s!r}")
    return float(a), float(b)


def fault_spec(s: str) -> tuple:
    """START:COUNT[:fail|nan] (``--inject-solver-failure``)."""
    parts = s.split(":")
    if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] not in ("fail", "nan")):
        raise argparse.ArgumentTypeError(f"expected START:COUNT[:fail|nan], got {s!r}")
    return (int(parts[0]), int(parts[1])) + ((parts[2],) if len(parts) == 3 else ())


def cpu_list(s: str) -> tuple[int, ...]:
    """Comma-separated CPU numbers (>= 0)."""
    try:
        cpus = tuple(int(v) for v in s.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated CPU numbers, got {s!r}") from None
    if any(c < 0 for c in cpus):
        raise argparse.ArgumentTypeError(f"CPU numbers are >= 0, got {s!r}")
    return cpus


def push_spec(s: str) -> tuple:
    """T:FX,FY,FZ[:DUR] -> (t, (fx, fy, fz), duration)."""
    bad = argparse.ArgumentTypeError(f"expected T:FX,FY,FZ[:DUR] (s, N, s; DUR > 0), got {s!r}")
    parts = s.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        t, dur = float(parts[0]), float(parts[2]) if len(parts) == 3 else 0.1
        force = tuple(float(v) for v in parts[1].split(","))
    except ValueError:
        raise bad from None
    if len(force) != 3 or not all(math.isfinite(v) for v in (*force, t, dur)) or dur <= 0:
        raise bad
    return (t, force, dur)


def margin_us(s: str) -> float | None:
    """``--tick-margin-us``: ``free`` (any case; no phase lock) or a finite number of microseconds >= 0."""
    if str(s).strip().lower() == "free":
        return None
    try:
        v = float(s)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected microseconds >= 0 or 'free', got {s!r}")
    return v


def qos_request(v: int) -> int | None:
    """``--cpu-latency-us``: a negative value means no PM QoS request."""
    return None if v < 0 else v


def add_realtime_args(g, what: str) -> None:
    """--rt-priority, --cpu-latency-us, --cpus on parser or group ``g``, for ``what`` runs."""
    g.add_argument("--rt-priority", type=int, default=0,
                   help=f"run {what} SCHED_FIFO at this priority, memory locked and a PM QoS wake-up latency request "
                        "held, each if permitted (recommended on the robot; 0: best effort, none of these)")
    g.add_argument("--cpu-latency-us", type=int, default=0,
                   help="PM QoS CPU wake-up latency bound held with --rt-priority [us] (0: CPUs poll instead of "
                        "sleeping deeply: steadier ticks, more power; -1: no request)")
    g.add_argument("--cpus", type=cpu_list, default=None, metavar="LIST", help=f"pin {what} to these CPUs, e.g. 1 or 2,3")
