"""Desired trajectories the companion controller flies (world ENU, SI units)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["EllipseTrajectory"]


def _is_number(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


@dataclass(frozen=True)
class EllipseTrajectory:
    """Desired flying path: an ellipse in the sagittal x-z plane, started smoothly.

    x(t) = cx + ax sin(phi), z(t) = cz - az cos(phi), phi = w (s - tau (1 - e^{-s/tau})),
    s = max(t - t_start, 0), w = 2 pi / period: the robot starts at rest at the bottom point
    (cx, cz - az) and spins up with time constant tau. The paper gives no numbers; the defaults
    (2 m x 0.6 m, 10 s) are an assumption sized for a TWR of 1.25.
    """

    center: tuple[float, float] = (0.0, 1.2)
    radii: tuple[float, float] = (1.0, 0.3)
    period: float = 10.0
    spin_up: float = 1.0
    t_start: float = 1.0

    def __post_init__(self) -> None:
        for key in ("center", "radii"):
            v = getattr(self, key)
            if not (isinstance(v, tuple) and len(v) == 2 and all(_is_number(x) for x in v)):
                raise ValueError(f"{key} must be two numbers (x, z) [m]; got {v!r}")
        if any(r < 0 for r in self.radii):
            raise ValueError(f"radii must be >= 0; got {self.radii!r}")
        for key in ("period", "spin_up"):
            if not (_is_number(getattr(self, key)) and getattr(self, key) > 0):
                raise ValueError(f"{key} must be a positive number of seconds; got {getattr(self, key)!r}")
        if not _is_number(self.t_start):
            raise ValueError(f"t_start must be a number of seconds; got {self.t_start!r}")

    def start_point(self) -> tuple[float, float]:
        return self.center[0], self.center[1] - self.radii[1]

    def sample(self, t: np.ndarray | float) -> dict[str, np.ndarray]:
        """x, vx, ax, z, vz, az at time(s) t (arrays shaped like t)."""
        t = np.asarray(t, dtype=float)
        w = 2.0 * math.pi / self.period
        tau = self.spin_up
        s = np.maximum(t - self.t_start, 0.0)
        e = np.exp(-s / tau)
        phi = w * (s - tau * (1.0 - e))
        dphi = w * (1.0 - e)
        ddphi = np.where(t > self.t_start, w * e / tau, 0.0)
        ax_, az_ = self.radii
        sp, cp = np.sin(phi), np.cos(phi)
        return {
            "x": self.center[0] + ax_ * sp,
            "vx": ax_ * cp * dphi,
            "ax": ax_ * (cp * ddphi - sp * dphi**2),
            "z": self.center[1] - az_ * cp,
            "vz": az_ * sp * dphi,
            "az": az_ * (sp * ddphi + cp * dphi**2),
        }
