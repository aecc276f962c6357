"""ddpc-codegen: reference steering via Data-Driven Predictive Control, generated as C.

Data flows one way: IODataset -> Hankel / PE check -> Predictor -> SteeringProblem (CasADi QP)
-> generated C solver -> runtime solver in the loop.
"""

from .data import IODataset, prbs
from .errors import (
    CodegenError,
    ConfigError,
    DataError,
    DDPCError,
    ExcitationError,
    ManifestError,
    SolverError,
)

__version__ = "0.1.0"

__all__ = [
    "IODataset",
    "prbs",
    "DDPCError",
    "DataError",
    "ExcitationError",
    "ConfigError",
    "SolverError",
    "CodegenError",
    "ManifestError",
]
