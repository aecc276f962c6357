"""Desired trajectories the companion controller flies (world ENU, SI units)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["EllipseTrajectory", "RandomSmoothTrajectory", "SampledTrajectory", "Trajectory"]


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


# ----------------------------------------------------------------------------- random smooth
def _smoothstep(s: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """w, dw/dt, d2w/dt2 of the quintic ramp from 0 (s <= 0) to 1 (s >= span)."""
    u = np.clip(s / span, 0.0, 1.0)
    inside = (s > 0.0) & (s < span)
    w = u**3 * (10.0 - 15.0 * u + 6.0 * u * u)
    w1 = np.where(inside, 30.0 * u * u * (1.0 - u) ** 2 / span, 0.0)
    w2 = np.where(inside, 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u) / span**2, 0.0)
    return w, w1, w2


@dataclass(frozen=True)
class RandomSmoothTrajectory:
    """A seeded, non-repeating smooth x-z path: per axis a sum of sinusoids with random
    frequencies in ``band`` and random phases, faded in from rest at the start point.

    x(t) = cx + w(s) d_x(s), d(s) = sum_i A_i (sin(w_i s + phi_i) - sin(phi_i)), s = t - t_start,
    w the quintic ramp over ``spin_up`` seconds. The frequencies are drawn independently (almost
    surely incommensurate), so the path does not repeat. Guaranteed bounds (all t):
    |x - cx| <= 2 amplitude[0] (|d| <= 2 sum A), and |x''| <= ``max_accel`` (the amplitudes of an
    axis are scaled down when its acceleration bound, see :meth:`_accel_bound`, would exceed it).

    Attributes:
        seed: RNG seed (the same seed gives the same path).
        center: (x, z) start point [m].
        amplitude: (x, z) sum of the sinusoid amplitudes per axis [m] (before acceleration scaling).
        band: (f_min, f_max) frequency range [Hz].
        n_components: sinusoids per axis.
        max_accel: bound on |x''| and |z''| [m/s^2].
        spin_up: fade-in duration [s]; t_start: time the fade-in starts [s].
    """

    seed: int = 0
    center: tuple[float, float] = (0.0, 1.2)
    amplitude: tuple[float, float] = (0.8, 0.25)
    band: tuple[float, float] = (0.05, 0.2)
    n_components: int = 4
    max_accel: float = 1.5
    spin_up: float = 3.0
    t_start: float = 1.0

    def __post_init__(self) -> None:
        for key in ("center", "amplitude", "band"):
            v = getattr(self, key)
            if not (isinstance(v, tuple) and len(v) == 2 and all(_is_number(x) for x in v)):
                raise ValueError(f"{key} must be two numbers; got {v!r}")
        if any(a < 0 for a in self.amplitude):
            raise ValueError(f"amplitude must be >= 0; got {self.amplitude!r}")
        if not 0.0 < self.band[0] <= self.band[1]:
            raise ValueError(f"band must be 0 < f_min <= f_max [Hz]; got {self.band!r}")
        if not (isinstance(self.n_components, int) and self.n_components >= 1):
            raise ValueError(f"n_components must be an integer >= 1; got {self.n_components!r}")
        for key in ("max_accel", "spin_up"):
            if not (_is_number(getattr(self, key)) and getattr(self, key) > 0):
                raise ValueError(f"{key} must be a positive number; got {getattr(self, key)!r}")
        if not (isinstance(self.seed, int) and _is_number(self.t_start)):
            raise ValueError(f"seed must be an integer and t_start a number; got {self.seed!r}, {self.t_start!r}")
        self._draw()

    def _draw(self) -> None:
        """Per axis (A (n,), omega (n,), phi (n,)) into ``_terms``, amplitudes scaled to honour max_accel."""
        rng = np.random.default_rng(self.seed)
        terms = []
        for amp in self.amplitude:
            w = 2.0 * math.pi * rng.uniform(*self.band, self.n_components)
            a = rng.uniform(0.5, 1.0, self.n_components)
            a *= amp / a.sum()
            phi = rng.uniform(0.0, 2.0 * math.pi, self.n_components)
            terms += [a, w, phi]
        object.__setattr__(self, "_terms", tuple(terms))
        for axis in range(2):
            bound = self._accel_bound(axis)
            if bound > self.max_accel:
                terms[3 * axis] *= self.max_accel / bound  # in place: _terms holds the same array

    def _accel_bound(self, axis: int) -> float:
        """An upper bound of |d2/dt2| of one axis over all t: after the fade-in sum(A w^2) (the
        sup of a sum of sinusoids); during it the maximum on a 1 ms grid + 2 % (the grid is fine
        against the fastest component, so the sampled maximum is within far less than 2 %)."""
        a, w, _ = self._terms[3 * axis : 3 * axis + 3]
        ts = self.t_start + np.arange(0.0, self.spin_up + 1e-3, 1e-3)
        during = float(np.max(np.abs(self.sample(ts)["ax" if axis == 0 else "az"])))
        return max(float((a * w * w).sum()), 1.02 * during)

    def start_point(self) -> tuple[float, float]:
        return self.center

    def sample(self, t: np.ndarray | float) -> dict[str, np.ndarray]:
        """x, vx, ax, z, vz, az at time(s) t (arrays shaped like t)."""
        t = np.asarray(t, dtype=float)
        s = np.maximum(t - self.t_start, 0.0)
        w, w1, w2 = _smoothstep(s, self.spin_up)
        out = {}
        for i, (name, c) in enumerate(zip("xz", self.center)):
            a, om, phi = self._terms[3 * i : 3 * i + 3]
            arg = s[..., None] * om + phi
            d = (a * (np.sin(arg) - np.sin(phi))).sum(-1)
            d1 = np.where(t > self.t_start, (a * om * np.cos(arg)).sum(-1), 0.0)
            d2 = np.where(t > self.t_start, -(a * om * om * np.sin(arg)).sum(-1), 0.0)
            out[name] = c + w * d
            out[f"v{name}"] = w1 * d + w * d1
            out[f"a{name}"] = w2 * d + 2.0 * w1 * d1 + w * d2
        return out


# ----------------------------------------------------------------------------- sampled (files)
def _natural_spline_m(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Second derivatives of the natural cubic spline through (t, v) (tridiagonal, Thomas)."""
    n = t.size
    m = np.zeros(n)
    if n < 3:
        return m
    h = np.diff(t)
    rhs = 6.0 * (np.diff(v[1:]) / h[1:] - np.diff(v[:-1]) / h[:-1])
    diag = 2.0 * (h[:-1] + h[1:])
    off = h[1:-1].copy()
    c, d = np.zeros(n - 2), np.zeros(n - 2)
    for i in range(n - 2):  # forward sweep (load time only; n = the file's rows)
        den = diag[i] - (h[i] * c[i - 1] if i else 0.0)
        c[i] = off[i] / den if i < n - 3 else 0.0
        d[i] = (rhs[i] - (h[i] * d[i - 1] if i else 0.0)) / den
    for i in range(n - 3, -1, -1):
        m[i + 1] = d[i] - (c[i] * m[i + 2] if i < n - 3 else 0.0)
    return m


@dataclass(frozen=True)
class SampledTrajectory:
    """An x-z path through given samples (e.g. from a file): natural cubic spline per axis, so
    position, velocity and acceleration are continuous. Before the first sample the robot holds
    the first point, after the last the last point (velocity and acceleration 0 there).

    Attributes:
        t: (n,) strictly increasing times [s] (trajectory time: 0 = when the run / off-board starts).
        x, z: (n,) positions [m].
        source: where the samples came from (for messages and logs).
    """

    t: tuple[float, ...]
    x: tuple[float, ...]
    z: tuple[float, ...]
    source: str = "<samples>"

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f"{self.source}: a trajectory needs at least 2 samples; got {t.size}")
        if len(self.x) != t.size or len(self.z) != t.size:
            raise ValueError(f"{self.source}: t, x, z must have the same length; got {t.size}, {len(self.x)}, {len(self.z)}")
        if not np.all(np.diff(t) > 0):
            raise ValueError(f"{self.source}: t must be strictly increasing")
        xs = np.asarray(self.x, dtype=float), np.asarray(self.z, dtype=float)
        object.__setattr__(self, "_m", tuple(_natural_spline_m(t, v) for v in xs))

    def start_point(self) -> tuple[float, float]:
        return float(self.x[0]), float(self.z[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def sample(self, t: np.ndarray | float) -> dict[str, np.ndarray]:
        """x, vx, ax, z, vz, az at time(s) t (arrays shaped like t)."""
        tk = np.asarray(self.t, dtype=float)
        tq = np.asarray(t, dtype=float)
        tc = np.clip(tq, tk[0], tk[-1])
        inside = (tq > tk[0]) & (tq < tk[-1])
        i = np.clip(np.searchsorted(tk, tc, side="right") - 1, 0, tk.size - 2)
        h = tk[i + 1] - tk[i]
        a, b = (tk[i + 1] - tc) / h, (tc - tk[i]) / h
        out = {}
        for name, v, m in (("x", self.x, self._m[0]), ("z", self.z, self._m[1])):
            v = np.asarray(v, dtype=float)
            m0, m1, v0, v1 = m[i], m[i + 1], v[i], v[i + 1]
            out[name] = a * v0 + b * v1 + ((a**3 - a) * m0 + (b**3 - b) * m1) * h * h / 6.0
            vel = (v1 - v0) / h + ((1 - 3 * a * a) * m0 + (3 * b * b - 1) * m1) * h / 6.0
            out[f"v{name}"] = np.where(inside, vel, 0.0)
            out[f"a{name}"] = np.where(inside, a * m0 + b * m1, 0.0)
        return out


# What the controller and the simulator need from a desired path: sample(t) -> x, vx, ax, z, vz, az
# and start_point() -> (x, z).
Trajectory = EllipseTrajectory | RandomSmoothTrajectory | SampledTrajectory
