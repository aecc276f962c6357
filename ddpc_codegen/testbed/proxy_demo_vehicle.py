"""``make proxy-demo``'s second part: the same pymavlink app (:mod:`.proxy_app`) in front of ``ddpc-vehicle``'s PX4
emulation (a PX4-style cascaded position controller without input shaping, OFFBOARD, its true state as its
telemetry), where the app streams position setpoints only, as MAVSDK's offboard example does. One collect flight
through the proxy (absolute coordinates, a dither), codegen with ``configs/proxy_px4.toml``, then per path: the
app with its own velocity and acceleration feed-forward, the position-only app directly, and the position-only
app steered (local preview, declared delay). Scored on the heights the app received (the vehicle's truth here).

In a private network namespace (:func:`.sitl.run_isolated`): ``ddpc-vehicle`` sends to UDP 14540, where the proxy
(or the app, directly) listens; every process is stopped by its pid.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

from ddpc_codegen.testbed.proxy_demo import ROOT, AppLogHeights, _proxy_figures, flight, score
from ddpc_codegen.testbed.sitl_demo import codegen

__all__ = ["VEHICLE_KINDS", "run_vehicle"]

VEHICLE_KINDS = ("direct", "direct_pos", "steer_local", "steer_delay")
_VEHICLE = "udpin:127.0.0.1:14540"


def run_vehicle(out_dir: str, paths: list[str], duration: float = 30.0, collect_s: float = 60.0,
                delay: float = 0.5, dither: float = 0.15, dither_hold: int = 10) -> dict:
    """``ddpc-vehicle`` (PX4 emulation, real time), the collect flight, codegen and per path the flights of
    :data:`VEHICLE_KINDS`; the report's ``ddpc_vehicle`` entry."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    veh = subprocess.Popen([sys.executable, "-m", "ddpc_codegen.testbed.vehicle_cli", "udpout:127.0.0.1:14540"],
                           stdout=subprocess.DEVNULL,
                           stderr=open(out / "vehicle.err", "w"), cwd=out)
    res: dict = {"setup": "ddpc-vehicle (PX4 emulation, true state as telemetry)", "paths": {}}
    kw = {"vehicle_url": _VEHICLE, "direct_url": _VEHICLE}
    try:
        time.sleep(2.0)
        print("[proxy-demo] ddpc-vehicle: collect through the proxy (a position-only app + a dither)", flush=True)
        col = flight(out, "collect", "wander", collect_s, ["--dither", f"{dither:g}", "--dither-hold", str(dither_hold),
                                                        "--coordinates", "absolute", "--collect",
                                                        str(out / "collect.npz")], feedforward="none", **kw)
        res["collect"] = {"path": "wander", "seconds": collect_s, "dither_m": dither, "dither_hold": dither_hold,
                          "proxy": _proxy_figures(col["proxy"])}
        solver = codegen(ROOT / "configs" / "proxy_px4.toml", out / "collect.npz", out / "solver")
        runs = {"direct": (None, "velacc"), "direct_pos": (None, "none"),
                "steer_local": (["--steer", str(solver)], "none"),
                "steer_delay": (["--steer", str(solver), "--preview-delay", f"{delay:g}"], "none")}
        for path in paths:
            res["paths"][path] = {}
            for kind, (args, ff) in runs.items():
                print(f"[proxy-demo] ddpc-vehicle: {path}, {kind}", flush=True)
                f = flight(out, f"{path}_{kind}", path, duration, args, feedforward=ff, **kw)
                log = Path(f["app_log"])
                res["paths"][path][kind] = {**score(log, AppLogHeights(log), delay if kind == "steer_delay" else 0.0),
                                            "proxy": _proxy_figures(f["proxy"]), "app_feedforward": ff}
    finally:
        if veh.poll() is None:
            veh.send_signal(signal.SIGINT)
            try:
                veh.wait(10)
            except subprocess.TimeoutExpired:
                veh.kill()
                veh.wait(5)
    return res
