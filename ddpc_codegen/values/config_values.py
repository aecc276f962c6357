"""One value of a steering config, checked and normalised: a number, a weight matrix, per-channel bounds,
the knots of the horizon, the rule of the incremental form.
Each bad value is a :class:`~ddpc_codegen.errors.ConfigError` naming the file, the key and the value."""

from __future__ import annotations

from typing import Any

import numpy as np

from ddpc_codegen.values.tomlconfig import config_error as _err

__all__ = ["is_number", "weight_matrix", "channel_bounds", "knot_positions", "incremental_problem"]


def is_number(v: Any) -> bool:
    """A real number as TOML gives it (bool is an int in Python, but `true` is not a weight)."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def weight_matrix(value: Any, n: int, key: str, src: str) -> np.ndarray:
    """Diagonal (n,) or full (n, n) weight -> symmetric PSD (n, n) matrix."""
    a = _numbers(value, n, key, src, "a list of numbers or a matrix")
    if a.ndim == 1:
        if a.shape[0] != n:
            raise _err(src, key, f"must have {n} entries (one per channel) or be a {n}x{n} matrix; got {a.shape[0]} entries {a.tolist()}")
        if np.any(a < 0) or not np.all(np.isfinite(a)):
            raise _err(src, key, f"diagonal entries must be finite and >= 0; got {a.tolist()}")
        return np.diag(a)
    if a.shape != (n, n):
        raise _err(src, key, f"must be {n} entries or a {n}x{n} matrix; got shape {a.shape}")
    if not np.all(np.isfinite(a)) or not np.allclose(a, a.T, atol=1e-12):
        raise _err(src, key, "must be a finite symmetric matrix")
    low = float(np.linalg.eigvalsh(a).min())
    if low < -1e-12 * max(1.0, float(np.abs(a).max())):  # relative: round-off grows with the entries
        raise _err(src, key, f"must be positive semidefinite; smallest eigenvalue {low:.3g}")
    return a


def channel_bounds(value: Any, n: int, key: str, src: str, default: float) -> np.ndarray:
    """A bound per channel (n,): a number for all, or n numbers (inf allowed, NaN not); ``default`` when None."""
    if value is None:
        return np.full(n, default)
    a = _numbers(value, n, key, src, f"a number or a list of {n} numbers")
    if a.shape != (n,):
        raise _err(src, key, f"must have {n} entries (one per channel); got {a.size}: {np.ravel(a).tolist()}")
    if np.any(np.isnan(a)):
        raise _err(src, key, f"must not contain NaN; got {a.tolist()}")
    return a


def _numbers(value: Any, n: int, key: str, src: str, what: str) -> np.ndarray:
    """``value`` as a float array, a single number broadcast to (n,); strings and booleans (anywhere in it) are
    refused: ``<src>: <key> must be <what>; got ...``."""
    try:
        if isinstance(value, (str, bool)) or any(isinstance(x, (str, bool)) for x in np.ravel(np.asarray(value, object))):
            raise TypeError
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise _err(src, key, f"must be {what}; got {value!r}") from None
    return np.full(n, float(a)) if a.ndim == 0 else a


def knot_positions(knots: int | list[int] | tuple[int, ...], t_f: int) -> tuple[int, ...]:
    """Knot sample indices for ``knots`` (a count, or the indices themselves) over a horizon of ``t_f``.

    A count K spaces the knots quadratically, (Tf-1) (i/(K-1))^2 rounded and made strictly increasing:
    short segments where the next moves are decided, long ones where the plan is only a preview.
    Raises ValueError with the reason for a count outside 2..Tf or indices that are not
    0 = k_0 < ... < k_{K-1} = Tf-1.
    """
    if isinstance(knots, (int, np.integer)) and not isinstance(knots, bool):
        k = int(knots)
        if not 2 <= k <= t_f:
            raise ValueError(f"must be between 2 and t_f = {t_f} knots; got {k}")
        raw = np.rint((t_f - 1) * (np.arange(k) / (k - 1)) ** 2).astype(int)
        pos = [0]
        for i in range(1, k):
            # strictly increasing, and leave room for the knots still to come
            pos.append(min(max(pos[-1] + 1, int(raw[i])), t_f - 1 - (k - 1 - i)))
        return tuple(pos)
    if not isinstance(knots, (list, tuple)) or not all(
            isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in knots):
        raise ValueError(f"must be a number of knots or a list of sample indices; got {knots!r}")
    pos = tuple(int(x) for x in knots)
    if len(pos) < 2 or pos[0] != 0 or pos[-1] != t_f - 1 or any(b <= a for a, b in zip(pos, pos[1:])):
        raise ValueError(f"sample indices must increase strictly from 0 to t_f - 1 = {t_f - 1}; got {list(pos)}")
    return pos


def incremental_problem(method: str, t_ini: int) -> str | None:
    """Why ``form = "incremental"`` cannot be fitted with this method and Tini, or None (the one rule
    the config loader and :func:`fit_incremental` both apply)."""
    if method != "lsq":
        return f"needs method = \"lsq\"; got method {method!r} (pem's slack on y_ini has no meaning for increments)"
    if int(t_ini) < 2:
        return f"needs t_ini >= 2 (one increment); got {t_ini}"
    return None
