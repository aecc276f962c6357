"""Online adaptation in the loop: which ticks update the predictor, when it is re-solved and swapped,
the optional dither, and the record of every update and rejection (issue 30).

One implementation for every loop (the simulator's hook, the MAVLink bridge): :class:`OnlineAdaptation`
sits behind :class:`~ddpc_codegen.runtime.policy.SteeringPolicy` and drives any solver with the adaptation
API (``adapt_push(u, y)``, ``adapt_refused()``, ``adapt_clear()``, ``adapt_resolve()``, ``adapt_swap()``, ``adapt_counts()``): a
generated solver built with ``[adapt] enabled`` or the interpreted
:class:`~ddpc_codegen.design.adaptation.AdaptiveProblem`.

Guards for closed-loop data: only steered ticks (engaged, fresh, not a fallback) update; any other tick
breaks the window (the next column needs depth steered ticks in a row). Every ``period_ticks`` updates G
is re-solved, verified and, if accepted, swapped in before the next tick; with ``[adapt] offset`` the output
offset every re-solve estimates (whatever the verdict on G) is swapped in too once it passed its own check.

``background=True`` (the bridge): a re-solve takes far longer than a tick at flight sizes, so
the tick only queues columns and takes the snapshot (``adapt_snapshot()``; the generated C folds the queued
columns into R in the re-solve) and a worker thread runs ``adapt_resolve(False)``
(C: cffi releases the GIL for the call) while later ticks keep pushing and solving. The first update tick
after it returned swaps (a verdict lands only on an update tick, as in the synchronous schedule: after a
reset, once the window has refilled). One re-solve at a time: a period that comes while one runs is counted
(``busy``), not queued. :meth:`OnlineAdaptation.close` (called by :meth:`~OnlineAdaptation.summary`) joins a
running re-solve and discards its result (counted, never swapped).
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.values.adapt import REJECTIONS

__all__ = ["OnlineAdaptation", "AdaptEvent", "ADAPT_CODES", "VERDICT_CODES", "UPDATE_CODES", "adapt_code", "SNAP_TAKEN",
           "SNAP_BUSY"]

# What a tick did about the background re-solve (the tick log's ``adapt_snap``): 0 nothing, 1 a snapshot was
# taken and handed to the worker, 2 a re-solve period came while one still ran (counted, skipped).
SNAP_TAKEN, SNAP_BUSY = 1, 2

# What a tick did, as the bridge's tick log stores it: 0 nothing (no update: not steered, or no adaptation),
# then the window filling, a column taken in, a re-solve swapped in, each rejection of a re-solve, and a full
# window whose column the solver refused (a NaN/inf: ``skipped``; its queue full: ``dropped``). Appended only:
# the codes of older tick logs keep their meaning.
ADAPT_CODES = ("", "warmup", "update", "accepted") + REJECTIONS + ("refused",)
# The codes of a tick that took a column in ("update" or a re-solve's verdict) and of a verdict alone.
VERDICT_CODES = tuple(ADAPT_CODES.index(k) for k in ("accepted",) + REJECTIONS)
UPDATE_CODES = (ADAPT_CODES.index("update"),) + VERDICT_CODES


def adapt_code(last: str) -> int:
    """The tick-log code of :attr:`OnlineAdaptation.last` ("skip" and "" are 0)."""
    return ADAPT_CODES.index(last) if last in ADAPT_CODES else 0


@dataclass(frozen=True)
class AdaptEvent:
    """One re-solve: the tick its verdict landed (and the swap was made; -1: discarded by
    :meth:`OnlineAdaptation.close`), its verdict ("accepted" or the rejection reason), whether G was swapped in,
    the norm of the output offset in use after it (data units; 0 without ``[adapt] offset``), the tick of the
    snapshot it read (the same tick when synchronous), in the background its wall time in the worker [ms], and
    for a verdict of the error check ("accepted", "prediction") the candidate's prediction error on the recent
    window over the current G's (``[adapt] min_improvement`` asks it to be below 1 - min_improvement), and
    whether a new output offset was swapped in. Ticks count :meth:`OnlineAdaptation.tick` calls from 0."""

    tick: int
    verdict: str
    swapped: bool
    offset_norm: float = 0.0
    snapshot_tick: int = -1
    resolve_ms: float = math.nan
    error_ratio: float = math.nan
    offset_swapped: bool = False


@dataclass
class OnlineAdaptation:
    """Per-tick driver of a solver's online update.

    Args:
        solver: a solver with the adaptation API.
        period_ticks: updates between re-solves (default: the solver's ``[adapt] period_ticks``).
        dither: amplitude of a +-dither added to steered references while adapting (their units, (m,) or a
            scalar; default: the solver's ``[adapt] dither``); 0 = none. Seeded, so runs repeat.
        background: re-solve in a worker thread from a snapshot taken in the tick (see the module docstring);
            False: snapshot, re-solve and swap within the tick (deterministic: the simulator, the tests).
    """

    solver: object
    period_ticks: int | None = None
    dither: float | np.ndarray | None = None
    seed: int = 0
    events: list = field(default_factory=list)
    background: bool = False

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
        self._refused = 0  # the solver's dropped + skipped columns as of the last refusal seen
        self._tick = 0
        self.last: str = ""  # what the last tick did: "update", "warmup", "skip", or a re-solve verdict
        self.offset_norm = 0.0  # norm of the output offset in use (data units), read back after each swap
        self.last_snap = 0  # this tick and the background re-solve: 0, SNAP_TAKEN or SNAP_BUSY
        self.busy = 0  # re-solve periods skipped because one still ran
        self.discarded = 0  # re-solves joined and dropped by close()
        self._pool: ThreadPoolExecutor | None = None
        self._running: tuple[Future, int] | None = None  # the re-solve in the worker and its snapshot tick
        if self.background:  # start the worker now, off the tick path (a thread start in a tick costs ~3 ms)
            self._worker().submit(int).result()

    def _worker(self) -> ThreadPoolExecutor:
        """The one worker thread (started on first use; created before the bridge turns real-time, it keeps the
        default policy and affinity)."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, "adapt-resolve", initializer=_not_realtime)
        return self._pool

    def perturb(self, u: np.ndarray, steered: bool) -> np.ndarray:
        """u plus the dither on a steered tick (bounded by ``dither`` per channel), else u itself."""
        if not steered or not np.any(self.dither > 0):
            return u
        return u + self.dither * self._rng.choice((-1.0, 1.0), size=np.shape(u))

    def tick(self, u: np.ndarray, y: np.ndarray, steered: bool) -> str:
        """The applied reference u (m,) and measured output y (p,) of this tick; ``steered``: the tick may
        update. Returns what happened: "update", "warmup" (window filling), "refused" (the solver did not take
        the column), "skip" (not an update tick), or the verdict of a re-solve ("accepted" and swapped, or the rejection reason)."""
        self._tick += 1
        self.last_snap = 0
        if not steered:
            self.solver.adapt_clear()
            self.last = "skip"
            return self.last
        if not self.solver.adapt_push(u, y):  # the window filling, or a full one's column refused (counted)
            refused = self.solver.adapt_refused()  # push's own counters: not the running re-solve's
            self.last = "refused" if refused > self._refused else "warmup"
            self._refused = refused
            return self.last
        self._since += 1
        self.last = "update"
        if self._running is not None and self._running[0].done():  # landed: swap before this tick's snapshot
            fut, snap = self._running
            self._running = None
            self._land(*fut.result(), snap)
        if self._since >= self.period_ticks:
            self._since = 0
            if not self.background:
                self._land(self.solver.adapt_resolve(), math.nan, self._tick - 1)
            elif self._running is not None:
                self.busy += 1
                self.last_snap = SNAP_BUSY
            else:
                self.solver.adapt_snapshot()
                self._running = (self._worker().submit(_timed_resolve, self.solver), self._tick - 1)
                self.last_snap = SNAP_TAKEN
        return self.last

    def _land(self, verdict: str, ms: float, snapshot_tick: int) -> None:
        """A re-solve's verdict on this tick: swap (always: a refused G may still come with a verified offset)."""
        done = self.solver.adapt_swap()
        counts = self.solver.adapt_counts()
        self.offset_norm = float(counts.get("offset_norm", 0.0))
        self.events.append(AdaptEvent(self._tick - 1, verdict, done.g, self.offset_norm, snapshot_tick, ms,
                                      _error_ratio(verdict, counts), done.offset))
        self.last = verdict

    def close(self) -> None:
        """Join a running re-solve and drop its result (recorded as an event with tick -1, never swapped: no
        tick follows to swap it in) and stop the worker. Idempotent; a later re-solve starts a new worker."""
        if self._running is not None:
            fut, snap = self._running
            self._running = None
            self.discarded += 1
            verdict, ms = fut.result()
            self.events.append(AdaptEvent(-1, verdict, False, self.offset_norm, snap, ms,
                                          _error_ratio(verdict, self.solver.adapt_counts())))
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def summary(self) -> dict:
        """The solver's counters and the re-solves (tick of the verdict / swap, verdict, G swapped, offset norm
        after it, tick of the snapshot, re-solve wall time [ms], error ratio, offset swapped); joins a running
        re-solve first (:meth:`close`)."""
        self.close()
        return {"counts": dict(self.solver.adapt_counts()), "period_ticks": self.period_ticks,
                "dither": self.dither.tolist(), "background": self.background, "busy": self.busy,
                "discarded": self.discarded,
                "events": [[e.tick, e.verdict, e.swapped, e.offset_norm, e.snapshot_tick, e.resolve_ms, e.error_ratio,
                            e.offset_swapped] for e in self.events]}


def _error_ratio(verdict: str, counts: dict) -> float:
    """The candidate's over the current G's recent prediction error when the verdict came from that check."""
    cur = float(counts.get("error_current", math.nan))
    if verdict not in ("accepted", "prediction") or not cur > 0:
        return math.nan
    return float(counts.get("error_candidate", math.nan)) / cur


def _timed_resolve(solver) -> tuple[str, float]:
    """(verdict, wall time [ms]) of a re-solve from the last snapshot (in the worker thread)."""
    t0 = time.perf_counter()
    verdict = solver.adapt_resolve(False)
    return verdict, (time.perf_counter() - t0) * 1e3


def _not_realtime() -> None:
    """The worker thread leaves a real-time policy it inherited (``--rt-priority``: SCHED_FIFO never time-slices,
    so a re-solve on the tick's CPU would hold the tick off until it ends)."""
    if hasattr(os, "sched_getscheduler") and os.sched_getscheduler(0) != os.SCHED_OTHER:
        try:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except OSError:
            pass  # stays real-time: the tick may then wait for the re-solve (visible in the loop gaps)

