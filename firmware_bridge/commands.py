"""COMMAND_LONG with retries over a link: one command per id in flight (COMMAND_ACK names only the id),
resent until acknowledged or out of tries."""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["CommandTracker", "PendingCommand"]


@dataclass
class PendingCommand:
    """A COMMAND_LONG waiting for its COMMAND_ACK."""

    command: int
    params: tuple[float, ...]
    label: str
    tries: int = 0
    sent_at: float = -math.inf
    result: int | None = None  # MAV_RESULT once acked
    done: bool = False
    timed_out: bool = False
    on_done: Callable[["PendingCommand"], None] | None = field(default=None, repr=False)

    @property
    def accepted(self) -> bool:
        return self.result == mavlink.MAV_RESULT_ACCEPTED


class CommandTracker:
    """Sends COMMAND_LONGs with retries. COMMAND_ACK names only the command id, so commands with
    the same id are sent one at a time (queued); different ids run in parallel.

    Args:
        link: the :class:`.link.MavLink` (its ``command_long``) the commands go out on.
        timeout: seconds to wait for an ACK before resending (confirmation + 1).
        max_tries: give up (``timed_out``) after this many sends.
    """

    def __init__(self, link, timeout: float = 0.5, max_tries: int = 4) -> None:
        self.link, self.timeout, self.max_tries = link, timeout, max_tries
        self.queues: dict[int, deque[PendingCommand]] = {}
        self.history: list[PendingCommand] = []

    def submit(self, command: int, params: tuple[float, ...], label: str = "",
               on_done: Callable[[PendingCommand], None] | None = None) -> PendingCommand:
        pc = PendingCommand(command, tuple(params), label or str(command), on_done=on_done)
        self.queues.setdefault(command, deque()).append(pc)
        return pc

    def busy(self) -> bool:
        return any(self.queues.values())

    def on_ack(self, msg) -> PendingCommand | None:
        q = self.queues.get(msg.command)
        if not q:
            return None
        if msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
            q[0].sent_at = time.monotonic()  # still working on it: do not resend yet
            return None
        pc = q.popleft()
        pc.result, pc.done = int(msg.result), True
        self.history.append(pc)
        if pc.on_done:
            pc.on_done(pc)
        return pc

    def poll(self, now: float) -> None:
        for q in self.queues.values():
            if not q:
                continue
            pc = q[0]
            if now - pc.sent_at < self.timeout:
                continue
            if pc.tries >= self.max_tries:
                q.popleft()
                pc.done, pc.timed_out = True, True
                self.history.append(pc)
                if pc.on_done:
                    pc.on_done(pc)
                continue
            if self.link.command_long(pc.command, pc.params, confirmation=pc.tries):
                pc.tries += 1
                pc.sent_at = now
            else:
                pc.sent_at = now  # link down or no peer yet: try again after the timeout
