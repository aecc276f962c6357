"""The off-board-loss failsafe's delay on PX4 SIH, the app connected directly against through ``ddpc-proxy``,
measured over many trials of one flight: one flight's delay varies from one flight to the next by more than the
issue's target (one app period + 10 ms) asks to resolve, so single flights cannot show it.

In a private network namespace (:func:`.sitl.run_isolated`): PX4 SIH (outdoor: its own GPS and barometer) started
with its off-board-loss action set to Hold (``COM_OBL_RC_ACT``, read back over MAVLink), so that the vehicle hovers
after each failsafe and the next trial re-enters OFFBOARD at once; an :class:`.sitl_observer.Observer` on the SIH
link; one transparent proxy (no ``--steer``) on PX4's off-board link. The app (:class:`.proxy_app.App`) takes off
through the proxy, then alternates: a direct trial sends to PX4's off-board link's own port (where the proxy sends
what it forwards: the same link into PX4 for both arms), a proxy trial to the proxy's app port. Each trial streams
the vehicle's current position (read through the proxy, where PX4 sends its telemetry) at 50 Hz while asking for
OFFBOARD, stops, and times the first mode change after its last send (:func:`.proxy_demo.mode_change_after`). The
proxy's tick log gives its last setpoint out after the app's last.
"""

from __future__ import annotations

import json
import math
import os
import signal
import struct
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from ddpc_codegen.testbed.bridge_flights import stop_process
from ddpc_codegen.testbed.proxy_app import MASKS, App, M, await_telemetry, take_off
from ddpc_codegen.testbed.proxy_demo import APP_PORT, WATCH_S, mode_change_after, observer, start_proxy
from ddpc_codegen.testbed.sitl import make_sitl

__all__ = ["ARMS", "HOLD_ACTION", "TARGET_S", "compare", "run"]

ARMS = ("direct", "proxy")
HOLD_ACTION = {"COM_OBL_RC_ACT": 5}  # PX4's off-board-loss action: 5 = Hold (its default, Position, falls to RTL)
RATE_HZ = 50.0
TARGET_S = 1.0 / RATE_HZ + 0.010  # the bound on the difference: one app period + 10 ms
STREAM_S = 1.5  # s of setpoints per trial ...
MIN_OFFBOARD_S = 0.5  # ... of which at least this long in OFFBOARD
SETTLE_S = 0.5  # s in Hold after a failsafe before the next trial


def compare(direct: Sequence[float | None], proxy: Sequence[float | None], target_s: float = TARGET_S) -> dict:
    """Per arm (failsafe delays [s]; None / NaN trials left out): n, mean, median, standard deviation, range; the
    mean difference proxy - direct [s] with its 95 % Welch confidence interval, and whether that interval lies
    within +- ``target_s`` (the target shown) or outside it (the target missed); None where n < 2 in an arm."""
    from scipy import stats  # optional heavy dependency

    arms = {k: np.array([v for v in a if v is not None and math.isfinite(v)], dtype=float)
            for k, a in zip(ARMS, (direct, proxy))}
    out: dict = {k: {"n": len(a), "mean_s": _f(a, np.mean), "median_s": _f(a, np.median),
                     "std_s": float(np.std(a, ddof=1)) if len(a) > 1 else None, "min_s": _f(a, np.min),
                     "max_s": _f(a, np.max)} for k, a in arms.items()}
    d, p = arms["direct"], arms["proxy"]
    out.update({"mean_diff_s": None, "ci95_s": None, "p_value": None, "ci_method": "Welch t", "target_s": target_s,
                "verdict": "too few trials"})
    if len(d) < 2 or len(p) < 2:
        return out
    res = stats.ttest_ind(p, d, equal_var=False)
    ci = res.confidence_interval(0.95)
    lo, hi = float(ci.low), float(ci.high)
    out.update({"mean_diff_s": float(p.mean() - d.mean()), "ci95_s": [lo, hi], "p_value": float(res.pvalue)})
    out["verdict"] = ("within target" if -target_s <= lo and hi <= target_s else
                      "target missed" if hi < -target_s or lo > target_s else "unresolved")
    return out


def _f(a: np.ndarray, fn) -> float | None:
    return float(fn(a)) if len(a) else None


def _mode(obs) -> str | None:
    """The vehicle's latest mode name from the observer's heartbeats and CURRENT_MODE messages (None: none yet)."""
    seen = [r[:2] for r in obs.hb[-1:] + obs.modes[-1:]]  # the tails only: this runs on every setpoint
    return obs.mode_name(max(seen)[1]) if seen else None


def _read_param(app: App, name: str, timeout: float = 10.0) -> float | None:
    """One parameter read over MAVLink (PX4 sends integers bytewise in the float field); None: no answer."""
    end, ask = time.monotonic() + timeout, 0.0
    while time.monotonic() < end:
        if time.monotonic() >= ask:
            ask = time.monotonic() + 1.0
            app.c.mav.param_request_read_send(app.c.target_system, app.c.target_component, name.encode(), -1)
        m = app.c.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
        if m is not None and m.param_id.rstrip("\x00") == name:
            v = m.param_value
            return float(struct.unpack("<i", struct.pack("<f", v))[0]) if m.param_type == M.MAV_PARAM_TYPE_INT32 else v
    return None


def _trial(app: App, obs, hover: np.ndarray) -> dict:
    """Stream ``hover`` (x, y, up) [m] at :data:`RATE_HZ`, asking for OFFBOARD until in it, for :data:`STREAM_S`
    (at least :data:`MIN_OFFBOARD_S` in OFFBOARD; at most 10 s), stop, and time the vehicle's reaction."""
    zero, period, t_start, k, asked, t_off = np.zeros(3), 1.0 / RATE_HZ, time.monotonic(), 0, 0.0, None
    while True:
        app.setpoint(hover, zero, zero, MASKS["none"], None)
        t_last = time.time()  # as the app's log stamps its sends
        now = time.monotonic()
        if k % int(RATE_HZ) == 0:
            app.beat()
        if _mode(obs) == "OFFBOARD":
            t_off = now if t_off is None else t_off
        elif now >= asked:
            asked = now + 0.25
            app.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
        app.pump()
        k += 1
        if (now - t_start >= STREAM_S and t_off is not None and now - t_off >= MIN_OFFBOARD_S) or now - t_start > 10:
            break
        time.sleep(max(0.0, t_start + k * period - time.monotonic()))
    end = time.monotonic() + WATCH_S
    while time.monotonic() < end and _mode(obs) == "OFFBOARD":
        time.sleep(0.02)
    time.sleep(0.1)  # a CURRENT_MODE that may trail the heartbeat
    return {"t_last": t_last, "entered_offboard": t_off is not None, **mode_change_after(obs, t_last)}


def _settle(obs, timeout: float = 10.0) -> None:
    """Until the vehicle has left OFFBOARD (at most ``timeout`` [s]), then :data:`SETTLE_S` more."""
    end = time.monotonic() + timeout
    while _mode(obs) == "OFFBOARD" and time.monotonic() < end:
        time.sleep(0.05)
    time.sleep(SETTLE_S)


def _hover(app: App) -> np.ndarray:
    """The vehicle's current position (x, y, up) [m] from the app's telemetry."""
    app.pump(0.05)
    lp = app.lpos
    return np.array([lp.x, lp.y, -lp.z])


def run(out_dir: str, repeats: int = 20, height: float = 2.5) -> dict:
    """``repeats`` trials (see the module docstring), direct and proxy alternately, direct first, ``height`` [m]
    above the take-off point; they stop early when the vehicle does not hold after a failsafe. Returns the trials,
    :func:`compare` of the two arms, the proxy's last setpoint out after the app's last per proxy trial [s], its
    counts, and the parameters read back."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    os.environ["MAVLINK20"] = "1"  # both arms' app speaks MAVLink 2 from its first message, as proxy_demo's app
    mavutil.set_dialect(mavutil.current_dialect)  # "all": CURRENT_MODE is not in common
    sitl = make_sitl("px4", params=HOLD_ACTION).start()
    proxy = obs = None
    try:
        obs = observer(sitl)
        proxy = start_proxy(out, "failsafe", sitl.url, [])  # transparent
        app = App(f"udpout:127.0.0.1:{APP_PORT}", None)
        await_telemetry(app, "the proxy")
        params = {n: _read_param(app, n) for n in (*HOLD_ACTION, "COM_OF_LOSS_T")}
        if params["COM_OBL_RC_ACT"] != HOLD_ACTION["COM_OBL_RC_ACT"]:
            raise RuntimeError(f"PX4 did not take the off-board-loss action Hold: {params}")
        take_off(app, np.array([app.lpos.x, app.lpos.y, 0.0]), height)
        _settle(obs)  # the take-off's own stream ends in a failsafe too: the first trial starts from Hold as the rest
        port = int(sitl.url.rpartition(":")[2]) + 40  # PX4's off-board link listens on 14580 + instance
        direct = App(f"udpout:127.0.0.1:{port}", None)
        direct.c.target_system, direct.c.target_component = app.c.target_system, app.c.target_component
        trials = []
        for i in range(repeats):
            arm = ARMS[i % 2]
            t = _trial(direct if arm == "direct" else app, obs, _hover(app))
            trials.append({"arm": arm, **t})
            print(f"[proxy-failsafe] {i + 1}/{repeats} {arm}: {t['failsafe_s']} s ({t['mode_before']} -> "
                  f"{t['mode_after']})", flush=True)
            _settle(obs)
            if not (t["entered_offboard"] and t["mode_after"] == "LOITER"):
                break  # the vehicle did not hold: later trials would start from elsewhere
    finally:
        stop_process(proxy, 15.0, signal.SIGINT)  # SIGINT: the proxy writes its tick log and statistics
        if obs is not None:
            obs.stop()
        sitl.stop()
    last_out = _last_out(out / "failsafe.ticks.npz", [t for t in trials if t["arm"] == "proxy"])
    valid = lambda arm: [t["failsafe_s"] if t["entered_offboard"] and t["mode_before"] == "OFFBOARD" else None  # noqa: E731
                         for t in trials if t["arm"] == arm]
    return {"autopilot": "px4", "setup": "outdoor", "app_rate_hz": RATE_HZ, "stream_s": STREAM_S,
            "params": params, "trials": trials, "stats": compare(valid("direct"), valid("proxy")),
            "proxy_last_out_s": last_out, "proxy": _proxy_counts(out / "failsafe.proxy.json")}


def _proxy_counts(path: Path) -> dict | None:
    """The proxy's scheduling and its app-to-vehicle counts and added latency (its statistics file)."""
    if not path.is_file():
        return None
    st = json.loads(path.read_text())
    up = st["app_to_vehicle"]
    return {"realtime": st.get("realtime"), **{k: up[k] for k in ("received", "forwarded", "dropped", "seq_gaps")},
            "latency_us": {k: up["latency_us"].get(k) for k in ("p50", "p99", "max")}}


def _last_out(ticks: Path, trials: list[dict]) -> list[float | None]:
    """Per proxy trial: the proxy's last setpoint out (its tick log) within 0.5 s after the app's last, minus the
    app's last send [s] (None: no tick log, or no tick there)."""
    if not ticks.is_file():
        return [None] * len(trials)
    t_out = np.load(ticks)["rows"]["t"]
    res = []
    for tr in trials:
        near = t_out[(t_out > tr["t_last"] - 0.5) & (t_out <= tr["t_last"] + 0.5)]
        res.append(float(near[-1] - tr["t_last"]) if len(near) else None)
    return res
