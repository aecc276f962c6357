"""Online adaptation measured in-process (issue 30): a vehicle change mid-flight, adapted vs static steering vs
the prefilter, on the true height; ``reports/summary.json`` section ``adaptation``.

Conditions (flying, the change at ``t_change``): ``nominal`` (none), ``mass`` (a payload: the true mass
+0.4 kg), ``thrust`` (battery sag: thrust per command x0.85, rotor drag alike), ``push`` (a sustained push
down, 12 N for 3 s). Metric: the RMS of true height minus desired height within 10 s of the change
(``nominal``: over the same window), in metres. The adapted run uses the config's ``[adapt]`` settings on
its own instance of the generated solver. ``offset_only``: the ablation, the same settings with every G refused
(``max_gain_change`` 1e-9: only the output offset adapts; the interpreted twin, equal to the C to 1e-9).
``evidence``: how well the predictor adapted on the static run's
closed-loop data predicts the following seconds compared with the shipped one (out of sample), and the steady-
state gains of both: the record of why an update was refused (``gain``: the fit explains the change's offset by
distorting the gains) or swapped in.

``ddpc-codegen adapt-eval [--out reports]`` (or ``python -m ddpc_codegen.experiments.adapt_eval``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ddpc_codegen.design.adaptation import adapter
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.experiments.baselines_eval import fit_scenario_prefilter
from ddpc_codegen.experiments.evaluate import run
from ddpc_codegen.experiments.pipeline import ROOT, build_setup, default_config
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.experiments.report_file import update_report
from ddpc_codegen.flight_metrics import rms
from ddpc_codegen.design.adapt_qp import steady_state_gain
from ddpc_codegen.design.adapter import solve_g
from ddpc_codegen.values.adapt import SampleWindow
from ddpc_codegen.runtime.baselines import PrefilterPolicy
from ddpc_codegen.sim import PogoXParams, Push, simulate

__all__ = ["conditions", "evaluate_adaptation", "ADAPT_DEFAULTS"]

T_CHANGE, WINDOW_S, DURATION = 10.0, 10.0, 25.0
# The settings measured (their reasons: a slow forgetting keeps the PRBS data's weight > 0.6 after 25 s, a bounded
# step per swap; the output offset absorbs what the gain check refuses to let G absorb, re-estimated every 0.25 s
# over the last 1 s: after the battery sag a 0.5 s window (period 0.5 or 0.25 s) made the offset an integrator fast
# enough to oscillate (197 / 450 mm), 0.75 s and 1 s did not; at most 0.1 m / 0.05 rad per entry, never reached at
# these settings). No dither: a 3 mm dither cost more than its excitation gave (adapted / static, with 3 mm and a
# 0.5 s period: nominal 0.81, mass 0.46, thrust 0.60, push 0.68; without it and every 0.25 s: 0.76, 0.43, 0.53,
# 0.64), as on the SITLs. A config's own [adapt] values override them.
ADAPT_DEFAULTS = {"enabled": True, "forgetting": 0.9999, "period_ticks": 50, "window": 200, "dither": 0.0,
                  "max_change": 0.05, "offset": True, "max_offset": (0.1, 0.05)}


def _mass(stepper) -> None:
    stepper.plant._m += 0.4


def _thrust(stepper) -> None:
    stepper.plant._kf *= 0.85
    stepper.plant._km *= 0.85


def conditions(t_change: float = T_CHANGE) -> dict[str, dict[str, Any]]:
    """name -> {"changes": [(t, fn)], "pushes": [Push], "what": description}."""
    return {
        "nominal": {"changes": [], "pushes": [], "what": "no change"},
        "mass": {"changes": [(t_change, _mass)], "pushes": [], "what": "true mass +0.4 kg at t_change"},
        "thrust": {"changes": [(t_change, _thrust)], "pushes": [],
                   "what": "thrust (and rotor drag) per command x0.85 at t_change (battery sag)"},
        "push": {"changes": [], "pushes": [Push(t_change, (0.0, 0.0, -5.0), 3.0)],
                 "what": "5 N down for 3 s from t_change"},
    }


def _rmse_after(res, t0: float, span: float) -> float | None:
    """RMS of true z - desired z over [t0, t0 + span) (None when the run crashed before its end)."""
    if res.crashed:
        return None
    t = res.t
    w = (t >= t0) & (t < t0 + span)
    return rms(res.y_true[w, 0] - res.extras["z_des"][w], float("nan"))


def _prefilter_run(setup, c: dict, params: PogoXParams, seed: int):
    pol = PrefilterPolicy(fit_scenario_prefilter(setup))
    pol.reset()
    return simulate("flying", DURATION, params=params, seed=seed, reference_hook=PolicyHook(pol, "flying"),
                    pushes=c["pushes"], changes=c["changes"])


def prediction_evidence(setup, res, settings, t0: float, split: float) -> dict[str, float]:
    """Out-of-sample check of what adaptation would learn: the predictor updated (the shipped R, the config's
    forgetting) on the closed-loop columns of ``res`` in [t0, split) against the shipped one, both predicting
    the columns of [split, end) (sum of squared scaled output errors), the shipped one plus the output offset
    of [t0, split) (its mean residual: what ``[adapt] offset`` adds) on the same columns, and both steady-state gains
    (outputs per constant reference, p x m: what the ``gain`` verification compares)."""
    ad = adapter(setup.problem, settings)
    lay = ad.layout
    sw = SampleWindow(lay.depth, lay.m, lay.p, lay.t_ini != setup.problem.predictor.t_ini)
    train, test = [], []
    for k, tk in enumerate(res.t):
        w = sw.push(res.u[k], res.y[k])
        if w is None or tk < t0:
            continue
        if tk < split:
            ad.push(w)
            train.append(lay.column(w, ad.scale))
        else:
            test.append(lay.column(w, ad.scale))
    G1, _ = solve_g(ad.R, lay, ad.slack_weight, ad.rcond)
    C, T = np.array(test), np.array(train)
    resid = lambda X, G: X[:, lay.r : lay.r + lay.q_y] - X[:, : lay.r] @ G[: lay.q_y].T  # noqa: E731
    err = lambda G, b=0.0: float(np.sum((resid(C, G) - b) ** 2))  # noqa: E731
    c = setup.problem.config
    gain = lambda G: steady_state_gain(ad.qp.data_predictor(G), c.m, c.p, c.t_ini, c.t_f)  # noqa: E731
    S0, S1 = gain(ad.G), gain(G1)
    return {"shipped": err(ad.G), "adapted": err(G1), "shipped_offset": err(ad.G, resid(T, ad.G).mean(axis=0)),
            "fit_s": [t0, split], "test_s": [split, float(res.t[-1])],
            "gain_shipped": None if S0 is None else S0.tolist(), "gain_adapted": None if S1 is None else S1.tolist()}


def evaluate_adaptation(config: SteeringConfig | str | Path | None = None, *, dataset: str | Path | None = None,
                        seed: int = 0, quiet: bool = False, names: tuple[str, ...] | None = None) -> dict[str, Any]:
    """Static vs adapted steering vs the prefilter per condition (see the module docstring)."""
    cfg = config if isinstance(config, SteeringConfig) else SteeringConfig.from_toml(config or default_config("flying"))
    settings = {**ADAPT_DEFAULTS, **({k: v for k, v in dataclasses.asdict(cfg.adapt).items()} if cfg.adapt.enabled
                                     else {})}
    cfg = cfg.replace(adapt=settings)
    raw = IODataset.load(dataset or cfg.dataset) if (dataset or (cfg.dataset and Path(cfg.dataset).exists())) else None
    log: Callable[[str], None] = (lambda s: None) if quiet else (lambda s: print(s, file=sys.stderr))
    with tempfile.TemporaryDirectory() as tmp:
        setup = build_setup("flying", config=cfg, raw=raw, generate_dir=tmp, save_data=False)
        params = PogoXParams()
        # the ablation (G never swapped) needs the offset on; its own settings, the interpreted twin
        ablation = dataclasses.replace(setup, config=cfg.replace(adapt={**settings, "max_gain_change": 1e-9})) \
            if cfg.adapt.offset else None
        out: dict[str, Any] = {"scenario": "flying", "metric": "rmse_z_true within window_s of the change [m]",
                               "t_change_s": T_CHANGE, "window_s": WINDOW_S, "duration_s": DURATION,
                               "adapt": dataclasses.asdict(cfg.adapt), "conditions": {}}
        for name, c in conditions().items():
            if names and name not in names:
                continue
            kw = dict(params=params, seed=seed, pushes=c["pushes"], changes=c["changes"])
            static = run(setup, "flying", DURATION, **kw)
            adapted = run(setup, "flying", DURATION, adapt=True, **kw)
            pre = _prefilter_run(setup, c, params, seed)
            row = {"what": c["what"], "static": _rmse_after(static.sim, T_CHANGE, WINDOW_S),
                   "adapted": _rmse_after(adapted.sim, T_CHANGE, WINDOW_S),
                   "offset_only": (_rmse_after(run(ablation, "flying", DURATION, adapt=True, interpreted=True,
                                                   **kw).sim, T_CHANGE, WINDOW_S) if ablation else None),
                   "prefilter": _rmse_after(pre, T_CHANGE, WINDOW_S),
                   "adapted_crashed": adapted.sim.crashed, "adaptation": adapted.steering["adaptation"]["counts"],
                   "swaps_at_s": [round(e[0] * setup.config.dt, 3) for e in adapted.steering["adaptation"]["events"]
                                  if e[2]]}
            if name != "nominal" and not static.sim.crashed:
                row["evidence"] = prediction_evidence(setup, static.sim, cfg.adapt, T_CHANGE,
                                                      T_CHANGE + WINDOW_S / 2)
            if row["static"] and row["adapted"] is not None:
                row["adapted_over_static"] = row["adapted"] / row["static"]
            out["conditions"][name] = row
            f = lambda v: "crashed" if v is None else f"{v * 1e3:.2f} mm"  # noqa: E731
            log(f"[adapt] {name}: static {f(row['static'])}, adapted {f(row['adapted'])}, offset only "
                f"{f(row['offset_only'])}, prefilter {f(row['prefilter'])}; swaps {row['adaptation']['swaps']}, "
                f"offset swaps {row['adaptation']['offset_swaps']}")
    return out


def _add_args(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--config", default=None, help="flying steering config (default configs/flying.toml)")
    ap.add_argument("--out", default=str(ROOT / "reports"), help="folder of summary.json (its 'adaptation' key)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quiet", action="store_true")


def _cmd(args: argparse.Namespace) -> int:
    res = evaluate_adaptation(args.config, seed=args.seed, quiet=args.quiet)
    path = Path(args.out) / "summary.json"
    update_report(path, {"adaptation": res})
    print(f"wrote {path} ['adaptation']")
    return 0


def register(subparsers: Any) -> None:
    """Add ``adapt-eval`` to the ddpc-codegen command."""
    p = subparsers.add_parser("adapt-eval", help="online adaptation vs static steering vs the prefilter after "
                              "mid-flight changes (reports/summary.json 'adaptation')",
                              description=__doc__.split("\n\n")[0])
    _add_args(p)
    p.set_defaults(func=_cmd)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="adapt-eval", description=__doc__.split("\n\n")[0])
    _add_args(ap)
    return _cmd(ap.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
