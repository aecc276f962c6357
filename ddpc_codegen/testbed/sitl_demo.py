"""The documented workflow against a real autopilot SITL: take off from the ground, fly the
baseline (passthrough), collect, generate the solver, steer, then the simple baselines (prefilter;
ILC: repeated flights of the same ellipse, :func:`fly_ilc`), then beyond the ellipse (a non-repeating
3-D steps file and unseen changes, :mod:`.sitl_conditions`) -- and the figures (``make sitl-demo``).
The steering config is whatever ``configs/sitl_<autopilot>.toml`` says.

Each flight is one ``ddpc-bridge`` process with ``--arm --offboard --takeoff --land``
(:mod:`.sitl_flight`): it arms the vehicle on the ground (retrying while the EKF initialises), takes off
to the trajectory start, flies, lands and waits for the disarm. The solver comes from ``ddpc-codegen codegen`` on the
collect flight's tick log (subprocesses: the bridge side never imports the design stack).

:func:`run_pipeline` works in the current network namespace; :func:`main` runs each available
autopilot in a private one (:func:`ddpc_codegen.testbed.sitl.run_isolated`) and writes
``reports/sitl.json``.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ThreadPoolExecutor
import json
import subprocess
import sys
import time
from pathlib import Path

from ddpc_codegen.experiments.report_file import nan_as_null, update_report
from ddpc_codegen.testbed.sitl import make_sitl, missing_reason, run_isolated
from ddpc_codegen.testbed.sitl_flight import ctrl_ff_profile, flight_figures, fly
from ddpc_codegen.testbed.sitl_conditions import (CONDITIONS, STEPS_DURATION, fly_condition, steered_estimator_rms,
                                                  summarize_rounds, write_steps_trajectory)
from ddpc_codegen.testbed.sitl_setups import SETUPS, describe_setup, flown_setup, setup_folder, setup_params
from firmware_bridge.ticklog import load_ticklog
from ddpc_codegen.design.baselines import ILC_CUTOFF_HZ, iterations_to_settle
from ddpc_codegen.design.baselines import fit_prefilter
from ddpc_codegen.testbed.ilc import next_table
from ddpc_codegen.testbed.sitl_front import steps_front
from ddpc_codegen.values.prefilter import PrefilterModel

__all__ = ["SITL_PARAMS", "CONFIGS", "COLLECT", "ILC_ITERATIONS", "fly_ilc", "run_pipeline", "run_setups", "merge_setups",
           "main", "format_condition"]

ROOT = Path(__file__).resolve().parents[2]  # the repository (ddpc_codegen/testbed/ -> .)
# ArduCopter: SET_ATTITUDE_TARGET.thrust as a thrust (GUID_OPTIONS bit 3), as the profile assumes.
SITL_PARAMS = {"ardupilot": {"GUID_OPTIONS": 8}, "px4": {}}
# Steering configs (configs/sitl_*.toml) and collect excitation: PX4's height responds ~0.1 s late,
# so it gets a 200 ms horizon and slower, larger PRBS bits (150 ms) to identify that response.
CONFIGS = {"ardupilot": "sitl_ardupilot.toml", "px4": "sitl_px4.toml"}
COLLECT = {"ardupilot": ("--excitation", "0.05,0.03", "--excitation-hold", "4"),
           "px4": ("--excitation", "0.15,0.03", "--excitation-hold", "30")}
# The steered flight takes its step guard from the profile ([steering] max_step: px4_sih 0.6 m, as a
# user flying the shipped PX4 config by hand gets it).
# ILC flights after the passthrough one (iteration 0): the in-process flying ILC settles at its
# second iteration; each flight here is a take-off, the ellipse and a landing (27-30 s of wall time).
ILC_ITERATIONS = 3


def codegen(config: Path, dataset: Path, out: Path) -> Path:
    """``ddpc-codegen codegen`` on a tick log; the generated solver folder."""
    cmd = [sys.executable, "-m", "ddpc_codegen.cli.main", "codegen", str(config), "--dataset", str(dataset),
           "--out", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if res.returncode != 0:
        raise RuntimeError(f"codegen failed ({res.returncode}):\n{res.stderr[-3000:]}")
    return Path(res.stdout.strip().splitlines()[-1])


def fit_prefilter_from_log(collect: Path, out: Path) -> Path:
    """The ``prefilter`` baseline (per channel gain + offset + lead) fitted on the collect flight's
    tick log as the in-process demo fits it (u and y low-passed at 1 Hz, leads up to 1 s); its JSON."""
    return fit_prefilter(load_ticklog(collect).to_dataset(), max_lead=200, smooth_hz=1.0).save(out)


def fly_ilc(sitl, autopilot: str, out: Path, duration: float, prefilter: Path,
            iterations: int = ILC_ITERATIONS, law: dict | None = None) -> dict:
    """ILC against the SITL: iteration 0 is the passthrough flight already flown
    (``<autopilot>_passthrough.npz``); each next one flies the same ellipse for ``duration`` s with
    the table learned so far (``--mode feedforward``, ``ilc_<i>.npz``), then its tick log updates
    the table (:func:`ddpc_codegen.testbed.ilc.next_table`, the in-process demo's law with this loop's
    prefilter; ``law``: other ``gain_scale`` / ``cutoff_hz``). The figures per iteration, the
    iteration it settled at, the last one's."""
    if iterations < 1:
        raise ValueError(f"ILC needs at least one iteration after the passthrough flight; got {iterations}")
    t0 = time.monotonic()
    pf = PrefilterModel.load(prefilter)
    logs = [out / f"{autopilot}_passthrough.npz"]
    per = [flight_figures(logs[0])]
    table = None
    for it in range(1, iterations + 1):
        table = next_table(logs[-1], table, pf, duration, **(law or {}))
        path = table.save(out / f"ilc_{it}.npz")
        fly(sitl, autopilot, "feedforward", out, duration, extra=("--feedforward", str(path)), tag=f"ilc{it}")
        logs.append(out / f"{autopilot}_ilc{it}.npz")
        per.append(flight_figures(logs[-1]))
    pick = lambda k: [f[k] for f in per]  # noqa: E731
    return {"rmse_z_per_iteration": pick("rmse_z"), "rmse_z_truth_per_iteration": pick("rmse_z_truth"),
            "thrust_step_rms_per_iteration": pick("thrust_step_rms"),
            "iterations_run": iterations, "iterations_to_settle": iterations_to_settle(pick("rmse_z")),
            "rmse_z": per[-1]["rmse_z"], "rmse_z_truth": per[-1]["rmse_z_truth"],
            "duration_s": duration, "wall_s": round(time.monotonic() - t0, 1),
            "law": {"gain_scale": 1.0, "cutoff_hz": ILC_CUTOFF_HZ, **(law or {}),
                    "what": "P-type, per channel lead d and gain gain_scale/g of this loop's prefilter, zero-phase "
                            "2nd-order Butterworth Q-filter at cutoff_hz; iteration 0 = passthrough; table row = "
                            "trajectory tick"}}


def run_pipeline(autopilot: str, out_dir: str, baseline_s: float = 13.0, collect_s: float = 30.0,
                 steer_s: float = 13.0, sitl_params: dict | None = None, baselines: bool = True,
                 ilc_iterations: int = ILC_ITERATIONS, ilc_law: dict | None = None,
                 conditions: list[str] | None = None, rounds: int = 2, steps_s: float = STEPS_DURATION,
                 trajectories: tuple[str, ...] = (), config: str | None = None, setup: str = "outdoor") -> dict:
    """Start the SITL here, fly baseline -> collect -> codegen -> steer (-> with ``baselines``: the
    prefilter baseline, identified from the same collect log, and ``ilc_iterations`` ILC flights of
    ``baseline_s`` each, :func:`fly_ilc`, with ``ilc_law`` if given; then each of ``conditions``
    (:data:`~ddpc_codegen.testbed.sitl_conditions.CONDITIONS`: "steps", "wind", "motor", "heavy") on
    the non-repeating steps file, ``rounds`` times, ``steps_s`` s per flight); with ``trajectories``
    (``--trajectory`` values, "steps" for the steps file) one more steered flight of ``steps_s`` s on each
    right after the steered ellipse (``steered_trajectories``); the figures (JSON-ready). ``config``: a
    steering config in ``configs/`` instead of the autopilot's default (:data:`CONFIGS`).
    ``sitl_params``: the SITL's extra parameters (default ``SITL_PARAMS``; e.g. ArduCopter's
    climb-rate mode: ``{"GUID_OPTIONS": 0}``). ``setup``: the estimation setup every flight flies in
    (:data:`~ddpc_codegen.testbed.sitl_setups.SETUPS`: "outdoor", the autopilot's EKF on its own sensors, or "lab",
    on the motion-capture stand-in), described in the result's ``setup``."""
    if conditions and not baselines:
        raise ValueError("conditions need the baselines (the prefilter is fitted there)")
    unknown = sorted(set(conditions or ()) - set(CONDITIONS[autopilot]))
    if unknown:
        raise ValueError(f"unknown condition(s) {unknown}; choose from {sorted(CONDITIONS[autopilot])}")
    params = setup_params(autopilot, setup, SITL_PARAMS[autopilot] if sitl_params is None else sitl_params)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    res: dict = {"autopilot": autopilot}
    with make_sitl(autopilot, params=params) as raw, flown_setup(raw, autopilot, setup) as sitl:
        base = fly(sitl, autopilot, "passthrough", out, baseline_s)
        fly(sitl, autopilot, "collect", out, collect_s, extra=("--dataset-skip", "1.0", *COLLECT[autopilot]))
        solver = codegen(ROOT / "configs" / (config or CONFIGS[autopilot]), out / f"{autopilot}_collect.npz",
                         out / "generated")
        steer = fly(sitl, autopilot, "steer", out, steer_s, solver=solver)
        for spec in trajectories:  # any trajectory steers with the solver collected on the ellipse
            path = str(write_steps_trajectory(out / "steps.csv")) if spec == "steps" else spec
            tag = trajectory_tag(spec)
            fly(sitl, autopilot, "steer", out, steps_s, solver=solver, extra=("--trajectory", path), tag=tag)
            res.setdefault("steered_trajectories", {})[spec] = flight_figures(out / f"{autopilot}_{tag}.npz")
        if baselines:
            pf = fit_prefilter_from_log(out / f"{autopilot}_collect.npz", out / "prefilter.json")
            fly(sitl, autopilot, "prefilter", out, baseline_s, extra=("--prefilter", str(pf)))
            fly(sitl, autopilot, "passthrough", out, baseline_s, extra=("--profile", str(ctrl_ff_profile(autopilot, out))),
                tag="ctrl_ff")
            ilc = fly_ilc(sitl, autopilot, out, baseline_s, pf, ilc_iterations, ilc_law)
        if conditions:
            steps = write_steps_trajectory(out / "steps.csv")
            res["conditions"] = {name: fly_condition(sitl, autopilot, name, out, steps, solver, pf, rounds, steps_s)
                                 for name in conditions}
    res["setup"] = describe_setup(autopilot, setup, sitl.mocap)
    if "steps" in res.get("conditions", {}):
        add_steps_front(res["conditions"]["steps"], out, autopilot, ROOT / "configs" / (config or CONFIGS[autopilot]))
    fb, fs = flight_figures(out / f"{autopilot}_passthrough.npz"), flight_figures(out / f"{autopilot}_steer.npz")
    if baselines:
        res["baselines"], ellipse = ellipse_figures(out, autopilot, ilc)
        res["conditions"] = {"ellipse": ellipse, **res.get("conditions", {})}
    res.update({
        "rmse_z": {"baseline": fb["rmse_z"], "steered": fs["rmse_z"]},
        "rmse_z_truth": {"baseline": fb["rmse_z_truth"], "steered": fs["rmse_z_truth"]},
        "estimator_rms": {"baseline": fb["estimator_rms"], "steered": fs["estimator_rms"]},
        "engaged_fraction": fs["engaged_fraction"], "engaged_share": fs["engaged_share"],
        "thrust_step_rms": {"baseline": fb["thrust_step_rms"], "steered": fs["thrust_step_rms"]},
        "rate_hz": steer["rate_hz"], "latency_us": steer["latency_us"], "fallbacks": steer["fallbacks"],
        "fallback_reasons": steer["fallback_reasons"], "missed_ticks": steer["missed_ticks"],
        "telemetry": steer["telemetry"], "arming": base.get("arming"),
        "approach": {"baseline": base.get("approach"), "steered": steer.get("approach")},
        "wall_s": round(time.monotonic() - t0, 1),
    })
    return res


def run_setups(autopilot: str, out_dir: str, setups: list[str], **kw) -> dict:
    """:func:`run_pipeline` in each of ``setups`` in turn (one SITL each, in ``<out_dir>/``
    :func:`~ddpc_codegen.testbed.sitl_setups.setup_folder`), ``kw`` for every one; the results per setup."""
    return {s: run_pipeline(autopilot, str(Path(out_dir) / setup_folder(autopilot, s)), setup=s, **kw) for s in setups}


def merge_setups(old: dict | None, new: dict[str, dict]) -> dict:
    """One autopilot's entry of ``sitl.json`` from its stored one (``old``) and the setups just flown (``new``):
    the outdoor result at the top (as before the lab existed), the lab one under ``lab``; a setup not flown now
    keeps its stored result."""
    old = old or {}
    outdoor = new.get("outdoor", {k: v for k, v in old.items() if k != "lab"})
    lab = new.get("lab", old.get("lab"))
    return {**outdoor, **({"lab": lab} if lab is not None else {})}


def trajectory_tag(spec: str) -> str:
    """The flight tag (``<autopilot>_<tag>.npz``) of the steered flight on a ``--trajectory`` value."""
    return "steer_" + "".join(ch for ch in Path(spec).stem if ch.isalnum())


def ellipse_figures(out: Path, autopilot: str, ilc: dict) -> tuple[dict, dict]:
    """The ellipse's flights (passthrough, ctrl ff, prefilter, ILC, steered) in ``out``: the
    ``baselines`` figures, and the same as a condition (estimator error and reference steps too)."""
    f = {m: flight_figures(out / f"{autopilot}_{name}.npz") for m, name in
         (("passthrough", "passthrough"), ("ctrl_ff", "ctrl_ff"), ("prefilter", "prefilter"), ("steered", "steer"))}
    pick = lambda key, ilc_value: {"passthrough": f["passthrough"][key], "ctrl_ff": f["ctrl_ff"][key],  # noqa: E731
                                   "prefilter": f["prefilter"][key], "ilc": ilc_value, "steered": f["steered"][key]}
    baselines = {"rmse_z": pick("rmse_z", ilc["rmse_z"]), "rmse_z_truth": pick("rmse_z_truth", ilc["rmse_z_truth"]),
                 "thrust_step_rms": pick("thrust_step_rms", ilc["thrust_step_rms_per_iteration"][-1]),
                 "prefilter": json.loads((out / "prefilter.json").read_text())["prefilter"], "ilc": ilc}
    ellipse = {k: baselines[k] for k in ("rmse_z", "rmse_z_truth", "thrust_step_rms")}
    ellipse.update(estimator_rms={m: v["estimator_rms"] for m, v in f.items()},
                   ekf_rms={m: v.get("ekf_rms") for m, v in f.items()},
                   max_ref_step={m: v["max_ref_step"] for m, v in f.items()},
                   max_offset_step={m: v["max_offset_step"] for m, v in f.items()},
                   solve_us_p99={m: v["solve_us_p99"] for m, v in f.items()})
    return baselines, ellipse


def main(argv: list[str] | None = None) -> int:
    """``make sitl-demo``: every available SITL, each in a private network namespace."""
    p = argparse.ArgumentParser(prog="python -m ddpc_codegen.testbed.sitl_demo", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=str(ROOT / "reports"), help="folder for sitl.json and the flight logs")
    p.add_argument("--autopilot", action="append", choices=("px4", "ardupilot"), help="default: every available")
    p.add_argument("--conditions", default="steps,wind,motor,heavy",
                   help="after the ellipse, on the non-repeating steps file (comma list, 'none': skip; default %(default)s)")
    p.add_argument("--rounds", type=int, default=2, help="flights of each method per condition (default %(default)s)")
    p.add_argument("--setups", default=",".join(SETUPS),
                   help="estimation setups to fly, each with every flight (comma list of outdoor, lab; default "
                        "%(default)s): outdoor the autopilot's EKF on its own sensors, lab on the motion-capture "
                        "stand-in; a setup not flown keeps its stored figures")
    p.add_argument("--steps-s", type=float, default=STEPS_DURATION, help="seconds of each steps-file flight")
    p.add_argument("--fit-prefilter", metavar="COLLECT_LOG", default=None,
                   help="only fit the prefilter baseline on a collect flight's tick log (as the demo does) and exit")
    p.add_argument("--prefilter-out", default="prefilter.json", help="where --fit-prefilter writes (default %(default)s)")
    p.add_argument("--write-steps", metavar="CSV", default=None,
                   help="only write the demo's non-repeating 3-D steps trajectory file and exit")
    p.add_argument("--rescore", action="store_true",
                   help="fly nothing: score <out>/sitl.json's flights again (the ellipse from its tick logs, each "
                        "condition from its rounds) and print them")
    a = p.parse_args(argv)
    if a.rescore:
        if not (Path(a.out) / "sitl.json").is_file():
            p.error(f"--rescore: {Path(a.out) / 'sitl.json'} not found (make sitl-demo writes it)")
        return rescore(Path(a.out))
    if a.fit_prefilter or a.write_steps:
        if a.fit_prefilter:
            print(fit_prefilter_from_log(Path(a.fit_prefilter), Path(a.prefilter_out)))
        if a.write_steps:
            print(write_steps_trajectory(a.write_steps))
        return 0
    conds = [] if a.conditions.strip() == "none" else comma_list(a.conditions)
    if a.rounds < 1:
        p.error(f"--rounds must be >= 1; got {a.rounds}")
    setups = comma_list(a.setups)
    if not setups or set(setups) - set(SETUPS):
        p.error(f"--setups: choose from {', '.join(SETUPS)}; got {a.setups!r}")
    jobs = {}
    for ap in available_autopilots(a.autopilot, "sitl-demo"):
        flights = sum(not isinstance(CONDITIONS[ap].get(c), str) for c in conds) * a.rounds * 4
        print(f"[sitl-demo] {ap} ({', '.join(setups)}): ground -> baseline -> collect -> codegen -> steer -> "
              f"prefilter, ctrl ff, ilc{f' -> {len(conds)} condition(s) x {a.rounds} round(s): {flights} more flights' if conds else ''} "
              "(~40 s of wall time per flight) ...", flush=True)
        jobs[ap] = ("ddpc_codegen.testbed.sitl_demo:run_setups",
                    {"autopilot": ap, "out_dir": str(Path(a.out)), "setups": setups, "conditions": conds,
                     "rounds": a.rounds, "steps_s": a.steps_s}, (900 + 120 * flights) * len(setups))
    flown, failed = fly_autopilots(jobs, "sitl-demo")
    path = Path(a.out) / "sitl.json"
    stored = json.loads(path.read_text()) if path.is_file() else {}
    report = {ap: merge_setups(stored.get(ap), per_setup) for ap, per_setup in flown.items()}
    for ap, res in report.items():
        print_setups(ap, res)
    update_report(path, report, default=nan_as_null)
    return 0 if report and not failed else 1


def rescore(out: Path) -> int:
    """Score the flights of ``out/sitl.json`` again with today's figures, without flying: each autopilot's
    ellipse from its tick logs, each condition from its stored rounds; print and write them back."""
    report = json.loads((out / "sitl.json").read_text())
    for ap, entry in report.items():
        if ap not in CONDITIONS:
            continue
        for setup, res in (("outdoor", entry), ("lab", entry.get("lab"))):
            if res is not None and "conditions" in res:
                rescore_setup(out / setup_folder(ap, setup), ap, res)
        print_setups(ap, entry)
    update_report(out / "sitl.json", report, default=nan_as_null)
    return 0


def rescore_setup(folder: Path, ap: str, res: dict) -> None:
    """One setup's result of autopilot ``ap`` scored again (in place) from its flights in ``folder``."""
    conds = res["conditions"]
    for name, c in conds.items():
        if name != "ellipse" and "rounds" in c:
            conds[name] = {**c, **summarize_rounds(rescored_rounds(folder, ap, name, c["rounds"]))}
    if "ellipse" in conds:
        res["baselines"], conds["ellipse"] = ellipse_figures(folder, ap, res["baselines"]["ilc"])
    if "steps" in conds and "rounds" in conds["steps"]:
        config = (conds["steps"].get("front") or {}).get("config") or CONFIGS[ap]
        add_steps_front(conds["steps"], folder, ap, ROOT / "configs" / config)


def add_steps_front(steps: dict, folder: Path, autopilot: str, config: Path) -> None:
    """The steps condition's ``front`` (:func:`~ddpc_codegen.testbed.sitl_front.steps_front`), at the steered
    flights' mean reference activity."""
    steps["front"] = steps_front(folder, autopilot, config, (steps.get("ref_rate_ratio") or {}).get("steered"))


def rescored_rounds(folder: Path, autopilot: str, name: str, rounds: list[dict]) -> list[dict]:
    """The rounds of condition ``name`` with each flight's figures computed again from its tick log
    (``<autopilot>_<name>_<method>_r<k>.npz`` in ``folder``; a flight without its log keeps its stored figures)."""
    out = []
    for k, figs in enumerate(rounds):
        new = {}
        for method, f in figs.items():
            log = folder / f"{autopilot}_{name}_{method}_r{k}.npz"
            new[method] = {**f, **flight_figures(log)} if log.exists() else f
        out.append(new)
    return out


def comma_list(text: str) -> list[str]:
    """The non-empty, stripped items of a command line's comma list."""
    return [c.strip() for c in text.split(",") if c.strip()]


def available_autopilots(requested: list[str] | None, tag: str) -> list[str]:
    """The requested autopilots (default: both) whose SITL is found; each one missing is said and skipped."""
    found = []
    for ap in requested or ["px4", "ardupilot"]:
        why = missing_reason(ap)
        if why:
            print(f"[{tag}] {ap}: skipped: {why}", flush=True)
        else:
            found.append(ap)
    return found


def fly_autopilots(jobs: dict[str, tuple[str, dict, float]], tag: str) -> tuple[dict, list[str]]:
    """Run each autopilot's job ``(module:function, kwargs, timeout [s])`` at once, each SITL and its bridges in
    a private network namespace (:func:`run_isolated`); (results per autopilot, the autopilots that failed:
    one failure never discards the other's flights)."""
    results, failed = {}, []
    with ThreadPoolExecutor(max_workers=max(1, len(jobs))) as pool:
        futures = {ap: pool.submit(run_isolated, fn, kw, timeout=t) for ap, (fn, kw, t) in jobs.items()}
        for ap, fut in futures.items():
            try:
                results[ap] = fut.result()
            except Exception as e:
                failed.append(ap)
                print(f"[{tag}] {ap}: FAILED: {e}", flush=True)
    return results, failed


def print_setups(ap: str, entry: dict) -> None:
    """The printed lines of one autopilot's entry: its outdoor result (if flown), then its lab one."""
    if "rmse_z" in entry:
        print_result(ap, entry)
    if entry.get("lab") is not None:
        print_result(f"{ap} lab", entry["lab"])


def print_result(ap: str, res: dict) -> None:
    """The printed lines of one autopilot: the ellipse, the baselines, each condition and its target."""
    r, rt = res["rmse_z"], res["rmse_z_truth"]
    truth = (f" (true height {1e3 * rt['baseline']:.1f} -> {1e3 * rt['steered']:.1f} mm)"
             if rt["baseline"] is not None and rt["steered"] is not None else "")
    print(f"[sitl-demo] {ap}: rmse z {1e3 * r['baseline']:.1f} -> {1e3 * r['steered']:.1f} mm{truth}, "
          f"steered {100 * res['engaged_fraction']:.1f} %, rate {res['rate_hz']:.1f} Hz, "
          f"fallbacks {res['fallbacks']}, {res['wall_s']:.0f} s", flush=True)
    for flight, ap_end in res["approach"].items():
        if ap_end is not None and not ap_end["held"]:
            print(f"[sitl-demo] {ap}: WARNING: the {flight} flight started {ap_end['error_at_start_m']:+.3f} m off its "
                  f"start height (did not hold it within {ap_end['timeout_s']:g} s)", flush=True)
        if ap_end is not None and ap_end.get("trim_m"):
            print(f"[sitl-demo] {ap}: the {flight} flight's take-off trimmed its reference {ap_end['trim_m']:+.3f} m "
                  "to reach its start", flush=True)
    if "baselines" in res:
        print(format_baselines(ap, res["baselines"]), flush=True)
    for name, c in res.get("conditions", {}).items():
        print(format_condition(ap, name, c), flush=True)


def format_condition(ap: str, name: str, c: dict) -> str:
    """One condition's lines: each method's EKF and true-height RMSE, the estimator's error, and the
    target: steered >= 2x better than the best simple method on the true height (or within 1.2x of
    the estimator's error), >= 10x better than passthrough on the ellipse."""
    if "skipped" in c:
        return f"[sitl-demo] {ap} {name}: {c['skipped']}"
    mm = lambda v: "-" if v is None else f"{1e3 * v:.1f}"  # noqa: E731
    lines = []
    for key, what in (("rmse_z", "EKF"), ("rmse_z_truth", "true")):
        v = c[key]
        lines.append(f"[sitl-demo] {ap} {name} {what} height rmse: " + ", ".join(
            f"{m.replace('_', ' ')} {mm(v.get(m))}" for m in ("passthrough", "ctrl_ff", "prefilter", "ilc", "steered"))
            + " mm")
    vt = c["rmse_z_truth"]
    simple = [vt.get(m) for m in ("ctrl_ff", "prefilter", "ilc") if vt.get(m) is not None]
    if vt.get("steered") and simple:
        best, est = min(simple), steered_estimator_rms(c)
        goal = f">= 10x passthrough ({vt['passthrough'] / vt['steered']:.1f}x)" if name == "ellipse" else (
            f">= 2x the best simple method ({best / vt['steered']:.2f}x)")
        est_txt = f"; estimator error in the steered flights {mm(est)} mm (steered {vt['steered'] / est:.2f}x of it)" if est else ""
        thr = c.get("thrust_step_rms") or {}
        thr_txt = (f"; thrust step {thr['steered'] / thr['passthrough']:.1f}x passthrough's"
                   if thr.get("steered") and thr.get("passthrough") else "")
        solve = (c.get("solve_us_p99") or {}).get("steered")
        solve_txt = f"; solve p99 in flight {solve / 1e3:.2f} ms (<= 1 ms)" if solve is not None else ""
        stalls, stale = ((c.get(k) or {}).get("steered") for k in ("stalls", "stale_ticks"))
        solve_txt += f"; bridge stalls {stalls:g}, stale ticks {stale:g}" if stalls is not None and stale is not None else ""
        sat = (c.get("guard_saturations") or {}).get("steered")
        solve_txt += f", guard saturations {sat:g}" if sat is not None else ""
        ch, st = c.get("rmse_z_truth_changing") or {}, c.get("rmse_z_truth_steady") or {}
        if ch.get("steered") is not None and st.get("steered") is not None:
            est_txt += (f"; true height near path changes / steady: steered {mm(ch['steered'])} / "
                        f"{mm(st['steered'])}, prefilter {mm(ch.get('prefilter'))} / {mm(st.get('prefilter'))} mm")
        lines.append(f"[sitl-demo] {ap} {name} target {goal}{est_txt}; largest reference step "
                     f"{mm((c.get('max_ref_step') or {}).get('steered'))} mm per tick (of the correction u - r_nom "
                     f"{mm((c.get('max_offset_step') or {}).get('steered'))}){thr_txt}{solve_txt}")
    return "\n".join(lines)


def format_baselines(ap: str, b: dict) -> str:
    """The printed baselines lines: height RMSE of each method (EKF; true height where the SITL
    sends it) and the ILC's per iteration [mm]."""
    mm = lambda v: "-" if v is None else f"{1e3 * v:.1f}"  # noqa: E731
    lines = []
    for key, what in (("rmse_z", "rmse z"), ("rmse_z_truth", "true height rmse")):
        r = b[key]
        if r["passthrough"] is None:
            continue
        lines.append(f"[sitl-demo] {ap}: baselines {what}: passthrough {mm(r['passthrough'])}, ctrl ff "
                     f"{mm(r.get('ctrl_ff'))}, prefilter {mm(r['prefilter'])}, ilc {mm(r['ilc'])}, "
                     f"steered {mm(r['steered'])} mm")
    il = b["ilc"]
    for key, what in (("rmse_z_per_iteration", "rmse z"), ("rmse_z_truth_per_iteration", "true height")):
        if il[key][0] is not None:
            lines.append(f"[sitl-demo] {ap}: ilc {what} per iteration: {', '.join(mm(v) for v in il[key])} mm "
                         f"(0 = passthrough)")
    lines.append(f"[sitl-demo] {ap}: ilc within 10 % of its best at iteration {il['iterations_to_settle']} "
                 f"of {il['iterations_run']}")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
