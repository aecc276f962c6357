"""One artificial-IO completion: the window it is given (checked alike for the interpreted and the
generated operator) and what it returns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ddpc_codegen.errors import DataError

__all__ = ["Completion", "check_window"]


@dataclass
class Completion:
    """Result of one artificial-IO completion.

    u (L, m), y (L, p): the window with the missing samples filled in.
    residual: max |H g - b| over the known samples (0 up to round-off for exact data).
    g_norm: ||g|| of the (least-norm) Hankel combination.
    bounded: True when a bound was active and the bounded QP was solved.
    status: "solved", or the QP's failure status (then the unbounded fill is returned, clipped).
    """

    u: np.ndarray
    y: np.ndarray
    residual: float
    g_norm: float
    bounded: bool = False
    status: str = "solved"


def check_window(u: np.ndarray, y: np.ndarray, missing: np.ndarray, m: int, p: int, depth: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A completion window as arrays: u (L, m), y (L, p) and the mask (L, m+p) of missing entries
    (``missing`` per sample (L,) or per entry); DataError when the shapes disagree, L is outside
    1..depth or a known entry is NaN / inf. One check for the interpreted and the generated operator."""
    u = np.asarray(u, float).reshape(-1, m)
    y = np.asarray(y, float).reshape(-1, p)
    L = u.shape[0]
    if y.shape[0] != L:
        raise DataError(f"u has {L} samples but y has {y.shape[0]}")
    if not 1 <= L <= depth:
        raise DataError(f"window of {L} samples: the artificial-IO depth is {depth} (1..{depth} allowed)")
    mask = np.asarray(missing, dtype=bool)
    if mask.ndim == 1:
        mask = np.repeat(mask[:, None], m + p, axis=1)
    if mask.shape != (L, m + p):
        raise DataError(f"missing must be ({L},) or ({L}, {m + p}); got {mask.shape}")
    if not np.all(np.isfinite(np.hstack([u, y])[~mask])):
        raise DataError("the known samples of the window contain NaN or inf")
    return u, y, mask
