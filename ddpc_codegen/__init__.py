"""ddpc-codegen: reference steering via Data-Driven Predictive Control, generated as C.

Layers, each importing only layers listed above it (``tests/test_layout.py`` enforces the rules, no import
circle among modules or packages, and project imports inside functions only where it lists them)::

    errors, stats, ...  small top-level modules
    values/      numpy only, nothing else of the project: SteeringConfig, SteeringResult, FitLayout,
                 AdaptSettings, hop phases, PrefilterModel, artificial-IO completion
    robot/       the companion controller, trajectories, frames (no simulator, no CasADi)
    runtime/     load_solver -> GeneratedSolver; ReferenceSteerer (per tick, with fallback); never design/
    design/      IODataset -> Hankel / PE check -> Predictor -> SteeringProblem (CasADi QP); never runtime/
    codegen/     SteeringProblem -> generated C + compiled extension + manifest.json
    pipeline/    build_solver: config + dataset -> checked data -> predictor -> generated solver
    sim/         the PogoX simulator and its closed loop (a plant: never generates code)
    logs/        PX4 ULog / MAVLink tlog import
    experiments/ the simulated pipeline, demo, benchmarks
    testbed/     the simulated vehicle, SITL and bridge demos
    cli/         the ``ddpc-codegen`` console command: imported by nothing (but the docs' reference of it)
    docsgen/     the pages the docs build generates

The companion loop (package ``firmware_bridge``) sits beside them: values/, robot/, runtime/ and the
dataset type of design/, never the design stack, the simulator or the test bed.
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
    "SteeringConfig": "ddpc_codegen.values.config",
    "SteeringProblem": "ddpc_codegen.design.problem",
    "SteeringResult": "ddpc_codegen.values.solve_result",
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
