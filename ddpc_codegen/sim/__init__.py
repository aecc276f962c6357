"""PogoX flying-hopping simulator: hybrid plant, PX4-like inner loops, closed loop at 200 Hz.

The companion-side controller it drives is :mod:`ddpc_codegen.robot.controller` (no simulator imports).
"""

from ddpc_codegen.sim.loop import Excitation, TickContext, simulate
from ddpc_codegen.sim.params import FlightControllerGains, PogoXParams, SensorNoise
from ddpc_codegen.sim.plant import PogoXPlant
from ddpc_codegen.sim.run_result import SimResult
from ddpc_codegen.sim.scenarios import FlyingScenario, HoppingScenario, get_scenario
from ddpc_codegen.sim.stepper import Push, Stepper

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
    "Stepper",
    "FlyingScenario",
    "HoppingScenario",
    "get_scenario",
]
