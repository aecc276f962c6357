"""How many examples the file-fuzzing property tests draw: their default in ``make test``, or
``DDPC_FUZZ_EXAMPLES`` (``make fuzz`` sets 10 000 per file kind)."""

from __future__ import annotations

import os


def fuzz_examples(default: int) -> int:
    """``DDPC_FUZZ_EXAMPLES`` if set (a positive integer), else ``default``."""
    raw = os.environ.get("DDPC_FUZZ_EXAMPLES")
    if raw is None:
        return default
    n = int(raw)
    if n < 1:
        raise ValueError(f"DDPC_FUZZ_EXAMPLES must be a positive integer; got {raw!r}")
    return n
