"""One function per use case: config + dataset -> checked data -> predictor -> generated solver.

:func:`build_solver` is what ``ddpc-codegen codegen``, ``ddpc-codegen fit``, the simulated pipeline, the
sweep and the benches call; :func:`load_checked` is the one loading and checking path of a dataset
against a config (damaged files, NaN, lengths, channel names and order, units, dt), so every caller
refuses the same inputs with the same one-line DataError / ConfigError.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ddpc_codegen.codegen import generate
from ddpc_codegen.codegen.artio import OnlineCompletion
from ddpc_codegen.design.artificial_io import ArtificialIO
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset, output_noise
from ddpc_codegen.design.fit import fit_configured
from ddpc_codegen.design.fleet import fit_files
from ddpc_codegen.design.holdout import holdout_check
from ddpc_codegen.design.hopping_data import ArtificialIOSpec, is_hopping_config, prepare_hopping
from ddpc_codegen.design.match import conform_dataset
from ddpc_codegen.design.predictor import Predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.design.step_response import settling_report
from ddpc_codegen.errors import ConfigError, DataError

__all__ = ["BuiltSolver", "FleetOptions", "build_solver", "build_from_config", "load_checked", "noise_warning", "PROVENANCE_KEYS"]

# What a dataset's metadata says about the loop it was recorded in (bridge tick logs).
PROVENANCE_KEYS = ("thrust_field", "autopilot")

DatasetArg = str | Path | IODataset | Sequence[str | Path] | None


@dataclass(frozen=True)
class FleetOptions:
    """How several dataset files are fitted (:func:`ddpc_codegen.design.fleet.fit_files`): parallel
    tasks (1 = serial), a Ray cluster address, Hankel columns per task at most."""

    workers: int = 1
    address: str | None = None
    chunk_columns: int = 2**18


@dataclass
class BuiltSolver:
    """What :func:`build_solver` made: the solver folder (None when not generated), the problem, the data
    the predictor was fitted on (hopping: the stitched hops), the hopping completion, the provenance
    recorded in the manifest, and a report (fit / codegen seconds, hopping and fleet facts)."""

    config: SteeringConfig
    problem: SteeringProblem
    dataset: IODataset | None
    path: Path | None = None
    art: ArtificialIO | None = None
    art_spec: ArtificialIOSpec = field(default_factory=ArtificialIOSpec)
    provenance: dict = field(default_factory=dict)
    report: dict = field(default_factory=dict)


def load_checked(config: SteeringConfig, dataset: str | Path | IODataset,
                 channel_map: dict[str, str] | None = None) -> tuple[IODataset, IODataset]:
    """(dataset as recorded, dataset conformed to the config's channels) after every check.

    A path is read by :meth:`IODataset.load` (damaged, foreign, oversized, NaN or mismatched-length data
    -> DataError naming the file); a bridge tick log marked unfit is refused; names, order, units and dt
    must match the config (:func:`~ddpc_codegen.design.match.conform_dataset`; ConfigError).
    """
    where = f"{config.source} with dataset {dataset}" if not isinstance(dataset, IODataset) else config.source
    raw = dataset if isinstance(dataset, IODataset) else IODataset.load(dataset)
    if raw.metadata.get("fit_ok") is False:
        # A bridge tick log without closed-loop data (firmware_bridge.ticklog): fitting on it
        # would splice gaps, stale stretches and mode changes into one trajectory.
        raise DataError(f"{dataset} is marked unfit for fitting: {raw.metadata.get('unfit_reason', 'no reason given')}")
    return raw, conform_dataset(config, raw, channel_map, where=where)


def _per_output(config: SteeringConfig, values: np.ndarray) -> str:
    units = config.output_units or ("",) * config.p
    return ", ".join(f"{n} {v * 1e3:.3g} m{u}" if u in ("m", "rad") else f"{n} {v:.3g} {u}".rstrip()
                     for n, v, u in zip(config.output_names, values, units))


def noise_warning(config: SteeringConfig, noise: np.ndarray) -> str | None:
    """A warning when the recording is noisier than the config was tuned for (``[data]
    max_output_noise``): least squares on noisy past outputs misjudges the dynamics, and the solver
    still reports every QP solved, so a steering that is worse than none would fly unnoticed."""
    lim = config.max_output_noise
    if lim is None or not np.any(noise > lim):
        return None
    return (f"WARNING: the recording is noisier than {config.source} was tuned for: {_per_output(config, noise)} "
            f"against [data] max_output_noise {_per_output(config, lim)}; a predictor fitted on it can steer worse "
            f"than no steering with every QP solved -- see the config's [predictor] ridge notes")


def _provenance(config: SteeringConfig, source: Any, raw: IODataset, ds: IODataset, log) -> dict:
    noise = output_noise(ds)
    log(f"  recording noise (white, from third differences): {_per_output(config, noise)}")
    warning = noise_warning(config, noise)
    if warning:
        log("  " + warning)
    meta = raw.metadata
    path = str(source) if not isinstance(source, IODataset) else str(meta.get("source", "<in memory>"))
    return {"path": path, **{k: meta[k] for k in PROVENANCE_KEYS if isinstance(meta.get(k), str)},
            "output_noise": [float(v) for v in noise], "noise_warning": warning}


def _fleet_predictor(config: SteeringConfig, paths: Sequence[Path], fleet: FleetOptions, log) -> tuple[Predictor, dict]:
    """Every file checked as one dataset is (one file in memory at a time), then the map/reduce fit."""
    if config.predictor.get("form", "absolute") != "absolute":
        raise ConfigError(f"{config.source}: [predictor] form = {config.predictor['form']!r}: the fleet fit streams "
                          "samples, not increments; fit this config with `ddpc-codegen codegen` on one dataset")
    for path in paths:
        raw, ds = load_checked(config, path)
        if ds is not raw:  # the fleet reads the files as stored: no renaming or reordering on the way
            raise ConfigError(f"{config.source} with dataset {path}: the fleet fit needs the config's channels "
                              "in the config's order; rename them in the file (or fit it with `ddpc-codegen codegen "
                              "--map-channels`)")
    opts = {k: v for k, v in config.predictor.items() if k not in ("method", "form")}
    fit = fit_files(paths, config.t_ini, config.t_f, config.predictor["method"], workers=fleet.workers,
                    address=fleet.address, chunk_columns=fleet.chunk_columns, log=log, **opts)
    report = {"files": fit.files, "used": fit.used, "skipped": [list(s) for s in fit.skipped], "pieces": fit.pieces,
              "samples": fit.samples, "columns": fit.columns, "workers": fit.workers, "fit_s": round(fit.seconds, 3),
              "peak_mib_per_worker": round(fit.peak_mib_per_worker, 1), "summary": fit.summary()}
    return fit.predictor, report


def _holdout(cfg: SteeringConfig, ds: IODataset, fit, share: float, report: dict, built: BuiltSolver, log) -> None:
    """The held-out check's lines logged, its figures into the report and the provenance."""
    figs, lines, warnings = holdout_check(cfg, ds, fit, share)
    for line in lines + warnings:
        log("  " + line)
    if figs is not None:
        report["holdout"] = built.provenance["holdout"] = {"share": share, **figs.as_dict()}


def build_solver(config: SteeringConfig | str | Path, dataset: DatasetArg, out: str | Path | None, *,
                 backend: str | None = None, name: str | None = None, channel_map: dict[str, str] | None = None,
                 march_native: bool | None = None, fit: Callable[[SteeringConfig, IODataset], Predictor] | None = None,
                 art_spec: ArtificialIOSpec | None = None, fleet: FleetOptions | None = None,
                 holdout: float = 0.0, log: Callable[[str], None] = lambda msg: None) -> BuiltSolver:
    """Config + dataset -> the generated, compiled, vector-checked solver folder ``out``.

    Args:
        config: a SteeringConfig or its TOML path.
        dataset: an IODataset, an ``.npz`` path, several paths (a fleet: checked one by one, then fitted
            by map/reduce with ``fleet``), or None for the config's ``[data] dataset``.
        out: the solver folder (replaced only once the new solver works); None = fit only.
        backend, name, march_native: as :func:`ddpc_codegen.codegen.artifact.generate`.
        channel_map: config channel -> dataset channel where they differ on purpose (one dataset only).
        fit: the predictor fit (default ``fit_configured``; the sweep passes a cached one).
        art_spec: hopping: the artificial-IO settings (default: the config's ``[artificial_io]``).
        holdout: share of each trajectory (0 < share < 1) held out of a second fit whose held-out prediction
            errors are logged, in the report and in the manifest's provenance
            (:mod:`ddpc_codegen.design.holdout`); 0 = no check. One dataset, not hopping.
    Raises:
        DataError / ConfigError (one line, naming the file and key) before anything is fitted or written;
        CodegenError when the build fails (the old solver in ``out`` is kept).
    """
    cfg = config if isinstance(config, SteeringConfig) else SteeringConfig.from_toml(config)
    source = dataset if dataset is not None else cfg.dataset
    if source is None or (isinstance(source, (str, Path)) and not str(source)):
        raise ConfigError(f"{cfg.source}: no dataset: give --dataset or set [data] dataset in the config")
    report: dict[str, Any] = {}
    built = BuiltSolver(cfg, None, None, art_spec=art_spec or ArtificialIOSpec(**cfg.artificial_io))  # type: ignore[arg-type]
    online = None
    t0 = time.perf_counter()
    if isinstance(source, (list, tuple)):
        if channel_map:
            raise ConfigError("--map-channels works on one dataset; the fleet fit reads files as they are")
        pred, report["fleet"] = _fleet_predictor(cfg, [Path(p) for p in source], fleet or FleetOptions(), log)
        built.provenance = {"path": [str(p) for p in source]}
    else:
        raw, ds = load_checked(cfg, source, channel_map)
        if channel_map:
            log(f"  channels mapped (config=dataset): {channel_map}")
        built.provenance = _provenance(cfg, source, raw, ds, log)
        if is_hopping_config(cfg):
            hd = prepare_hopping(ds, cfg, built.art_spec, where=str(source if not isinstance(source, IODataset)
                                                                   else "the recorded hopping data"))
            rep = report["artificial_io"] = hd.report
            log(f"  hopping: {rep['hops']} hops stitched with artificial IO (skipped {rep['skipped']}), operator "
                f"depth {rep['depth']}, rank {rep['rank']} from {rep['aerial_segments']} aerial segments")
            ds, built.art = hd.dataset, hd.art
            if out is not None:
                online = OnlineCompletion.from_spec(hd.art, built.art_spec)
                online.check()  # refused before the fit
        pred = (fit or fit_configured)(cfg, ds)
        built.dataset = ds
        log(f"  data: {ds.n_trajectories} trajectories, {ds.n_samples} samples -> {pred.n_columns} Hankel columns")
    report["fit_s"] = round(time.perf_counter() - t0, 3)
    log(f"  excitation: {pred.excitation().summary()}")
    log(f"  predictor: {pred.method}, rank {pred.rank}, fitted in {report['fit_s']:.2f} s")
    lines, warnings = settling_report(pred)  # does the horizon cover the loop the data describe?
    for line in lines + warnings:
        log("  " + line)
    if holdout and built.dataset is not None:
        if is_hopping_config(cfg):
            log("  held-out check skipped: hopping data (the ground phases are artificial IO)")
        else:
            _holdout(cfg, built.dataset, fit or fit_configured, holdout, report, built, log)
    built.problem, built.report = SteeringProblem(pred, cfg), report
    if out is not None:
        t1 = time.perf_counter()
        built.path = generate(built.problem, out, backend, name=name, march_native=march_native,
                              artificial_io=online, provenance=built.provenance)
        report["codegen_s"] = round(time.perf_counter() - t1, 2)
    return built


def build_from_config(config: SteeringConfig, dataset: str | Path | None = None,
                      log=lambda msg: None, channel_map: dict[str, str] | None = None) -> SteeringProblem:
    """The SteeringProblem :func:`~ddpc_codegen.pipeline.solver_build.build_solver` fits (no solver folder)."""
    return build_solver(config, dataset, None, channel_map=channel_map, log=log).problem
