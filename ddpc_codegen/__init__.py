"""ddpc-codegen: reference steering via Data-Driven Predictive Control, generated as C.

Data flows one way: IODataset -> Hankel / PE check -> Predictor -> SteeringProblem (CasADi QP)
-> generated C solver -> runtime solver in the loop.
"""

__version__ = "0.1.0"

from .config import SteeringConfig
from .data import IODataset, prbs
from .deepc import DeePCProblem
from .errors import (
    CodegenError,
    ConfigError,
    DataError,
    DDPCError,
    ExcitationError,
    ManifestError,
    SolverError,
)
from .hankel import PEReport, block_hankel, mosaic_hankel, persistency_of_excitation
from .predictor import Predictor, fit_predictor
from .problem import SteeringProblem, SteeringResult
from .codegen import generate
from .runtime import GeneratedSolver, load_solver
from .steering import ReferenceSteerer, SteerOutcome

__all__ = [
    "IODataset",
    "prbs",
    "block_hankel",
    "mosaic_hankel",
    "persistency_of_excitation",
    "PEReport",
    "fit_predictor",
    "Predictor",
    "SteeringConfig",
    "SteeringProblem",
    "SteeringResult",
    "DeePCProblem",
    "generate",
    "load_solver",
    "GeneratedSolver",
    "ReferenceSteerer",
    "SteerOutcome",
    "DDPCError",
    "DataError",
    "ExcitationError",
    "ConfigError",
    "SolverError",
    "CodegenError",
    "ManifestError",
]
