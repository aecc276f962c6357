"""Online predictor updates (numpy reference of the generated ``<name>_adapt*.c``; no casadi).

The fit's sufficient statistic is the upper-triangular R factor of the scaled data matrix
X = [Up; Yp; Uf; Yf (; 0)]^T, one row per Hankel column (see :class:`~ddpc_codegen.values.fit_layout.FitLayout`).
Online, each new Hankel column x (width,) joins the recent window of ``window`` columns; the column it pushes
out updates R with exponential forgetting f:

    R <- triu(qr([sqrt(f) R; x^T]))      (Givens rotations, O(width^2), :func:`givens_update`)

so R holds every column but the recent window's: the window is held out of the fit. The batch fit's relative
ridge (rows sqrt(lam) e_k, k < r, lam = ridge ||R11||_F^2 / r of the data) lives in R (:func:`with_ridge`): folded
once, forgotten with the data, and renewed one row per folded column (:meth:`Adapter._fold`: row k = columns
folded before mod r, topped up to the lam of the data as they are then), so that a re-solve need not fold r
rows: row k carries the lam of at most r columns ago, forgotten since (f^(r-1) lam at the least). At a low rate
G is re-solved from R as the batch fit does (the pem slack rows appended, then G^T = R11^-1 R12;
:func:`solve_g`), so with f = 1 the result is the batch refit of the columns before the window, with each ridge
row's lam up to r columns old. A candidate G is verified before it may replace the current one
(:meth:`Adapter.resolve`): finite, R11 well conditioned, a bounded change, a positive definite QP Hessian and
the rest of the rebuilt QP data (when a QP model is given), the recent window exciting enough, and a smaller prediction error than the current
G's on that window -- out of sample for both (the current G was fitted on columns older still), so a candidate
that predicts the window better predicts data it has not seen better, not its own noise. Rejections are counted
by reason. The candidate only becomes current on :meth:`Adapter.swap` (between control ticks).

A re-solve reads a snapshot (:meth:`Adapter.snapshot`: R and the recent columns as of one tick), so it may run
while later columns are pushed (the C code's threaded schedule); ``resolve()`` takes the snapshot itself
(synchronous), ``resolve(snapshot=False)`` re-solves from the last one.

Everything is on the scaled fit domain (channels divided by ``scale``); G is (q_y + q_s, r).

Output offset (``[adapt] offset``, the offset-free MPC answer to a change the predictor has no term for, such as
a payload or battery sag): closed-loop data explain such a change's constant offset only by distorting G's gains,
which the gain check refuses. Instead each re-solve stages b (p Tf,), the mean residual y_f - Gy z of the recent
window in data units, against the G that is current after the swap (the candidate when it was accepted, else
the current one: offset and G always belong together), clipped per output to ``max_offset`` (by default
:data:`OFFSET_SPAN` fit-domain standard deviations mapped to output units: about the recorded outputs' span).
It has its own verification, whatever the verdict on G: finite, and a smaller sum of absolute residuals
|y_f - Gy z - b| on the recent window (each output over its channel scale) than the offset in use -- the mean
that a few outliers or absurd columns drag away predicts the window's other columns worse, so it is refused
(``offset_rejected``). The swap installs only what was verified (:class:`~ddpc_codegen.values.adapt.Swapped`).
The steering then aims at y_des - b (||Gy z + b - y_des||^2 = ||Gy z - (y_des - b)||^2: the QP data do not
change).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.errors import DataError
from ddpc_codegen.design.adapt_qp import QPData, QPModel
from ddpc_codegen.values.adapt import OFFSET_COUNTS, REJECTIONS, AdaptSettings, Swapped
from ddpc_codegen.values.fit_layout import FitLayout

__all__ = ["AdaptLayout", "Adapter", "givens_update", "slack_rows", "data_trace", "with_ridge",
           "solve_g", "excitation_ratio", "OFFSET_SPAN", "OFFSET_MARGIN"]

AdaptLayout = FitLayout  # the online update's name for the fit's layout

# The default max_offset: this many fit-domain units (the recorded data's standard deviation per channel) per
# residual entry, in output units: about the span of the recorded outputs (an offset beyond it is no payload)
OFFSET_SPAN = 4.0
# The offset check's margin: an estimate must cut the window's error by more than this fraction (a cut within
# rounding, e.g. of a window dominated by absurd columns, is none; the C and numpy verdicts agree on it)
OFFSET_MARGIN = 1e-9


def givens_update(R: np.ndarray, x: np.ndarray, forgetting: float = 1.0) -> None:
    """In place: R (n, n) upper triangular <- the R factor of [sqrt(forgetting) R; x^T] (x (n,) is consumed).

    Row i of R and x are rotated so that x[i] becomes 0; diagonal entries end up >= 0.
    """
    n = R.shape[0]
    if forgetting != 1.0:
        R *= np.sqrt(forgetting)
    for i in range(n):
        xi = x[i]
        if xi == 0.0:
            continue
        a = R[i, i]
        rad = np.sqrt(a * a + xi * xi)  # as the C (the scaled data are far from overflow)
        c, s = a / rad, xi / rad
        ri = R[i, i:].copy()
        R[i, i:] = c * ri + s * x[i:]
        x[i:] = c * x[i:] - s * ri
        R[i, i] = rad


def slack_rows(layout: AdaptLayout, slack_weight: float) -> list[np.ndarray]:
    """The rows pem's batch fit appends to the data rows: its slack columns of M (none for lsq)."""
    r, q_y, width = layout.r, layout.q_y, layout.width
    n_up, n_yp = layout.m * layout.t_ini, layout.p * layout.t_ini
    rows = []
    if layout.method == "pem":
        for k in range(n_yp):
            e = np.zeros(width)
            e[n_up + k] = e[r + q_y + k] = 1.0 / np.sqrt(slack_weight)
            rows.append(e)
    return rows


def data_trace(R: np.ndarray, r: int) -> float:
    """||R[:, :r]||_F^2 of a data-only factor: the scale of the relative ridge."""
    return float(np.sum(R[:, :r] ** 2))


def with_ridge(R: np.ndarray, r: int, ridge: float) -> np.ndarray:
    """A copy of the data-only R (width, width) with the batch fit's ridge rows sqrt(lam) e_k (k < r, in order;
    lam = ridge ||R11||_F^2 / r) folded in: the factor the batch fit solves G from. ridge = 0: R unchanged."""
    Rr = np.array(R, dtype=float)
    if ridge > 0.0:
        lam = ridge * data_trace(R, r) / r
        for k in range(r):
            e = np.zeros(Rr.shape[1])
            e[k] = math.sqrt(lam)
            givens_update(Rr, e)
    return Rr


def solve_g(R: np.ndarray, layout: AdaptLayout, slack_weight: float,
            rcond: float) -> tuple[np.ndarray | None, float]:
    """(G (q_y + q_s, r), diag ratio) from R (width, width; the data and the ridge rows, :func:`with_ridge`):
    pem's slack rows appended by Givens rotations, then G^T = R11^-1 R12 by back substitution. G is None when
    min |diag R11| <= rcond * max |diag R11| (rank deficient: the batch fit would truncate)."""
    r = layout.r
    Ra = np.array(R, dtype=float)
    for e in slack_rows(layout, slack_weight):
        givens_update(Ra, e)
    d = np.abs(np.diag(Ra)[:r])
    ratio = float(d.min() / d.max()) if d.max() > 0 else 0.0
    if not ratio > rcond:
        return None, ratio
    R11, X = Ra[:r, :r], Ra[:r, r:].copy()
    for i in range(r - 1, -1, -1):
        X[i] = (X[i] - R11[i, i + 1 :] @ X[i + 1 :]) / R11[i, i]
    return X.T, ratio


def excitation_ratio(columns: np.ndarray, layout: AdaptLayout) -> float:
    """min/max |diag| of the R factor (Givens) of the input rows of ``columns`` (k, width); 0 if k < rows."""
    rows = columns[:, layout.u_rows]
    n = rows.shape[1]
    if rows.shape[0] < n:
        return 0.0
    Rx = np.zeros((n, n))
    for x in rows:
        givens_update(Rx, x.copy())
    d = np.abs(np.diag(Rx))
    return float(d.min() / d.max()) if d.max() > 0 else 0.0


def _prediction_error(G: np.ndarray, cols: np.ndarray, layout: AdaptLayout) -> float:
    """Sum of squared output-prediction errors ||Gy z - y_f||^2 over the columns (k, width) (scaled)."""
    r, q_y = layout.r, layout.q_y
    e = cols[:, :r] @ G[:q_y].T - cols[:, r : r + q_y]
    return float(np.sum(e * e))


@dataclass
class Adapter:
    """The online update of one predictor (the interpreted twin of ``<name>_adapt_*`` in C).

    R0: the shipped data-only R factor (k <= width rows; ``R``: it with the ridge rows, as updated); scale
    (m+p,): the fit's channel scale; slack_weight, ridge, rcond: the fit's options; qp: the QP's :class:`~ddpc_codegen.design.adapt_qp.QPModel`
    or None (then no QP data are rebuilt and the Hessian is not checked). ``qp_data``: the QP data of the
    current G (None until the first swap: the shipped data are in use). ``offset`` (p Tf,): the output offset in
    use (data units, time-major; zeros until the first offset swap), ``offset_estimate`` the last re-solve's
    (clipped; None when not finite), ``pending_offset`` it once verified, until the swap.
    """

    layout: AdaptLayout
    R0: np.ndarray
    scale: np.ndarray
    settings: AdaptSettings
    slack_weight: float = 1.0
    ridge: float = 0.0
    rcond: float = 1e-10
    qp: QPModel | None = None
    counts: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        w = self.layout.width
        if self.R0.ndim != 2 or self.R0.shape[1] != w or self.R0.shape[0] > w:
            raise DataError(f"the R factor must have {w} columns and at most {w} rows; got shape {self.R0.shape}")
        s = self.settings
        if not (0.0 < s.forgetting <= 1.0):
            raise DataError(f"[adapt] forgetting must be in (0, 1]; got {s.forgetting}")
        if s.window < self.layout.min_window:
            raise DataError(f"[adapt] window must be >= m (Tini+Tf) = {self.layout.min_window} columns "
                            f"(fewer cannot show excitation); got {s.window}")
        R = np.zeros((w, w))
        R[: self.R0.shape[0]] = self.R0
        self.trace = data_trace(R, self.layout.r)  # of the data alone, forgotten as they are
        self.R = with_ridge(R, self.layout.r, self.ridge)
        # the ridge each of R's ridge rows carries now (forgotten with the data, topped up on schedule)
        self.ridge_k = np.full(self.layout.r, self.ridge * self.trace / self.layout.r)
        self.ring = np.zeros((s.window, w))
        self.n_ring = 0
        self.head = 0
        self.snapshot()  # a re-solve before any snapshot sees the shipped R and an empty window
        G, _ = solve_g(self.R, self.layout, self.slack_weight, self.rcond)
        if G is None:
            raise DataError("the shipped R factor is rank deficient: the predictor cannot be re-solved from it "
                            "(fit it with [predictor] ridge > 0)")
        self.G = G
        self.pending: np.ndarray | None = None
        self.pending_qp: QPData | None = None
        self.qp_data: QPData | None = None
        lay = self.layout
        # fit-domain output residual (q_y,) -> data units (p Tf,): the data-unit predictor's map of G's Yf rows
        self.offset_map = (self.qp.Lm[: self.qp.n_y, : lay.q_y] if self.qp is not None
                           else np.diag(np.tile(self.scale[lay.m :], lay.t_f)))
        rows = np.abs(self.offset_map).sum(axis=1)  # (a hand-made QP model may predict no output: the scale's)
        span = OFFSET_SPAN * (rows.reshape(lay.t_f, lay.p).max(axis=0) if rows.size == lay.t_f * lay.p
                              else self.scale[lay.m :])
        self.max_offset = _max_offset(s.max_offset, lay.p, span)
        self.offset_weight = 1.0 / np.tile(self.scale[lay.m :], lay.t_f)  # the verification's per-entry weight
        self.offset = np.zeros(self.offset_map.shape[0])
        self.offset_estimate: np.ndarray | None = None
        self.pending_offset: np.ndarray | None = None
        # "folded": columns in R (here as they leave the window: the reference has no tick to keep short);
        # "dropped": never here, the C refuses columns only when its bounded queue is full
        self.counts = {"updates": 0, "skipped": 0, "dropped": 0, "folded": 0, "resolves": 0, "accepted": 0, "swaps": 0, "clipped": 0,
                       **{f"rejected_{k}": 0 for k in REJECTIONS},
                       **{k: 0 for k in OFFSET_COUNTS}, "offset_norm": 0.0,
                       "error_current": 0.0, "error_candidate": 0.0,  # of the last error check
                       "offset_error_current": 0.0, "offset_error_candidate": 0.0}  # of the last offset check

    def push(self, window: np.ndarray) -> bool:
        """One new Hankel column from a time-major window (depth, m+p) in data units: into the recent window;
        the column it pushes out (the window's oldest) into R. A window with a NaN/inf is skipped (False,
        counted): it must not poison R."""
        x = self.layout.column(window, self.scale)
        if not np.all(np.isfinite(x)):
            self.counts["skipped"] += 1
            return False
        if self.n_ring == self.settings.window:  # the oldest leaves the held-out window: R takes it
            self._fold(self.ring[self.head])
        self.ring[self.head] = x
        self.head = (self.head + 1) % self.settings.window
        self.n_ring = min(self.n_ring + 1, self.settings.window)
        self.counts["updates"] += 1
        return True

    def _fold(self, x: np.ndarray) -> None:
        """One data column (width,) into R with forgetting f, then ridge row k = (columns folded before) mod r
        topped up to the current lam: sqrt(lam - its forgotten ridge) e_k (>= 0 but for rounding: the trace
        shrinks by at most f per column, the ridge by exactly f)."""
        f, r = self.settings.forgetting, self.layout.r
        self.trace = f * self.trace + float(np.dot(x[:r], x[:r]))
        givens_update(self.R, x.copy(), f)
        if self.ridge > 0.0:
            self.ridge_k *= f
            k, lam = self.counts["folded"] % r, self.ridge * self.trace / r
            add = lam - self.ridge_k[k]
            if add > 0.0:
                e = np.zeros(self.layout.width)
                e[k] = math.sqrt(add)
                givens_update(self.R, e)
                self.ridge_k[k] = lam
        self.counts["folded"] += 1

    def recent(self) -> np.ndarray:
        """The recent columns (n_ring, width), oldest first."""
        k, n = self.n_ring, self.settings.window
        return np.roll(self.ring, -self.head, axis=0)[n - k :] if k else self.ring[:0]

    def snapshot(self) -> None:
        """Copy what a re-solve reads and :meth:`push` writes: R (width, width) and the recent columns
        (n_ring, width), oldest first."""
        self._R_snap = self.R.copy()
        self._recent_snap = self.recent().copy()

    def resolve(self, snapshot: bool = True) -> str:
        """Re-solve G from R and verify it: "accepted" (pending until :meth:`swap`) or the rejection reason.
        ``snapshot``: take the snapshot first (synchronous); False: from the last :meth:`snapshot`."""
        if snapshot:
            self.snapshot()
        self.counts["resolves"] += 1
        # a new re-solve replaces any candidate not yet swapped in
        self.pending, self.pending_qp, self.pending_offset, self.offset_estimate = None, None, None, None
        G, _ = solve_g(self._R_snap, self.layout, self.slack_weight, self.rcond)
        reason = self._verify(G)
        if reason is None:
            self.counts["accepted"] += 1
        else:
            self.counts[f"rejected_{reason}"] += 1
        if self.settings.offset:  # whatever the verdict on G: against the G current after the swap
            self._stage_offset(self.G if self.pending is None else self.pending)
        return reason or "accepted"

    def offset_of(self, G: np.ndarray) -> np.ndarray | None:
        """The mean residual y_f - Gy z (p Tf,) of the snapshot's recent window under the fit-domain G, in data
        units (time-major); None while the window is empty."""
        cols = self._recent_snap
        if cols.shape[0] == 0:
            return None
        r, q_y = self.layout.r, self.layout.q_y
        e = (cols[:, r : r + q_y] - cols[:, :r] @ G[:q_y].T).mean(axis=0)
        return self.offset_map @ e

    def offset_errors(self, G: np.ndarray, b: np.ndarray) -> tuple[float, float]:
        """(of b, of the offset in use): the sums over the snapshot's recent window of |y_f - Gy z - offset| (data
        units, each entry over its output's channel scale) under the fit-domain G."""
        cols, r, q_y = self._recent_snap, self.layout.r, self.layout.q_y
        d = (cols[:, r : r + q_y] - cols[:, :r] @ G[:q_y].T) @ self.offset_map.T
        w = self.offset_weight
        return float(np.sum(np.abs(d - b) * w)), float(np.sum(np.abs(d - self.offset) * w))

    def _stage_offset(self, G: np.ndarray) -> None:
        """Estimate the offset of G, clipped per output to max_offset (counted), and stage it if verified: finite
        and predicting the recent window better than the offset in use (else refused, counted)."""
        with np.errstate(all="ignore"):
            b = self.offset_of(G)
        if b is None:
            return
        if not np.all(np.isfinite(b)):
            self.counts["offset_rejected"] += 1
            return
        lim = np.tile(self.max_offset, self.layout.t_f)
        if np.any(np.abs(b) > lim):
            b = np.clip(b, -lim, lim)
            self.counts["offset_clipped"] += 1
        self.offset_estimate = b
        with np.errstate(all="ignore"):  # absurd (1e300) columns: inf / NaN sums, refused below
            e_b, e_0 = self.offset_errors(G, b)
        self.counts["offset_error_candidate"], self.counts["offset_error_current"] = e_b, e_0
        if not e_b < (1.0 - OFFSET_MARGIN) * e_0:
            self.counts["offset_rejected"] += 1
            return
        self.pending_offset = b

    def _verify(self, G: np.ndarray | None) -> str | None:
        if G is None:
            return "rank"
        if not np.all(np.isfinite(G)):
            return "nonfinite"
        step = G - self.G
        big = self.settings.max_change * np.linalg.norm(self.G)
        if np.linalg.norm(step) > big:  # a bounded change: scale the step down onto the bound
            G = self.G + step * (big / np.linalg.norm(step))
            self.counts["clipped"] += 1
        data = self.qp.rebuild(G) if self.qp is not None else None
        if isinstance(data, str):
            return data
        cols = self._recent_snap
        if excitation_ratio(cols, self.layout) < self.settings.min_excitation:
            return "excitation"
        with np.errstate(over="ignore", invalid="ignore"):  # absurd (1e300) columns: inf, refused below
            e_c, e_g = _prediction_error(G, cols, self.layout), _prediction_error(self.G, cols, self.layout)
        self.counts["error_candidate"], self.counts["error_current"] = e_c, e_g
        if not e_c < (1.0 - self.settings.min_improvement) * e_g:
            return "prediction"
        self.pending, self.pending_qp = G, data
        return None

    def swap(self) -> Swapped:
        """Make the verified candidate G and the verified offset current (call between ticks); what was
        installed."""
        swapped = self.pending is not None
        if swapped:
            self.G, self.pending = self.pending, None
            if self.pending_qp is not None:
                self.qp_data, self.pending_qp = self.pending_qp, None
            self.counts["swaps"] += 1
        offset = self.pending_offset is not None
        if offset:
            self.offset, self.pending_offset = self.pending_offset, None
            self.counts["offset_swaps"] += 1
            self.counts["offset_norm"] = float(np.linalg.norm(self.offset))
        return Swapped(swapped, offset)


def _max_offset(value, p: int, default: np.ndarray) -> np.ndarray:
    """[adapt] max_offset as (p,) finite bounds > 0 (one number for every output, or one per output; inf: the
    output's entry of ``default`` (p,))."""
    try:
        bad = isinstance(value, bool) or any(isinstance(x, bool) for x in np.ravel(np.asarray(value, dtype=object)))
        v = np.array([np.nan]) if bad else np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        v = np.array([np.nan])
    if v.ndim > 1 or (v.ndim == 1 and v.size != p) or np.any(np.isnan(v)) or np.any(v <= 0):
        raise DataError(f"[adapt] max_offset must be one number > 0 or {p} of them (one per output); got {value!r}")
    v = np.broadcast_to(v, (p,)).astype(float)
    return np.where(np.isinf(v), default, v)
