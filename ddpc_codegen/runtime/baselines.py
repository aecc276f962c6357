"""Baseline reference policies behind the steering policy's per-tick interface.

Each has ``decide(y, r_nom, y_des) -> SteerOutcome`` like :class:`~ddpc_codegen.runtime.policy.SteeringPolicy`
(y (p,) measured outputs, r_nom (m,) the nominal reference of this tick, y_des (H, p) the desired
outputs at ticks k..k+H-1), plus ``reset()``, ``observe()`` and ``horizon`` (the H it needs), so any
loop that runs the steering (the simulator hook, the MAVLink bridge) can run them instead:

* :class:`PassthroughPolicy`: u = r_nom (the model-based controller alone).
* :class:`PrefilterPolicy`: u = r_nom + (y_des[k + d] - c) / g - y_des[k] per channel (a
  :class:`~ddpc_codegen.design.baselines.PrefilterModel` fitted offline); needs H = max lead + 1.
* :class:`FeedforwardPolicy`: u = r_nom + delta[j], a learned table (the ILC's last iteration),
  j = ticks since :meth:`~FeedforwardPolicy.reset` (trajectory time, or time since liftoff when the
  loop resets it at every liftoff), or set by :meth:`~FeedforwardPolicy.seek` from the loop's own
  trajectory clock (the bridge); beyond the table the last row is held.

numpy only: no CasADi, no simulator.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ddpc_codegen.design.baselines import PrefilterModel
from ddpc_codegen.errors import ConfigError
from ddpc_codegen.runtime.steerer import SteerOutcome

__all__ = ["PassthroughPolicy", "PrefilterPolicy", "FeedforwardPolicy"]


@dataclass
class PassthroughPolicy:
    """u = r_nom: the unsteered controller behind the policy interface."""

    horizon: int = 1
    counts: dict = field(default_factory=dict)

    def reset(self) -> None:
        """Nothing to forget."""

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """A tick the policy did not decide (nothing to record)."""

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        self.counts["ticks"] = self.counts.get("ticks", 0) + 1
        return SteerOutcome(np.array(r_nom, dtype=float, copy=True), False, "passthrough")

    def summary(self) -> dict:
        return dict(self.counts)


@dataclass
class PrefilterPolicy:
    """Static gain + offset + lead inverse of the closed loop (see :class:`PrefilterModel`).

    Args:
        model: the fitted prefilter.
        u_min, u_max: (m,) limits on the applied reference (clipped; counted in ``counts``).
    """

    model: PrefilterModel
    u_min: np.ndarray | None = None
    u_max: np.ndarray | None = None
    counts: dict = field(default_factory=dict)

    @property
    def horizon(self) -> int:
        """Desired outputs needed ahead: ticks k..k+max(lead)."""
        return int(max(self.model.lead)) + 1

    @classmethod
    def load(cls, path: str | Path, **kw) -> "PrefilterPolicy":
        """From a prefilter JSON file (:meth:`PrefilterModel.save`)."""
        return cls(PrefilterModel.load(path), **kw)

    def reset(self) -> None:
        """Memoryless: nothing to forget."""

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """Memoryless: nothing to record."""

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        u = self.model.inverse(y_des, r_nom)
        reason = "prefilter"
        if self.u_min is not None or self.u_max is not None:
            lo = -np.inf if self.u_min is None else self.u_min
            hi = np.inf if self.u_max is None else self.u_max
            clipped = np.clip(u, lo, hi)
            if np.any(clipped != u):
                reason = "prefilter_clipped"
                u = clipped
        self.counts[reason] = self.counts.get(reason, 0) + 1
        return SteerOutcome(u, True, reason)

    def summary(self) -> dict:
        return dict(self.counts)


@dataclass
class FeedforwardPolicy:
    """A learned feed-forward table on top of the nominal reference (the ILC's output).

    Args:
        delta: (N, m) offsets added to r_nom at ticks 0..N-1 after :meth:`reset` [input units].
        dt: tick [s] (for the record; the table is indexed by ticks).
        clock: "trajectory" (index = ticks since the run started) or "liftoff" (the loop calls
            :meth:`reset` at every liftoff; index = ticks in the air).
    """

    delta: np.ndarray
    dt: float = 0.005
    clock: str = "trajectory"
    counts: dict = field(default_factory=dict)
    horizon: int = 1  # needs only this tick's desired output

    def __post_init__(self) -> None:
        self.delta = np.atleast_2d(np.asarray(self.delta, dtype=float))
        if self.delta.shape[0] == 0 or not np.all(np.isfinite(self.delta)):
            raise ConfigError(f"a feed-forward table needs finite (N >= 1, m) values; got shape {self.delta.shape}")
        if self.clock not in ("trajectory", "liftoff"):
            raise ConfigError(f"clock must be 'trajectory' or 'liftoff'; got {self.clock!r}")
        self._k = 0

    def reset(self) -> None:
        """Restart the table's clock (start of a run, or a liftoff)."""
        self._k = 0

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """A tick the policy did not decide: the clock still advances."""
        self._k += 1

    def seek(self, j: int) -> None:
        """The next :meth:`decide` applies row j (a loop with its own clock: the trajectory tick,
        which a stall or a re-engagement does not restart)."""
        if j < 0:
            raise ValueError(f"a feed-forward table row must be >= 0; got {j}")
        self._k = int(j)

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        j = min(self._k, self.delta.shape[0] - 1)
        if self._k >= self.delta.shape[0]:
            self.counts["beyond_table"] = self.counts.get("beyond_table", 0) + 1
        self._k += 1
        self.counts["ticks"] = self.counts.get("ticks", 0) + 1
        return SteerOutcome(np.asarray(r_nom, dtype=float) + self.delta[j], True, "feedforward")

    def save(self, path: str | Path) -> Path:
        """npz with delta, dt and clock (what :meth:`load` reads)."""
        path = Path(path)
        np.savez(path, delta=self.delta, dt=self.dt, clock=self.clock)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "FeedforwardPolicy":
        try:
            with np.load(path) as z:
                return cls(z["delta"], float(z["dt"]), str(z["clock"]))
        except (OSError, KeyError, ValueError) as e:
            raise ConfigError(f"{path}: not a feed-forward table ({type(e).__name__}: {e})") from None

    def summary(self) -> dict:
        return dict(self.counts)
