"""Desired trajectories the companion controller flies (trajectory frame: x forward, y left, z up; SI units).

Every kind follows one protocol (:class:`Trajectory`), which is all the controller, the simulator and
the bridge's checks use:

* ``sample(t)``: x, vx, ax, y, vy, ay, z, vz, az [m, m/s, m/s^2] and yaw [rad] at time(s) t;
* ``start_position()``: (x, y, z) where the path starts (``start_point()``: its (x, z));
* ``time_span()``: (t0, t1) [s], the part of trajectory time in which the path moves: before t0
  it holds its start, after t1 it holds its end or repeats what [t0, t1] showed (t1 = inf: it never
  repeats nor stops);
* ``extent()``: {"x", "y", "z"} -> (low, high) [m], bounds of every position the path takes, at
  any time (exact for the ellipse and the samples, a guaranteed bound for the random path).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["EllipseTrajectory", "RandomSmoothTrajectory", "SampledTrajectory", "Trajectory", "AXES"]

AXES = ("x", "y", "z")


@runtime_checkable
class Trajectory(Protocol):
    """What the controller, the simulator and the bridge need from a desired path (module docstring)."""

    def sample(self, t: np.ndarray | float) -> dict[str, np.ndarray]:
        """x, vx, ax, y, vy, ay, z, vz, az, yaw at time(s) t (arrays shaped like t)."""

    def start_point(self) -> tuple[float, float]:
        """(x, z) of the start [m]."""

    def start_position(self) -> tuple[float, float, float]:
        """(x, y, z) of the start [m]."""

    def time_span(self) -> tuple[float, float]:
        """(t0, t1) [s]: the part of trajectory time in which the path moves (t1 may be inf)."""

    def extent(self) -> dict[str, tuple[float, float]]:
        """{"x", "y", "z"} -> (low, high) [m]: bounds of every position the path takes."""


def _planar(out: dict[str, np.ndarray], like: np.ndarray) -> dict[str, np.ndarray]:
    """Complete an x-z sample with y = vy = ay = yaw = 0 (the path lies in the sagittal plane)."""
    zero = np.zeros_like(like, dtype=float)
    out.update(y=zero, vy=zero, ay=zero, yaw=zero)
    return out


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

    def start_position(self) -> tuple[float, float, float]:
        return self.center[0], 0.0, self.center[1] - self.radii[1]

    def time_span(self) -> tuple[float, float]:
        """From t_start over the spin-up (5 time constants: within e^-5 of the full rate) and one period."""
        return self.t_start, self.t_start + 5.0 * self.spin_up + self.period

    def extent(self) -> dict[str, tuple[float, float]]:
        (cx, cz), (ax_, az_) = self.center, self.radii
        return {"x": (cx - ax_, cx + ax_), "y": (0.0, 0.0), "z": (cz - az_, cz + az_)}

    def sample(self, t: np.ndarray | float) -> dict[str, np.ndarray]:
        """x, vx, ax, y, vy, ay, z, vz, az, yaw at time(s) t (arrays shaped like t; y = yaw = 0)."""
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
        return _planar({
            "x": self.center[0] + ax_ * sp,
            "vx": ax_ * cp * dphi,
            "ax": ax_ * (cp * ddphi - sp * dphi**2),
            "z": self.center[1] - az_ * cp,
            "vz": az_ * sp * dphi,
            "az": az_ * (sp * ddphi + cp * dphi**2),
        }, t)


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

    def start_position(self) -> tuple[float, float, float]:
        return self.center[0], 0.0, self.center[1]

    def time_span(self) -> tuple[float, float]:
        """From t_start on, for ever (the path neither stops nor repeats)."""
        return self.t_start, math.inf

    def extent(self) -> dict[str, tuple[float, float]]:
        """center +- 2 sum(A) per axis (|sin(.) - sin(phi)| <= 2, the fade-in weight <= 1)."""
        out = {"y": (0.0, 0.0)}
        for i, (name, c) in enumerate(zip("xz", self.center)):
            r = 2.0 * float(self._terms[3 * i].sum())
            out[name] = (c - r, c + r)
        return out

    def sample(self, t: np.ndarray | float) -> dict[str, np.ndarray]:
        """x, vx, ax, y, vy, ay, z, vz, az, yaw at time(s) t (arrays shaped like t; y = yaw = 0)."""
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
        return _planar(out, t)


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


def _cubic_coefficients(t: np.ndarray, v: np.ndarray, vel: np.ndarray | None) -> np.ndarray:
    """(n-1, 4) per segment: v(t_i + s) = c0 + c1 s + c2 s^2 + c3 s^3. Without velocities the natural
    cubic spline (position, velocity and acceleration continuous); with them the cubic Hermite spline
    through (t, v, vel) (position and velocity continuous and as given, acceleration jumps at samples)."""
    h = np.diff(t)
    slope = np.diff(v) / h
    if vel is None:
        m = _natural_spline_m(t, v)
        c1 = slope - h * (2.0 * m[:-1] + m[1:]) / 6.0
        c2, c3 = 0.5 * m[:-1], (m[1:] - m[:-1]) / (6.0 * h)
    else:
        c1 = vel[:-1]
        c2 = (3.0 * slope - 2.0 * vel[:-1] - vel[1:]) / h
        c3 = (vel[:-1] + vel[1:] - 2.0 * slope) / (h * h)
    return np.column_stack([v[:-1], c1, c2, c3])


def _cubic_range(t: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    """Exact (min, max) of the piecewise cubic over [t0, t_n]: the samples and every interior
    extremum (roots of c1 + 2 c2 s + 3 c3 s^2 inside a segment)."""
    h = np.diff(t)
    ends = np.concatenate([c[:, 0], [float(np.polyval(c[-1, ::-1], h[-1]))]])
    a, b, q = 3.0 * c[:, 3], 2.0 * c[:, 2], c[:, 1]
    disc = b * b - 4.0 * a * q
    ok = disc >= 0.0
    r = np.sqrt(np.where(ok, disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        quad = np.abs(a) > 1e-12 * (np.abs(b) + np.abs(q) + 1e-300)
        roots = [np.where(quad, (-b + r) / (2.0 * a), -q / b), np.where(quad, (-b - r) / (2.0 * a), -q / b)]
    cand = [ends]
    for s in roots:
        inside = ok & np.isfinite(s) & (s > 0.0) & (s < h)
        si = s[inside]
        ci = c[inside]
        cand.append(ci[:, 0] + si * (ci[:, 1] + si * (ci[:, 2] + si * ci[:, 3])))
    allv = np.concatenate(cand)
    return float(allv.min()), float(allv.max())


@dataclass(frozen=True)
class SampledTrajectory:
    """A path through given samples (e.g. from a file): per axis a cubic spline (natural, or Hermite
    where velocities are given), so position and velocity are continuous (acceleration too without
    velocities). Before the first sample the robot holds the first point, after the last the last
    (velocity and acceleration 0 there). Yaw, if given, is splined like a position (unwrapped).

    Attributes:
        t: (n,) strictly increasing times [s] (trajectory time: 0 = when the run / off-board starts).
        x, z: (n,) positions [m].
        source: where the samples came from (for messages and logs).
        y: (n,) lateral positions [m] (None: 0, the sagittal x-z plane).
        yaw: (n,) heading [rad] in the trajectory frame (None: 0, the heading at the start).
        vx, vy, vz: (n,) velocities [m/s] at the samples (None: the natural spline's).
    """

    t: tuple[float, ...]
    x: tuple[float, ...]
    z: tuple[float, ...]
    source: str = "<samples>"
    y: tuple[float, ...] | None = None
    yaw: tuple[float, ...] | None = None
    vx: tuple[float, ...] | None = None
    vy: tuple[float, ...] | None = None
    vz: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f"{self.source}: a trajectory needs at least 2 samples; got {t.size}")
        cols = {k: getattr(self, k) for k in ("x", "z", "y", "yaw", "vx", "vy", "vz") if getattr(self, k) is not None}
        bad = {k: len(v) for k, v in cols.items() if len(v) != t.size}
        if bad:
            raise ValueError(f"{self.source}: every column must have the {t.size} samples of t; got "
                             + ", ".join(f"{k}: {n}" for k, n in bad.items()))
        if not np.all(np.diff(t) > 0):
            raise ValueError(f"{self.source}: t must be strictly increasing")
        arr = {k: np.asarray(v, dtype=float) for k, v in cols.items()}
        if any(not np.all(np.isfinite(v)) for v in arr.values()):
            raise ValueError(f"{self.source}: every value must be a finite number")
        coef = {ax: _cubic_coefficients(t, arr.get(ax, np.zeros(t.size)), arr.get(f"v{ax}")) for ax in AXES}
        coef["yaw"] = _cubic_coefficients(t, np.unwrap(arr.get("yaw", np.zeros(t.size))), None)
        object.__setattr__(self, "_t", t)
        object.__setattr__(self, "_coef", coef)

    def start_point(self) -> tuple[float, float]:
        return float(self.x[0]), float(self.z[0])

    def start_position(self) -> tuple[float, float, float]:
        return float(self.x[0]), float(self.y[0]) if self.y is not None else 0.0, float(self.z[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def time_span(self) -> tuple[float, float]:
        """From the first sample to the last (held before and after)."""
        return float(self.t[0]), float(self.t[-1])

    def extent(self) -> dict[str, tuple[float, float]]:
        """Exact range of each axis (the spline's extremes between samples included)."""
        return {ax: _cubic_range(self._t, self._coef[ax]) for ax in AXES}

    def sample(self, t: np.ndarray | float) -> dict[str, np.ndarray]:
        """x, vx, ax, y, vy, ay, z, vz, az, yaw at time(s) t (arrays shaped like t)."""
        tk = self._t
        tq = np.asarray(t, dtype=float)
        tc = np.clip(tq, tk[0], tk[-1])
        inside = (tq > tk[0]) & (tq < tk[-1])
        i = np.clip(np.searchsorted(tk, tc, side="right") - 1, 0, tk.size - 2)
        s = tc - tk[i]
        out = {}
        for name in (*AXES, "yaw"):
            c = self._coef[name][i]
            c0, c1, c2, c3 = c[..., 0], c[..., 1], c[..., 2], c[..., 3]
            out[name] = c0 + s * (c1 + s * (c2 + s * c3))
            if name != "yaw":
                out[f"v{name}"] = np.where(inside, c1 + s * (2.0 * c2 + 3.0 * s * c3), 0.0)
                out[f"a{name}"] = np.where(inside, 2.0 * c2 + 6.0 * s * c3, 0.0)
        return out
