"""PogoX flying-hopping simulator: hybrid plant, PX4-like inner loops, closed loop at 200 Hz.

The companion-side controller it drives is :mod:`ddpc_codegen.robot.controller` (no simulator imports).
"""

from ddpc_codegen.sim.loop import Excitation, Push, SimResult, TickContext, simulate
from ddpc_codegen.sim.params import FlightControllerGains, PogoXParams, SensorNoise
from ddpc_codegen.sim.plant import PogoXPlant
from ddpc_codegen.sim.scenarios import FlyingScenario, HoppingScenario, get_scenario

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
