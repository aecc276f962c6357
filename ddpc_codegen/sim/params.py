"""Physical and flight-controller parameters of the simulated PogoX.

=========================  ================  ============================================================
parameter                  default           source / assumption
=========================  ================  ============================================================
mass                       3.65 kg           paper ("weighs 3.65 kg"); includes the foot
height                     0.53 m            paper (overall height; informs leg_rest_length)
inertia (Ixx, Iyy, Izz)    0.09, 0.09, 0.05  assumption: 4 x 0.15 kg rotors at 0.25 m (Izz ~0.04), a
                           kg m^2            0.5 kg leg and the foot below the COM add ~0.07 to Ixx/Iyy
arm_length                 0.25 m            assumption: ~500 mm motor-to-motor diagonal X frame
k_F                        1.5e-5 N/(rad/s)^2  assumption: 11-in props, hover at ~770 rad/s (7.4 krpm)
k_M                        0.016 k_F  N m s^2  assumption: typical drag-torque/thrust ratio 0.016 m
thrust_to_weight           1.25              paper: "TWR slightly over 1" (battery-less flights); the
                                             battery-carrying robot's 0.82 is an option. Sets
                                             omega_max = sqrt(TWR m g / (4 k_F)).
idle_fraction              0.10              assumption: ESC idle speed = 10 % of omega_max
motor_tau                  0.03 s            assumption within the 20-50 ms of brushless motors + ESC
drag                       0.15 N s/m        assumption: small isotropic linear drag (off: 0)
leg_stiffness              2500 N/m          assumption within the 2-3 kN/m of PogoX's pogo stick
leg_damping                6 N s/m           assumption: damping ratio ~0.03 in stance (~17 % energy/stance)
leg_rest_length            0.40 m            assumption: body COM to foot tip at rest (of 0.53 m height)
leg_max_compression        0.12 m            assumption (>= 0.1 m travel); a stiff bump stop beyond it
bump_stiffness             50 x leg_stiffness  assumption (end-stop rubber)
foot_mass                  0.20 kg           assumption within 0.1-0.3 kg (foot + lower tube); lumped
                                             into the body, its axial momentum is lost at touchdown
g                          9.81 m/s^2
controller_mass_error      -0.2 kg           paper: controller's model mass is 200 g less than the truth
meas_delay                 0.005 s           assumption: motion-capture + link latency of the state the
                                             companion computer sees (rounded to the 1 ms physics step)
physics_dt, control_dt     1 ms, 5 ms        RK4 step with event location; 200 Hz control (paper)
=========================  ================  ============================================================

Flight controller (PX4-like, :mod:`ddpc_codegen.sim.flight_controller`): attitude P gains
(6.5, 6.5, 2.8) 1/s = PX4 defaults MC_ROLL_P / MC_PITCH_P / MC_YAW_P; body-rate PID in
physical units (angular-acceleration per rate error) tuned for a ~18 rad/s rate bandwidth under
the 30 ms motor lag; rate limits 220/220/200 deg/s (PX4 MC_ROLLRATE_MAX, MC_PITCHRATE_MAX,
MC_YAWRATE_MAX defaults); tilt limit 35 deg; rate loop 1 kHz, attitude loop 250 Hz.

Normalized thrust -> newtons (PX4 with THR_MDL_FAC = 1, i.e. thrust-linear motor outputs):
collective thrust T = thrust_norm * max_thrust, max_thrust = 4 k_F omega_max^2 =
thrust_to_weight * mass * g. See :meth:`PogoXParams.max_thrust`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

__all__ = ["PogoXParams", "FlightControllerGains", "SensorNoise"]


@dataclass(frozen=True)
class FlightControllerGains:
    """PX4-like cascaded attitude (P) -> body-rate (PID) gains, in physical units.

    Attributes:
        att_p: attitude P (roll, pitch, yaw) [1/s]: rate setpoint per rad of attitude error.
        rate_p: rate P [1/s]: angular acceleration command per rad/s of rate error.
        rate_i: rate I [1/s^2]; rate_d: rate D [-] (on the measured rate, low-pass filtered).
        rate_i_limit: integrator clamp [rad/s^2 of angular acceleration].
        d_cutoff_hz: D-term low-pass cutoff [Hz].
        rate_max: (roll, pitch, yaw) rate setpoint limits [rad/s].
        tilt_max: limit on the tilt of the incoming attitude setpoint [rad].
        rate_hz: body-rate loop frequency [Hz]; att_hz: attitude loop frequency [Hz].
    """

    att_p: tuple[float, float, float] = (6.5, 6.5, 2.8)
    rate_p: tuple[float, float, float] = (18.0, 18.0, 10.0)
    rate_i: tuple[float, float, float] = (20.0, 20.0, 10.0)
    rate_d: tuple[float, float, float] = (0.15, 0.15, 0.0)
    rate_i_limit: float = 10.0
    d_cutoff_hz: float = 30.0
    rate_max: tuple[float, float, float] = (math.radians(220.0), math.radians(220.0), math.radians(200.0))
    tilt_max: float = math.radians(35.0)
    rate_hz: float = 1000.0
    att_hz: float = 250.0


@dataclass(frozen=True)
class SensorNoise:
    """Measurement model of the companion computer's state estimate (motion capture + EKF).

    Attributes:
        position, velocity, angle, rate: white-noise standard deviations [m, m/s, rad, rad/s].

    The latency is a plant parameter (:attr:`PogoXParams.meas_delay`), present with or without noise.
    """

    position: float = 0.002
    velocity: float = 0.02
    angle: float = 0.004
    rate: float = 0.02


@dataclass(frozen=True)
class PogoXParams:
    """True physical parameters of the simulated PogoX (see the module table for sources).

    All SI units. ``controller_model_mass`` is what the model-based controller believes.
    """

    mass: float = 3.65
    height: float = 0.53
    inertia: tuple[float, float, float] = (0.09, 0.09, 0.05)
    arm_length: float = 0.25
    k_f: float = 1.5e-5
    k_m_ratio: float = 0.016
    thrust_to_weight: float = 1.25
    idle_fraction: float = 0.10
    motor_tau: float = 0.03
    drag: float = 0.15
    leg_stiffness: float = 2500.0
    leg_damping: float = 6.0
    leg_rest_length: float = 0.40
    leg_max_compression: float = 0.12
    bump_stiffness_factor: float = 50.0
    foot_mass: float = 0.20
    g: float = 9.81
    controller_mass_error: float = -0.2
    physics_dt: float = 0.001
    control_dt: float = 0.005
    fc: FlightControllerGains = field(default_factory=FlightControllerGains)
    meas_delay: float = 0.005

    def __post_init__(self) -> None:
        pos = {
            "mass": self.mass, "k_f": self.k_f, "motor_tau": self.motor_tau,
            "leg_stiffness": self.leg_stiffness, "leg_rest_length": self.leg_rest_length,
            "physics_dt": self.physics_dt, "control_dt": self.control_dt,
            "thrust_to_weight": self.thrust_to_weight, "arm_length": self.arm_length,
        }
        for k, v in pos.items():
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"PogoXParams.{k} must be positive; got {v}")
        if not 0 <= self.foot_mass < self.mass:
            raise ValueError(f"foot_mass must be in [0, mass); got {self.foot_mass}")
        if self.leg_damping < 0 or self.drag < 0:
            raise ValueError("leg_damping and drag must be >= 0")
        if self.controller_model_mass <= 0:
            raise ValueError(f"controller model mass must be > 0; got {self.controller_model_mass}")
        ratio = self.control_dt / self.physics_dt
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError("control_dt must be an integer multiple of physics_dt")

    # ------------------------------------------------------------------ derived
    @property
    def controller_model_mass(self) -> float:
        """Mass the height controller uses [kg] (true mass + controller_mass_error)."""
        return self.mass + self.controller_mass_error

    @property
    def omega_max(self) -> float:
        """Maximum rotor speed [rad/s] giving the stated thrust-to-weight ratio."""
        return math.sqrt(self.thrust_to_weight * self.mass * self.g / (4.0 * self.k_f))

    @property
    def omega_idle(self) -> float:
        return self.idle_fraction * self.omega_max

    @property
    def max_thrust(self) -> float:
        """Collective thrust at normalized thrust 1 [N] = 4 k_F omega_max^2."""
        return 4.0 * self.k_f * self.omega_max**2

    @property
    def hover_omega(self) -> float:
        """Rotor speed for hover of the true mass [rad/s]."""
        return math.sqrt(self.mass * self.g / (4.0 * self.k_f))

    @property
    def substeps(self) -> int:
        """Physics steps per control tick."""
        return int(round(self.control_dt / self.physics_dt))

    def with_(self, **changes) -> "PogoXParams":
        """A modified copy (dataclasses.replace)."""
        return replace(self, **changes)
