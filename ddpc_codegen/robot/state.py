"""What the companion controller reads and writes each tick: the measured state and the
attitude setpoint (ENU / FLU, SI units). The simulator, the vehicle's telemetry and the bridge
all speak these two types.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ddpc_codegen.robot.frames import quat_ned_frd_from_enu_flu

__all__ = ["MeasuredState", "AttitudeTarget"]


@dataclass(frozen=True)
class MeasuredState:
    """What the companion computer knows at one control tick (ENU / FLU, SI units).

    Attributes:
        t: measurement time stamp [s].
        position: (3,) [m], velocity: (3,) [m/s], world ENU.
        euler: (3,) roll, pitch, yaw [rad] (Z-Y-X).
        body_rates: (3,) [rad/s] body FLU.
        contact: foot-on-ground estimate (contact switch / leg compression), hopping only.
    """

    t: float
    position: np.ndarray
    velocity: np.ndarray
    euler: np.ndarray
    body_rates: np.ndarray
    contact: bool = False


@dataclass(frozen=True)
class AttitudeTarget:
    """The SET_ATTITUDE_TARGET content, in the controller's ENU/FLU frame.

    Attributes:
        q: (4,) attitude setpoint (w, x, y, z), body FLU -> world ENU.
        thrust: normalized collective thrust in [0, 1].
        thrust_newton: the collective thrust [N] the controller *believes* it asks for
            (thrust * max_thrust of its model).
        euler: (3,) commanded roll, pitch, yaw [rad] (for logs).
    """

    q: np.ndarray
    thrust: float
    thrust_newton: float
    euler: np.ndarray

    def q_ned_frd(self) -> np.ndarray:
        """The quaternion (4,) in PX4's NED/FRD convention."""
        return np.array(quat_ned_frd_from_enu_flu(self.q))
