"""Online adaptation on the real SITLs (issue 30, item 5): a vehicle change applied MID-FLIGHT while
``ddpc-bridge`` keeps flying, static steering vs adapted steering (``--adapt``) vs the prefilter
(``make sitl-adapt``).

Per autopilot: one collect flight, one solver generated from ``configs/sitl_<autopilot>.toml`` (its
``[adapt]`` section), the prefilter fitted on the same collect; then, ``rounds`` times, every condition
(``nominal``: no change; ``motor`` and ``heavy``: :data:`~ddpc_codegen.testbed.sitl_conditions.CONDITIONS`)
with every method on the steps file. The change is made by this harness at trajectory time
:data:`CHANGE_S` over a second MAVLink link of the SITL (ArduCopter: its SERIAL1 TCP server, port
5762 + 10 * instance; PX4: its GCS link, which sends to UDP 14550), while the bridge holds the first;
it is undone after the landing over the first link (:meth:`~ddpc_codegen.testbed.sitl.Sitl.set_params`).
The trajectory start is the bridge's own ``trajectory starts`` event in its output file (``--verbose``).

Figures per flight (:func:`window_figures`, through :func:`ddpc_codegen.flight_metrics.flight_metrics`):
the EKF and true-height RMSE and the estimator's error in the nominal part ``[SETTLE_S, t_change)`` and in
the ``WINDOW_S`` s after the change; the adaptation's counters from the tick log's ``adapt`` codes.
``reports/sitl.json`` gets them under ``adaptation`` (the other keys are kept, :func:`merge_report`).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.flight_metrics import flight_metrics
from ddpc_codegen.runtime.adapt_loop import ADAPT_CODES, UPDATE_CODES, VERDICT_CODES
from ddpc_codegen.values.adapt import REJECTIONS
from ddpc_codegen.testbed.sitl import Sitl, SitlError, make_sitl
from ddpc_codegen.testbed.sitl_conditions import CONDITIONS, write_steps_trajectory
from ddpc_codegen.testbed.sitl_flight import fly
from ddpc_codegen.testbed.sitl_setups import second_link
from ddpc_codegen.testbed.sitl_demo import (COLLECT, CONFIGS, ROOT, SITL_PARAMS, codegen, fit_prefilter_from_log,
                                            available_autopilots, comma_list, fly_autopilots)
from ddpc_codegen.experiments.report_file import nan_as_null, update_report
from firmware_bridge.ticklog import load_ticklog

__all__ = ["CHANGE_S", "WINDOW_S", "LEARN_S", "DURATION_S", "SETTLE_S", "METHODS", "ADAPT_CONDITIONS", "second_link", "send_params",
           "window_figures", "adapt_tick_counts", "change_cost", "summarize", "merge_report", "flight_record", "rescore", "run_adapt", "format_adaptation", "main"]

CHANGE_S, WINDOW_S, SETTLE_S = 10.0, 10.0, 3.0  # trajectory time of the change, scoring window after it, settle [s]
# The first seconds after the change, before a re-solved G can know it: the SITL configs verify a candidate on the
# last 2 s of columns ([adapt] window 400 at 200 Hz), so until then the window still holds pre-change data.
LEARN_S = 2.0
DURATION_S = CHANGE_S + WINDOW_S + 2.0  # each flight's trajectory seconds (the window ends 2 s before the landing)
METHODS = ("static", "adapted", "prefilter")
ADAPT_CONDITIONS = ("nominal", "motor", "heavy")
# The bridge's verbose events that end the approach (its "engaged" line also names "trajectory starts", mid-line).
START_EVENTS = ("trajectory starts", "trajectory starts anyway")


def send_params(conn, params: dict[str, float], timeout: float = 5.0) -> tuple[float, float]:
    """PARAM_SET every parameter on an open connection (repeated each 0.5 s until echoed); the monotonic
    times [s] of the first send and of the last confirmation. Raises SitlError when not confirmed."""
    got: set[str] = set()
    t_first = time.monotonic()
    t_end, next_send = t_first + timeout, 0.0
    while len(got) < len(params) and time.monotonic() < t_end:
        if time.monotonic() >= next_send:
            next_send = time.monotonic() + 0.5
            for name, value in params.items():  # dict order: ArduCopter's factor before its motor mask
                if name not in got:
                    conn.mav.param_set_send(conn.target_system, conn.target_component, name.encode(), float(value), 9)
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.05)
        if msg is not None:
            name = (msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="ignore")).rstrip("\x00")
            if name in params and abs(float(msg.param_value) - params[name]) <= 1e-4 * max(1.0, abs(params[name])):
                got.add(name)
    if len(got) < len(params):
        raise SitlError(f"mid-flight change not confirmed within {timeout:g} s: {sorted(set(params) - got)}")
    return t_first, time.monotonic()


class MidFlightChange(threading.Thread):
    """Watches a flight's output file for the bridge's trajectory start, then sets ``params`` over the
    SITL's second link ``at_s`` seconds later. ``result``: the trajectory times [s] of the first send and
    of the confirmation (``sent_s``, ``confirmed_s``), or ``error``. Stop it with :attr:`done` after the flight."""

    def __init__(self, sitl: Sitl, out_file: Path, params: dict[str, float], at_s: float = CHANGE_S):
        super().__init__(daemon=True)
        self.sitl, self.out_file, self.params, self.at_s = sitl, out_file, params, at_s
        self.done = threading.Event()
        self.result: dict[str, Any] = {}

    def run(self) -> None:
        try:
            t0 = self._wait_start()
            if t0 is None:
                self.result = {"error": "the flight ended before its trajectory started"}
                return
            conn = second_link(self.sitl).connect(timeout=5.0)
            try:
                # polling at 10 ms: the change time is known to ~10 ms (the event's line -> this read)
                if self.done.wait(max(0.0, t0 + self.at_s - time.monotonic())):
                    self.result = {"error": "the flight ended before the change"}
                    return
                t_sent, t_ok = send_params(conn, self.params)
            finally:
                conn.close()
            self.result = {"sent_s": round(t_sent - t0, 3), "confirmed_s": round(t_ok - t0, 3)}
        except Exception as e:  # reported with the flight, which goes on
            self.result = {"error": f"{type(e).__name__}: {e}"}

    def _wait_start(self) -> float | None:
        while not self.done.is_set():
            if self.out_file.exists() and _started(self.out_file.read_text(errors="replace")):
                return time.monotonic()
            self.done.wait(0.01)
        return None


def _started(text: str) -> bool:
    """A bridge output (``--verbose``) has the event that starts the trajectory (a line ending with it)."""
    return any(line.rstrip().endswith(START_EVENTS) for line in text.splitlines())


def adapt_tick_counts(codes: np.ndarray, t_traj: np.ndarray, t_change: float) -> dict[str, Any]:
    """From the tick log's ``adapt`` codes (N,) (:data:`ADAPT_CODES`) and trajectory times (N,) [s]: columns
    folded in (``updates``), columns the solver refused (``refused``), re-solves, accepted swaps and rejections by
    reason, over the whole flight and
    (``*_after``) from ``t_change`` on."""
    codes = np.asarray(codes).astype(int).ravel()
    after = np.nan_to_num(np.asarray(t_traj, dtype=float).ravel(), nan=-np.inf) >= t_change
    idx = {k: i for i, k in enumerate(ADAPT_CODES)}
    verdict = np.isin(codes, VERDICT_CODES)
    out: dict[str, Any] = {}
    for suffix, win in (("", np.ones_like(after)), ("_after", after)):
        out["updates" + suffix] = int(np.sum(np.isin(codes, UPDATE_CODES) & win))
        out["refused" + suffix] = int(np.sum((codes == idx["refused"]) & win))
        out["resolves" + suffix] = int(np.sum(verdict & win))
        out["accepted" + suffix] = int(np.sum((codes == idx["accepted"]) & win))
        out["rejected" + suffix] = {r: int(np.sum((codes == idx[r]) & win)) for r in REJECTIONS
                                    if np.any((codes == idx[r]) & win)}
    return out


def window_figures(log_path: Path, t_change: float, window: float = WINDOW_S, settle: float = SETTLE_S) -> dict:
    """One flight's figures: ``before`` (nominal part, trajectory time in [settle, t_change)) and ``after``
    ([t_change, t_change + window)), each rmse_z (EKF), rmse_z_truth, estimator_rms [m], ticks, over the active
    ticks (:func:`~ddpc_codegen.flight_metrics.flight_metrics`); ``floor``: the true-height RMS of the window
    after the change if the error were zero from :data:`LEARN_S` s after it on (:func:`_floor`); ``adapt``:
    :func:`adapt_tick_counts`."""
    t = load_ticklog(log_path).ticks
    tt = np.nan_to_num(t["t_traj"], nan=-np.inf)
    zt = t["truth_position"][:, 2] if "truth_position" in t else None
    out: dict[str, Any] = {}
    for key, lo, hi in (("before", settle, t_change), ("after", t_change, t_change + window)):
        f = flight_metrics(t["t_traj"], t["y"], t["y_des"], settle=lo, active=t["active"] & (tt < hi), z_truth=zt)
        out[key] = {"rmse_z": f["rmse"][0], "rmse_z_truth": f.get("rmse_z_truth"),
                    "estimator_rms": f.get("estimator_rms"), "ticks": f["ticks"]}
    f = flight_metrics(t["t_traj"], t["y"], t["y_des"], settle=t_change, active=t["active"] & (tt < t_change + LEARN_S),
                       z_truth=zt)
    out["floor"] = _floor(f.get("rmse_z_truth"), f["ticks"], out["after"]["ticks"])
    out["adapt"] = adapt_tick_counts(t["adapt"], t["t_traj"], t_change)
    return out


def _floor(first_rms: float | None, first_ticks: int, window_ticks: int) -> float | None:
    """The after-change window's true-height RMS if every tick after the first :data:`LEARN_S` s had no error:
    what no learner that needs data of the change can go below [m]."""
    if first_rms is None or not window_ticks:
        return None
    return float(first_rms * np.sqrt(first_ticks / window_ticks))


def _mean(vals: list) -> float | None:
    return None if not vals or any(v is None for v in vals) else float(np.mean(vals))


def summarize(per_round: list[dict[str, dict]]) -> dict[str, Any]:
    """One condition's rounds (each method -> :func:`window_figures` + ``fallbacks``) -> per method the mean over
    the rounds of each figure (``before`` / ``after`` x rmse_z, rmse_z_truth, estimator_rms; None if any round has
    none), ``floor`` (:func:`_floor`, mean of the rounds), the adaptation counters summed, the range of the
    accepted swaps' error ratios (``accepted_ratio_range``: [min, max] over the rounds, None without a swap), and
    ``static_over_adapted`` (true height, after / before the change)."""
    out: dict[str, Any] = {}
    for m in METHODS:
        runs = [r[m] for r in per_round if m in r]
        if not runs:
            continue
        fig: dict[str, Any] = {w: {k: _mean([r[w][k] for r in runs]) for k in ("rmse_z", "rmse_z_truth", "estimator_rms")}
                               for w in ("before", "after")}
        fig["fallbacks"] = sum(int(r.get("fallbacks") or 0) for r in runs)
        fig["missed_ticks"] = sum(int(r.get("missed_ticks") or 0) for r in runs)
        fig["max_gap_ms"] = max((r["max_gap_ms"] for r in runs if r.get("max_gap_ms") is not None), default=None)
        fig["flights"] = len(runs)
        fig["floor"] = _mean([r.get("floor") for r in runs])
        if m == "adapted":
            c: dict[str, Any] = {}
            for r in runs:
                _add_counts(c, r["adapt"])
            fig["adapt"] = c
            acc = [x for r in runs for x in r.get("accepted_ratios", [])]
            # what a swap cut: the same range in nominal flight as after a change is a margin that cannot tell them apart
            fig["accepted_ratio_range"] = [min(acc), max(acc)] if acc else None
        out[m] = fig
    if "static" in out and "adapted" in out:
        ratio = lambda w: (out["static"][w]["rmse_z_truth"] / out["adapted"][w]["rmse_z_truth"]  # noqa: E731
                           if out["static"][w]["rmse_z_truth"] and out["adapted"][w]["rmse_z_truth"] else None)
        out["static_over_adapted"] = {"after": ratio("after"), "before": ratio("before")}
    out["rounds"] = per_round
    return out


def _add_counts(total: dict, counts: dict) -> None:
    """In place: ``total`` += ``counts`` (nested dicts of integers, keys unioned)."""
    for k, v in counts.items():
        if isinstance(v, dict):
            _add_counts(total.setdefault(k, {}), v)
        else:
            total[k] = total.get(k, 0) + v


def merge_report(path: Path, adaptation: dict) -> dict:
    """Load ``path`` (a JSON object; {} if absent), replace only its ``adaptation`` key, write it back; the result.
    The figures of an autopilot not flown this time (``--autopilot`` the other one) are kept."""
    prev = json.loads(path.read_text()) if path.is_file() else {}
    flown = (prev.get("adaptation") or {}).get("autopilots") if isinstance(prev, dict) else None
    if isinstance(flown, dict) and isinstance(adaptation.get("autopilots"), dict):
        adaptation = {**adaptation, "autopilots": {**flown, **adaptation["autopilots"]}}
    return update_report(path, {"adaptation": adaptation}, default=nan_as_null)


def _fly_one(sitl: Sitl, autopilot: str, cond: str, method: str, r: int, out: Path, steps: Path, solver: Path,
             prefilter: Path) -> dict:
    """One flight of ``method`` with ``cond`` applied at :data:`CHANGE_S` (undone after the landing); its figures."""
    spec = CONDITIONS[autopilot].get(cond, ({}, {}))
    apply, undo = spec if not isinstance(spec, str) else ({}, {})
    tag = f"adapt_{cond}_{method}_r{r}"
    mode, extra = {"static": ("steer", ()), "adapted": ("steer", ("--adapt",)),
                   "prefilter": ("prefilter", ("--prefilter", str(prefilter)))}[method]
    (out / f"{autopilot}_{tag}.out").unlink(missing_ok=True)  # a stale file would fake the start event
    change = MidFlightChange(sitl, out / f"{autopilot}_{tag}.out", apply) if apply else None
    if change is not None:
        change.start()
    try:
        # one attempt: a second one would fly without the change (its watcher has seen the first start)
        fly(sitl, autopilot, mode, out, DURATION_S, solver=solver if mode == "steer" else None,
            extra=("--trajectory", str(steps), *extra), tag=tag, attempts=1)
    finally:
        if change is not None:
            change.done.set()
            change.join(10.0)
            sitl.set_params(undo)  # the bridge has exited: the first link is free
    at = change.result if change is not None else {"sent_s": None}
    if "error" in at:  # kept with the flight's figures (scored from CHANGE_S) rather than losing the other flights
        print(f"[sitl-adapt] {autopilot} {tag}: WARNING: the change was not made: {at['error']}", flush=True)
    return flight_record(out, autopilot, tag, at)


def flight_record(out: Path, autopilot: str, tag: str, change: dict) -> dict:
    """A flown flight's figures from its files (``<autopilot>_<tag>.npz`` / ``.json`` in ``out``): :func:`window_figures`
    around ``change["sent_s"]`` (:data:`CHANGE_S` without one), the fallbacks, the loop's missed ticks and largest
    gap [ms] (a re-solve runs inside a tick), the bridge's adaptation counters, ``change``, and ``error_ratios``:
    each re-solve's candidate-over-current prediction error on its recent window, in flight order (what
    ``[adapt] min_improvement`` is set against), and ``accepted_ratios``: those of the swaps accepted."""
    summary = json.loads((out / f"{autopilot}_{tag}.json").read_text())
    f = window_figures(out / f"{autopilot}_{tag}.npz", change.get("sent_s") or CHANGE_S)
    adaptation = (summary.get("steering") or {}).get("adaptation") or {}
    f.update(fallbacks=summary.get("fallbacks"), missed_ticks=summary.get("missed_ticks"),
             max_gap_ms=summary.get("max_gap_ms"), change=change, bridge_counts=adaptation.get("counts"),
             error_ratios=[round(e[6], 4) for e in adaptation.get("events", [])
                           if len(e) > 6 and e[6] is not None and np.isfinite(e[6])],
             accepted_ratios=[round(e[6], 4) for e in adaptation.get("events", [])
                              if len(e) > 6 and e[1] == "accepted" and e[6] is not None and np.isfinite(e[6])])
    return f


def rescore(adaptation: dict, out_dir: Path) -> dict:
    """``adaptation`` (as :func:`main` wrote it) with every flight scored again from its files in
    ``out_dir/sitl_adapt_<autopilot>/`` (:func:`flight_record`, each flight's recorded change time) and summarized
    again: what a change of the scoring needs, without flying."""
    res = json.loads(json.dumps(adaptation))
    for ap, a in res.get("autopilots", {}).items():
        for cond, c in a.get("conditions", {}).items():
            per = [{m: flight_record(Path(out_dir) / f"sitl_adapt_{ap}", ap, f"adapt_{cond}_{m}_r{r}", f.get("change") or {})
                    for m, f in rnd.items()} for r, rnd in enumerate(c.get("rounds", []))]
            a["conditions"][cond] = {**summarize(per), "params": c.get("params", {})}
    return res


def run_adapt(autopilot: str, out_dir: str, rounds: int = 2, conditions: list[str] | None = None,
              methods: list[str] | None = None, collect_s: float = 30.0) -> dict:
    """Start the SITL here (a private network namespace: :func:`main`), collect, generate with ``[adapt]``,
    fit the prefilter, then ``rounds`` x conditions x methods flights (:func:`_fly_one`); the figures."""
    conditions, methods = list(conditions or ADAPT_CONDITIONS), list(methods or METHODS)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with make_sitl(autopilot, params=SITL_PARAMS[autopilot]) as sitl:
        fly(sitl, autopilot, "collect", out, collect_s, extra=("--dataset-skip", "1.0", *COLLECT[autopilot]))
        config = ROOT / "configs" / CONFIGS[autopilot]
        solver = codegen(config, out / f"{autopilot}_collect.npz", out / "generated")
        prefilter = fit_prefilter_from_log(out / f"{autopilot}_collect.npz", out / "prefilter.json")
        steps = write_steps_trajectory(out / "steps.csv", duration=DURATION_S + 2.0)
        per: dict[str, list[dict]] = {c: [] for c in conditions}
        for r in range(rounds):  # every method in the same round: slow drifts of the SITL hit all alike
            for cond in conditions:
                figs = {}
                for m in methods:
                    figs[m] = _fly_one(sitl, autopilot, cond, m, r, out, steps, solver, prefilter)
                    a = figs[m]["after"]
                    print(f"[sitl-adapt] {autopilot} {cond} round {r + 1}/{rounds} {m}: true height after the change "
                          f"{_mm(a['rmse_z_truth'])} mm, EKF {_mm(a['rmse_z'])} mm, change at "
                          f"{figs[m]['change'].get('sent_s')} s ({time.monotonic() - t0:.0f} s)", flush=True)
                per[cond].append(figs)
    return {"config": CONFIGS[autopilot], "adapt": adapt_settings(solver),
            "conditions": {c: {**summarize(per[c]), "params": _params(autopilot, c)} for c in conditions},
            "wall_s": round(time.monotonic() - t0, 1)}


def adapt_settings(solver: Path) -> dict | None:
    """The ``[adapt]`` settings the generated solver in ``solver`` was built with (its manifest's ``adapt``), or None."""
    path = Path(solver) / "manifest.json"
    return json.loads(path.read_text()).get("adapt") if path.is_file() else None


def _params(autopilot: str, cond: str) -> dict:
    spec = CONDITIONS[autopilot].get(cond)
    return {} if spec is None or isinstance(spec, str) else spec[0]


def change_cost(conditions: dict, name: str) -> tuple[float | None, float | None]:
    """What a change costs the static steering: its after-window RMSE under condition ``name`` over the same
    window of the ``nominal`` condition's flights (true height, EKF height); None without both. Adaptation can at
    best give back what the change cost (adapted nominal flights fly like static ones)."""
    def after(c: str, k: str) -> float | None:
        return (((conditions.get(c) or {}).get("static") or {}).get("after") or {}).get(k)
    return tuple(after(name, k) / after("nominal", k) if after(name, k) and after("nominal", k) else None
                 for k in ("rmse_z_truth", "rmse_z"))


def _x(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}x"


def _mm(v: Any) -> str:
    return "-" if v is None else f"{1e3 * v:.1f}"


def _ratios(c: dict) -> str:
    """`` (error ratio a-b)``: the range of the accepted swaps' candidate-over-current errors, when any."""
    rng = (c.get("adapted") or {}).get("accepted_ratio_range")
    return f" (error ratio {rng[0]:.2f}-{rng[1]:.2f})" if rng else ""


def format_adaptation(adaptation: dict) -> str:
    """Printed lines per autopilot and condition: true height after the change per method, the ratio, the
    nominal part, the estimator's error and the counters of the adapted flights."""
    lines = []
    for ap, res in adaptation.get("autopilots", {}).items():
        for name, c in res.get("conditions", {}).items():
            after = ", ".join(f"{m} {_mm(c[m]['after']['rmse_z_truth'])}" for m in METHODS if m in c)
            before = ", ".join(f"{m} {_mm(c[m]['before']['rmse_z_truth'])}" for m in METHODS if m in c)
            ratio = (c.get("static_over_adapted") or {}).get("after")
            ad = (c.get("adapted") or {}).get("adapt") or {}
            est = (c.get("static") or {}).get("after", {}).get("estimator_rms")
            floor = (c.get("static") or {}).get("floor")
            best = (c["static"]["after"]["rmse_z_truth"] / floor if floor and "static" in c
                    and c["static"]["after"]["rmse_z_truth"] else None)
            cost = change_cost(res.get("conditions", {}), name)
            lines.append(f"[sitl-adapt] {ap} {name}: true height rmse after the change {after} mm "
                         f"(static / adapted {'-' if ratio is None else f'{ratio:.2f}'}; static's first {LEARN_S:g} s "
                         f"alone {_mm(floor)} mm, so static / any learner <= {'-' if best is None else f'{best:.2f}'}; "
                         f"static after this change / in nominal flight: true {_x(cost[0])}, EKF {_x(cost[1])}); "
                         f"nominal part {before} mm; "
                         f"estimator {_mm(est)} mm; adapted: {ad.get('updates', '-')} updates, "
                         f"{ad.get('accepted', '-')} swaps accepted{_ratios(c)}, rejected {ad.get('rejected', {})}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run every available autopilot (each in a private network namespace, both at once) and merge the
    figures into ``<out>/sitl.json`` under ``adaptation``."""
    p = argparse.ArgumentParser(prog="python -m ddpc_codegen.testbed.sitl_adapt", description=main.__doc__)
    p.add_argument("--autopilot", action="append", choices=["px4", "ardupilot"], help="default: both")
    p.add_argument("--out", default=str(ROOT / "reports"), help="reports folder (default %(default)s)")
    p.add_argument("--rounds", type=int, default=2, help="rounds of every condition and method (default %(default)s)")
    p.add_argument("--conditions", default=",".join(ADAPT_CONDITIONS), help="comma list (default %(default)s)")
    p.add_argument("--methods", default=",".join(METHODS), help="comma list (default %(default)s)")
    p.add_argument("--rescore", action="store_true",
                   help="fly nothing: score the flights of <out>/sitl.json's adaptation again from their files")
    a = p.parse_args(argv)
    if a.rescore:
        adaptation = {**rescore(json.loads((Path(a.out) / "sitl.json").read_text())["adaptation"], Path(a.out)),
                      "learn_s": LEARN_S}
        merge_report(Path(a.out) / "sitl.json", adaptation)
        print(format_adaptation(adaptation), flush=True)
        return 0
    conds, methods = comma_list(a.conditions), comma_list(a.methods)
    if a.rounds < 1 or set(methods) - set(METHODS) or set(conds) - set(ADAPT_CONDITIONS):
        p.error(f"--rounds >= 1, methods from {METHODS}, conditions from {ADAPT_CONDITIONS}")
    jobs = {}
    for ap in available_autopilots(a.autopilot, "sitl-adapt"):
        flights = a.rounds * len(conds) * len(methods)
        print(f"[sitl-adapt] {ap}: collect -> codegen with [adapt] -> {flights} flights (~60 s each) ...", flush=True)
        jobs[ap] = ("ddpc_codegen.testbed.sitl_adapt:run_adapt",
                    {"autopilot": ap, "out_dir": str(Path(a.out) / f"sitl_adapt_{ap}"), "rounds": a.rounds,
                     "conditions": conds, "methods": methods}, 900 + 150 * flights)
    results, failed = fly_autopilots(jobs, "sitl-adapt")
    if results:
        adaptation = {"t_change_s": CHANGE_S, "window_s": WINDOW_S, "settle_s": SETTLE_S, "duration_s": DURATION_S,
                      "learn_s": LEARN_S, "rounds": a.rounds, "metric": "RMS of true height - desired height [m] in [t_change, "
                      "t_change + window_s) (after) and [settle_s, t_change) (before), mean of the rounds",
                      "autopilots": results}
        merge_report(Path(a.out) / "sitl.json", adaptation)
        print(format_adaptation(adaptation), flush=True)
    return 0 if results and not failed else 1


if __name__ == "__main__":
    sys.exit(main())
