"""Reference steering in the simulated loop: collect -> predictor -> generated solver -> runs -> metrics.

The pipeline of the paper's evaluation, on :mod:`ddpc_codegen.sim`:

* **Flying** (DDPC-Flying). PRBS-excited closed-loop data on a *training* ellipse (other size,
  centre and period than the test ellipse: the data describe the loop, not the task); predictor
  fitted on it; steering QP generated as C and loaded; the test ellipse flown without and with
  steering.
* **Hopping** (DDPC-Hopping). PRBS on the references in the aerial phase only; the Hankel of
  the artificial-IO QP from aerial segments only; every hop's ground phase replaced by artificial
  IO (:mod:`ddpc_codegen.design.artificial_io`) and the hops joined into the mosaic H_G the predictor is fitted
  on; online the ground part of u_ini / y_ini is filled the same way; steering in the air only.

Runs, metrics and the steering hook are in :mod:`.evaluate`.

Timing (the steerer's convention, checked against the simulator's logs): the simulator logs
y[k] = the measurement tick k decided on and u[k] = the reference applied from t_k on, so u[k]
first shows in y[k+1]. At tick k the window holds the pairs (u[k-Tini..k-1], y[k-Tini..k-1])
(the policy records (u[k], y[k]) once tick k is decided), exactly the Hankel columns' pairing,
and the horizon is ticks k..k+Tf-1 (y_des = ``ctx.desired_ahead(Tf)``). The newest measurement
y[k] is then not used by the decision at tick k (it is predicted): one tick of information
latency, the price of a window that matches the data pairing without re-indexing the data.

Predictor choice (the measured figures are in ``configs/*.toml`` and the report):

* Training data are recorded without sensor noise (the paper's motion capture is far more precise
  than the simulator's pessimistic default noise). On such data the SPC least-squares predictor
  (``lsq``) is exact up to the recording's round-off, but its gains on y_ini are large and the loop goes
  unstable as soon as the measurements are noisy; a small relative ridge (``configs/*.toml``
  document the measured choice) keeps the gains bounded. The paper's ``pem`` at slack_weight = 1
  is biased on the same data.
* Recording *with* noise instead regularises the fit by itself but biases it (errors in
  variables): on hopping the multi-step height prediction is pulled toward the training
  hops' height. So: clean data, ``lsq`` with a ridge.
* The constant offset of the loop (gravity against a wrong model mass: the IO map is affine)
  needs no extra handling: a constant is an uncontrollable but observable mode, so it is part of
  the state the Tini window determines, and the linear predictor reproduces it (a mass error the
  data never saw is still steered out, see the robustness runs).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable


from ddpc_codegen.design.artificial_io import ArtificialIO
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.hopping_data import ArtificialIOSpec
from ddpc_codegen.design.predictor import Predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.errors import DataError
from ddpc_codegen.pipeline.solver_build import BuiltSolver, build_solver
from ddpc_codegen.sim import Excitation, FlyingScenario, PogoXParams, SimResult, simulate
from ddpc_codegen.sim.scenarios import EllipseTrajectory, HoppingScenario
from ddpc_codegen.runtime.loader import load_solver

__all__ = [
    "ROOT",
    "BuiltSolver",
    "build_solver",
    "CollectSpec",
    "SteeringSetup",
    "collect",
    "build_setup",
    "default_config",
]

ROOT = Path(__file__).resolve().parents[2]  # the repository (configs/, generated/, reports/)
_SCENARIOS = ("flying", "hopping")

# The ellipse the flying data are recorded on: not the test ellipse (centre (0, 1.2), radii (1, 0.3), 10 s).
TRAIN_ELLIPSE = EllipseTrajectory(center=(0.0, 1.0), radii=(0.6, 0.2), period=7.0)


def default_config(scenario: str) -> Path:
    """configs/<scenario>.toml of the repository."""
    return ROOT / "configs" / f"{scenario}.toml"


def say(msg: str, show: bool = True) -> None:
    """Progress text of the experiments for a person at the terminal (stderr; the data goes to stdout / files)."""
    if show:
        print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- data collection
@dataclass(frozen=True)
class CollectSpec:
    """How training data are recorded on the simulator.

    Attributes:
        duration: simulated seconds (flying: 90 s = 17 400 samples after the settle time;
            hopping: 120 s = ~145 hops).
        seed: PRBS and noise seed (the evaluation runs use other seeds).
        noise: record with sensor noise (default no; see the module docstring).
        amplitude: PRBS amplitude per reference channel (m, rad); None = the simulator's defaults.
        min_hold: PRBS bit length [ticks].
        mass_error: controller model mass minus true mass [kg] during the recording.
    """

    duration: float = 90.0
    seed: int = 1
    noise: bool = False
    amplitude: tuple[float, ...] | None = None
    min_hold: int = 4
    mass_error: float = -0.2

    @classmethod
    def default(cls, scenario: str) -> "CollectSpec":
        if scenario == "flying":
            return cls(duration=90.0, amplitude=(0.05, 0.03))
        return cls(duration=120.0, amplitude=(0.01, 0.02, 0.02))


def collect(scenario: str, spec: CollectSpec | None = None, *, progress: bool = False) -> SimResult:
    """Record PRBS-excited closed-loop data (flying: on :data:`TRAIN_ELLIPSE`; hopping: aerial PRBS)."""
    if scenario not in _SCENARIOS:
        raise DataError(f"unknown scenario {scenario!r}; choose one of {list(_SCENARIOS)}")
    spec = spec or CollectSpec.default(scenario)
    sc = FlyingScenario(ellipse=TRAIN_ELLIPSE) if scenario == "flying" else HoppingScenario()
    amp = spec.amplitude if spec.amplitude is not None else (0.05, 0.03) if scenario == "flying" else (0.01, 0.02, 0.02)
    res = simulate(sc, spec.duration, params=PogoXParams(controller_mass_error=spec.mass_error), seed=spec.seed,
                   excitation=Excitation(amplitude=tuple(amp), min_hold=spec.min_hold, aerial_only=True),
                   noise=spec.noise or None, progress=progress)
    if res.crashed:
        raise DataError(f"the robot was lost while collecting {scenario} data ({res.crash_reason}); "
                        "lower the PRBS amplitude")
    return res


# ----------------------------------------------------------------------------- setup
@dataclass
class SteeringSetup:
    """Everything a steered run needs.

    problem: interpreted SteeringProblem; solver: the generated C solver (None if not compiled);
    dataset: the predictor's data (flying: the PRBS run; hopping: the stitched hops H_G);
    art: hopping's completion operator; info: provenance (PE summary, held-out prediction error, timings);
    raw: the recorded data as collected (hopping: with ground phases; what the baselines are fitted on).
    """

    scenario: str
    config: SteeringConfig
    predictor: Predictor
    problem: SteeringProblem
    dataset: IODataset
    solver: Any = None
    solver_path: Path | None = None
    art: ArtificialIO | None = None
    art_spec: ArtificialIOSpec = field(default_factory=ArtificialIOSpec)
    info: dict = field(default_factory=dict)
    raw: IODataset | None = None


def build_setup(
    scenario: str,
    *,
    config: SteeringConfig | str | Path | None = None,
    raw: IODataset | SimResult | None = None,
    collect_spec: CollectSpec | None = None,
    art_spec: ArtificialIOSpec | None = None,
    generate_dir: str | Path | None = "generated",
    solver_name: str | None = None,
    backend: str | None = None,
    save_data: bool = True,
    progress: bool = False,
    fit: Callable[[SteeringConfig, IODataset], Predictor] | None = None,
) -> SteeringSetup:
    """Data -> predictor -> steering problem -> generated, compiled, loaded solver (:func:`build_solver`).

    Args:
        scenario: "flying" or "hopping".
        config: SteeringConfig or TOML path (default configs/<scenario>.toml).
        raw: recorded data (an IODataset with phase labels for hopping, or a SimResult);
            None records new data with ``collect_spec``.
        generate_dir: root of the generated solver folder (``<dir>/<solver_name>``); None = do
            not generate (interpreted runs only).
        solver_name: default ``steer_<scenario>``.
        fit: fits the predictor from (config, dataset) (default: ``fit_configured``, the predictor the config's
            [predictor] table asks for); a sweep passes a cached one.
        save_data: write the recorded data (flying: the config's [data] dataset; hopping: the raw
            log as the [data] dataset and the stitched hops next to it as ``hopping_stitched.npz``).
    """
    t_start = time.perf_counter()
    cfg = config if isinstance(config, SteeringConfig) else SteeringConfig.from_toml(config or default_config(scenario))
    info: dict[str, Any] = {"config": cfg.source}
    if raw is None:
        say(f"[{scenario}] collecting PRBS-excited data on the simulator ...", progress)
        raw = collect(scenario, collect_spec, progress=progress)
    if isinstance(raw, SimResult):
        raw = raw.to_dataset("none", t_min=getattr(raw.scenario_obj, "settle_time", 0.0) if scenario == "flying" else 0.0)
    info["raw_samples"] = raw.n_samples
    name = solver_name or f"steer_{scenario}"
    if generate_dir is not None:
        say(f"[{scenario}] fitting, generating + compiling the C solver generated/{name} ...", progress)
    b = build_solver(cfg, raw, None if generate_dir is None else Path(generate_dir) / name, backend=backend,
                     name=name, fit=fit, art_spec=art_spec, log=lambda msg: say(msg, progress))
    if save_data and cfg.dataset:  # the raw log is what `ddpc-codegen codegen` builds a hopping solver from
        raw.save(cfg.dataset)
        if b.art is not None:
            b.dataset.save(Path(cfg.dataset).with_name("hopping_stitched.npz"))
    if b.art is not None:
        info["artificial_io"] = b.report["artificial_io"]
    pred = b.problem.predictor
    info["excitation"] = pred.excitation().summary()
    info["predictor"] = {"method": pred.method, "rank": pred.rank, "columns": pred.n_columns,
                         **{k: v for k, v in pred.options.items() if not k.startswith("_")}}
    setup = SteeringSetup(scenario, b.config, pred, b.problem, b.dataset, art=b.art, art_spec=b.art_spec, info=info,
                          raw=raw)
    if b.path is not None:
        setup.solver = load_solver(b.path)
        setup.solver_path = b.path
        info["codegen_s"] = b.report["codegen_s"]
        info["backend"] = setup.solver.backend
    info["setup_s"] = round(time.perf_counter() - t_start, 2)
    return setup
