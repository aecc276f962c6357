"""PogoX flying-hopping simulator: hybrid plant, PX4-like inner loops, closed loop at 200 Hz.

The companion-side controller it drives is :mod:`ddpc_codegen.control` (no simulator imports).
"""

from .loop import Excitation, Push, SimResult, TickContext, simulate
from .params import FlightControllerGains, PogoXParams, SensorNoise
from .plant import PogoXPlant
from .scenarios import FlyingScenario, HoppingScenario, get_scenario

__all__ = [
    "simulate",
    "SimResult",
    "TickContext",
    "Push",
    "Excitation",
    "PogoXParams",
    "FlightControllerGains",
    "SensorNoise",
    "PogoXPlant",
    "FlyingScenario",
    "HoppingScenario",
    "get_scenario",
]
