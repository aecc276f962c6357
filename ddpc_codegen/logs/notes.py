"""How an import reports what it dropped: warnings kept for provenance, log times in seconds."""

from __future__ import annotations

import warnings

__all__ = ["LogImportWarning", "Notes", "fmt_t"]


class LogImportWarning(UserWarning):
    """Something was dropped or is of doubtful quality while importing a log (the data was
    not changed to hide it: the message says what was dropped and where)."""


class Notes:
    """Collects import warnings: each is issued with :func:`warnings.warn` and kept for the
    dataset's provenance (``metadata['warnings']``)."""

    def __init__(self) -> None:
        self.items: list[str] = []

    def warn(self, msg: str) -> None:
        self.items.append(msg)
        warnings.warn(msg, LogImportWarning, stacklevel=3)


def fmt_t(t_us: int | float, origin_us: int) -> str:
    """A log time as seconds since the log's origin, the way errors quote time ranges."""
    return f"{(float(t_us) - origin_us) / 1e6:.3f} s"
