"""ddpc-codegen: reference steering via Data-Driven Predictive Control, generated as C.

Data flows one way, and so does the package layout::

    design/      IODataset -> Hankel / PE check -> Predictor -> SteeringProblem (CasADi QP)
    codegen/     SteeringProblem -> generated C + compiled extension + manifest.json
    runtime/     load_solver -> GeneratedSolver; ReferenceSteerer (per tick, with fallback)
    robot/       the companion controller, trajectories, frames (no simulator, no CasADi)
    sim/         the PogoX simulator and its closed loop
    logs/        PX4 ULog / MAVLink tlog import
    experiments/ data collection, demo, benchmarks
    cli/         the ``ddpc-codegen`` console command

Public names are imported lazily: ``import ddpc_codegen`` loads neither CasADi nor the simulator.
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:
    __version__ = version("ddpc-codegen")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0+unknown"

# public name -> module that defines it
_EXPORTS: dict[str, str] = {
    "IODataset": "ddpc_codegen.design.data",
    "prbs": "ddpc_codegen.design.data",
    "block_hankel": "ddpc_codegen.design.hankel",
    "mosaic_hankel": "ddpc_codegen.design.hankel",
    "persistency_of_excitation": "ddpc_codegen.design.hankel",
    "PEReport": "ddpc_codegen.design.hankel",
    "fit_predictor": "ddpc_codegen.design.predictor",
    "Predictor": "ddpc_codegen.design.predictor",
    "SteeringConfig": "ddpc_codegen.design.config",
    "SteeringProblem": "ddpc_codegen.design.problem",
    "SteeringResult": "ddpc_codegen.design.solve_result",
    "DeePCProblem": "ddpc_codegen.design.deepc",
    "generate": "ddpc_codegen.codegen",
    "load_solver": "ddpc_codegen.runtime.loader",
    "GeneratedSolver": "ddpc_codegen.runtime.loader",
    "ReferenceSteerer": "ddpc_codegen.runtime.steerer",
    "SteerOutcome": "ddpc_codegen.runtime.steerer",
    "Policy": "ddpc_codegen.runtime.policy",
    "SteeringPolicy": "ddpc_codegen.runtime.policy",
    "DDPCError": "ddpc_codegen.errors",
    "DataError": "ddpc_codegen.errors",
    "ExcitationError": "ddpc_codegen.errors",
    "ConfigError": "ddpc_codegen.errors",
    "SolverError": "ddpc_codegen.errors",
    "CodegenError": "ddpc_codegen.errors",
    "ManifestError": "ddpc_codegen.errors",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'ddpc_codegen' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
