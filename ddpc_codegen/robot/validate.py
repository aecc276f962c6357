"""The one validation layer for the files and values the robot side flies on (robot profiles, prefilter
models, feed-forward tables, the bridge's command-line values): sizes checked before reading, nesting
bounded before parsing, and every number checked for type, finiteness and range with a message that
names the file and the key. Every refusal is a :class:`~ddpc_codegen.errors.ConfigError`.

numpy only: the companion computer's bridge imports it.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.errors import ConfigError

__all__ = ["Range", "check_size", "read_text_bounded", "load_json_bounded", "nesting_depth", "check_number",
           "check_numbers", "check_table", "MAX_TEXT_BYTES", "MAX_DEPTH"]

MAX_TEXT_BYTES = 1_000_000  # a profile or a prefilter model is a few hundred bytes
MAX_DEPTH = 32              # tables / arrays nested deeper are not a file of ours (and recurse the parsers)


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


def check_size(path: str | Path, limit: int, what: str) -> Path:
    """``path`` must be a regular file of at most ``limit`` bytes (checked before anything reads it)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such {what} file" + (" (a directory)" if p.is_dir() else ""))
    size = p.stat().st_size
    if size > limit:
        raise ConfigError(f"{p}: {size} bytes, more than a {what} file may have ({limit} bytes)")
    return p


def nesting_depth(text: str) -> int:
    """Deepest nesting of [ ] / { } brackets outside quoted strings (JSON and TOML alike)."""
    depth = best = 0
    quote = ""
    escaped = False
    for ch in text:
        if quote:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
            best = max(best, depth)
        elif ch in "]}":
            depth -= 1
    return best


def read_text_bounded(path: str | Path, what: str, *, limit: int = MAX_TEXT_BYTES, max_depth: int = MAX_DEPTH) -> str:
    """The text of a small file, refused when larger than ``limit`` bytes, not UTF-8, or nested deeper
    than ``max_depth`` (the parsers recurse per level)."""
    p = check_size(path, limit, what)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{p}: not a readable {what} file ({type(e).__name__}: {e})") from None
    depth = nesting_depth(text)
    if depth > max_depth:
        raise ConfigError(f"{p}: nested {depth} levels deep, more than a {what} file may be ({max_depth})")
    return text


def load_json_bounded(path: str | Path, what: str, *, limit: int = MAX_TEXT_BYTES) -> Any:
    """A small JSON file (see :func:`read_text_bounded`). NaN / Infinity literals parse (informational
    fields may hold them); the caller checks the values it uses."""
    text = read_text_bounded(path, what, limit=limit)
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as e:
        raise ConfigError(f"{path}: not a {what} JSON file ({type(e).__name__}: {e})") from None


def _is_real(v: Any) -> bool:
    return not isinstance(v, (bool, np.bool_)) and isinstance(v, (int, float, np.integer, np.floating))


def check_number(value: Any, where: str, r: Range = Range()) -> float | int:
    """One value against ``r``; returns it as float (int when ``r.integer``). ``where`` names the file
    and the key ("p.toml: [controller] kp_z")."""
    bad = ConfigError(f"{where} must be {r.describe()}; got {value!r}")
    if not _is_real(value) or not math.isfinite(float(value)):
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
