"""``ddpc-codegen codegen``: TOML config(s) + dataset -> generated/<name>/ (C sources, extension, manifest).

    ddpc-codegen codegen configs/flying.toml
    ddpc-codegen codegen configs/flying.toml --dataset data/flight1.npz --backend osqp --out generated
    ddpc-codegen codegen configs/hopping.toml --dataset data/hopping_raw.npz   # raw hopping log, phases labelled
    ddpc-codegen codegen cfg.toml --dataset log.npz --map-channels z=pos_z,pitch=att_pitch

Every config is loaded and checked before any fit; the dataset must match the config's channel
names and order, units and dt (or be mapped explicitly with --map-channels). A hopping config
([artificial_io]) takes the raw hopping log: the hops are stitched here and the artifact carries the
generated artificial-IO completion.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.design.config import SteeringConfig
from ddpc_codegen.design.data import IODataset, output_noise
from ddpc_codegen.design.match import conform_dataset, parse_channel_map
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.design.fit import fit_configured
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.design.hopping_data import is_hopping_config, prepare_hopping
from ddpc_codegen.codegen import BACKENDS, OnlineCompletion, generate

# What a dataset's metadata says about the loop it was recorded in (bridge tick logs).
PROVENANCE_KEYS = ("thrust_field", "autopilot")

__all__ = ["register", "build_from_config", "prepare_from_config"]


def build_from_config(config: SteeringConfig, dataset: str | Path | None = None,
                      log=lambda msg: None, channel_map: dict[str, str] | None = None) -> SteeringProblem:
    """The SteeringProblem of :func:`prepare_from_config` (without the hopping completion)."""
    return prepare_from_config(config, dataset, log, channel_map)[0]


def prepare_from_config(config: SteeringConfig, dataset: str | Path | None = None,
                        log=lambda msg: None, channel_map: dict[str, str] | None = None
                        ) -> tuple[SteeringProblem, OnlineCompletion | None, dict]:
    """Config + dataset file -> (SteeringProblem, online completion or None, provenance).

    The provenance (recorded in the manifest as ``dataset``) names the file and what the data say about
    the loop they were recorded in (e.g. a bridge tick log's ``thrust_field`` and ``autopilot``), so a
    solver is never flown on a different loop unnoticed.

    The dataset is checked against the config first (names, order, units, dt; see
    :func:`~ddpc_codegen.design.match.conform_dataset`); ``channel_map`` maps config channel names to
    dataset channel names where they differ on purpose. A hopping config (``[artificial_io]``) needs
    the raw hopping log with phase labels: its hops are stitched with artificial IO
    (:func:`~ddpc_codegen.design.hopping_data.prepare_hopping`), the predictor is fitted on them and
    the online completion is returned for the artifact.
    """
    path = dataset or config.dataset
    if not path:
        raise ConfigError(f"{config.source}: no dataset: give --dataset or set [data] dataset in the config")
    raw = IODataset.load(path)
    if raw.metadata.get("fit_ok") is False:
        # A bridge tick log without closed-loop data (firmware_bridge.ticklog): fitting on it
        # would splice gaps, stale stretches and mode changes into one trajectory.
        raise DataError(f"{path} is marked unfit for fitting: {raw.metadata.get('unfit_reason', 'no reason given')}")
    ds = conform_dataset(config, raw, channel_map, where=f"{config.source} with dataset {path}")
    if channel_map:
        log(f"  channels mapped (config=dataset): {channel_map}")
    noise = output_noise(ds)
    log(f"  recording noise (white, from third differences): {_per_output(config, noise)}")
    warning = noise_warning(config, noise)
    if warning:
        log("  " + warning)
    online = None
    if is_hopping_config(config):
        hd = prepare_hopping(ds, config, where=str(path))
        rep = hd.report
        log(f"  hopping: {rep['hops']} hops stitched with artificial IO (skipped {rep['skipped']}), operator depth "
            f"{rep['depth']}, rank {rep['rank']} from {rep['aerial_segments']} aerial segments")
        ds = hd.dataset
        online = OnlineCompletion.from_spec(hd.art, hd.spec)
        online.check()  # refused before the fit
    t0 = time.perf_counter()
    pred = fit_configured(config, ds)
    pe = pred.excitation()
    log(f"  data: {ds.n_trajectories} trajectories, {ds.n_samples} samples -> {pred.n_columns} Hankel columns")
    log(f"  excitation: {pe.summary()}")
    log(f"  predictor: {pred.method}, rank {pred.rank}, fitted in {time.perf_counter() - t0:.2f} s")
    meta = raw.metadata
    provenance = {"path": str(path), **{k: meta[k] for k in PROVENANCE_KEYS if isinstance(meta.get(k), str)},
                  "output_noise": [float(v) for v in noise], "noise_warning": warning}
    return SteeringProblem(pred, config), online, provenance


def _per_output(config: SteeringConfig, values: np.ndarray) -> str:
    units = config.output_units or ("",) * config.p
    return ", ".join(f"{n} {v * 1e3:.3g} m{u}" if u in ("m", "rad") else f"{n} {v:.3g} {u}".rstrip()
                     for n, v, u in zip(config.output_names, values, units))


def noise_warning(config: SteeringConfig, noise: np.ndarray) -> str | None:
    """A warning when the recording is noisier than the config was tuned for (``[data]
    max_output_noise``): least squares on noisy past outputs misjudges the dynamics, and the solver
    still reports every QP solved (measured: a hopping solver from a 2 mm-noise recording with the
    clean recordings' ridge steered 45 mm against 33 mm unsteered)."""
    lim = config.max_output_noise
    if lim is None or not np.any(noise > lim):
        return None
    return (f"WARNING: the recording is noisier than {config.source} was tuned for: {_per_output(config, noise)} "
            f"against [data] max_output_noise {_per_output(config, lim)}; a predictor fitted on it can steer worse "
            f"than no steering with every QP solved -- see the config's [predictor] ridge notes")


def _cmd_codegen(args: argparse.Namespace) -> int:
    say = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    mapping = parse_channel_map(args.map_channels)
    configs = [SteeringConfig.from_toml(p) for p in args.configs]  # every config refused before any fit
    for cfg_path, cfg in zip(args.configs, configs):
        backend = args.backend or cfg.codegen["backend"]
        say(f"[{cfg.name}] {cfg_path}: m={cfg.m} p={cfg.p} Tini={cfg.t_ini} Tf={cfg.t_f} backend={backend}")
        prob, online, provenance = prepare_from_config(cfg, args.dataset, say, mapping)
        out = Path(args.out) / cfg.name
        t0 = time.perf_counter()
        generate(prob, out, backend, march_native=args.march_native or None, artificial_io=online,
                 provenance=provenance)
        say(f"  generated + compiled {out}/ in {time.perf_counter() - t0:.1f} s "
            f"({prob.n_u} variables, {prob.n_theta} parameters, {prob.n_g} general constraints)")
        print(out)
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "codegen",
        help="emit and compile steering solvers from TOML configs into generated/<name>/",
        description="Fit the predictor from the dataset, form the steering QP, emit C (CasADi parameter map + "
                    "daqp/osqp backend + exact fast path), compile a Python-loadable extension, write manifest.json.",
    )
    p.add_argument("configs", nargs="+", help="steering config TOML file(s)")
    p.add_argument("--dataset", default=None, help="IODataset .npz (default: the config's [data] dataset)")
    p.add_argument("--map-channels", default=None, metavar="CFG=DATA,...",
                   help="use dataset channel DATA as config channel CFG (names that differ on purpose; also "
                        "allows another order and extra dataset channels). Without it the dataset must have "
                        "the config's channel names in the config's order")
    p.add_argument("--backend", choices=BACKENDS, default=None, help="override the config's [codegen] backend")
    p.add_argument("--out", default="generated", help="output root (default generated/)")
    p.add_argument("--march-native", action="store_true", help="opt-in -march=native (binary tied to this CPU)")
    p.add_argument("--quiet", action="store_true", help="print only the output folders")
    p.set_defaults(func=_cmd_codegen)
