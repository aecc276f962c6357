"""The proxy never hides the app's death (``ddpc-vehicle`` in PX4's OFFBOARD, position setpoints at 50 Hz): with
the proxy rewriting every setpoint (a dithered collect), the vehicle receives exactly the setpoints the app sent,
none after its last one, and its off-board-loss failsafe fires as late after the app's last setpoint as without the
proxy (measured on the vehicle's own clock, mapped to the app's through the telemetry's stamps)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from mav_app import M, command, connect, drain
from proxy_support import free_port, spawn_proxy
from support.bridge_helpers import read_json

pytestmark = [pytest.mark.e2e, pytest.mark.realtime]  # the failsafe times are wall-clock times

RATE_HZ = 50.0


def _fly_then_stop(url: str) -> dict:
    """OFFBOARD at 50 Hz of position setpoints for 3 s, then silence: (sent, last send [s, time.time()], the vehicle
    clock's offset to time.time() from LOCAL_POSITION_NED's stamps)."""
    app = connect(url, 245)
    assert command(app, M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20000) == 0
    mask = 0b0000_1111_1111_1000
    offsets, sent, t0, last = [], 0, time.monotonic(), 0.0
    while time.monotonic() - t0 < 3.0:
        app.mav.set_position_target_local_ned_send(sent, app.target_system, app.target_component,
                                                   M.MAV_FRAME_LOCAL_NED, mask, 0, 0, -1.5, 0, 0, 0, 0, 0, 0, 0, 0)
        last, sent = time.time(), sent + 1
        if sent == 25:
            assert command(app, M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0) == 0
        for _, m in drain(app, 0.0, {"LOCAL_POSITION_NED"}):
            offsets.append(time.time() - m.time_boot_ms * 1e-3)
        time.sleep(max(0.0, t0 + sent / RATE_HZ - time.monotonic()))
    for _, m in drain(app, 2.0, {"LOCAL_POSITION_NED"}):  # silence: the failsafe fires meanwhile
        offsets.append(time.time() - m.time_boot_ms * 1e-3)
    app.close()
    return {"sent": sent, "last": last, "offset": float(np.min(offsets))}


def _flight(procs, tmp_path, through_proxy: bool) -> tuple[dict, dict, dict | None]:
    vp = free_port()
    ap = free_port() if through_proxy else vp
    name = "proxied" if through_proxy else "direct"
    px = None
    if through_proxy:
        px = spawn_proxy(procs, "--app", f"udpin:127.0.0.1:{ap}", "--vehicle", f"udpin:127.0.0.1:{vp}",
                         "--dither", "0.05", "--stats", str(tmp_path / f"{name}_proxy.json"), name=f"{name}_proxy")
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{vp}", "--summary", str(tmp_path / f"{name}_vehicle.json"),
                      name=f"{name}_vehicle")
    app = _fly_then_stop(f"udpout:127.0.0.1:{ap}" if through_proxy else f"udpin:127.0.0.1:{vp}")
    procs.terminate(veh)
    stats = None
    if px is not None:
        assert procs.terminate(px) == 0, procs.log(px)
        stats = read_json(tmp_path / f"{name}_proxy.json")
    return app, read_json(tmp_path / f"{name}_vehicle.json"), stats


def _failsafe_after_last(app: dict, vehicle: dict) -> float:
    """Seconds from the app's last setpoint to the vehicle leaving OFFBOARD (the vehicle's event time, mapped)."""
    t = [ev[0] for ev in vehicle["events"] if "setpoints lost" in ev[1]]
    assert t, vehicle["events"]
    return t[0] + app["offset"] - app["last"]


def test_the_failsafe_fires_as_late_through_the_proxy_as_without_it(procs, tmp_path):
    app_d, veh_d, _ = _flight(procs, tmp_path, False)
    app_p, veh_p, s = _flight(procs, tmp_path, True)
    assert s["steering"]["rewritten"] > 100 and s["steering"]["ticks"] == app_p["sent"]
    # every setpoint the app sent reached the vehicle through the proxy, and no other (it never adds one)
    assert veh_p["position_setpoints"] == app_p["sent"] == s["setpoints"]["count"], (veh_p, app_p)
    direct, proxied = _failsafe_after_last(app_d, veh_d), _failsafe_after_last(app_p, veh_p)
    print(f"failsafe after the app's last setpoint: direct {direct * 1e3:.1f} ms, through the proxy "
          f"{proxied * 1e3:.1f} ms")
    loss_t = 1.0  # ddpc-vehicle's COM_OF_LOSS_T default
    for f in (direct, proxied):
        assert loss_t - 0.02 < f < loss_t + 0.1
    assert abs(proxied - direct) < 1.0 / RATE_HZ + 0.010
