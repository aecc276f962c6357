"""Helpers of the bounded-input tests: a call that must return within a time (a FIFO opened by mistake
blocks; the test fails instead of hanging), a refusal's one-line message, a FIFO that can be unblocked."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from ddpc_codegen.errors import ConfigError

needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
needs_dev_zero = pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")


def within(seconds: float, fn, *args, unblock=None, **kw):
    """``fn(*args, **kw)`` in a thread that must finish within ``seconds``; returns its result or raises its
    exception. ``unblock`` frees a thread still stuck (the test fails either way)."""
    box: dict = {}

    def run():
        try:
            box["value"] = fn(*args, **kw)
        except BaseException as e:  # handed to the test
            box["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    if t.is_alive():
        if unblock:
            unblock()
        pytest.fail(f"{getattr(fn, '__name__', fn)} still blocked after {seconds} s")
    if "error" in box:
        raise box["error"]
    return box["value"]


def refusal(fn, *args, error: type[Exception] = ConfigError, **kw) -> str:
    """The message of ``fn(*args, **kw)``'s refusal (``error``), checked to be one line."""
    with pytest.raises(error) as e:
        fn(*args, **kw)
    msg = str(e.value)
    assert "\n" not in msg, msg
    return msg


def bounded_refusal(fn, *args, error: type[Exception] = ConfigError, unblock=None, seconds: float = 10.0,
                    **kw) -> str:
    """:func:`refusal` within ``seconds``."""
    return within(seconds, refusal, fn, *args, error=error, unblock=unblock, **kw)


def make_fifo(path: Path):
    """A FIFO at ``path``, and the function that frees a reader blocked opening it."""
    os.mkfifo(path)

    def unblock():  # a reader blocked in open() returns once a writer opens
        try:
            os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:
            pass

    return path, unblock
