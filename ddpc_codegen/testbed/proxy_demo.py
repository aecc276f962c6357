"""``make proxy-demo``: a user's own app (:mod:`.proxy_app`, plain pymavlink) flies the ArduCopter and PX4 SIH SITLs
directly and through ``ddpc-proxy``: pass-through, then steered with the local preview, with a declared preview
delay and with the app's path given ahead as a trajectory file (``--preview-file``, the path written by
:func:`.proxy_app.write_path`), on paths the steering never saw; on PX4 it then times the off-board-loss failsafe
over many trials, the app directly against through the proxy (:mod:`.proxy_failsafe`, ``--failsafe-repeats``). The
steering is learned from the app's own flight through the proxy (``--collect`` with a dither). Every flight is judged
on the simulator's true height against the path the app declared (played late by the delay where there is one), with
the autopilot's estimate and its own error beside; the proxy's counters and added latency come from its statistics.
Writes ``reports/proxy.json``.

Two estimation setups (``--setup``, :mod:`.sitl_setups`): "lab" (default), a motion-capture stand-in
(:mod:`.mocap`) whose poses reach the proxy (``--position-source mocap``: it measures the height as a lab's
companion would) and, on ArduCopter, the EKF too (PX4's SITL build fuses no external vision: its EKF keeps GPS and
barometer); "outdoor", the stock GPS + barometer, the proxy measuring on the autopilot's estimate.

All of it runs in a private network namespace (:func:`.sitl.run_isolated`): the SITL (ArduCopter's TCP 5760, PX4's
UDP 14540: the proxy's vehicle side, or the app's when it flies directly), the mocap stand-in on its second link,
the observer on a spare one (:data:`.sitl_observer.SPARE_PORT`), the proxy and the app processes, each stopped by
its pid."""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ddpc_codegen.experiments.report_file import nan_as_null, update_report
from ddpc_codegen.testbed.bridge_flights import stop_process
from ddpc_codegen.testbed.mocap import MocapConfig
from ddpc_codegen.testbed.proxy_app import write_path
from ddpc_codegen.testbed.sitl import make_sitl, missing_reason, run_isolated
from ddpc_codegen.testbed.sitl_demo import codegen
from ddpc_codegen.testbed.sitl_observer import SPARE_PORT, Observer, wait_tcp_port, wait_udp_bound
from ddpc_codegen.testbed.sitl_setups import describe_setup, flown_setup, setup_params
from ddpc_codegen.values.config import SteeringConfig

__all__ = ["KINDS", "CONFIGS", "flight", "start_proxy", "failsafe", "mode_change_after", "observer", "run", "score", "main"]

ROOT = Path(__file__).resolve().parents[2]
APP_PORT = 14541
SKIP_S = 3.0  # path seconds left out of a score (the lead-in's end and the steering's warm-up)
WATCH_S = 3.0  # s watched after the app's last setpoint (the proxy still up): the autopilot's setpoint-loss failsafe
DEATH_AT_S = 10.0  # path seconds into the proxy-death flight when the proxy is killed


def flight(out: Path, name: str, path: str, duration: float, proxy_args: list[str] | None, feedforward: str = "velacc",
           height: float = 2.5, vehicle_url: str = "tcp:127.0.0.1:5760", direct_url: str = "tcp:127.0.0.1:5760",
           kill_proxy_at: float | None = None, frame: str = "local") -> dict:
    """One app flight, directly (``proxy_args`` None: the app on ``direct_url``) or through a proxy started with
    ``proxy_args`` (its vehicle side ``vehicle_url``; SCHED_FIFO 20, as the guide runs it on a robot, where this
    machine permits); :data:`WATCH_S` watched after the app's end, the proxy still up. ``kill_proxy_at``: SIGKILL
    the proxy that many path seconds in (its death, not the app's). ``frame``: the app's setpoints' frame
    (:mod:`.proxy_app`'s ``--frame``)."""
    applog = out / f"{name}.app.jsonl"
    applog.unlink(missing_ok=True)
    proxy = None
    if proxy_args is not None:
        proxy = start_proxy(out, name, vehicle_url, proxy_args)
        time.sleep(1.0)  # the proxy's TCP connection to the vehicle
    url = f"udpout:127.0.0.1:{APP_PORT}" if proxy else direct_url
    cmd = [sys.executable, "-m", "ddpc_codegen.testbed.proxy_app", "--connect", url, "--path", path, "--duration",
           f"{duration:g}", "--feedforward", feedforward, "--height", f"{height:g}", "--log", str(applog),
           "--frame", frame]
    app = subprocess.Popen(cmd, env={**os.environ, "MAVLINK20": "1"}, stdout=subprocess.DEVNULL,
                           stderr=open(out / f"{name}.app.err", "w"), cwd=out)
    t_kill = _kill_at(proxy, applog, kill_proxy_at) if kill_proxy_at is not None else None
    try:
        rc = app.wait(duration + 200)
    except subprocess.TimeoutExpired:
        app.kill()
        rc = app.wait(5)
    time.sleep(WATCH_S)  # the autopilot's own reaction to the app's silence, watched with the proxy still up
    stats = None
    if proxy is not None:
        stop_process(proxy, 15.0, signal.SIGINT)  # SIGINT: the proxy writes its statistics
        p = out / f"{name}.proxy.json"
        stats = json.loads(p.read_text()) if p.is_file() else None
    if rc != 0:
        raise RuntimeError(f"{name}: the app failed ({rc}): {(out / f'{name}.app.err').read_text()[-1500:]}")
    return {"name": name, "path": path, "app_log": str(applog), "proxy": stats, "t_proxy_killed": t_kill}


def start_proxy(out: Path, name: str, vehicle_url: str, args: list[str]) -> subprocess.Popen:
    """``ddpc-proxy`` with ``args``, its apps on :data:`APP_PORT`, its vehicle side ``vehicle_url``, at SCHED_FIFO 20
    where this machine permits (as the guide runs it on a robot); statistics, tick log and stderr in ``out`` as
    ``name``.proxy.json, .ticks.npz, .proxy.err. Raises when it does not bind its port."""
    cmd = [sys.executable, "-m", "firmware_bridge.proxy.cli", "--app", f"udpin:127.0.0.1:{APP_PORT}",
           "--vehicle", vehicle_url, "--stats", str(out / f"{name}.proxy.json"),
           "--log", str(out / f"{name}.ticks.npz"), "--overwrite", "--rt-priority", "20", *args]
    proxy = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=open(out / f"{name}.proxy.err", "w"), cwd=out)
    if not wait_udp_bound(APP_PORT) or proxy.poll() is not None:
        stop_process(proxy, 5.0, signal.SIGINT)
        raise RuntimeError(f"{name}: the proxy did not start: {(out / f'{name}.proxy.err').read_text()[-1500:]}")
    return proxy


def _kill_at(proxy: subprocess.Popen | None, applog: Path, path_s: float) -> float | None:
    """SIGKILL ``proxy`` once the app's log reaches path time ``path_s`` [s]; the kill's time.time() (None: no
    proxy, or the app never got there within 300 s)."""
    end = time.monotonic() + 300
    while proxy is not None and time.monotonic() < end:
        last = _last_line(applog)
        if last.endswith("}") and json.loads(last).get("tp", path_s) >= path_s:
            proxy.kill()
            return time.time()
        time.sleep(0.05)
    return None


def _last_line(path: Path, tail: int = 512) -> str:
    """The last whole line of a growing text file (its last ``tail`` bytes read; "" before it exists)."""
    if not path.is_file():
        return ""
    with path.open("rb") as f:
        f.seek(max(0, f.seek(0, os.SEEK_END) - tail))
        lines = f.read().decode(errors="replace").splitlines()
    return lines[-1] if lines else ""


def failsafe(applog: Path, obs: Observer, ticks: Path | None = None, since: float | None = None) -> dict:
    """The vehicle's reaction to the end of the app's stream (:func:`mode_change_after`) from the app's last
    setpoint (or ``since``, e.g. the proxy's death); ``ticks``: the proxy's tick log, whose last setpoint to the
    vehicle is given after the app's last [s] (the proxy stamps it on receipt and sends it in that call)."""
    rows = [json.loads(s) for s in applog.read_text().splitlines() if s.strip().endswith("}")]
    t0 = since if since is not None else rows[-1]["t"]
    out = {"from": "proxy death" if since is not None else "app's last setpoint", **mode_change_after(obs, t0)}
    if ticks is not None and ticks.is_file():
        t_out = np.load(ticks)["rows"]["t"]
        out["proxy_last_out_s"] = float(t_out[-1] - rows[-1]["t"]) if len(t_out) else None
    return out


def mode_change_after(obs: Observer, t0: float) -> dict:
    """Seconds from ``t0`` [s, time.time()] to the vehicle's first mode or arming other than the one at ``t0``
    (``failsafe_s``; None: none within :data:`WATCH_S`), from its heartbeats and its ``CURRENT_MODE`` messages (PX4
    sends one on each change, but heartbeats at 1 Hz only); the modes before and after, and what timed it."""
    near = lambda rec: [r for r in list(rec) if t0 - WATCH_S < r[0] <= t0 + WATCH_S]  # noqa: E731 (a session's
    hb, modes = near(obs.hb), near(obs.modes)  # heartbeats: ArduPilot sends them at the streams' 50 Hz)
    armed = lambda t: next((h[2] for h in reversed(hb) if h[0] <= t), True)  # noqa: E731
    seen = sorted(hb + [(t, cm, armed(t)) for t, cm in modes])
    before = [h for h in seen if h[0] <= t0]
    base = before[-1][1:] if before else None
    fired = next((h for h in seen if h[0] > t0 and base is not None and h[1:] != base), None)
    return {"failsafe_s": None if fired is None else fired[0] - t0,
            "mode_before": None if base is None else obs.mode_name(base[0]) + ("" if base[1] else ", disarmed"),
            "mode_after": None if fired is None else obs.mode_name(fired[1]) + ("" if fired[2] else ", disarmed"),
            "timed_by": "CURRENT_MODE, sent on a change" if modes else
            f"heartbeats every {(_period([h[0] for h in hb]) or float('nan')) * 1e3:.0f} ms"}


def _period(ts: list[float]) -> float | None:
    """The median spacing of the heartbeats [s] (the failsafe time's resolution)."""
    return float(np.median(np.diff(ts))) if len(ts) > 2 else None


def score(applog: Path, obs: Observer, delay: float = 0.0, skip: float = SKIP_S, ground: float = 0.0) -> dict:
    """RMSE [mm] of the true and estimated heights against the app's declared heights (``delay`` [s] late), over the
    path after ``skip`` [s]; the estimator's own error (RMS of estimate - truth) beside. ``ground``: the truth's
    height where the local frame's origin is (the vehicle on the ground before take-off) [m]."""
    rows = [r for r in (json.loads(s) for s in applog.read_text().splitlines() if s.strip()) if "tp" in r]
    t = np.array([r["t"] for r in rows if r["tp"] >= skip]) + delay
    want = -np.array([r["z"] for r in rows if r["tp"] >= skip])
    truth, est = obs.heights(t)
    truth = truth - ground

    def rms(e: np.ndarray) -> float | None:
        ok = np.isfinite(e)
        return float(np.sqrt(np.mean(e[ok] ** 2)) * 1e3) if ok.any() else None

    return {"rmse_z_truth_mm": rms(truth - want), "rmse_z_mm": rms(est - want), "estimator_rms_mm": rms(est - truth),
            "samples": int(np.isfinite(est).sum()), "delay_s": delay}


def _proxy_figures(stats: dict | None) -> dict | None:
    """What a flight's proxy statistics say: counts both ways, added latency, the steering's counts."""
    if stats is None:
        return None
    up, down = stats["app_to_vehicle"], stats["vehicle_to_app"]
    keep = ("received", "forwarded", "rewritten", "dropped", "seq_gaps", "send_errors")
    st = stats.get("steering") or {}
    solver = st.get("steering") or {}  # the steerer's own counts (steer only)
    return {"realtime": stats.get("realtime"),
            "app_to_vehicle": {k: up[k] for k in keep}, "vehicle_to_app": {k: down[k] for k in keep},
            "latency_us": {"app_to_vehicle": up["latency_us"], "vehicle_to_app": down["latency_us"]},
            "steering": {**{k: st.get(k) for k in ("mode", "ticks", "steered", "rewritten", "activations",
                                                   "period_mismatch", "preview_delay_s", "frames", "preview",
                                                   "jerk_bound")},
                         "model_mismatch": (solver.get("fallback_reasons") or {}).get("model_mismatch", 0),
                         "beyond_jerk": (solver.get("fallback_reasons") or {}).get("beyond_jerk", 0),
                         "prediction_watch": solver.get("prediction_watch")} if st else None}


KINDS = ("direct", "passthrough", "steer_local", "steer_delay", "steer_file")
# The steering's config per autopilot (the app sends its own feed-forward: deviation coordinates on both)
CONFIGS = {"ardupilot": "proxy_ardupilot.toml", "px4": "proxy_px4_app.toml"}
# The collect's dither [m] per autopilot. ArduCopter's height loop is not linear in the size of a move (its position
# controller's square-root law): +-0.15 m steps identify a loop slower than the one the steering's small moves meet,
# and the steering then rings. PX4's offsets mostly carry its estimator's drift, steered well with +-0.15 m.
DITHERS = {"ardupilot": 0.05, "px4": 0.15}
# The autopilot's vertical jerk limit the steered flights declare (--max-jerk): ArduCopter's PSC_JERK_Z default. PX4's
# offboard position control does not shape an app's acceleration field that way: none.
JERK_LIMITS = {"ardupilot": 5.0}


def run(autopilot: str, out_dir: str, paths: list[str], duration: float = 30.0, collect_s: float = 60.0,
        delay: float = 0.5, dither: float | None = None, dither_hold: int = 10, setup: str = "lab",
        kinds: tuple[str, ...] = KINDS, z_feedforward: str = "keep", config: str | None = None,
        proxy_death: bool = True, frame: str = "local") -> dict:
    """In a private network namespace: the SITL of ``autopilot`` in ``setup`` (:mod:`.sitl_setups`; in the lab the
    proxy measures on the motion capture, which ArduCopter's EKF fuses too), the collect flight, codegen,
    then per path the ``kinds`` of flight: direct, pass-through, steered (local preview), steered (``delay``),
    steered (the path's file, :func:`.proxy_app.write_path`), each with the vehicle's reaction to the app's end
    (:func:`failsafe`); ``proxy_death``: one more steered flight whose proxy is killed mid-path; ``frame``: the
    app's frame in the path flights (the collect's is local). Returns the report's entry of ``autopilot``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sitl = make_sitl(autopilot, params=setup_params(autopilot, setup, {}, MocapConfig(seed=1))).start()
    res: dict = {"setup": setup, "z_feedforward": z_feedforward, "app_frame": frame, "paths": {}, "collect": {}}
    dither = DITHERS[autopilot] if dither is None else dither
    try:
        with flown_setup(sitl, autopilot, setup, MocapConfig(seed=1), measure_on_mocap=True) as lab:
            obs = observer(sitl)
            try:
                res.update(_flights(lab, obs, out, paths, duration, collect_s, delay, dither, dither_hold,
                                    (*kinds, *(("proxy_death",) if proxy_death else ())),
                                    ["--z-feedforward", z_feedforward, *lab.bridge_args],
                                    ROOT / "configs" / (config or CONFIGS[autopilot]), frame))
                res["setup_detail"] = {**describe_setup(autopilot, setup, lab.mocap),  # what the proxy measured on
                                       "position_source": "mocap" if lab.mocap is not None else "autopilot"}
            finally:
                obs.stop()
    finally:
        sitl.stop()
    return res


def _flights(lab, obs: Observer, out: Path, paths, duration, collect_s, delay, dither, hold, kinds, extra,
             config: Path, frame: str = "local") -> dict:
    """The collect flight, codegen and every path's flights (see :func:`run`); the report's figures."""
    url = lab.url
    time.sleep(10.0)  # PX4's EKF moves its height by 0.5 m in its first seconds
    ground = obs.ground()
    print(f"[proxy-demo] {lab.autopilot}: collect through the proxy (the app's own path + a dither)", flush=True)
    coords = "deviation" if SteeringConfig.from_toml(config).input_names == ("z_offset",) else "absolute"
    col = flight(out, "collect", "wander", collect_s, ["--dither", f"{dither:g}", "--dither-hold", str(hold),
                                                    "--coordinates", coords, "--collect", str(out / "collect.npz"),
                                                    "--overwrite", *extra],
                 vehicle_url=url, direct_url=url)
    res = {"collect": {"path": "wander", "seconds": collect_s, "dither_m": dither, "dither_hold": hold,
                       "config": config.name, "coordinates": coords, "proxy": _proxy_figures(col["proxy"])}, "paths": {}}
    solver = codegen(config, out / "collect.npz", out / "solver")
    limit = JERK_LIMITS.get(lab.autopilot)
    jerk = [] if limit is None else ["--max-jerk", f"{limit:g}"]
    res["collect"]["max_jerk"] = limit
    offset = ((col["proxy"] or {}).get("steering") or {}).get("position_source", {}).get("offset_m")
    if offset is not None:  # the frames' offset measured on the ground before the collect's take-off, kept after
        extra = [*extra, f"--mocap-offset={offset:.6f}"]  # "=": argparse takes "-1e-05" for an option
        res["collect"]["mocap_offset_m"] = offset
    for path in paths:
        ahead = [str(write_path(path, duration, out / f"{path}.path.csv"))] if "steer_file" in kinds else []
        steer = ["--steer", str(solver), *jerk, *extra]
        runs = {"direct": None, "passthrough": [*extra], "steer_local": steer,
                "steer_delay": [*steer, "--preview-delay", f"{delay:g}"], "steer_file": [*steer, "--preview-file", *ahead]}
        res["paths"][path] = {}
        for kind in (k for k in runs if k in kinds):
            print(f"[proxy-demo] {lab.autopilot}: {path}, {kind}", flush=True)
            f = flight(out, f"{path}_{kind}", path, duration, runs[kind], vehicle_url=url, direct_url=url, frame=frame)
            res["paths"][path][kind] = {**score(Path(f["app_log"]), obs, delay if kind == "steer_delay" else 0.0,
                                                ground=ground), "proxy": _proxy_figures(f["proxy"]),
                                        "app_stops": failsafe(Path(f["app_log"]), obs,
                                                              None if runs[kind] is None else out / f"{path}_{kind}.ticks.npz")}
    if "proxy_death" in kinds and paths:
        print(f"[proxy-demo] {lab.autopilot}: the proxy killed mid-flight", flush=True)
        f = flight(out, "proxy_death", paths[0], duration, ["--steer", str(solver), *extra], vehicle_url=url,
                   direct_url=url, kill_proxy_at=DEATH_AT_S, frame=frame)
        res["proxy_death"] = failsafe(Path(f["app_log"]), obs, since=f["t_proxy_killed"]) \
            if f["t_proxy_killed"] is not None else {"error": "the app never reached the kill time"}
    res["ground_truth_offset_mm"] = ground * 1e3
    return res


def observer(sitl) -> Observer:
    """The observer on the SITL's spare port (:data:`.sitl_observer.SPARE_PORT`), once the SITL serves it."""
    if sitl.autopilot == "px4":
        port = int(SPARE_PORT["px4"].rpartition(":")[2]) + sitl.sysid - 1  # PX4 instance N: every port + N
        return Observer(f"udpin:127.0.0.1:{port}", autopilot="px4", sysid=sitl.sysid)
    end = time.monotonic() + 60
    while not sitl._port_ready() and time.monotonic() < end:
        time.sleep(0.2)
    keep = socket.create_connection(("127.0.0.1", 5760), timeout=2)  # ArduPilot serves 5763 once 5760 has a client
    try:
        wait_tcp_port(5763)
        return Observer(SPARE_PORT["ardupilot"])
    finally:
        keep.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ddpc_codegen.testbed.proxy_demo", description=__doc__.split("\n\n")[0])
    p.add_argument("--paths", default="helix,steps,wander", help="app paths to fly (default %(default)s)")
    p.add_argument("--duration", type=float, default=30.0, help="seconds of each path (default %(default)s)")
    p.add_argument("--collect", type=float, default=60.0, help="seconds of the collect flight (default %(default)s)")
    p.add_argument("--delay", type=float, default=0.5, help="the declared preview delay [s] (default %(default)s)")
    p.add_argument("--setup", choices=("lab", "outdoor"), default="lab",
                   help="lab: a motion-capture stand-in (ArduCopter's EKF fuses it; on PX4, whose SITL build cannot, "
                        "the proxy measures on it); outdoor: GPS + barometer (default %(default)s)")
    p.add_argument("--z-feedforward", choices=("keep", "zero"), default="keep",
                   help="the proxy's --z-feedforward in the collect and steered flights (default %(default)s)")
    p.add_argument("--autopilots", default="ardupilot,px4", help="SITLs to fly (default %(default)s)")
    p.add_argument("--kinds", default=",".join(KINDS), help="flights per path (default %(default)s)")
    p.add_argument("--failsafe-repeats", type=int, default=20, metavar="N",
                   help="PX4: N off-board-loss trials, direct and through the proxy alternately, after the flights "
                        "(ddpc_codegen.testbed.proxy_failsafe; 0: none; default %(default)s)")
    p.add_argument("--out", type=Path, default=ROOT / "reports", help="flights go to OUT/proxy_<autopilot>/")
    p.add_argument("--report", type=Path, default=ROOT / "reports" / "proxy.json")
    a = p.parse_args(argv)
    paths = [s for s in a.paths.split(",") if s]
    kinds = tuple(k for k in a.kinds.split(",") if k)
    if set(kinds) - set(KINDS) or set(a.autopilots.split(",")) - set(CONFIGS):
        p.error(f"--kinds from {KINDS}, --autopilots from {tuple(CONFIGS)}")
    for autopilot in a.autopilots.split(","):
        why = missing_reason(autopilot)
        if why:
            print(f"[proxy-demo] {autopilot} skipped: {why}", file=sys.stderr)
            continue
        kw = {"autopilot": autopilot, "out_dir": str(a.out / f"proxy_{autopilot}"), "paths": paths,
              "duration": a.duration, "collect_s": a.collect, "delay": a.delay, "setup": a.setup,
              "z_feedforward": a.z_feedforward, "kinds": kinds}
        budget = 300 + a.collect + len(paths) * len(kinds) * (a.duration + 60)
        res = run_isolated("ddpc_codegen.testbed.proxy_demo:run", kw, timeout=budget)
        if autopilot == "px4" and a.failsafe_repeats > 0:  # one flight's failsafe time varies more than the target
            print(f"[proxy-demo] px4: {a.failsafe_repeats} off-board-loss trials, direct / proxy", flush=True)
            res["failsafe_repeats"] = run_isolated("ddpc_codegen.testbed.proxy_failsafe:run",
                                                   {"out_dir": str(a.out / "proxy_px4_failsafe"),
                                                    "repeats": a.failsafe_repeats},
                                                   timeout=180 + 10 * a.failsafe_repeats)
        update_report(a.report, {autopilot: res}, default=nan_as_null)
        print(json.dumps({autopilot: res["paths"]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
