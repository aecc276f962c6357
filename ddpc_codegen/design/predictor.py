"""Multi-step predictors from data: y = Gy_w w + Gy_u u, sigma = Gs_w w + Gs_u u, w = [u_ini; y_ini].

Two methods:

* ``"pem"`` — the paper's PEM-MPC predictor, G = [[Yf, 0], [0, I]] pinv([[Up, 0], [Yp, I], [Uf, 0]]).
  It solves min ||g||^2 + rho ||sigma||^2 s.t. [Up; Yp; Uf] g + [0; sigma; 0] = [u_ini; y_ini; u];
  ``slack_weight`` is rho (the paper's equal weighting is rho = 1). Equal weighting biases the
  prediction even on noise-free data (sigma absorbs part of y_ini), a documented property.
* ``"lsq"`` — subspace predictive control, y = Yf pinv([Up; Yp; Uf]) [u_ini; y_ini; u], sigma = 0;
  exact on noise-free LTI data when Tini >= lag and the input is persistently exciting.

Both are computed from an R factor of the data matrix accumulated over blocks of Hankel columns
(TSQR), so memory does not grow with the number of samples and the condition number is not
squared as it would be with normal equations.

Unit-free: every channel is divided by its standard deviation over the dataset (its RMS if it is
near-constant) before the fit and G is
rescaled afterwards, so changing the units of any input or output channel rescales the
predictions and nothing else (``pem``'s slack weighting, the ridge and the rank cutoff all act
on the scaled data). The ridge is relative to the data: ``ridge`` times the mean eigenvalue of
Z Z^T of the scaled data matrix Z = [Up; Yp; Uf] (about the number of Hankel columns), so it
means the same for 200 or 200 000 samples.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Iterable, Iterator, Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import DataError, ExcitationError
from ddpc_codegen.design.hankel import PEReport, channel_stats, near_constant_channels
from ddpc_codegen.values.fit_layout import FitLayout

__all__ = ["Predictor", "fit_predictor", "min_samples", "FitLayout", "channel_scale", "hankel_r_factor",
           "stack_r_factors", "predictor_from_r"]

_METHODS = ("pem", "lsq")


@dataclass(frozen=True, eq=False)
class Predictor:
    """Affine multi-step predictor of horizon ``t_f`` from ``t_ini`` past samples.

    Matrices (stacked, time-major windows; w = [u_ini (m*Tini); y_ini (p*Tini)]):
        Gy_w (p*Tf, (m+p)*Tini), Gy_u (p*Tf, m*Tf)   -> y     (p*Tf)
        Gs_w (p*Tini, (m+p)*Tini), Gs_u (p*Tini, m*Tf) -> sigma (p*Tini), zero for "lsq"
    """

    t_ini: int
    t_f: int
    m: int
    p: int
    method: str
    Gy_w: np.ndarray
    Gy_u: np.ndarray
    Gs_w: np.ndarray
    Gs_u: np.ndarray
    singular_values: np.ndarray
    rank: int
    n_columns: int
    dt: float
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    options: dict = field(default_factory=dict)

    @property
    def n_w(self) -> int:
        """Length of w = [u_ini; y_ini]."""
        return (self.m + self.p) * self.t_ini

    def predict(
        self, u_ini: np.ndarray, y_ini: np.ndarray, u: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predict outputs over the horizon.

        Args:
            u_ini: past inputs, (Tini, m) or stacked (m*Tini,).
            y_ini: past outputs, (Tini, p) or stacked (p*Tini,).
            u: future inputs, (Tf, m) or stacked (m*Tf,).
        Returns:
            y (Tf, p) predicted outputs, sigma (Tini, p) the slack on y_ini.
        """
        w = np.concatenate(
            [
                _stacked(u_ini, self.m * self.t_ini, "u_ini"),
                _stacked(y_ini, self.p * self.t_ini, "y_ini"),
            ]
        )
        uu = _stacked(u, self.m * self.t_f, "u")
        y = self.Gy_w @ w + self.Gy_u @ uu
        s = self.Gs_w @ w + self.Gs_u @ uu
        return y.reshape(self.t_f, self.p), s.reshape(self.t_ini, self.p)

    @property
    def digest(self) -> str:
        """SHA-256 of the matrices and horizons: identifies the predictor in manifests."""
        h = hashlib.sha256()
        h.update(f"{self.method}:{self.t_ini}:{self.t_f}:{self.m}:{self.p}".encode())
        for a in (self.Gy_w, self.Gy_u, self.Gs_w, self.Gs_u):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
        return h.hexdigest()

    def excitation(self) -> PEReport:
        """PE report of order Tini+Tf of the inputs used to fit (from the data's R factor)."""
        return self.options["_pe_report"]

    def __repr__(self) -> str:
        return (
            f"Predictor(method={self.method!r}, t_ini={self.t_ini}, t_f={self.t_f}, m={self.m}, "
            f"p={self.p}, columns={self.n_columns}, rank={self.rank})"
        )


def _stacked(x: np.ndarray, n: int, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=float).reshape(-1)
    if a.shape[0] != n:
        raise DataError(f"{what} must have {n} entries (stacked time-major); got shape {np.shape(x)}")
    if not np.all(np.isfinite(a)):
        raise DataError(f"{what} contains NaN or inf")
    return a


def min_samples(t_ini: int, t_f: int, m: int) -> int:
    """Fewest samples of one trajectory for H_L(u) (L = Tini+Tf) to possibly have full row rank."""
    L = t_ini + t_f
    return (m + 1) * L - 1


def _hankel_blocks(trajectories: Iterable[tuple[np.ndarray, np.ndarray]], depth: int, block: int,
                   scale: np.ndarray) -> Iterator[np.ndarray]:
    """Yield column blocks (b, depth*(m+p)) of the *transposed* mosaic Hankel of [u y] / scale."""
    for u, y in trajectories:
        w = np.hstack([u, y]) / scale
        T, d = w.shape
        if T < depth:
            continue
        win = sliding_window_view(w, (depth, d))[:, 0].reshape(T - depth + 1, depth * d)
        for s in range(0, win.shape[0], block):
            yield win[s : s + block]


def _accumulate_r(R: np.ndarray | None, rows: np.ndarray) -> np.ndarray:
    X = rows if R is None else np.vstack([R, rows])
    return np.linalg.qr(X, mode="r")


def channel_scale(rms: np.ndarray, std: np.ndarray, names: Sequence[str]) -> tuple[np.ndarray, tuple[str, ...]]:
    """(scale (m+p,), near-constant channel names) from the channels' RMS and std over all the data.

    Unit std per channel (its variation, offsets kept: the predictor has no intercept); a
    near-constant channel is scaled by its RMS instead (1 if all zero) so its noise is not blown up.
    """
    near = near_constant_channels(std, rms, names)
    return np.array([sd if n not in near else (r if r > 0 else 1.0) for n, sd, r in zip(names, std, rms)]), near


def hankel_r_factor(trajectories: Iterable[tuple[np.ndarray, np.ndarray]], layout: FitLayout, scale: np.ndarray,
                    block_columns: int = 8192, R: np.ndarray | None = None) -> np.ndarray | None:
    """R factor (<= width, width) of the data rows of X over the trajectories' Hankel columns of the
    channels divided by ``scale`` (each trajectory its own columns; shorter than Tini+Tf: none),
    accumulated onto ``R``; None if there is no column.

    The map step of a fit: R factors of disjoint sets of columns combine with :func:`stack_r_factors`.
    Memory: one block, ~ block_columns * width * 8 bytes (times a few for copies and the QR).
    """
    for blk in _hankel_blocks(trajectories, layout.depth, int(block_columns), scale):
        R = _accumulate_r(R, layout.data_rows(blk))
    return R


def stack_r_factors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The R factor of [A; B] from those of A and B (the reduce step: one QR of the stacked factors)."""
    return _accumulate_r(a, b)


def _check_options(method: str, t_ini: int, t_f: int, slack_weight: float, ridge: float) -> None:
    if method not in _METHODS:
        raise DataError(f"unknown predictor method {method!r}; choose one of {list(_METHODS)}")
    if t_ini < 1 or t_f < 1:
        raise DataError(f"horizons must be >= 1; got Tini={t_ini}, Tf={t_f}")
    if not (np.isfinite(slack_weight) and slack_weight > 0):
        raise DataError(f"slack_weight must be a positive number; got {slack_weight}")
    if not (np.isfinite(ridge) and ridge >= 0):
        raise DataError(f"ridge must be >= 0; got {ridge}")


def _check_columns(layout: FitLayout, cols: int, lengths: Sequence[int]) -> None:
    m, L = layout.m, layout.depth
    if cols < m * L:
        need = min_samples(layout.t_ini, layout.t_f, m)
        raise DataError(
            f"need at least {need} samples for Tini={layout.t_ini}, Tf={layout.t_f}, m={m}; got {max(lengths)}"
            + (f" in the longest of {len(lengths)} trajectories ({cols} Hankel columns in all, need {m * L})"
               if len(lengths) > 1 else "")
            + ". Record longer data or shorten the horizons."
        )


def fit_predictor(
    dataset: IODataset,
    t_ini: int,
    t_f: int,
    method: str = "pem",
    *,
    slack_weight: float = 1.0,
    ridge: float = 0.0,
    rcond: float = 1e-10,
    block_columns: int = 8192,
    streaming: bool = True,
    check_excitation: bool = True,
) -> Predictor:
    """Fit a multi-step predictor from a dataset (mosaic Hankel over its trajectories).

    The fit runs on channels scaled to unit standard deviation and G is rescaled back (predictions do not
    depend on the units of u or y).

    Args:
        dataset: the IO data; each trajectory contributes its own Hankel columns.
        t_ini, t_f: past and future horizon (samples).
        method: ``"pem"`` (paper, DDPC-Flying) or ``"lsq"`` (subspace predictive control).
        slack_weight: rho in min ||g||^2 + rho ||sigma||^2, sigma in std-scaled output units
            (``pem`` only; 1 = the paper).
        ridge: relative Tikhonov weight: the fit minimises ||G Z - T||^2 + lam ||G||^2 (scaled
            data) with lam = ridge * trace(Z Z^T) / rows(Z), the mean eigenvalue of the data Gram
            matrix; 0 = none. Unitless, independent of the amount of data.
        rcond: relative singular-value cutoff of the pseudo-inverse (rank decision, scaled data).
        block_columns: Hankel columns per streamed block (memory ~ block * rows * 8 bytes).
        streaming: False forms the whole Hankel and uses numpy's pinv (reference path).
        check_excitation: raise ExcitationError when the inputs are not PE of order Tini+Tf
            (near-constant input channels included).
    """
    t_ini, t_f = int(t_ini), int(t_f)
    _check_options(method, t_ini, t_f, slack_weight, ridge)
    layout = FitLayout(dataset.m, dataset.p, t_ini, t_f, method)
    cols = dataset.columns(layout.depth)
    _check_columns(layout, cols, dataset.lengths)
    rms, std = channel_stats([np.hstack(t) for t in dataset.trajectories()])
    if streaming:
        scale, _ = channel_scale(rms, std, dataset.input_names + dataset.output_names)
        R = hankel_r_factor(dataset.trajectories(), layout, scale, block_columns)
        return predictor_from_r(R, layout, cols, rms, std, dataset.dt, dataset.input_names, dataset.output_names,
                                slack_weight=slack_weight, ridge=ridge, rcond=rcond,
                                check_excitation=check_excitation)
    return _predictor(layout, _fit_unstreamed(dataset, layout, slack_weight, ridge, rcond, rms, std), cols, rms,
                      std, dataset.dt, dataset.input_names, dataset.output_names, check_excitation)


def predictor_from_r(R: np.ndarray, layout: FitLayout, cols: int, rms: np.ndarray, std: np.ndarray, dt: float,
                     input_names: tuple[str, ...], output_names: tuple[str, ...], *, slack_weight: float = 1.0,
                     ridge: float = 0.0, rcond: float = 1e-10, check_excitation: bool = True) -> Predictor:
    """The predictor from the data-only R factor of all ``cols`` Hankel columns of the channels
    divided by ``channel_scale(rms, std, names)`` (what :func:`fit_predictor` computes after its
    map; here for an R reduced elsewhere, e.g. over many files). rms, std: (m+p,) over all samples."""
    _check_options(layout.method, layout.t_ini, layout.t_f, slack_weight, ridge)
    _check_columns(layout, cols, [cols + layout.depth - 1])
    fitted = _solve_r(R, layout, slack_weight, ridge, rcond)
    fitted["R"] = R  # the fit's sufficient statistic (data rows only), shipped with generated solvers
    return _predictor(layout, fitted, cols, rms, std, dt, input_names, output_names, check_excitation)


def _extra_rows(layout: FitLayout, slack_weight: float, lam: float) -> list[np.ndarray]:
    """Rows of X = [Z^T | target^T] for the slack columns of M (pem) and for the ridge."""
    r, q_y, width = layout.r, layout.q_y, layout.width
    n_up, n_yp = layout.m * layout.t_ini, layout.p * layout.t_ini
    extra = []
    if layout.method == "pem":
        e = np.zeros((n_yp, width))
        e[:, n_up : n_up + n_yp] = np.eye(n_yp) / np.sqrt(slack_weight)
        e[:, r + q_y :] = np.eye(n_yp) / np.sqrt(slack_weight)
        extra.append(e)
    if lam > 0:
        e = np.zeros((r, width))
        e[:, :r] = np.eye(r) * np.sqrt(lam)
        extra.append(e)
    return extra


def _solve_r(R: np.ndarray, layout: FitLayout, slack_weight: float, ridge: float, rcond: float) -> dict:
    """Data-only R factor -> G (q_y + q_s, r) on the scaled data, the singular values s of Z (and
    which are kept), the singular values su of the u rows (PE), the effective ridge lam."""
    r = layout.r
    su = np.linalg.svd(R[:r, layout.u_rows], compute_uv=False)  # PE from the data-only factor
    lam = ridge * float(np.sum(R[:, :r] ** 2)) / r  # ||Z||_F^2 = ||R[:, :r]||_F^2
    for e in _extra_rows(layout, slack_weight, lam):
        R = _accumulate_r(R, e)
    R11, R12 = R[:r, :r], R[:r, r:]
    U, s, Vt = np.linalg.svd(R11, full_matrices=False)
    keep = s > rcond * s[0]
    # G^T = pinv(R11) R12 (min-norm least squares of M^T G^T = T^T)
    G = ((Vt[keep].T / s[keep]) @ (U[:, keep].T @ R12)).T
    return {"G": G, "s": s, "keep": keep, "su": su, "lam": lam, "slack_weight": slack_weight, "ridge": ridge,
            "rcond": rcond}


def _fit_unstreamed(dataset: IODataset, layout: FitLayout, slack_weight: float, ridge: float, rcond: float,
                    rms: np.ndarray, std: np.ndarray) -> dict:
    """The reference path: the whole scaled Hankel in memory and numpy's pinv (same outputs as _solve_r)."""
    r = layout.r
    scale, _ = channel_scale(rms, std, dataset.input_names + dataset.output_names)
    Xd = np.vstack([layout.data_rows(b) for b in _hankel_blocks(dataset.trajectories(), layout.depth, 10**9, scale)])
    su = np.linalg.svd(Xd[:, layout.u_rows], compute_uv=False)
    lam = ridge * float(np.sum(Xd[:, :r] ** 2)) / r
    X = np.vstack([Xd] + _extra_rows(layout, slack_weight, lam))
    Z, Tg = X[:, :r].T, X[:, r:].T
    G = Tg @ np.linalg.pinv(Z, rcond=rcond)
    s = np.linalg.svd(Z, compute_uv=False)
    return {"G": G, "s": s, "keep": s > rcond * s[0], "su": su, "lam": lam, "slack_weight": slack_weight,
            "ridge": ridge, "rcond": rcond, "R": np.linalg.qr(Xd, mode="r")}


def _predictor(layout: FitLayout, fitted: dict, cols: int, rms: np.ndarray, std: np.ndarray, dt: float,
               input_names: tuple[str, ...], output_names: tuple[str, ...], check_excitation: bool) -> Predictor:
    """G on the scaled data -> the Predictor in the data's units (PE report checked)."""
    m, p, t_ini, t_f = layout.m, layout.p, layout.t_ini, layout.t_f
    scale, near = channel_scale(rms, std, input_names + output_names)
    pe = _pe_report(fitted["su"], layout.depth, m, cols, near, input_names, output_names, std)
    if check_excitation and not pe.ok:
        raise ExcitationError(
            f"inputs are not persistently exciting enough for Tini={t_ini}, Tf={t_f}: {pe.summary()}. "
            "Excite the references more (e.g. add a PRBS) or record longer data."
        )
    Gy, Gs = _unscale(fitted["G"], scale, m, p, t_ini, t_f, layout.method)
    nw = (m + p) * t_ini
    opts = {"slack_weight": float(fitted["slack_weight"]), "ridge": float(fitted["ridge"]),
            "rcond": float(fitted["rcond"]), "ridge_effective": float(fitted["lam"]), "channel_scale": scale.tolist(),
            "_pe_report": pe, "_r_factor": fitted["R"]}
    return Predictor(
        t_ini=t_ini, t_f=t_f, m=m, p=p, method=layout.method,
        Gy_w=np.ascontiguousarray(Gy[:, :nw]),
        Gy_u=np.ascontiguousarray(Gy[:, nw:]),
        Gs_w=np.ascontiguousarray(Gs[:, :nw]),
        Gs_u=np.ascontiguousarray(Gs[:, nw:]),
        singular_values=fitted["s"],
        rank=int(np.sum(fitted["keep"])),
        n_columns=cols,
        dt=dt,
        input_names=input_names,
        output_names=output_names,
        options=opts,
    )


def _pe_report(su: np.ndarray, L: int, m: int, cols: int, near: tuple[str, ...], input_names: tuple[str, ...],
               output_names: tuple[str, ...], std: np.ndarray) -> PEReport:
    """PE of order L from the singular values su of the (scaled) input rows, with near-constant channels named."""
    tol_u = max(cols, m * L) * np.finfo(float).eps * su[0] * 10
    return PEReport(L, int(np.sum(su > tol_u)), m * L, su, float(tol_u),
                    float(su[0] / su[-1]) if su[-1] > 0 else float("inf"), cols,
                    near_constant_inputs=tuple(n for n in near if n in input_names),
                    near_constant_outputs=tuple(n for n in near if n in output_names),
                    channel_std={n: float(v) for n, v in zip(input_names + output_names, std)})


def _unscale(G: np.ndarray, scale: np.ndarray, m: int, p: int, t_ini: int, t_f: int,
             method: str) -> tuple[np.ndarray, np.ndarray]:
    """(Gy (p*Tf, r), Gs (p*Tini, r)) in the data's units from G fitted on channels divided by ``scale`` (m+p,)."""
    su_, sy_ = scale[:m], scale[m:]
    s_in = np.concatenate([np.tile(su_, t_ini), np.tile(sy_, t_ini), np.tile(su_, t_f)])
    s_out = np.concatenate([np.tile(sy_, t_f), np.tile(sy_, t_ini) if method == "pem" else np.zeros(0)])
    G = (s_out[:, None] * G) / s_in[None, :]
    q_y = p * t_f
    return G[:q_y], (G[q_y:] if method == "pem" else np.zeros((p * t_ini, s_in.size)))
