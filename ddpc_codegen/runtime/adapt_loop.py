"""Online adaptation in the loop: which ticks update the predictor, when it is re-solved and swapped,
the optional dither, and the record of every update and rejection (issue 30).

One implementation for every loop (the simulator's hook, the MAVLink bridge): :class:`OnlineAdaptation`
sits behind :class:`~ddpc_codegen.runtime.policy.SteeringPolicy` and drives any solver with the adaptation
API (``adapt_push(u, y)``, ``adapt_clear()``, ``adapt_resolve()``, ``adapt_swap()``, ``adapt_counts()``): a
generated solver built with ``[adapt] enabled`` or the interpreted
:class:`~ddpc_codegen.design.adaptation.AdaptiveProblem`.

Guards for closed-loop data: only steered ticks (engaged, fresh, not a fallback) update; any other tick
breaks the window (the next column needs depth steered ticks in a row). Every ``period_ticks`` updates G
is re-solved, verified and, if accepted, swapped in before the next tick; with ``[adapt] offset`` the output
offset staged by every re-solve (accepted or not) is swapped in too.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.runtime.adaptation import REJECTIONS

__all__ = ["OnlineAdaptation", "AdaptEvent", "ADAPT_CODES", "adapt_code"]

# What a tick did, as the bridge's tick log stores it: 0 nothing (no update: not steered, or no adaptation),
# then the window filling, a column folded in, a re-solve swapped in, and each rejection of a re-solve.
ADAPT_CODES = ("", "warmup", "update", "accepted") + REJECTIONS


def adapt_code(last: str) -> int:
    """The tick-log code of :attr:`OnlineAdaptation.last` ("skip" and "" are 0)."""
    return ADAPT_CODES.index(last) if last in ADAPT_CODES else 0


@dataclass(frozen=True)
class AdaptEvent:
    """One re-solve: the tick, its verdict ("accepted" or the rejection reason), whether G was swapped in, and
    the norm of the output offset in use after it (data units; 0 without ``[adapt] offset``)."""

    tick: int
    verdict: str
    swapped: bool
    offset_norm: float = 0.0


@dataclass
class OnlineAdaptation:
    """Per-tick driver of a solver's online update.

    Args:
        solver: a solver with the adaptation API.
        period_ticks: updates between re-solves (default: the solver's ``[adapt] period_ticks``).
        dither: amplitude of a +-dither added to steered references while adapting (their units, (m,) or a
            scalar; default: the solver's ``[adapt] dither``); 0 = none. Seeded, so runs repeat.
    """

    solver: object
    period_ticks: int | None = None
    dither: float | np.ndarray | None = None
    seed: int = 0
    events: list = field(default_factory=list)

    def __post_init__(self) -> None:
        st = self.solver.adapt_settings
        self.period_ticks = int(st.period_ticks if self.period_ticks is None else self.period_ticks)
        if self.period_ticks < 1:
            raise ValueError(f"period_ticks must be >= 1; got {self.period_ticks}")
        d = np.asarray(st.dither if self.dither is None else self.dither, dtype=float)
        if not np.all(np.isfinite(d)) or np.any(d < 0):
            raise ValueError(f"dither must be finite and >= 0; got {d.tolist()}")
        self.dither = d
        self._rng = np.random.default_rng(self.seed)
        self._since = 0  # updates since the last re-solve
        self._tick = 0
        self.last: str = ""  # what the last tick did: "update", "warmup", "skip", or a re-solve verdict
        self.offset_norm = 0.0  # norm of the output offset in use (data units), read back after each swap

    def perturb(self, u: np.ndarray, steered: bool) -> np.ndarray:
        """u plus the dither on a steered tick (bounded by ``dither`` per channel), else u itself."""
        if not steered or not np.any(self.dither > 0):
            return u
        return u + self.dither * self._rng.choice((-1.0, 1.0), size=np.shape(u))

    def tick(self, u: np.ndarray, y: np.ndarray, steered: bool) -> str:
        """The applied reference u (m,) and measured output y (p,) of this tick; ``steered``: the tick may
        update. Returns what happened: "update", "warmup" (window filling), "skip" (not an update tick), or
        the verdict of a re-solve ("accepted" and swapped, or the rejection reason)."""
        self._tick += 1
        if not steered:
            self.solver.adapt_clear()
            self.last = "skip"
            return self.last
        if not self.solver.adapt_push(u, y):
            self.last = "warmup"
            return self.last
        self._since += 1
        self.last = "update"
        if self._since >= self.period_ticks:
            self._since = 0
            verdict = self.solver.adapt_resolve()
            swapped = bool(self.solver.adapt_swap())  # always: a refused G may still come with a new offset
            self.offset_norm = float(self.solver.adapt_counts().get("offset_norm", 0.0))
            self.events.append(AdaptEvent(self._tick - 1, verdict, swapped, self.offset_norm))
            self.last = verdict
        return self.last

    def summary(self) -> dict:
        """The solver's counters and the re-solves (tick, verdict, G swapped, offset norm after it)."""
        return {"counts": dict(self.solver.adapt_counts()), "period_ticks": self.period_ticks,
                "dither": self.dither.tolist(),
                "events": [[e.tick, e.verdict, e.swapped, e.offset_norm] for e in self.events]}

