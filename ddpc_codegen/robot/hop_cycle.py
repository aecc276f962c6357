"""The nominal hop cycle the hopping controller predicts with: an undamped vertical
spring-mass stance between ballistic arcs of the reduced gravity g_eff (SI units)."""

from __future__ import annotations

import math

__all__ = ["spring_mass_stance", "stance_height"]


def spring_mass_stance(v_td: float, m: float, k: float, g_eff: float) -> tuple[float, float]:
    """Stance duration and compression amplitude of an undamped vertical spring-mass.

    m z'' = k (L0 - z) - m g_eff, entering at z = L0 with speed v_td (downwards). Returns
    (duration [s], equilibrium offset m g_eff / k [m]).
    """
    w = math.sqrt(k / m)
    a = m * g_eff / k
    b = -v_td / w
    delta = math.atan2(b, a)
    return (2.0 * math.pi + 2.0 * delta) / w, a


def stance_height(tau: float, L0: float, v_td: float, w: float, z_off: float) -> float:
    """Vertical undamped spring-mass height tau seconds after touchdown at L0 with speed v_td."""
    return L0 - z_off + z_off * math.cos(w * tau) - (v_td / w) * math.sin(w * tau)
