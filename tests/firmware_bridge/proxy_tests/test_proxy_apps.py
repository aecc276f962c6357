"""``ddpc-proxy`` as a process between real MAVLink programs and ``ddpc-vehicle``: a plain pymavlink app
(UDP) and a ground station (TCP) at once, ``ddpc-bridge`` flying lock-step exactly as it does directly, the
statistics written on SIGTERM, and the command line's exit codes."""

from __future__ import annotations

import json
import signal
import time

import pytest

from ddpc_codegen.testbed.sitl_observer import wait_udp_bound

from firmware_bridge.profiles import px4_custom_mode

from mav_app import M, command, connect, drain, read_param
from proxy_support import free_port, spawn_proxy
from support.bridge_helpers import read_json

pytestmark = [pytest.mark.e2e]

OFFBOARD, PX4_MAIN_MODE = px4_custom_mode(6), 0xFF << 16


def _proxy(procs, tmp_path, ap: int, vp: int, *more: str, name: str = "proxy"):
    """The proxy, once it listens for apps (what an app sends earlier is lost, as with any UDP server)."""
    px = spawn_proxy(procs, "--app", f"udpin:127.0.0.1:{ap}", *more, "--vehicle", f"udpin:127.0.0.1:{vp}",
                     "--stats", str(tmp_path / f"{name}.json"), name=name)
    assert wait_udp_bound(ap), procs.log(px)
    return px


def test_a_pymavlink_app_and_a_ground_station_fly_through_the_proxy(procs, tmp_path):
    ap, vp, tp = free_port(), free_port(), free_port()
    px = _proxy(procs, tmp_path, ap, vp, "--app", f"tcpin:127.0.0.1:{tp}")
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{vp}", name="vehicle")
    app = connect(f"udpout:127.0.0.1:{ap}", 245)
    gcs = connect(f"tcp:127.0.0.1:{tp}", 255)                # a ground station over TCP
    try:
        hover = read_param(app, "MPC_THR_HOVER")
        loss_t = read_param(gcs, "COM_OF_LOSS_T")            # both clients' requests answered to each
        assert 0.3 < hover < 1.0 and loss_t > 0
        assert command(app, M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20000) == 0
        t0, modes, zs, last_sp = time.monotonic(), [], [], 0.0
        k = 0
        while time.monotonic() - t0 < 2.5:                   # 50 Hz hover setpoints, OFFBOARD after 0.5 s
            app.mav.set_attitude_target_send(k, app.target_system, app.target_component, 0b111, [1, 0, 0, 0],
                                             0, 0, 0, hover)
            last_sp = time.monotonic()
            if k == 25:
                assert command(app, M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0) == 0
            k += 1
            while gcs.recv_match(blocking=False) is not None:  # the ground station keeps up (no backlog)
                pass
            for _, m in drain(app, 0.02, {"LOCAL_POSITION_NED", "HEARTBEAT"}):
                if m.get_type() == "HEARTBEAT":
                    modes.append(m.custom_mode & PX4_MAIN_MODE)
                else:
                    zs.append(m.z)
        assert OFFBOARD in modes and len(zs) > 50 and abs(zs[-1] - zs[0]) < 0.3
        # The app stops: the autopilot's own off-board-loss failsafe fires, as without the proxy.
        hb = [(t, m.custom_mode & PX4_MAIN_MODE) for t, m in drain(gcs, loss_t + 1.5, {"HEARTBEAT"})]
        left = [t for t, mode in hb if mode != OFFBOARD]
        assert left and left[0] - last_sp < loss_t + 1.0     # heartbeats come at 2 Hz
    finally:
        app.close()
        gcs.close()
        procs.terminate(veh)
        assert procs.terminate(px) == 0, procs.log(px)
    s = read_json(tmp_path / "proxy.json")
    assert s["stop_reason"] == "SIGTERM" and s["events"]["clients_joined"] == 2
    for d in ("app_to_vehicle", "vehicle_to_app"):
        assert s[d]["send_errors"] == 0 and s[d]["garbage_bytes"] == 0 and s[d]["latency_us"]["p99"] > 0
    up = s["app_to_vehicle"]  # (the clients' first heartbeats may come before the vehicle is heard: dropped)
    assert up["forwarded"] + up["dropped"] == up["received"] and up["dropped"] <= 4


def _bridge_flight(procs, tmp_path, name: str, through_proxy: bool) -> tuple[dict, dict | None]:
    vp = free_port()
    ap = free_port() if through_proxy else vp
    px = _proxy(procs, tmp_path, ap, vp, name=f"{name}_proxy") if through_proxy else None
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{vp}", "--lockstep", "--seed", "3", name=f"{name}_vehicle")
    br = procs.spawn("bridge", f"udpout:127.0.0.1:{ap}" if through_proxy else f"udpin:127.0.0.1:{vp}",
                     "--lockstep", "--offboard", "--mode", "passthrough", "--duration", "3", "--settle", "1",
                     "--summary", str(tmp_path / f"{name}.json"), "--timeout", "60", "--wait-heartbeat", "20",
                     name=f"{name}_bridge")
    assert procs.wait(br, 90) == 0, procs.log(br)
    procs.terminate(veh)
    if px is None:
        return read_json(tmp_path / f"{name}.json"), None
    assert procs.terminate(px) == 0, procs.log(px)
    return read_json(tmp_path / f"{name}.json"), read_json(tmp_path / f"{name}_proxy.json")


def test_ddpc_bridge_flies_through_the_proxy_as_it_does_directly(procs, tmp_path):
    direct, _ = _bridge_flight(procs, tmp_path, "direct", False)
    proxied, s = _bridge_flight(procs, tmp_path, "proxied", True)
    for b in (direct, proxied):
        assert b["stop_reason"].startswith("duration") and b["activations"] == 1 and b["missed_ticks"] == 0
        assert b["link"]["bad_data"] == 0
        assert b["setpoints_sent"] == b["ticks"], b
    # lock-step and seeded: the same flight, to the stamps' rounding (when the bridge engages is set by wall-clock
    # heartbeats, so the flight may be a tick longer or shorter)
    assert abs(proxied["ticks"] - direct["ticks"]) <= 2, (proxied["ticks"], direct["ticks"])
    assert proxied["rmse_z_measured"] == pytest.approx(direct["rmse_z_measured"], rel=5e-3)
    up, down = s["app_to_vehicle"], s["vehicle_to_app"]
    # all the bridge sent, but what came before the vehicle was heard (its first heartbeats, if it started first)
    assert up["received"] == proxied["link"]["tx"] and up["send_errors"] == 0, (up, proxied["link"])
    assert up["forwarded"] + up["dropped"] == up["received"] and up["dropped"] <= 3, up
    # every message the bridge received came through; a heartbeat may follow between its exit and the vehicle's
    assert 0 <= down["forwarded"] - proxied["link"]["rx"] <= 3, (down, proxied["link"])
    assert up["latency_us"]["count"] == up["forwarded"] and up["latency_us"]["p50"] > 0  # one message a datagram


def test_the_command_line(procs, tmp_path):
    bad = spawn_proxy(procs, "--app", "tcp:127.0.0.1:1", name="bad")
    assert procs.wait(bad, 20) == 2 and "udpin" in procs.log(bad)
    ap, vp = free_port(), free_port()
    p = spawn_proxy(procs, "--app", f"udpin:127.0.0.1:{ap}", "--vehicle", f"udpin:127.0.0.1:{vp}",
                    "--duration", "0.3", "--stats", str(tmp_path / "s.json"), name="timed")
    assert procs.wait(p, 20) == 0
    s = read_json(tmp_path / "s.json")
    assert s["stop_reason"] == "duration" and s["app_to_vehicle"]["received"] == 0
    assert json.loads(procs.log(p)[procs.log(p).index("{"):]) == s     # the same summary on stdout


def test_sigint_stops_it_cleanly_with_its_summary(procs, tmp_path):
    ap, vp = free_port(), free_port()
    p = _proxy(procs, tmp_path, ap, vp, name="interrupted")
    end = time.monotonic() + 20
    while "ddpc-proxy: apps on" not in procs.log(p) and time.monotonic() < end:  # its handlers are set by then
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    assert procs.wait(p, 20) == 0, procs.log(p)
    assert read_json(tmp_path / "interrupted.json")["stop_reason"] == "SIGINT"
