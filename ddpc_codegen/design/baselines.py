"""Simple baselines a control engineer tries before reference steering, identified offline.

* **Prefilter** (the "afternoon fix"): per channel the closed loop is taken as a static map with
  a dead time, y[k] ~= g u[k - d] + c, fitted by least squares on recorded (u, y) (the same PRBS
  data the predictor is built from); the inverse sends u[k] = (y_des[k + d] - c) / g, i.e. the
  desired output ``d`` ticks early, rescaled and offset (see :class:`PrefilterModel`).
* **ILC** (iterative learning control) on repeated runs of the same trajectory: a feed-forward
  table delta (N, m) added to the nominal references and updated from each run's error:
  P-type with a lead, delta += gamma e[k + d], zero-phase low-pass Q-filtered
  (:func:`ilc_update_p`), or norm-optimal with a lifted model G of the loop,
  delta += (G^T G + w I)^-1 G^T e (:func:`ilc_update_norm_optimal`; G from an impulse response
  identified on the same data, :func:`fit_impulse_response` / :func:`lifted_matrix`).

Signals are time-major: u (T, m), y (T, p), m == p (channel i of u is the reference of output i).
numpy only at import time; scipy is imported inside the functions that need it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ddpc_codegen.errors import ConfigError, DataError

__all__ = [
    "PrefilterModel",
    "fit_prefilter",
    "ilc_update_p",
    "ilc_update_norm_optimal",
    "fit_impulse_response",
    "lifted_matrix",
    "shift_ahead",
    "ILC_CUTOFF_HZ",
    "ilc_step",
    "error_on_grid",
    "iterations_to_settle",
]


# ----------------------------------------------------------------------------- prefilter
@dataclass(frozen=True)
class PrefilterModel:
    """Per-channel static gain, offset and dead time of the closed loop: y_i[k] = g_i u_i[k - d_i] + c_i.

    Attributes:
        gain: (m,) g [output unit / input unit]; offset: (m,) c [output unit]; lead: (m,) d [ticks].
        dt: tick [s]. names: channel names (inputs). residual_rms: (m,) fit residual [output unit].
        r2: (m,) share of the output variance the fit explains.
    """

    gain: tuple[float, ...]
    offset: tuple[float, ...]
    lead: tuple[int, ...]
    dt: float
    names: tuple[str, ...] = ()
    residual_rms: tuple[float, ...] = ()
    r2: tuple[float, ...] = ()

    @property
    def m(self) -> int:
        return len(self.gain)

    def inverse(self, y_des_ahead: np.ndarray, r_nom: np.ndarray) -> np.ndarray:
        """u (m,) for desired outputs ``y_des_ahead`` (H, p) at ticks k..k+H-1 and the nominal
        reference r_nom (m,): u_i = r_nom_i + (y_des[d_i, i] - c_i) / g_i - y_des[0, i].

        Written as a correction of r_nom so that whatever the controller adds to its reference
        (e.g. the horizontal PD in the pitch reference) is kept; leads beyond the horizon are
        clipped to H - 1."""
        yd = np.atleast_2d(np.asarray(y_des_ahead, dtype=float))
        u = np.array(r_nom, dtype=float, copy=True)
        for i in range(self.m):
            d = min(int(self.lead[i]), yd.shape[0] - 1)
            u[i] += (yd[d, i] - self.offset[i]) / self.gain[i] - yd[0, i]
        return u

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict, src: str = "<dict>") -> "PrefilterModel":
        try:
            m = cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})
        except TypeError as e:
            raise ConfigError(f"{src}: not a prefilter model ({e})") from None
        if not (len(m.gain) == len(m.offset) == len(m.lead) > 0) or any(g == 0 for g in m.gain):
            raise ConfigError(f"{src}: gain, offset and lead need one nonzero gain per channel; got {d!r}")
        return m

    def save(self, path: str | Path) -> Path:
        """JSON (what the bridge loads with :meth:`load`)."""
        path = Path(path)
        path.write_text(json.dumps({"prefilter": self.to_dict()}, indent=2) + "\n")
        return path

    @classmethod
    def load(cls, path: str | Path) -> "PrefilterModel":
        path = Path(path)
        try:
            d = json.loads(path.read_text())["prefilter"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ConfigError(f"{path}: not a prefilter JSON file ({type(e).__name__}: {e})") from None
        return cls.from_dict(d, str(path))


def _segments(u, y) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(u (T, m), y (T, p))] from arrays, lists of arrays or an IODataset."""
    if hasattr(u, "trajectories") and y is None:
        return [(np.asarray(a, float), np.asarray(b, float)) for a, b in u.trajectories()]
    if isinstance(u, np.ndarray) and u.ndim == 2:
        return [(np.asarray(u, float), np.asarray(y, float))]
    return [(np.asarray(a, float), np.asarray(b, float)) for a, b in zip(u, y)]


def fit_prefilter(u, y=None, *, max_lead: int = 200, dt: float | None = None, smooth_hz: float | None = None,
                  names: Sequence[str] = ()) -> PrefilterModel:
    """Least-squares gain, offset and dead time per channel.

    Args:
        u: (T, m) inputs, a list of such arrays (several trajectories), or an IODataset (then y = None).
        y: (T, p) outputs (p == m) or a list matching ``u``.
        max_lead: largest dead time tried [ticks]; every d in 0..max_lead is fitted and the one
            with the smallest residual kept (a lead of d ticks needs the desired output d ticks ahead).
        dt: tick [s] (default: the dataset's).
        smooth_hz: zero-phase low-pass both u and y at this cut-off before the fit. A static map
            commutes with a unity-DC-gain linear filter, so the model is unchanged; what the filter
            removes is the fast PRBS the loop does not pass, which would otherwise bias the gain low
            (measured on the flying data: gain 0.84, R^2 0.82 unfiltered).
    Returns:
        :class:`PrefilterModel`. On noise-free data generated by y = g u[k-d] + c it is exact.
    """
    segs = _segments(u, y)
    if dt is None:
        dt = float(getattr(u, "dt", 0.0)) or 1.0
    names = tuple(names) or tuple(getattr(u, "input_names", ()) or ())
    if smooth_hz is not None:
        segs = [(_q_filter(a, smooth_hz, dt), _q_filter(b, smooth_hz, dt)) for a, b in segs]
    m = segs[0][0].shape[1]
    if any(a.shape[1] != m or b.shape[1] != m or a.shape[0] != b.shape[0] for a, b in segs):
        raise DataError(f"the prefilter needs u and y of equal length with m == p channels; got "
                        f"{[(a.shape, b.shape) for a, b in segs]}")
    # A segment no longer than max_lead has no sample that every lead can use (seen: a 117-tick piece
    # of an ArduCopter collect log between two stale stretches, with max_lead 200).
    segs = [(a, b) for a, b in segs if a.shape[0] > max_lead]
    if sum(max(a.shape[0] - max_lead, 0) for a, _ in segs) < 3 * (max_lead + 2):
        raise DataError(f"too few samples ({sum(a.shape[0] for a, _ in segs)}) to fit a prefilter with "
                        f"max_lead={max_lead}; record longer or lower max_lead")
    gain, off, lead, res, r2 = [], [], [], [], []
    for i in range(m):
        best = None
        for d in range(max_lead + 1):
            # The same samples for every d (k >= max_lead), so residuals are comparable.
            x = np.concatenate([a[max_lead - d : a.shape[0] - d, i] for a, _ in segs])
            t = np.concatenate([b[max_lead:, i] for _, b in segs])
            A = np.column_stack([x, np.ones_like(x)])
            coef, *_ = np.linalg.lstsq(A, t, rcond=None)
            r = t - A @ coef
            ss = float(r @ r)
            if best is None or ss < best[0] - 1e-12 * max(best[0], 1e-300):
                best = (ss, d, coef, t)
        ss, d, coef, t = best
        if abs(coef[0]) < 1e-9:
            raise DataError(f"channel {i}: the output does not respond to the input (gain {coef[0]:.3g}); "
                            "no prefilter can be fitted")
        gain.append(float(coef[0])); off.append(float(coef[1])); lead.append(int(d))
        res.append(float(np.sqrt(ss / t.size)))
        var = float(np.var(t))
        r2.append(float(1.0 - ss / (t.size * var)) if var > 0 else 1.0)
    return PrefilterModel(tuple(gain), tuple(off), tuple(lead), float(dt), names, tuple(res), tuple(r2))


# ----------------------------------------------------------------------------- ILC
def shift_ahead(e: np.ndarray, d: int) -> np.ndarray:
    """e[k + d] (T, ...) with the last sample held at the end (d >= 0 ticks)."""
    e = np.asarray(e, dtype=float)
    if d <= 0:
        return e.copy()
    return np.concatenate([e[d:], np.repeat(e[-1:], min(d, e.shape[0]), axis=0)])[: e.shape[0]]


def _q_filter(x: np.ndarray, cutoff_hz: float | None, dt: float, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass along axis 0 (the ILC Q-filter); identity if cutoff is None."""
    if cutoff_hz is None:
        return x
    from scipy.signal import butter, filtfilt

    b, a = butter(order, cutoff_hz * 2.0 * dt)  # normalized to Nyquist = 1 / (2 dt)
    if x.shape[0] <= 3 * max(len(a), len(b)):
        return x
    return filtfilt(b, a, x, axis=0)


def ilc_update_p(delta: np.ndarray, error: np.ndarray, gain: float | Sequence[float], lead: int | Sequence[int], *,
                 cutoff_hz: float | None = None, dt: float = 1.0, mask: np.ndarray | None = None) -> np.ndarray:
    """P-type ILC with lead: delta_next = Q(delta - gamma e[k + d]) per channel.

    Args:
        delta: (N, m) feed-forward of this iteration (added to the nominal references).
        error: (N, p) y - y_des of this iteration (p == m); NaN where there is no error to learn from.
        gain: gamma per channel (about 1/static gain for a one-shot offset correction; smaller is safer).
        lead: d per channel [ticks] (the loop's dead time: the error d ticks later is what u[k] causes).
        cutoff_hz: Q-filter cut-off (zero-phase Butterworth); None = no filter.
        dt: tick [s]; mask: (N,) bool, where delta may change (e.g. the aerial ticks of a hop).
    Returns:
        (N, m) the next delta.
    """
    delta = np.asarray(delta, dtype=float)
    e = np.nan_to_num(np.asarray(error, dtype=float))
    m = delta.shape[1]
    g = np.broadcast_to(np.asarray(gain, dtype=float), (m,))
    d = np.broadcast_to(np.asarray(lead, dtype=int), (m,))
    step = np.column_stack([g[i] * shift_ahead(e[:, i], int(d[i])) for i in range(m)])
    new = _q_filter(delta - step, cutoff_hz, dt)
    if mask is not None:
        new = np.where(np.asarray(mask, bool)[:, None], new, delta)
    return new


# The Q-filter cut-off of the demos' ILC (in-process and against the SITLs): the flying loops pass
# ~1 Hz (the ellipse is 0.2 Hz), the table above it would only learn noise.
ILC_CUTOFF_HZ = 1.0


def ilc_step(delta: np.ndarray, error: np.ndarray, prefilter: PrefilterModel, *, dt: float,
             mask: np.ndarray | None = None, gain_scale: float = 1.0,
             cutoff_hz: float | None = ILC_CUTOFF_HZ) -> np.ndarray:
    """The demos' ILC law: :func:`ilc_update_p` with the lead d_i and gain gain_scale / g_i of a
    prefilter fitted on the same loop, Q-filtered at ``cutoff_hz``.

    Args: delta (N, m) this iteration's table; error (N, p) y - y_des on the table's grid; dt tick [s];
        mask (N,) where the error was observed (elsewhere delta is kept).
    Returns: (N, m) the next table.
    """
    gains = gain_scale / np.asarray(prefilter.gain, dtype=float)
    return ilc_update_p(delta, error, gains, prefilter.lead, cutoff_hz=cutoff_hz, dt=dt, mask=mask)


def error_on_grid(t: np.ndarray, e: np.ndarray, n: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Errors sampled at times ``t`` put on the table's grid j = round(t / dt), j = 0..n-1.

    Args:
        t: (T,) trajectory time of each sample [s] (NaN: not on the trajectory, ignored).
        e: (T, p) error y - y_des of each sample.
        n: rows of the table; dt: its tick [s].
    Returns:
        (error (n, p), observed (n,) bool). Several samples on one grid point are averaged; grid
        points between observed ones (a missed tick) are interpolated linearly and count as
        observed; before the first / after the last observed point nothing is (mask False) and the
        edge value is held there (so that a Q-filter over the whole grid sees no step to zero).
    """
    t = np.asarray(t, dtype=float)
    e = np.asarray(e, dtype=float).reshape(t.shape[0], -1)
    ok = np.isfinite(t) & np.all(np.isfinite(e), axis=1)
    j = np.rint(t[ok] / dt).astype(int)
    keep = (j >= 0) & (j < n)
    j, ev = j[keep], e[ok][keep]
    acc, cnt = np.zeros((n, e.shape[1])), np.zeros(n)
    np.add.at(acc, j, ev)
    np.add.at(cnt, j, 1.0)
    seen = cnt > 0
    out = np.zeros_like(acc)
    if not seen.any():
        return out, seen
    out[seen] = acc[seen] / cnt[seen, None]
    idx = np.flatnonzero(seen)
    for c in range(out.shape[1]):  # np.interp holds the edge values outside [idx[0], idx[-1]]
        out[:, c] = np.interp(np.arange(n), idx, out[idx, c])
    mask = np.zeros(n, dtype=bool)
    mask[idx[0] : idx[-1] + 1] = True
    return out, mask


def iterations_to_settle(metric: Sequence[float], tol: float = 0.1) -> int:
    """The first ILC iteration whose metric is within ``tol`` (relative) of the best one (NaN: ignored)."""
    v = np.asarray(metric, dtype=float)
    if not np.isfinite(v).any():
        raise DataError(f"no finite ILC metric to settle on: {list(metric)}")
    best = np.nanmin(v)
    return int(np.flatnonzero(np.isfinite(v) & (v <= (1.0 + tol) * best))[0])


def ilc_update_norm_optimal(delta: np.ndarray, error: np.ndarray, G: np.ndarray, weight: float) -> np.ndarray:
    """Norm-optimal ILC step: delta_next = delta - (G^T G + w I)^-1 G^T e, the minimizer of
    ||e - G (delta_next - delta)||^2 + w ||delta_next - delta||^2 with e_next = e + G (delta_next - delta).

    Args:
        delta: (N,) or (N, m) this iteration's feed-forward (stacked time-major if m > 1).
        error: y - y_des, same shape as delta.
        G: (N m, N m) lifted map from a change of delta to the change of y (time-major stacking).
        weight: w > 0 (larger = slower, more robust to model error).
    """
    if not weight > 0:
        raise ConfigError(f"norm-optimal ILC needs weight > 0; got {weight!r}")
    shape = np.shape(delta)
    e = np.asarray(error, dtype=float).reshape(-1)
    H = G.T @ G + weight * np.eye(G.shape[1])
    step = np.linalg.solve(H, G.T @ e)
    return (np.asarray(delta, dtype=float).reshape(-1) - step).reshape(shape)


def fit_impulse_response(u, y=None, *, n_taps: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel FIR with offset by least squares: y_i[k] = sum_{j<n} h_i[j] u_i[k-j] + c_i.

    Returns (h (n_taps, m), c (m,)); the model the norm-optimal ILC lifts (:func:`lifted_matrix`).
    """
    segs = _segments(u, y)
    m = segs[0][0].shape[1]
    hs, cs = [], []
    for i in range(m):
        rows, rhs = [], []
        for a, b in segs:
            if a.shape[0] <= n_taps:
                continue
            from numpy.lib.stride_tricks import sliding_window_view

            win = sliding_window_view(a[:, i], n_taps)[:, ::-1]  # row k: u[k+n-1], ..., u[k]
            rows.append(win)
            rhs.append(b[n_taps - 1 :, i])
        if not rows:
            raise DataError(f"every trajectory is shorter than n_taps={n_taps}; record longer or lower n_taps")
        A = np.vstack(rows)
        A = np.column_stack([A, np.ones(A.shape[0])])
        coef, *_ = np.linalg.lstsq(A, np.concatenate(rhs), rcond=None)
        hs.append(coef[:-1]); cs.append(coef[-1])
    return np.column_stack(hs), np.asarray(cs)


def lifted_matrix(h: np.ndarray, n: int) -> np.ndarray:
    """(n, n) lower-triangular Toeplitz matrix of the impulse response h (taps,): y = G u over n ticks."""
    from scipy.linalg import toeplitz

    col = np.zeros(n)
    k = min(n, len(h))
    col[:k] = h[:k]
    return toeplitz(col, np.zeros(n))
