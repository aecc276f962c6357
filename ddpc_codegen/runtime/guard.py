"""One generated solver instance per thread: the guard its calls take.

A :class:`Guard` is a non-blocking mutex: a call that would share a C workspace with another thread is refused
(:class:`SolverBusyError`), never waited for nor let through. It is one token in a list: ``list.pop()`` and
``list.append()`` are atomic (one C call under the GIL; per-object locked in free-threaded builds), and cost less
in the tick than a ``threading.Lock`` try-acquire and release.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from ddpc_codegen.errors import SolverError

__all__ = ["SolverBusyError", "Guard", "busy", "workspace_guard"]

_MODULE_GUARDS: dict[str, Guard] = {}  # osqp: the guard of every instance of one extension (static OSQP)


class SolverBusyError(SolverError):
    """A generated solver instance was called while another thread was inside a call on it (one instance per
    thread: load the folder again for another thread)."""


def busy(name: str, what: str) -> SolverBusyError:
    """The refusal of a call (``what``) on an instance of solver ``name`` that another thread is using."""
    return SolverBusyError(f"solver {name!r}: {what} called while another thread is inside a call on this "
                           "instance; a generated solver is one instance per thread (load_solver again for "
                           "another thread)")


class Guard:
    """A non-blocking mutex of solver ``name``: ``take()`` (IndexError when held: see :meth:`held`), then
    ``give(None)``; the tick path calls the two bound methods directly."""

    __slots__ = ("name", "take", "give", "_token")

    def __init__(self, name: str) -> None:
        self.name = name
        self._token: list[None] = [None]
        self.take, self.give = self._token.pop, self._token.append

    @property
    def in_use(self) -> bool:
        """Held by some thread now."""
        return not self._token

    @contextlib.contextmanager
    def held(self, what: str) -> Iterator[None]:
        """Hold the guard for the block, or raise :class:`SolverBusyError` naming ``what`` (never wait)."""
        try:
            self.take()
        except IndexError:
            raise busy(self.name, what) from None
        try:
            yield
        finally:
            self.give(None)


def workspace_guard(module, backend: str, name: str) -> Guard:
    """The guard of one instance's C workspace: its own, or for osqp (a static OSQP workspace in the extension
    ``module``) the one every instance of that module shares."""
    if backend != "osqp":
        return Guard(name)
    return _MODULE_GUARDS.setdefault(f"{module.__name__}:{getattr(module, '__file__', '')}", Guard(name))
