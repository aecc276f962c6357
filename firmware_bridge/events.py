"""The bridge's event list: what happened when (seconds since the bridge started), printed as it happens
with ``verbose``. One instance is shared by the parts of the companion loop (:mod:`.bridge`)."""

from __future__ import annotations

import sys
import time

__all__ = ["EventLog"]


class EventLog:
    """Timestamped events of one bridge.

    Args:
        t0: the bridge's start on the monotonic clock [s]; times are relative to it.
        verbose: also print each event to stderr.
        name: the prefix of printed lines.
    """

    def __init__(self, t0: float | None = None, verbose: bool = False, name: str = "bridge") -> None:
        self.t0 = time.monotonic() if t0 is None else t0
        self.verbose = verbose
        self.name = name
        self.events: list[tuple[float, str]] = []

    def __call__(self, what: str) -> None:
        """Record ``what`` now."""
        t = time.monotonic() - self.t0
        self.events.append((round(t, 4), what))
        if self.verbose:
            print(f"[{self.name} {t:8.3f}] {what}", file=sys.stderr, flush=True)

    def restart(self) -> None:
        """Count times from now (the owner's set-up is done)."""
        self.t0 = time.monotonic()

    def since_start(self, now: float) -> float:
        """``now`` [s, monotonic] as seconds since the start."""
        return now - self.t0
