"""``make bridge-demo``: the real-robot workflow over MAVLink, with the simulated vehicle as robot.

Vehicle (``ddpc-vehicle``, real time) and bridge (``ddpc-bridge``) run as two processes talking
UDP on 127.0.0.1, both with ``--rt-priority`` (SCHED_FIFO, mlockall, a 0 us PM QoS request;
see :mod:`firmware_bridge.realtime`):

0. machine: a few seconds per CPU of a real-time sleeper's wake-up latency, without and with the
   PM QoS request, so the timing figures come with the machine they were measured on;
1. collect: the bridge flies the ellipse with PRBS on the references (``--mode collect``) and
   logs every tick; the log *is* the dataset;
2. codegen: ``ddpc-codegen codegen <config> --dataset <log>`` (unchanged CLI, no glue); the
   config is configs/flying.toml with ``[predictor] method = "lsq"`` (``--predictor config``
   keeps the file's "pem", which is biased on this data);
3. baseline: the model-based controller alone over the link (``--mode passthrough``), 20 s;
4. steered: the generated solver in the loop (``--mode steer``), 20 s;
5. flood round (:mod:`.bridge_flood`): the steered flight again, quiet and then under a 10 kHz flood from
   foreign addresses (``--flood-hz``; 0 skips it), back to back;
6. the same baseline / steered flights in-process (:func:`ddpc_codegen.sim.simulate` with the
   same solver), for the "within 20 % of in-process" check.

Writes ``reports/bridge.json``::

    {"rate_hz", "latency_us": {"p50", "p99", "max"}, "missed_ticks", "fallbacks",
     "rmse_z": {"baseline", "steered"}, "flood_round": {"quiet", "flood"}, ...}

``latency_us`` is :func:`.bridge_flood.tick_latency_us`: telemetry receive -> setpoint sent on the ticks with new
telemetry (the wait for the bridge's grid boundary included, see :func:`.bridge_flood.latency_parts`). Timing
figures (rate, latency, missed ticks) are over all three link runs (collect, baseline,
steered; the flood round's flights are reported apart); ``fallbacks`` counts fallback ticks of the steered run. ``rmse_z`` is the true height
error (vehicle truth log) against the desired height, after the 3 s settle time, like the
in-process metrics; ``rmse_z_telemetry`` the same from the bridge's telemetry.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ddpc_codegen.flight_metrics import flight_metrics
from ddpc_codegen.stats import percentiles
from ddpc_codegen.testbed.bridge_demo_hopping import run_hopping_demo
from ddpc_codegen.testbed.bridge_flood import FLOOD_HZ, flood_round, flood_rows, tick_latency_us
from ddpc_codegen.testbed.bridge_flights import ROOT, child_env, fly, free_udp_port, python_m, write_report, write_toml
from firmware_bridge.realtime import kernel_preemption
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.runtime.loader import load_solver
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer
from ddpc_codegen.sim import simulate
from firmware_bridge.realtime import probe_cpus
from firmware_bridge.report import trajectory_ticks
from firmware_bridge.ticklog import load_ticklog

__all__ = ["main", "run_demo", "free_udp_port", "truth_rmse"]

def truth_rmse(ticks_path: Path, truth_path: Path, settle: float = 3.0) -> dict:
    """True height error over the link: vehicle truth at each tick's vehicle time (interpolated) minus that
    tick's desired height, over every tick of the flown trajectory (engaged or not, as
    :func:`firmware_bridge.report.trajectory_ticks` says) with trajectory time >= settle [m]."""
    tl = load_ticklog(ticks_path).ticks
    with np.load(truth_path) as z:
        tt, st = z["t"], z["state"]
    # The bridge ticks on its own clock: a tick's vehicle time falls between the truth log's
    # samples (1 kHz physics, logged per 5 ms tick), so the truth is interpolated there.
    tv = tl["t_vehicle"]
    ok = (tv >= tt[0]) & (tv <= tt[-1])
    z_truth = np.full(tv.shape, np.nan)
    z_truth[ok] = np.interp(tv[ok], tt, st[:, 2])
    f = flight_metrics(tl["t_traj"], tl["y"], tl["y_des"], settle=settle, active=trajectory_ticks(tl["t_traj"], tl["reason"]),
                       z_truth=z_truth, empty=math.nan)
    return {"rmse_z": f["rmse_z_truth"], "rmse_z_telemetry": f["rmse"][0], "samples": f["truth_ticks"],
            "flown_s": float(np.nanmax(tl["t_traj"])) if np.isfinite(tl["t_traj"]).any() else 0.0}


def in_process(solver_dir: Path, duration: float, seed: int, max_step=(0.3, 0.5)) -> dict:
    """Baseline and steered flights in-process (simulate + ReferenceSteerer, the same solver)."""
    solver = load_solver(solver_dir)
    st = ReferenceSteerer.for_solver(solver, max_step=np.asarray(max_step, float))
    res = {}
    for name, h in (("baseline", None), ("steered", PolicyHook(SteeringPolicy(st), "flying"))):
        r = simulate("flying", duration, seed=seed, noise=True, reference_hook=h)
        # scored as over the link (truth_rmse): the telemetry y and the true height
        f = flight_metrics(r.t, r.y, r.y_des, settle=r.scenario_obj.settle_time, z_truth=r.y_true[:, 0],
                           empty=math.nan)
        res[name] = {"rmse_z": f["rmse_z_truth"], "rmse_z_telemetry": f["rmse"][0]}
    res["steering"] = st.summary()
    return res


def run_demo(out: Path, work: Path, *, collect_s: float = 60.0, flight_s: float = 20.0, solver: Path | None = None,
             config: Path = ROOT / "configs" / "flying.toml", predictor: str = "lsq", rt_priority: int = 30,
             cpu_latency_us: int = 0, probe_s: float = 4.0, pin: bool = False, seed: int = 1,
             flood_hz: float = FLOOD_HZ, flood_s: float | None = None, log=print) -> dict:
    """The whole job (see the module docstring). ``predictor``: "config" keeps the config's
    [predictor]; "lsq" / "pem" override it (the demo's copy of the config is written to ``work``).
    The bridge runs at SCHED_FIFO ``rt_priority`` and the vehicle 10 below (if permitted): on the
    robot they are different computers, here the simulated vehicle must not block the bridge.
    Both hold a ``cpu_latency_us`` PM QoS request (-1: none). First, for ``probe_s`` seconds per
    CPU, a 1 kHz real-time sleeper measures this machine's wake-up latency without and with that
    request (:func:`firmware_bridge.realtime.measure_wakeup_latency`; 0: skip), so the timing
    figures come with the machine they were measured on. ``flood_hz`` > 0: the flood round, each flight
    ``flood_s`` s (default ``flight_s``)."""
    import tomllib

    work.mkdir(parents=True, exist_ok=True)
    if predictor != "config":
        raw = tomllib.loads(Path(config).read_text())
        raw["predictor"] = {"method": predictor}
        raw.pop("data", None)
        config = write_toml(raw, work / f"{raw.get('name', 'flying')}.toml")
    t_start = time.monotonic()
    machine = probe_machine(probe_s, rt_priority, cpu_latency_us, log) if probe_s > 0 else None
    runs: dict[str, dict] = {}
    if solver is None:
        log(f"1. collect: {collect_s:g} s of PRBS-excited flight over MAVLink")
        runs["collect"] = fly("collect", work, ["--mode", "collect", "--dataset-skip", "3", "--seed", str(seed)],
                              duration=collect_s, seed=seed, rt_priority=rt_priority,
                              cpu_latency_us=cpu_latency_us, pin=pin, log=log)
        log(f"2. codegen: ddpc-codegen codegen {config} --dataset {runs['collect']['ticks']}")
        gen_root = work / "generated"
        r = subprocess.run(python_m() + ["ddpc_codegen.cli.main", "codegen", str(config), "--dataset", str(runs["collect"]["ticks"]),
                                    "--out", str(gen_root)], env=child_env(), capture_output=True, text=True, timeout=600)
        if r.returncode != 0:
            raise RuntimeError(f"codegen failed:\n{r.stderr}")
        log("    " + r.stderr.strip().replace("\n", "\n    "))
        solver = Path(r.stdout.strip().splitlines()[-1])
    log(f"3. baseline: {flight_s:g} s, model-based controller alone (passthrough)")
    runs["baseline"] = fly("baseline", work, ["--mode", "passthrough"], duration=flight_s, seed=seed + 1,
                           rt_priority=rt_priority, cpu_latency_us=cpu_latency_us, pin=pin, log=log)
    log(f"4. steered: {flight_s:g} s, generated solver {solver} in the loop")
    runs["steered"] = fly("steered", work, ["--mode", "steer", "--solver", str(solver)], duration=flight_s,
                          seed=seed + 1, rt_priority=rt_priority, cpu_latency_us=cpu_latency_us, pin=pin, log=log)
    flood = None
    if flood_hz > 0:
        log(f"5. flood round: the steered flight quiet, then under {flood_hz:g} datagrams/s from foreign addresses")
        flood = flood_round(work, solver, duration=flood_s or flight_s, seed=seed + 1, hz=flood_hz,
                            rt_priority=rt_priority, cpu_latency_us=cpu_latency_us, pin=pin, load=os.getloadavg,
                            log=log)
    log("6. in-process reference (simulate, same solver)")
    ip = in_process(solver, flight_s, seed + 1)

    report = _report(runs, ip, solver, {"collect_s": collect_s if "collect" in runs else None, "flight_s": flight_s,
                                        "seed": seed, "config": str(config), "predictor": predictor,
                                        "rt_priority": rt_priority, "cpu_latency_us": cpu_latency_us, "pin": pin,
                                        "settle_s": 3.0})
    report["machine_wakeup_latency"] = machine
    report["flood_round"] = flood
    return write_report(report, out, t_start, format_table, log)


def _report(runs: dict[str, dict], ip: dict, solver: Path, settings: dict) -> dict:
    """reports/bridge.json from the flights over the link and the in-process reference."""
    lat, sent, dur, missed, ticks = [], 0, 0.0, 0, 0
    for name, rr in runs.items():
        s = rr["summary"]
        tl = load_ticklog(rr["ticks"]).ticks
        lat.append(tick_latency_us(tl))
        sent += s["setpoints_sent"]
        dur += s["duration_s"]
        missed += s["missed_ticks"]
        ticks += s["ticks"]
    lat = np.concatenate(lat)
    link = {k: truth_rmse(runs[k]["ticks"], runs[k]["truth"]) for k in ("baseline", "steered")}
    return {
        "rate_hz": sent / dur if dur > 0 else None,
        "latency_us": percentiles(lat),
        "missed_ticks": int(missed),
        "fallbacks": int(runs["steered"]["summary"]["fallbacks"]),
        "rmse_z": {"baseline": link["baseline"]["rmse_z"], "steered": link["steered"]["rmse_z"]},
        "rmse_z_telemetry": {"baseline": link["baseline"]["rmse_z_telemetry"],
                             "steered": link["steered"]["rmse_z_telemetry"]},
        "rmse_z_in_process": {"baseline": ip["baseline"]["rmse_z"], "steered": ip["steered"]["rmse_z"]},
        "steered_vs_in_process": link["steered"]["rmse_z"] / ip["steered"]["rmse_z"],
        "link_seconds": dur, "longest_run_s": max(rr["summary"]["duration_s"] for rr in runs.values()),
        "setpoints": sent, "ticks": ticks, "latency_samples": int(lat.size),
        "solver": str(solver), "scheduling": runs["steered"]["summary"].get("scheduling", ""),
        "runs": {k: {key: v["summary"][key] for key in ("rate_hz", "latency_us", "missed_ticks", "max_gap_ms",
                                                        "fallbacks", "fallback_reasons", "telemetry_gaps",
                                                        "duration_s", "rmse_z_measured", "stop_reason")}
                     | {"phase_lock": v["summary"].get("phase_lock")} for k, v in runs.items()},
        "steering": runs["steered"]["summary"].get("steering"),
        "in_process_steering": ip["steering"],
        "settings": settings,
        "kernel": {"release": os.uname().release, "preemption": kernel_preemption()},
    }


def probe_machine(seconds: float, rt_priority: int, cpu_latency_us: int, log=print) -> list[dict]:
    """Wake-up latency of a 1 kHz SCHED_FIFO sleeper per CPU, without and with the PM QoS request."""
    log(f"0. machine: kernel {os.uname().release}, preemption {kernel_preemption()}")
    log(f"   wake-up latency of a real-time sleeper, {seconds:g} s per CPU, without / with PM QoS")
    return probe_cpus(seconds, priority=rt_priority, cpu_latency_us=None if cpu_latency_us < 0 else cpu_latency_us,
                      log=lambda line: log("    " + line))


def format_table(r: dict) -> str:
    f = lambda v, fmt: "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)  # noqa: E731
    lat = r["latency_us"]
    rows = [
        ("rate", f(r["rate_hz"], "{:.1f} Hz"), "200 Hz"),
        ("latency p50 / p99 / max", f"{lat['p50']:.0f} / {lat['p99']:.0f} / {lat['max']:.0f} us", "p99 <= 1000 us"),
        ("missed ticks", f"{r['missed_ticks']} in {r['link_seconds']:.0f} s (longest run {r['longest_run_s']:.0f} s)",
         "0 over 60 s"),
        ("fallbacks (steered run)", str(r["fallbacks"]), ""),
        ("rmse z baseline (link / in-process)",
         f"{f(r['rmse_z']['baseline'], '{:.4f}')} / {f(r['rmse_z_in_process']['baseline'], '{:.4f}')} m", ""),
        ("rmse z steered  (link / in-process)",
         f"{f(r['rmse_z']['steered'], '{:.4f}')} / {f(r['rmse_z_in_process']['steered'], '{:.4f}')} m",
         f"ratio {r['steered_vs_in_process']:.2f} (<= 1.2)"),
    ]
    rows += flood_rows(r.get("flood_round"))
    w = max(len(a) for a, _, _ in rows)
    v = max(len(b) for _, b, _ in rows)
    lines = ["", f"bridge demo over UDP loopback ({r['scheduling'] or 'best effort'}; "
                 f"kernel preemption {r['kernel']['preemption']})"]
    lines += [f"  {a:<{w}}  {b:<{v}}  {c}" for a, b, c in rows]
    return "\n".join(lines)


_OUT = str(ROOT / "reports" / "bridge.json")
_FLY_CONFIG = str(ROOT / "configs" / "flying.toml")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ddpc_codegen.testbed.bridge_demo", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=_OUT)
    p.add_argument("--work", default=str(ROOT / "build" / "bridge-demo"), help="logs, dataset, generated solver")
    p.add_argument("--collect", type=float, default=None,
                   help="seconds of data collection over the link (default 60 flying, 120 hopping)")
    p.add_argument("--flight", type=float, default=20.0, help="seconds of each baseline / steered flight")
    p.add_argument("--solver", default=None, help="use this generated solver instead of collecting + codegen")
    p.add_argument("--config", default=_FLY_CONFIG)
    p.add_argument("--predictor", choices=("lsq", "pem", "config"), default="lsq",
                   help="predictor of the generated solver (default lsq: exact on LTI data; 'config' keeps the "
                        "config's [predictor])")
    p.add_argument("--rt-priority", type=int, default=30,
                   help="bridge SCHED_FIFO priority if permitted, vehicle 10 below (0: best effort)")
    p.add_argument("--cpu-latency-us", type=int, default=0,
                   help="PM QoS wake-up latency bound both processes hold [us] (-1: none; see firmware_bridge.realtime)")
    p.add_argument("--probe", type=float, default=4.0,
                   help="seconds per CPU of the machine wake-up latency probe before the flights (0: skip)")
    p.add_argument("--pin", action="store_true", help="pin the bridge and the vehicle to different CPUs")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--flood-hz", type=float, default=FLOOD_HZ,
                   help="flood round: datagrams/s from foreign addresses against the steered flight (0: no round)")
    p.add_argument("--flood-flight", type=float, default=None,
                   help="seconds of each flood-round flight (default: --flight)")
    p.add_argument("--scenario", choices=("flying", "hopping"), default="flying",
                   help="hopping: ddpc_codegen.testbed.bridge_demo_hopping (collect -> codegen configs/hopping.toml -> baseline -> "
                        "steered; default out reports/bridge_hopping.json, 120 s collect, lock-step)")
    p.add_argument("--realtime", action="store_true", help="hopping: real time instead of lock-step")
    p.add_argument("--noise", action="store_true", help="hopping: sensor noise on the vehicle (default: none, as make demo)")
    p.add_argument("--contact", choices=("estimate", "signal"), default="estimate",
                   help="hopping: the bridge's phases from telemetry alone (default) or the vehicle's contact signal")
    a = p.parse_args(argv)
    if a.scenario == "hopping":
        out = Path(a.out) if a.out != _OUT else ROOT / "reports" / "bridge_hopping.json"
        run_hopping_demo(out, Path(a.work), collect_s=a.collect or 120.0, flight_s=a.flight,
                         solver=Path(a.solver) if a.solver else None,
                         config=None if a.config == _FLY_CONFIG else Path(a.config), lockstep=not a.realtime,
                         noise=a.noise, contact=a.contact, rt_priority=a.rt_priority, seed=a.seed, log=lambda s: print(s, flush=True))
        return 0
    run_demo(Path(a.out), Path(a.work), collect_s=a.collect or 60.0, flight_s=a.flight,
             solver=Path(a.solver) if a.solver else None, config=Path(a.config), predictor=a.predictor,
             rt_priority=a.rt_priority, cpu_latency_us=a.cpu_latency_us, probe_s=a.probe, pin=a.pin, seed=a.seed,
             flood_hz=a.flood_hz, flood_s=a.flood_flight, log=lambda s: print(s, flush=True))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
