"""The online update's shared values: its settings (the ``[adapt]`` table), its counters and the window of
samples it is fed (numpy only; the update itself is :mod:`ddpc_codegen.design.adapter`, the generated one
:mod:`ddpc_codegen.runtime.adapt_generated`)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ddpc_codegen.errors import ConfigError

__all__ = ["AdaptSettings", "adapt_settings", "SampleWindow", "Swapped", "REJECTIONS", "OFFSET_COUNTS"]

# Reasons a candidate G is rejected (the C code's codes 1..6, in this order). Checked in the order rank, nonfinite,
# gain, (QP data) nonfinite, hessian, excitation, prediction -- numpy and C alike.
REJECTIONS = ("rank", "nonfinite", "hessian", "excitation", "prediction", "gain")


# The output offset's counters (besides offset_norm, the norm of the offset in use, data units).
OFFSET_COUNTS = ("offset_swaps", "offset_clipped", "offset_rejected")


@dataclass(frozen=True)
class Swapped:
    """What one swap installed: ``g`` the verified candidate G (and its QP data), ``offset`` the verified output
    offset; true when either was. ``code``: the generated ``<name>_adapt_swap``'s result (1 G, 2 offset, 3 both)."""

    g: bool = False
    offset: bool = False

    def __bool__(self) -> bool:
        return self.g or self.offset

    @property
    def code(self) -> int:
        return int(self.g) | 2 * int(self.offset)

    @classmethod
    def of_code(cls, code: int) -> Swapped:
        """From ``<name>_adapt_swap``'s result (-1, the QP backend refused the data: nothing installed)."""
        return cls(code > 0 and bool(code & 1), code > 0 and bool(code & 2))


@dataclass(frozen=True)
class AdaptSettings:
    """What an update may do (``[adapt]`` of a steering config; defaults in one place).

    forgetting: f in (0, 1], weight of the past per new column (0.999: ~1000 columns, 5 s at 200 Hz).
    period_ticks: new columns between two re-solves of G.
    dither: amplitude of the optional dither on the steered references while adapting (their units; 0 = none).
    window: recent columns kept for the verification (prediction error, excitation), held out of the fit until
        they leave it (a change reaches a candidate once it is older than the window); >= m (Tini+Tf).
    max_change: largest ||G_new - G||_F / ||G||_F of one swap (a bigger step is scaled down to it).
    min_excitation: smallest min/max |diag| of the R factor of the recent window's scaled input rows.
    min_improvement: the fraction by which a candidate must cut the current G's prediction error on the recent
        window to be accepted (0: any cut). The window is held out of the candidate's fit, so the cut is out of
        sample; the margin keeps G through the noise of closed-loop data until they show a change the current
        one does not predict.
    max_gain_change: largest ||S_new - S_0||_F / ||S_0||_F of the predictor's steady-state gain S (outputs per
        constant reference, p x m) against the shipped one. Closed-loop data explain an offset the fit has no
        term for (a payload, battery sag) by distorting the gains, e.g. height through the pitch reference;
        the tracking loop's steady-state gains are set by its structure, so a large change is refused.
    offset: estimate and apply the predictor's output offset b (see the module docstring); off by default (for the
        incremental form, which is offset-free by construction, it is rarely useful).
    max_offset: the largest |b| per output (output units; one number for every output or one per output); a
        larger estimate is clipped to it and counted (``offset_clipped``). inf (the default): derived from the
        fit's data, a few of its recorded standard deviations per output (about the recorded outputs' span).
        A staged offset is installed only when finite and better than the one in use on the recent window.
    """

    enabled: bool = False
    forgetting: float = 0.999
    period_ticks: int = 200
    dither: float = 0.0
    window: int = 200
    max_change: float = 0.2
    min_excitation: float = 1e-3
    min_improvement: float = 0.1
    max_gain_change: float = 0.25
    offset: bool = False
    max_offset: float | tuple[float, ...] = math.inf


_FLOAT_KEYS = {"forgetting": (0.0, 1.0, True), "dither": (0.0, np.inf, False), "max_change": (0.0, np.inf, True),
               "min_excitation": (0.0, 1.0, False), "min_improvement": (0.0, 1.0, False),
               "max_gain_change": (0.0, np.inf, True)}
_INT_KEYS = ("period_ticks", "window")


def adapt_settings(table: dict | None, src: str = "config", p: int | None = None) -> AdaptSettings:
    """The ``[adapt]`` table (enabled, forgetting, period_ticks, dither, window, max_change, min_excitation,
    min_improvement, max_gain_change, offset, max_offset) -> :class:`AdaptSettings`; None or {} gives the defaults (disabled).
    ``p``: the number of outputs (checks the length of a ``max_offset`` list).

    Raises:
        ConfigError: unknown key or a value out of range (the message names both).
    """
    table = dict(table or {})
    known = {f.name for f in dataclasses.fields(AdaptSettings)}
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(f"{src}: [adapt] unknown key(s) {unknown}; allowed: {sorted(known)}")
    for key in ("enabled", "offset"):
        if key in table and not isinstance(table[key], bool):
            raise ConfigError(f"{src}: [adapt] {key} must be true or false; got {table[key]!r}")
    if "max_offset" in table:
        table["max_offset"] = _max_offset_entry(table["max_offset"], src, p)
    for key, (lo, hi, lo_open) in _FLOAT_KEYS.items():
        if key in table:
            v = table[key]
            num = isinstance(v, (int, float)) and not isinstance(v, bool)
            ok = num and (np.isfinite(v) or (key == "max_gain_change" and v == np.inf)) and v <= hi  # inf: no check
            if not ok or (v <= lo if lo_open else v < lo):
                opening = "(" if lo_open else "["
                rng = f"in {opening}{lo:g}, {hi:g}]" if np.isfinite(hi) else f"{'>' if lo_open else '>='} {lo:g}"
                raise ConfigError(f"{src}: [adapt] {key} must be {rng}; got {v!r}")
            table[key] = float(v)
    for key in _INT_KEYS:
        if key in table and (not isinstance(table[key], int) or isinstance(table[key], bool) or table[key] < 1):
            raise ConfigError(f"{src}: [adapt] {key} must be an integer >= 1; got {table[key]!r}")
    return AdaptSettings(**table)


def _max_offset_entry(v, src: str, p: int | None) -> float | tuple[float, ...]:
    """[adapt] max_offset: a number > 0 (every output; inf: no bound) or a list of them, one per output."""
    seq = isinstance(v, (list, tuple))
    vals = list(v) if seq else [v]
    num = all(isinstance(x, (int, float)) and not isinstance(x, bool) and not np.isnan(x) and x > 0 for x in vals)
    if not num or (seq and (not v or (p is not None and len(v) != p))):
        per = f"{p} of them" if p is not None else "one per output"
        raise ConfigError(f"{src}: [adapt] max_offset must be a number > 0 or a list of {per} (output units); "
                          f"got {v!r}")
    return tuple(float(x) for x in v) if seq else float(v)


class SampleWindow:
    """Turns one (u, y) sample per tick into the update's windows (depth, m + p): the last ``depth``
    samples, or for an increment fit (``increments=True``) the last ``depth`` increments (depth + 1 samples).
    :meth:`push` returns the window once enough samples have arrived, else None; :meth:`clear` forgets them
    (a gap, a disengagement: a window must not span ticks that were not updates)."""

    def __init__(self, depth: int, m: int, p: int, increments: bool) -> None:
        self.depth, self.m, self.p, self.increments = depth, m, p, increments
        self._buf = np.zeros((depth + int(increments), m + p))
        self._n = 0

    def clear(self) -> None:
        self._n = 0

    def push(self, u: np.ndarray, y: np.ndarray) -> np.ndarray | None:
        """Append the sample u (m,), y (p,); the window (depth, m + p) in data units, or None."""
        self._buf[:-1] = self._buf[1:]
        self._buf[-1, : self.m] = u
        self._buf[-1, self.m :] = y
        self._n = min(self._n + 1, self._buf.shape[0])
        if self._n < self._buf.shape[0]:
            return None
        return np.diff(self._buf, axis=0) if self.increments else self._buf.copy()
