"""The last gate every applied reference passes, whatever produced it (steer, prefilter, feed-forward,
passthrough, hopping, a fallback, a stall's hand-back), before the controller turns it into a setpoint:

* finite -- a non-finite reference is replaced by the nominal one (hand back), rate-limited;
* rate-limited from where it stood: ``|u[k] - u[k-1]| <= rate + |r_nom[k] - r_nom[k-1]|`` per reference,
  i.e. the correction on top of the model-based controller moves at most ``rate`` per tick while the
  nominal reference itself moves freely. A fallback that would step by the whole steering offset (a
  solver failure, a disengagement, stale telemetry, a guard saturation's hand-back) is blended back at
  that rate instead; a resume's re-anchored nominal is no motion of the path (:meth:`hold_nominal`). ``rate`` is the steering solver's own ``du_max`` (the bound its solutions keep, so a
  steered tick is never altered) or tighter, the profile's ``[envelope] offset_rate``;
* inside the envelope: each reference within [lo, hi] (height range, +-max_tilt).

Collect mode passes ``rate=None`` for its excitation (PRBS steps are the point there); finiteness and the
envelope still apply. numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SetpointGate", "GATE_FLAGS"]

# Bits of the tick log's ``gate`` column: what the gate (and the loop around it) did on that tick.
GATE_FLAGS = {"stall": 1, "rate_limited": 2, "envelope": 4, "nonfinite_reference": 8, "nonfinite_setpoint": 16,
              "guard_clamped": 32, "guard_saturated": 64}


@dataclass
class SetpointGate:
    """Per-tick check of the applied reference (see the module docstring).

    Args:
        lo, hi: (m,) the envelope of each reference [m, rad].
        rate: (m,) largest change per tick of the correction u - r_nom (None: not rate-limited).
    """

    lo: np.ndarray
    hi: np.ndarray
    rate: np.ndarray | None = None
    counts: dict = field(default_factory=lambda: {k: 0 for k in GATE_FLAGS})

    def __post_init__(self) -> None:
        self.lo, self.hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        if self.lo.shape != self.hi.shape or not np.all(self.lo < self.hi):
            raise ValueError(f"the envelope needs lo < hi per reference; got {self.lo.tolist()}, {self.hi.tolist()}")
        if self.rate is not None:
            self.rate = np.asarray(self.rate, float)
            if self.rate.shape != self.lo.shape or not np.all(self.rate > 0):
                raise ValueError(f"rate must be > 0 per reference; got {self.rate.tolist()}")
        self.last_u: np.ndarray | None = None
        self.last_r: np.ndarray | None = None

    def apply(self, u: np.ndarray, r_nom: np.ndarray) -> tuple[np.ndarray, int]:
        """(u to apply (m,), flags): ``u`` proposed by the mode, ``r_nom`` the nominal reference of the
        tick (finite: telemetry with non-finite fields never reaches the controller)."""
        flags = 0
        r = np.asarray(r_nom, dtype=float)
        u = np.asarray(u, dtype=float)
        if not np.all(np.isfinite(r)):
            # Nothing to hand back to: hold where it stood (or the envelope's nearest point at the start).
            flags |= GATE_FLAGS["nonfinite_reference"]
            out = self.last_u.copy() if self.last_u is not None else np.clip(np.nan_to_num(r), self.lo, self.hi)
            return self._done(out, self.last_r if self.last_r is not None else out, flags)
        if not np.all(np.isfinite(u)):
            flags |= GATE_FLAGS["nonfinite_reference"]
            u = np.where(np.isfinite(u), u, r)
        if self.rate is not None and self.last_u is not None:
            room = self.rate + np.abs(r - self.last_r)
            lo, hi = self.last_u - room, self.last_u + room
            if np.any(u < lo - 1e-12) or np.any(u > hi + 1e-12):
                flags |= GATE_FLAGS["rate_limited"]
                u = np.clip(u, lo, hi)
        out = np.clip(u, self.lo, self.hi)
        if np.any(out != u):
            flags |= GATE_FLAGS["envelope"]
        return self._done(out, r, flags)

    def hold_nominal(self, r_nom: np.ndarray) -> None:
        """This tick's nominal reference ``r_nom`` (m,) was re-anchored (a resume's blend starts): its jump is no
        motion of the path, so the applied reference may move only ``rate`` from where it stood this tick."""
        if self.last_u is not None:
            self.last_r = np.array(r_nom, dtype=float)

    def passed(self, r_nom: np.ndarray) -> None:
        """The loop applied the nominal reference ``r_nom`` (m,) itself, past the gate (the proxy's hand-back of a
        fault: the app's own setpoint): the rate bound counts from there."""
        self.last_u, self.last_r = np.array(r_nom, dtype=float), np.array(r_nom, dtype=float)

    def _done(self, out: np.ndarray, r: np.ndarray, flags: int) -> tuple[np.ndarray, int]:
        self.last_u, self.last_r = out.copy(), np.array(r, dtype=float)
        for k, bit in GATE_FLAGS.items():
            if flags & bit:
                self.counts[k] += 1
        return out, flags

    def summary(self) -> dict:
        """Ticks per gate action, and the bounds it enforced."""
        return {**self.counts, "lo": self.lo.tolist(), "hi": self.hi.tolist(),
                "rate_per_tick": None if self.rate is None else self.rate.tolist()}
