"""Scenarios: which desired trajectory, which controller mode, which initial condition.

* ``flying``: the sagittal (x-z) ellipse of the paper, flown from a hover at its bottom point.
  Inputs u = [z_ref, pitch_ref], outputs y = [z, pitch].
* ``hopping``: periodic hopping at a target apex height and horizontal velocity, released at
  rest from the apex. Inputs u = [z_ref, roll_ref, pitch_ref], outputs y = [z, roll, pitch].

The trajectory math itself (ellipse, ballistic arcs, nominal hop cycle) lives in
:mod:`ddpc_codegen.robot.controller`, because the companion computer needs it too; a scenario only binds
it to the simulated robot's parameters.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from ddpc_codegen.robot.controller import ControllerConfig, HeightLegAngleController
from ddpc_codegen.robot.trajectory import EllipseTrajectory
from ddpc_codegen.sim.params import PogoXParams

__all__ = ["FlyingScenario", "HoppingScenario", "Scenario", "get_scenario", "EllipseTrajectory"]


def _controller_config(params: PogoXParams, mode: str, overrides: dict[str, Any], **mode_fields: Any) -> ControllerConfig:
    """The controller's view of the robot (its *model* mass, thrust limit, leg), plus overrides."""
    base = ControllerConfig(
        mode=mode,
        dt=params.control_dt,
        model_mass=params.controller_model_mass,
        max_thrust=params.max_thrust,
        g=params.g,
        leg_length=params.leg_rest_length,
        leg_stiffness=params.leg_stiffness,
        **mode_fields,
    )
    return replace(base, **overrides)


@dataclass(frozen=True)
class FlyingScenario:
    """Fly the sagittal ellipse (paper, Fig. "Results on flying").

    Attributes:
        ellipse: desired x-z path (center (x, z) [m], radii (ax, az) [m], period [s]).
        controller: overrides of :class:`ControllerConfig` fields (gains), e.g. {"kp_z": 12}.
        settle_time: metrics ignore t < settle_time [s] (take-off transient of the PD offset).
    """

    ellipse: EllipseTrajectory = field(default_factory=EllipseTrajectory)
    controller: dict[str, Any] = field(default_factory=dict)
    settle_time: float = 3.0
    name: str = "flying"

    def controller_config(self, params: PogoXParams) -> ControllerConfig:
        return _controller_config(params, "flying", self.controller)

    def make_controller(self, params: PogoXParams) -> HeightLegAngleController:
        return HeightLegAngleController(self.controller_config(params), self.ellipse)

    def initial_position(self, params: PogoXParams) -> tuple[float, float, float]:
        x, z = self.ellipse.start_point()
        return (x, 0.0, z)


@dataclass(frozen=True)
class HoppingScenario:
    """Periodic hopping (paper, Fig. "Results on periodic hopping").

    Attributes:
        apex_height: target apex height of the body COM [m].
        target_velocity: target horizontal velocity (vx, vy) [m/s].
        thrust_fraction: share of the model weight carried by thrust (reduced-gravity arcs).
        release_height: the robot starts at rest at this height (default: apex_height).
        controller: overrides of :class:`ControllerConfig` fields.
        settle_hops: metrics ignore the first hops (the release transient).
    """

    apex_height: float = 0.7
    target_velocity: tuple[float, float] = (0.3, 0.0)
    thrust_fraction: float = 0.5
    release_height: float | None = None
    controller: dict[str, Any] = field(default_factory=dict)
    settle_hops: int = 3
    name: str = "hopping"

    def controller_config(self, params: PogoXParams) -> ControllerConfig:
        return _controller_config(
            params, "hopping", self.controller, thrust_fraction=self.thrust_fraction,
            apex_height=self.apex_height, target_velocity=tuple(self.target_velocity),
            initial_apex=self.release_height,
        )

    def make_controller(self, params: PogoXParams) -> HeightLegAngleController:
        return HeightLegAngleController(self.controller_config(params))

    def initial_position(self, params: PogoXParams) -> tuple[float, float, float]:
        z = self.release_height if self.release_height is not None else self.apex_height
        return (0.0, 0.0, z)


Scenario = FlyingScenario | HoppingScenario


def get_scenario(scenario: str | Scenario, **overrides: Any) -> Scenario:
    """A scenario object from its name ("flying" / "hopping") or as given, with field overrides."""
    if isinstance(scenario, (FlyingScenario, HoppingScenario)):
        return replace(scenario, **overrides) if overrides else scenario
    name = str(scenario).lower()
    if name == "flying":
        return FlyingScenario(**overrides)
    if name == "hopping":
        return HoppingScenario(**overrides)
    raise ValueError(f"unknown scenario {scenario!r}; choose 'flying' or 'hopping'")
