"""``make fuzz``: mutants of every input that defines the flown path, accepted ones flown, the link fuzzed.

1. Dynamics mutants (:mod:`.fuzz_mutants`), drawn from seeds until ``--mutants`` accepted ones have flown: each
   goes through ``ddpc-bridge``'s own loaders and before-arming path checks (:func:`.fuzz_flight.accept`); a
   refusal must be one line (a traceback or an empty message is a defect of its own); an accepted mutant flies
   ``--duration`` s from engagement in-process, lock-step (:func:`.fuzz_flight.fly_in_process`) and is judged on
   the vehicle's true position and the applied references' one-tick steps. The flights run on ``--workers``
   processes (each flight: the bridge's thread and the vehicle's, taking turns).
2. A sample of accepted mutants (``--process-flights``) flown as ``ddpc-vehicle`` + ``ddpc-bridge`` processes
   (:func:`.fuzz_flight.fly_processes`).
3. The MAVLink input fuzzed against flying bridges (:mod:`.fuzz_link`).

The flights of 2 and 3 go to the same pool first and fly beside those of 1.

Prints a short table and writes ``--out`` (reports/fuzz.json). A violation names the mutant's seed:
``python -m ddpc_codegen.testbed.fuzz --replay SEED`` rebuilds and flies it alone. Exit 1 on any violation or
defect, else 0.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from ddpc_codegen.testbed.bridge_flights import ROOT, free_udp_port
from ddpc_codegen.testbed.fuzz_flight import (REFUSALS, TRACK_MARGIN_M, accept, fly_in_process,
                                              fly_processes)
from ddpc_codegen.testbed.fuzz_link import LINK_ATTACKS, STARTUP_STAMP, fly_link_attack
from ddpc_codegen.testbed.fuzz_mutants import make_mutant

__all__ = ["run_mutant", "fuzz_dynamics", "accepted_seeds", "side_flights", "run_fuzz", "format_table", "main"]

_SLACK_S = 2.0  # vehicle time beyond the flight's duration: start-up, pre-stream, hand-back


def run_mutant(seed: int, work: Path, duration: float, fly: bool = True, solver: str | None = None) -> dict:
    """Build the mutant of ``seed`` in ``work``, put it through the bridge's acceptance and (``fly``) fly it:
    {"mutant", "status": "refused" | "defect" | "accepted", "message", "flight"}."""
    m = make_mutant(seed, Path(work) / f"m{seed}", solver=solver)
    rec: dict = {"mutant": m.as_dict(), "status": "accepted", "message": "", "flight": None}
    try:
        cfg = accept(m.args, free_udp_port(), duration)
    except SystemExit as e:  # argparse: its usage line and one error line, exit 2
        rec.update(status="refused" if e.code == 2 else "defect", message=f"argparse exit {e.code}")
        return rec
    except REFUSALS as e:
        msg = str(e)
        precise = bool(msg.strip()) and "\n" not in msg.strip()
        rec.update(status="refused" if precise else "defect", message=msg if precise else f"imprecise: {msg!r}")
        return rec
    except Exception as e:  # noqa: BLE001 -- a traceback where a refusal belongs: reported, never fatal here
        rec.update(status="defect", message=f"{type(e).__name__}: {e}")
        return rec
    if fly:
        check = fly_in_process(cfg, Path(work), sim_time=duration + _SLACK_S, seed=seed)
        rec["flight"] = check.as_dict()
        if check.outcome == "refused":
            rec.update(status="refused_preflight", message=check.notes[0] if check.notes else "")
        elif check.outcome != "flown":
            rec.update(status="defect", message=check.outcome)
    return rec


def _worker(seeds: list[int], duration: float, solver: str | None) -> list[dict]:
    with tempfile.TemporaryDirectory(prefix="ddpc-fuzz-") as tmp:
        return [run_mutant(s, Path(tmp), duration, solver=solver) for s in seeds]


def fuzz_dynamics(pool: ProcessPoolExecutor, target: int, seed: int, duration: float, workers: int, batch: int = 8,
                  time_budget: float = 240.0, solver: str | None = None, log=print) -> list[dict]:
    """Mutants from seeds ``seed``, ``seed + 1``, ... on ``pool`` until ``target`` accepted ones have flown (or
    ``time_budget`` s have passed): the records of :func:`run_mutant`, in seed order (``solver``: steered ones too)."""
    records: list[dict] = []
    t_end = time.monotonic() + time_budget
    next_seed = seed
    flown = 0
    pending: set = set()
    while True:
        while len(pending) < 2 * workers and flown < target and time.monotonic() < t_end:
            pending.add(pool.submit(_worker, list(range(next_seed, next_seed + batch)), duration, solver))
            next_seed += batch
        if not pending:
            break
        done, pending = wait(pending, return_when=FIRST_COMPLETED)
        before = len(records)
        for f in done:
            for r in f.result():
                records.append(r)
                flown += r["flight"] is not None and r["flight"]["outcome"] == "flown"
        if len(records) // 200 != before // 200:
            log(f"  mutants {len(records)}  flown {flown}/{target}", flush=True)
    return sorted(records, key=lambda r: r["mutant"]["seed"])


def _process_flight(seed: int, duration: float, solver: str | None) -> dict:
    """The mutant of ``seed`` (accepted) flown as two processes: {"seed", "kind", "flight"}."""
    with tempfile.TemporaryDirectory(prefix="ddpc-fuzz-") as tmp:
        m = make_mutant(seed, Path(tmp) / "m", solver=solver)
        cfg = accept(m.args, free_udp_port(), duration)
        check = fly_processes(m.args, cfg, Path(tmp), sim_time=duration + _SLACK_S, seed=seed)
    return {"seed": seed, "kind": m.kind, "mutant": m.as_dict(), "flight": check.as_dict()}


def _link_flight(attack: str, seed: int, duration: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="ddpc-fuzz-") as tmp:
        return fly_link_attack(attack, seed, duration, Path(tmp))


def accepted_seeds(n: int, seed: int, solver: str | None = None) -> list[int]:
    """The first ``n`` seeds from ``seed`` on whose mutants the bridge accepts (nothing flown)."""
    out: list[int] = []
    with tempfile.TemporaryDirectory(prefix="ddpc-fuzz-") as tmp:
        while len(out) < n:
            if run_mutant(seed, Path(tmp), 1.0, fly=False, solver=solver)["status"] == "accepted":
                out.append(seed)
            seed += 1
    return out


def side_flights(pool: ProcessPoolExecutor, args) -> tuple[list, list, object]:
    """Submitted first, so that they fly beside the dynamics mutants: ``--process-flights`` accepted mutants (seeds
    from ``--seed + 10**6``) as two processes, every attack of :data:`.fuzz_link.LINK_ATTACKS` ``--link-rounds``
    times, and the known finding (:data:`.fuzz_link.STARTUP_STAMP`) once: their futures."""
    procs = [pool.submit(_process_flight, s, args.duration, args.solver)
             for s in accepted_seeds(args.process_flights, args.seed + 10**6, args.solver)]
    link = [pool.submit(_link_flight, attack, args.seed + 100 * i + j, args.duration + 1.0)
            for i in range(args.link_rounds) for j, attack in enumerate(LINK_ATTACKS)]
    finding = pool.submit(_link_flight, STARTUP_STAMP, args.seed, args.duration + 1.0)
    return procs, link, finding


def _summary(records: list[dict], procs: list[dict], link: list[dict], seconds: float, args) -> dict:
    flights = [r["flight"] for r in records if r["flight"] and r["flight"]["outcome"] == "flown"]
    flights += [p["flight"] for p in procs if p["flight"]["outcome"] == "flown"]
    flights += [r["flight"] for r in link if r["flight"]["outcome"] == "flown"]
    per_kind: dict[str, dict] = {}
    for r in records:
        k = per_kind.setdefault(r["mutant"]["kind"], {"generated": 0, "refused": 0, "accepted": 0, "flown": 0})
        k["generated"] += 1
        k["refused"] += r["status"] in ("refused", "refused_preflight")
        k["accepted"] += r["status"] == "accepted"
        k["flown"] += bool(r["flight"] and r["flight"]["outcome"] == "flown")

    def worst(key: str) -> float | None:
        vals = [f[key] for f in flights if f[key] is not None]
        return max(vals) if vals else None

    return {
        "generated": len(records), "refused": sum(v["refused"] for v in per_kind.values()),
        "refused_before_arming": sum(r["status"] == "refused_preflight" for r in records),
        "accepted": sum(v["accepted"] for v in per_kind.values()),
        "flown": sum(v["flown"] for v in per_kind.values()), "process_flights": len(procs),
        "link_flights": len(link), "violations": sum(bool(f["violation"]) for f in flights),
        "defects": [r for r in records if r["status"] == "defect"] + [r for r in link if r.get("defect")],
        "max_excess_m": worst("excess_m"), "margin_m": TRACK_MARGIN_M, "max_rate_ratio": worst("rate_ratio"),
        "per_kind": per_kind, "seconds": round(seconds, 1),
        # the flights that came closest to (or furthest past) an edge of their envelope: what to look at first
        "closest": [{"seed": r["mutant"]["seed"], "kind": r["mutant"]["kind"], "excess_m": r["flight"]["excess_m"],
                     "rate_ratio": r["flight"]["rate_ratio"], "changes": r["mutant"]["changes"]}
                    for r in sorted((r for r in records if r["flight"] and r["flight"]["excess_m"] is not None),
                                    key=lambda r: -r["flight"]["excess_m"])[:10]],
        "settings": {"seed": args.seed, "duration_s": args.duration, "workers": args.workers, "target": args.mutants,
                     "solver": args.solver},
        "violating": [r for r in records if r["flight"] and r["flight"]["violation"]]
        + [p for p in procs if p["flight"]["violation"]] + [r for r in link if r["flight"]["violation"]],
        "process": procs, "link": link,
    }


def format_table(s: dict) -> str:
    """The short table ``make fuzz`` prints."""
    f = lambda v, fmt: "-" if v is None else fmt.format(v)  # noqa: E731
    rows = [("mutants generated", s["generated"]), ("refused (one line, exit 2)", s["refused"]),
            ("  of them when set up or before arming", s["refused_before_arming"]), ("accepted", s["accepted"]),
            ("flown in-process (lock-step)", s["flown"]), ("flown as ddpc-vehicle + ddpc-bridge", s["process_flights"]),
            ("link attacks flown", s["link_flights"]), ("envelope / rate violations", s["violations"]),
            ("defects (traceback, imprecise refusal, link)", len(s["defects"])),
            ("known findings still present (see the report)", len(s.get("findings", []))),
            ("max true excess over the envelope [m]",
             f(s["max_excess_m"], "{:+.3f}") + f" (margin {s['margin_m']:g})"),
            ("max one-tick reference step / bound", f(s["max_rate_ratio"], "{:.3f}")), ("seconds", s["seconds"])]
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{w}}  {v}" for k, v in rows)


def run_fuzz(args) -> dict:
    """The whole fuzz run of the parsed ``args`` (see :func:`main`): the report dict."""
    t0 = time.monotonic()
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        procs, link, finding = side_flights(pool, args)
        records = fuzz_dynamics(pool, args.mutants, args.seed, args.duration, args.workers,
                                time_budget=args.time_budget, solver=args.solver)
        procs, link, finding = [f.result() for f in procs], [f.result() for f in link], finding.result()
    out = _summary(records, procs, link, time.monotonic() - t0, args)
    out["findings"] = [finding] if finding["defect"] else []
    return out


def _replay(seed: int, duration: float, solver: str | None) -> int:
    with tempfile.TemporaryDirectory(prefix="ddpc-fuzz-") as tmp:
        r = run_mutant(seed, Path(tmp), duration, solver=solver)
    print(json.dumps(r, indent=1))
    return 1 if r["status"] == "defect" or (r["flight"] and r["flight"]["violation"]) else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ddpc_codegen.testbed.fuzz", description=__doc__.split("\n\n")[0])
    p.add_argument("--mutants", type=int, default=1000, help="accepted mutants to fly in-process")
    p.add_argument("--seed", type=int, default=1, help="the first mutant's seed")
    p.add_argument("--duration", type=float, default=1.0, help="seconds flown from engagement per flight")
    p.add_argument("--workers", type=int, default=2 * (os.cpu_count() or 1),
                   help="flight processes (each flight waits about half its time on the other thread)")
    p.add_argument("--time-budget", type=float, default=240.0, help="stop drawing mutants after this many s")
    p.add_argument("--process-flights", type=int, default=6)
    p.add_argument("--link-rounds", type=int, default=2, help="times each link attack is flown")
    p.add_argument("--out", type=Path, default=ROOT / "reports" / "fuzz.json")
    p.add_argument("--replay", type=int, default=None, help="build and fly this seed's mutant alone")
    p.add_argument("--solver", default=None, help="a generated steering solver folder: steered mutants too")
    a = p.parse_args(argv)
    if a.replay is not None:
        return _replay(a.replay, a.duration, a.solver)
    s = run_fuzz(a)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(s, indent=1, default=str) + "\n")
    print(format_table(s))
    for r in s["violating"][:5] + s["defects"][:5]:
        print("  ", json.dumps(r.get("mutant") or r)[:400])
    return 1 if s["violations"] or s["defects"] else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
