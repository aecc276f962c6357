"""The one validation layer for the values the robot side flies on (robot profiles, prefilter models,
feed-forward tables, the bridge's command-line values): every number checked for type, finiteness and
range with a message that names the file and the key. Every refusal is a
:class:`~ddpc_codegen.errors.ConfigError`. The files themselves are read by :mod:`ddpc_codegen.values.files`
(sizes and nesting bounded).

numpy only: the companion computer's bridge imports it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ddpc_codegen.errors import ConfigError

__all__ = ["Range", "check_number", "check_numbers", "check_table"]


@dataclasses.dataclass(frozen=True)
class Range:
    """What one key may hold: a number in [lo, hi] (``lo_open``: lo excluded, ``hi_open``: hi excluded),
    an integer (``integer``), ``n`` numbers (``n`` > 0), None (``optional``) or a string (``text``, at
    most ``max_len`` characters)."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    n: int = 0
    optional: bool = False
    text: bool = False
    max_len: int = 64

    def describe(self) -> str:
        lo = "(" if self.lo_open else "["
        hi = ")" if self.hi_open else "]"
        kind = "an integer" if self.integer else "a finite number"
        return f"{kind} in {lo}{self.lo:g}, {self.hi:g}{hi}"


def _is_real(v: Any) -> bool:
    return not isinstance(v, (bool, np.bool_)) and isinstance(v, (int, float, np.integer, np.floating))


def check_number(value: Any, where: str, r: Range = Range()) -> float | int:
    """One value against ``r``; returns it as float (int when ``r.integer``). ``where`` names the file
    and the key ("p.toml: [controller] kp_z")."""
    bad = ConfigError(f"{where} must be {r.describe()}; got {value!r}")
    try:
        finite = _is_real(value) and math.isfinite(float(value))
    except OverflowError:  # an integer beyond float range (a 401-digit gain)
        finite = False
    if not finite:
        raise bad
    if r.integer and float(value) != int(value):
        raise bad
    v = float(value)
    if v < r.lo or v > r.hi or (r.lo_open and v == r.lo) or (r.hi_open and v == r.hi):
        raise bad
    return int(value) if r.integer else v


def check_numbers(value: Any, where: str, r: Range) -> tuple:
    """``r.n`` numbers (a list or tuple), each against ``r``."""
    if not isinstance(value, (list, tuple)) or len(value) != r.n:
        raise ConfigError(f"{where} must be {r.n} numbers, each {r.describe()}; got {value!r}")
    return tuple(check_number(v, f"{where}[{i}]", r) for i, v in enumerate(value))


def check_table(table: dict, ranges: dict[str, Range], where: str) -> dict:
    """Every key of ``table`` that ``ranges`` names, checked (others are left to the caller's key check).
    Lists come back as tuples."""
    out = dict(table)
    for key, value in table.items():
        r = ranges.get(key)
        if r is None:
            continue
        at = f"{where} {key}"
        if value is None and r.optional:
            continue
        if r.text:
            if not isinstance(value, str) or not 0 < len(value) <= r.max_len or not value.isprintable():
                raise ConfigError(f"{at} must be a string of 1 to {r.max_len} printable characters; got {value!r}")
        elif r.n:
            out[key] = check_numbers(value, at, r)
        else:
            out[key] = check_number(value, at, r)
    return out
