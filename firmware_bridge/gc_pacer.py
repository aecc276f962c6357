"""Python's cyclic garbage collector kept off a real-time loop's critical path (the bridge's tick, the proxy's
receive-to-send).

Left automatic, the collector runs whenever allocations cross its thresholds: in the middle of a tick, between a
setpoint's arrival and its send. A young-generation pass takes a fraction of a millisecond, an older one several.
:class:`GcPacer` collects once and freezes what the set-up made (never scanned again), turns the automatic passes
off, and runs the young generation's pass itself once a second right after the loop sent what was due (the middle
generation's every ``middle_every`` passes), so a pass lands in the idle part of a period. Objects made in the loop
that only a cycle frees wait for those passes; nothing is freed later than a second plus that.
"""

from __future__ import annotations

import gc
import time

__all__ = ["GcPacer"]


class GcPacer:
    """Collect when the loop says it is idle (see the module docstring).

    Args:
        every: the young generation's pass at most this often [s].
        middle_every: every this many passes, the middle generation's too.
    """

    def __init__(self, every: float = 1.0, middle_every: int = 30) -> None:
        self.every, self.middle_every = float(every), int(middle_every)
        self._was_enabled = gc.isenabled()
        self._last = -float("inf")
        self.passes = 0
        self.running = False

    def start(self) -> None:
        """Before the loop: one full pass, the survivors frozen, the automatic passes off."""
        self._was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()
        self._last = time.monotonic()
        self.running = True

    def idle(self, now: float) -> None:
        """The loop has just sent what was due (``now`` [s], monotonic): a pass when one is due."""
        if self.running and now - self._last > self.every:
            self.passes += 1
            gc.collect(1 if self.passes % self.middle_every == 0 else 0)
            self._last = now

    def stop(self) -> None:
        """After the loop: the collector as it was (the frozen objects scanned again)."""
        if not self.running:
            return
        self.running = False
        if self._was_enabled:
            gc.enable()
        gc.unfreeze()
