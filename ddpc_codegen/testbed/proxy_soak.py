"""``make proxy-soak``: ``ddpc-proxy`` (transparent) in front of ``ddpc-vehicle`` for a long session, measured at
both ends. An app (pymavlink, a thread) streams ``SET_POSITION_TARGET_LOCAL_NED`` at 50 Hz with heartbeats; a
ground station on the proxy's TCP port beats at 1 Hz and, every ``param_period`` seconds, asks for the full
parameter list, two stream rates and the off-board mode; optionally a flooder (its own process, :mod:`.proxy_flood`) sends garbage and
valid-but-foreign MAVLink (other system ids, aimed at another system) at F Hz from several ports to the app's port.

Judged: the proxy's own counters and added latency (``--stats``); the vehicle's log of every setpoint it received
(``ddpc-vehicle --setpoint-log``) against the app's: each exactly once, in order, the same bytes' fields and
sequence numbers, and the time from the app's send to the vehicle's kernel receive stamp (an upper bound of the
added latency); the ground station's parameter lists and acknowledgements; the vehicle's messages lost at the
app and the ground station (pymavlink's sequence check). With a flood, the app's setpoints as the vehicle got
them are compared with the session without.

``python -m ddpc_codegen.testbed.proxy_soak --minutes 10 --flood-hz 10000 --flood-minutes 2``
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from ddpc_codegen.testbed.bridge_flights import stop_process
from ddpc_codegen.testbed.proxy_app import M, App
from ddpc_codegen.testbed.sitl import in_private_netns, run_isolated
from ddpc_codegen.testbed.sitl_observer import wait_udp_bound
from firmware_bridge.proxy.app_side import deep_receive_buffer

__all__ = ["run_session", "check_setpoints", "same_setpoints", "main"]

ROOT = Path(__file__).resolve().parents[2]
RATE_HZ = 50.0
APP_ID, GCS_ID = (245, M.MAV_COMP_ID_ONBOARD_COMPUTER), (255, M.MAV_COMP_ID_MISSIONPLANNER)
_MASK = 0b0000_1111_1111_1000  # position only
_STREAMS = (M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, M.MAVLINK_MSG_ID_ATTITUDE)


def _free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _measuring(c) -> None:
    """A client as an instrument: MAVLink 2 from its first message (pymavlink's switch on the first one heard would
    restart its sequence: a gap the proxy counts), a deep receive buffer (a late wake-up of its thread loses none)."""
    c.auto_mavlink_version(b"\xfd")
    deep_receive_buffer(getattr(c, "port", None))


def _point(k: int) -> tuple[float, float, float]:
    """The app's k-th setpoint [m, NED]: a 0.2 m circle at 1 m height, 10 s a turn (the same in every session)."""
    w = 2 * np.pi * k / 500.0
    return 0.2 * np.sin(w), 0.2 * (1 - np.cos(w)), -1.0 - 0.1 * np.sin(2 * w)


def _app(url: str, n: int, out: dict, streaming: threading.Event) -> None:
    """The app: OFFBOARD after 25 setpoints, ``n`` at 50 Hz; per setpoint its send time [s, monotonic] and seq."""
    app = App(url, None, sysid=APP_ID[0])
    _measuring(app.c)
    if not app.wait(lambda: app.hb is not None, 30.0):
        out["error"] = "the app heard no heartbeat"
        return
    mav, c = app.c.mav, app.c
    t_sent, seq = np.zeros(n), np.zeros(n, dtype=int)
    t0 = time.monotonic()
    for k in range(n):
        buf = mav.set_position_target_local_ned_encode(20 * k, c.target_system, c.target_component,
                                                       M.MAV_FRAME_LOCAL_NED, _MASK, *_point(k),
                                                       0, 0, 0, 0, 0, 0, 0, 0).pack(mav)
        seq[k], mav.seq = mav.seq, (mav.seq + 1) % 256  # pymavlink counts on in send(), not in pack()
        t_sent[k] = time.monotonic()
        c.write(buf)
        if k % int(RATE_HZ) == 0:
            app.beat()
        if k == 25:
            app.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
        if k == 50:
            streaming.set()
        app.pump()
        time.sleep(max(0.0, t0 + (k + 1) / RATE_HZ - time.monotonic()))
    app.pump(0.2)
    out.update(t_sent=t_sent, seq=seq, received=c.mav_count, lost_by_seq=c.mav_loss)
    c.close()


class _Gcs(threading.Thread):
    """A ground station: heartbeats at 1 Hz; every ``period`` s a PARAM_REQUEST_LIST, two SET_MESSAGE_INTERVALs and
    an OFFBOARD request; the PARAM_VALUEs of each round and the COMMAND_ACKs (all clients hear them: the app's
    one OFFBOARD request is acknowledged here too) counted."""

    def __init__(self, url: str, period: float) -> None:
        super().__init__(daemon=True)
        self.url, self.period, self.halt = url, period, threading.Event()
        self.rounds: list[dict] = []
        self.acks = {M.MAV_CMD_SET_MESSAGE_INTERVAL: 0, M.MAV_CMD_DO_SET_MODE: 0}
        self.c = None

    def run(self) -> None:
        c = self.c = mavutil.mavlink_connection(self.url, source_system=GCS_ID[0], source_component=GCS_ID[1])
        _measuring(c)
        beat = nxt = time.monotonic()
        while not self.halt.is_set():
            now = time.monotonic()
            if now >= beat:
                beat += 1.0
                c.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            if now >= nxt and c.target_system:
                nxt += self.period
                self.rounds.append({"params": set(), "count": None})
                c.mav.param_request_list_send(c.target_system, c.target_component)
                for msgid in _STREAMS:
                    c.mav.command_long_send(c.target_system, c.target_component, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                            msgid, 20_000, 0, 0, 0, 0, 0)
                c.mav.command_long_send(c.target_system, c.target_component, M.MAV_CMD_DO_SET_MODE, 0,
                                        M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0, 0, 0, 0, 0)
            m = c.recv_match(blocking=True, timeout=0.05)
            while m is not None:
                typ = m.get_type()
                if typ == "HEARTBEAT" and m.autopilot != M.MAV_AUTOPILOT_INVALID and not c.target_system:
                    c.target_system, c.target_component = m.get_srcSystem(), m.get_srcComponent()
                elif typ == "PARAM_VALUE" and self.rounds:
                    self.rounds[-1]["params"].add(m.param_index)
                    self.rounds[-1]["count"] = m.param_count
                elif typ == "COMMAND_ACK" and m.command in self.acks:
                    self.acks[m.command] += 1
                m = c.recv_match(blocking=False)

    def summary(self) -> dict:
        r = self.rounds
        full = [x["count"] is not None and x["params"] == set(range(x["count"])) for x in r]
        return {"param_lists": len(r), "param_lists_complete": sum(full), "params_per_list": r[0]["count"] if r else None,
                "interval_requests": 2 * len(r), "interval_acks": self.acks[M.MAV_CMD_SET_MESSAGE_INTERVAL],
                "mode_requests": len(r) + 1, "mode_acks": self.acks[M.MAV_CMD_DO_SET_MODE],  # (+1: the app's)
                "received": self.c.mav_count if self.c else 0, "lost_by_seq": self.c.mav_loss if self.c else 0}


def _spawn(out: Path, name: str, *args: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-m", *args], env=env, cwd=out, stdout=subprocess.DEVNULL,
                            stderr=open(out / f"{name}.err", "w"))


def _udp_errors() -> int:
    """The kernel's UDP receive-buffer drops so far (of the network namespace: all of them are ours in a private one)."""
    rows = [line.split() for line in Path("/proc/net/snmp").read_text().splitlines() if line.startswith("Udp:")]
    return int(dict(zip(rows[0], rows[1]))["RcvbufErrors"])


def _pcts(v: np.ndarray) -> dict:
    if v.size == 0:
        return {"p50": None, "p99": None, "max": None}
    p50, p99 = np.percentile(v, [50, 99])
    return {"p50": float(p50), "p99": float(p99), "max": float(v.max())}


def check_setpoints(t_sent: np.ndarray, seq: np.ndarray, log: dict) -> dict:
    """The app's setpoints (send times [s] and seqs, index k = time_boot_ms / 20) against the vehicle's log:
    lost, duplicated, reordered, fields or sequence changed; send -> receive latency [ms]."""
    app = (log["sysid"] == APP_ID[0]) & (log["compid"] == APP_ID[1])
    k = np.rint(log["time_boot_ms"][app] / 20.0).astype(int)
    n = len(t_sent)
    first = np.unique(k, return_index=True)[1]
    kk = k[first]
    want = np.array([_point(int(j)) for j in kk], dtype=np.float32).reshape(-1, 3)
    got = np.stack([log[f][app][first] for f in ("x", "y", "z")], axis=1).astype(np.float32)
    changed = (np.any(got != want, axis=1) | (log["type_mask"][app][first] != _MASK)).sum()
    return {"sent": n, "received": int(k.size), "lost": int(n - np.isin(np.arange(n), k).sum()),
            "duplicated": int(k.size - kk.size), "reordered": int((np.diff(k) < 0).sum()),
            "fields_changed": int(changed), "seq_changed": int((log["seq"][app][first] != seq[kk]).sum()),
            "foreign_setpoints_at_vehicle": int((~app).sum()),
            "send_to_vehicle_ms": _pcts(1e3 * (log["rx"][app][first] - t_sent[kk]))}


def run_session(out_dir: str, name: str, minutes: float, flood_hz: float = 0.0, flood_ports: int = 4,
                param_period: float = 60.0) -> dict:
    """One session (see the module docstring); its figures. Files: OUT_DIR/NAME.*."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ap, vp, tp = _free_port(), _free_port(), _free_port(socket.SOCK_STREAM)
    f = {k: out / f"{name}.{k}" for k in ("proxy.json", "vehicle.json", "setpoints.npz", "flood.json")}
    for p in f.values():
        p.unlink(missing_ok=True)
    procs = {"proxy": _spawn(out, f"{name}.proxy", "firmware_bridge.proxy.cli", "--app", f"udpin:127.0.0.1:{ap}",
                             "--app", f"tcpin:127.0.0.1:{tp}", "--vehicle", f"udpin:127.0.0.1:{vp}",
                             "--stats", str(f["proxy.json"]))}
    app_out: dict = {}
    errors0 = _udp_errors()
    gcs, streaming = _Gcs(f"tcp:127.0.0.1:{tp}", param_period), threading.Event()
    try:
        if not wait_udp_bound(ap) or not wait_udp_bound(vp):
            raise RuntimeError("the proxy did not bind its ports")
        procs["vehicle"] = _spawn(out, f"{name}.vehicle", "ddpc_codegen.testbed.vehicle_cli",
                                  f"udpout:127.0.0.1:{vp}", "--no-noise", "--setpoint-log", str(f["setpoints.npz"]),
                                  "--summary", str(f["vehicle.json"]))
        gcs.start()
        app = threading.Thread(target=_app, args=(f"udpout:127.0.0.1:{ap}", int(round(minutes * 60 * RATE_HZ)),
                                                  app_out, streaming), daemon=True)
        app.start()
        if flood_hz > 0 and streaming.wait(40.0):  # the app is the proxy's setpoint client before the flood
            procs["flood"] = _spawn(out, f"{name}.flood", "ddpc_codegen.testbed.proxy_flood", str(ap), "--hz",
                                    f"{flood_hz:g}", "--ports", str(flood_ports), "--seconds", f"{minutes * 60:g}",
                                    "--stats", str(f["flood.json"]))
        app.join(minutes * 60 + 60)
    finally:
        stop_process(procs.get("flood"))
        time.sleep(0.5)  # what is in flight arrives
        gcs.halt.set()
        gcs.join(5)
        stop_process(procs.get("vehicle"))
        stop_process(procs["proxy"], 15.0, signal.SIGINT)  # SIGINT: the proxy writes its statistics
    errors = _udp_errors() - errors0
    if "t_sent" not in app_out:
        raise RuntimeError(f"{name}: the app did not finish: {app_out.get('error', 'timed out')}")
    if flood_hz > 0 and not f["flood.json"].is_file():
        raise RuntimeError(f"{name}: the flood did not run: {(out / f'{name}.flood.err').read_text()[-1500:]}")
    px, veh = json.loads(f["proxy.json"].read_text()), json.loads(f["vehicle.json"].read_text())
    keep = ("received", "forwarded", "dropped", "seq_gaps", "garbage_bytes", "send_errors", "latency_us")
    return {"minutes": minutes, "flood_hz": flood_hz, "setpoint_log": str(f["setpoints.npz"]),
            "udp_rcvbuf_errors": errors, "private_netns": in_private_netns(),
            "setpoints": check_setpoints(app_out["t_sent"], app_out["seq"], dict(np.load(f["setpoints.npz"]))),
            "proxy": {**{d: {k: px[d][k] for k in keep} for d in ("app_to_vehicle", "vehicle_to_app")},
                      "foreign_setpoints": px["events"]["foreign_setpoints"], "clients": len(px["clients"]),
                      "clients_joined": px["events"]["clients_joined"], "clients_left": px["events"]["clients_left"]},
            "app": {"received": app_out["received"], "lost_by_seq": app_out["lost_by_seq"]}, "gcs": gcs.summary(),
            "vehicle": {"rx": veh["link"]["rx"], "bad_data": veh["link"].get("bad_data", 0),
                        "overruns": veh["overruns"], "setpoints_ignored": veh["setpoints_ignored"]},
            "flood": json.loads(f["flood.json"].read_text()) if f["flood.json"].is_file() else None}


def same_setpoints(a: str, b: str) -> dict:
    """Whether the app's setpoints in two vehicle logs agree (time_boot_ms, frame, mask, x, y, z) over the shorter."""
    rows = []
    for path in (a, b):
        log = np.load(path)
        sel = (log["sysid"] == APP_ID[0]) & (log["compid"] == APP_ID[1])
        rows.append(np.stack([log[f][sel] for f in ("time_boot_ms", "coordinate_frame", "type_mask", "x", "y", "z")], 1))
    n = min(len(r) for r in rows)
    return {"compared": n, "counts": [len(r) for r in rows], "differing": int(np.any(rows[0][:n] != rows[1][:n], 1).sum())}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ddpc_codegen.testbed.proxy_soak", description=__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, default=10.0, help="the session without a flood (default %(default)s)")
    p.add_argument("--flood-hz", type=float, default=0.0, help="also a session with this flood [datagrams/s]")
    p.add_argument("--flood-minutes", type=float, default=None, help="its length (default: --minutes)")
    p.add_argument("--flood-ports", type=int, default=4, help="the flood's source ports / system ids")
    p.add_argument("--param-period", type=float, default=60.0, help="the ground station's round period [s]")
    p.add_argument("--out", type=Path, default=ROOT / "reports" / "proxy_soak")
    p.add_argument("--report", type=Path, default=ROOT / "reports" / "proxy_soak.json")
    a = p.parse_args(argv)
    runs = [("baseline", a.minutes, 0.0)] + ([("flood", a.flood_minutes or a.minutes, a.flood_hz)] if a.flood_hz else [])
    report: dict = {}
    for name, minutes, hz in runs:
        kw = {"out_dir": str(a.out), "name": name, "minutes": minutes, "flood_hz": hz, "flood_ports": a.flood_ports,
              "param_period": a.param_period}
        report[name] = run_isolated("ddpc_codegen.testbed.proxy_soak:run_session", kw, timeout=minutes * 60 + 180)
        print(f"[proxy-soak] {name}: {json.dumps(report[name]['setpoints'])}", flush=True)
    if "flood" in report:
        report["flood_vs_baseline"] = same_setpoints(report["baseline"]["setpoint_log"], report["flood"]["setpoint_log"])
    a.report.parent.mkdir(parents=True, exist_ok=True)
    a.report.write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
