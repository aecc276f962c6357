"""Gains and model of the height and leg angle controller (:class:`ControllerConfig`, SI units)."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ControllerConfig"]


@dataclass(frozen=True)
class ControllerConfig:
    """Gains and model of the height and leg angle controller (SI units).

    The model values (``model_mass``, ``max_thrust``, ``leg_*``) are what the controller
    believes; the simulator's true plant may differ (by default the mass is 200 g off).

    Attributes:
        mode: "flying" or "hopping".
        dt: control period [s] (200 Hz).
        model_mass: mass used for the thrust computation [kg].
        max_thrust: model collective thrust at normalized thrust 1 [N].
        g: gravity [m/s^2].
        kp_z, kd_z: height PD [1/s^2], [1/s].
        ref_velocity_gain: weight of the filtered reference derivative in the D term
            (None -> 0 flying, 1 hopping); ref_velocity_tau: its low-pass time constant [s].
        kp_xy, kd_xy: horizontal position PD -> tilt (flying) [1/s^2], [1/s].
        max_tilt: limit on commanded roll/pitch [rad].
        thrust_fraction: hopping only, share of the model weight carried by thrust (a_ff).
        apex_height: hopping target apex height of the body [m].
        target_velocity: hopping target horizontal velocity (vx, vy) [m/s].
        stance_boost: hopping, extra thrust acceleration while the leg extends [m/s^2].
        raibert_gain: foot-placement gain [m per m/s] on the horizontal velocity error.
        velocity_integral_gain: per-hop integral of the velocity error, as a multiple of
            raibert_gain (0 disables); the S2S "u* adaptation" that removes the steady velocity error.
        leg_length, leg_stiffness: model leg rest length [m] (body COM to foot), stiffness [N/m].
        initial_apex: hopping: height the robot is released from (apex of the first arc) [m];
            None -> apex_height.
    """

    mode: str = "flying"
    dt: float = 0.005
    model_mass: float = 3.45
    max_thrust: float = 1.25 * 3.65 * 9.81
    g: float = 9.81
    kp_z: float = 10.0
    kd_z: float = 5.0
    ref_velocity_gain: float | None = None
    ref_velocity_tau: float = 0.03
    kp_xy: float = 1.5
    kd_xy: float = 2.0
    max_tilt: float = math.radians(30.0)
    thrust_fraction: float = 0.5
    apex_height: float = 0.7
    target_velocity: tuple[float, float] = (0.3, 0.0)
    stance_boost: float = 8.0
    raibert_gain: float = 0.06
    velocity_integral_gain: float = 1.0
    leg_length: float = 0.40
    leg_stiffness: float = 2500.0
    initial_apex: float | None = None

    def __post_init__(self) -> None:
        if self.mode not in ("flying", "hopping"):
            raise ValueError(f"ControllerConfig.mode must be 'flying' or 'hopping'; got {self.mode!r}")
        if self.model_mass <= 0 or self.max_thrust <= 0 or self.dt <= 0:
            raise ValueError("model_mass, max_thrust and dt must be positive")
        if self.mode == "hopping" and not 0.0 <= self.thrust_fraction < 1.0:
            raise ValueError(f"thrust_fraction must be in [0, 1); got {self.thrust_fraction}")

    @property
    def g_eff(self) -> float:
        """Hopping: the reduced gravity of the aerial arcs [m/s^2]."""
        return (1.0 - self.thrust_fraction) * self.g if self.mode == "hopping" else self.g
