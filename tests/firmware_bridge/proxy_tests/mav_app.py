"""A plain pymavlink app for the proxy tests (what a user's script does, connection string aside):
heartbeats, parameter reads, a telemetry rate request, arming, an off-board / guided mode request and a
stream of setpoints; and a ground station that watches and reads parameters. Every wait is bounded."""

from __future__ import annotations

import time

from pymavlink import mavutil

M = mavutil.mavlink


def connect(url: str, sysid: int, timeout: float = 20.0):
    """A pymavlink connection that has heard the autopilot's heartbeat (sending its own meanwhile)."""
    c = mavutil.mavlink_connection(url, source_system=sysid, source_component=M.MAV_COMP_ID_MISSIONPLANNER)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        c.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        hb = c.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if hb is not None and hb.autopilot != M.MAV_AUTOPILOT_INVALID:
            c.target_system, c.target_component = hb.get_srcSystem(), hb.get_srcComponent()
            return c
    raise AssertionError(f"no autopilot heartbeat through {url} in {timeout} s")


def read_param(c, name: str, timeout: float = 5.0) -> float:
    """PARAM_REQUEST_READ by name, retried; the PARAM_VALUE's value."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        c.mav.param_request_read_send(c.target_system, c.target_component, name.encode(), -1)
        m = c.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
        if m is not None and m.param_id.rstrip("\x00") == name:
            return float(m.param_value)
    raise AssertionError(f"parameter {name} not answered in {timeout} s")


def command(c, cmd: int, *params: float, timeout: float = 5.0) -> int:
    """COMMAND_LONG, retried until its COMMAND_ACK; the result."""
    p = list(params) + [0.0] * (7 - len(params))
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        c.mav.command_long_send(c.target_system, c.target_component, cmd, 0, *p)
        ack = c.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if ack is not None and ack.command == cmd:
            return ack.result
    raise AssertionError(f"command {cmd} not acknowledged in {timeout} s")


def drain(c, seconds: float, types: set[str] | None = None) -> list[tuple[float, object]]:
    """(receive time [s, monotonic], message) of everything received for ``seconds`` (only ``types``)."""
    out, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        m = c.recv_match(blocking=True, timeout=0.05)
        if m is not None and (types is None or m.get_type() in types):
            out.append((time.monotonic(), m))
    return out
