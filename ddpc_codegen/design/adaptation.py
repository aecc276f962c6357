"""Design side of online predictor updates: what a generated solver ships for them.

The runtime update itself (Givens rank-one update of R, re-solve of G, verification) lives in
:mod:`ddpc_codegen.runtime.adaptation` (numpy, the reference of the generated C); here:

* :func:`fit_statistic` -- the fit's sufficient statistic of a predictor: its data-only R factor (square,
  width x width, zero rows padded) with the layout, scale and fit options it came from;
* :func:`write_fit_statistic` -- ``<name>_fit_r.npy`` beside the manifest and the manifest's
  ``fit_statistic`` entry (shape, scale, forgetting defaults);
* :func:`adapt_settings` -- the ``[adapt]`` table of a steering config, checked;
* :func:`hessian_model` -- the steering QP's Hessian as a function of the re-solved G (for the check);
* :func:`adapter` -- the interpreted :class:`~ddpc_codegen.runtime.adaptation.Adapter` of a problem.

For the incremental (offset-free) predictor the statistic is that of the increment fit (Tini - 1 past
increments): the update feeds it windows of increments.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np

from ddpc_codegen.design.predictor import Predictor
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.runtime.adaptation import AdaptLayout, Adapter, AdaptSettings, HessianModel

__all__ = ["fit_statistic", "fit_layout", "write_fit_statistic", "ship_fit_statistic", "adapt_settings", "hessian_model", "adapter",
           "FIT_FILE"]

FIT_FILE = "{name}_fit_r.npy"


def fit_layout(predictor: Predictor) -> AdaptLayout:
    """The layout of the fit the predictor came from (the increment fit's for ``form = "incremental"``)."""
    inc = predictor.options.get("form") == "incremental"
    method = "lsq" if inc else predictor.method
    return AdaptLayout(predictor.m, predictor.p, predictor.t_ini - (1 if inc else 0), predictor.t_f, method)


def fit_statistic(predictor: Predictor) -> tuple[np.ndarray, AdaptLayout]:
    """(R (width, width) upper triangular, its layout): the data-only R factor of the scaled Hankel data
    the predictor was fitted on (rows beyond the number of columns are zero).

    Raises:
        DataError: the predictor carries no R factor (built by hand rather than fitted from data).
    """
    R = predictor.options.get("_r_factor")
    if R is None:
        raise DataError("this predictor carries no R factor of its data (not fitted by fit_predictor / "
                        "predictor_from_r): online adaptation needs the fit's sufficient statistic")
    layout = fit_layout(predictor)
    w = layout.width
    if R.shape[1] != w or R.shape[0] > w:
        raise DataError(f"the predictor's R factor has shape {R.shape}; its layout needs ({w}, {w}) at most")
    full = np.zeros((w, w))
    full[: R.shape[0]] = np.triu(R)
    return full, layout


def write_fit_statistic(predictor: Predictor, out_dir: Path, name: str, settings: AdaptSettings) -> dict:
    """Write ``<name>_fit_r.npy`` (float64 R, C order) into ``out_dir``; returns the manifest entry."""
    R, lay = fit_statistic(predictor)
    path = Path(out_dir) / FIT_FILE.format(name=name)
    np.save(path, np.ascontiguousarray(R), allow_pickle=False)
    o = predictor.options
    return {"file": path.name, "sha256": hashlib.sha256(path.read_bytes()).hexdigest(), "shape": list(R.shape),
            "layout": {"m": lay.m, "p": lay.p, "t_ini": lay.t_ini, "t_f": lay.t_f, "method": lay.method,
                       "r": lay.r, "q_y": lay.q_y, "q_s": lay.q_s,
                       "rows": "[Up; Yp; Uf; Yf; slack] of the scaled Hankel columns, time-major, u then y"},
            "signal": "increments" if o.get("form") == "incremental" else "samples",
            "channel_scale": [float(v) for v in o["channel_scale"]], "n_columns": int(predictor.n_columns),
            "slack_weight": float(o["slack_weight"]), "ridge": float(o["ridge"]), "rcond": float(o["rcond"]),
            "adapt": dataclasses.asdict(settings)}


def ship_fit_statistic(predictor: Predictor, out_dir: Path, name: str,
                       settings: AdaptSettings | None = None) -> dict | None:
    """What the generator calls: :func:`write_fit_statistic` for a fitted predictor (default settings:
    the ``[adapt]`` defaults), None for one without an R factor (built from matrices, nothing to ship)."""
    if predictor.options.get("_r_factor") is None:
        return None
    return write_fit_statistic(predictor, out_dir, name, settings or AdaptSettings())


_FLOAT_KEYS = {"forgetting": (0.0, 1.0, True), "dither": (0.0, np.inf, False), "max_change": (0.0, np.inf, True),
               "min_excitation": (0.0, 1.0, False)}
_INT_KEYS = ("period_ticks", "window")


def adapt_settings(table: dict | None, src: str = "config") -> AdaptSettings:
    """The ``[adapt]`` table (enabled, forgetting, period_ticks, dither, window, max_change,
    min_excitation) -> :class:`AdaptSettings`; None or {} gives the defaults (disabled).

    Raises:
        ConfigError: unknown key or a value out of range (the message names both).
    """
    table = dict(table or {})
    known = {f.name for f in dataclasses.fields(AdaptSettings)}
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(f"{src}: [adapt] unknown key(s) {unknown}; allowed: {sorted(known)}")
    if "enabled" in table and not isinstance(table["enabled"], bool):
        raise ConfigError(f"{src}: [adapt] enabled must be true or false; got {table['enabled']!r}")
    for key, (lo, hi, lo_open) in _FLOAT_KEYS.items():
        if key in table:
            v = table[key]
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v <= hi
            if not ok or (v <= lo if lo_open else v < lo):
                opening = "(" if lo_open else "["
                rng = f"in {opening}{lo:g}, {hi:g}]" if np.isfinite(hi) else f"{'>' if lo_open else '>='} {lo:g}"
                raise ConfigError(f"{src}: [adapt] {key} must be {rng}; got {v!r}")
            table[key] = float(v)
    for key in _INT_KEYS:
        if key in table and (not isinstance(table[key], int) or isinstance(table[key], bool) or table[key] < 1):
            raise ConfigError(f"{src}: [adapt] {key} must be an integer >= 1; got {table[key]!r}")
    return AdaptSettings(**table)


def _fit_congruence(predictor: Predictor, layout: AdaptLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T (n_u, n_u), Sy (q_y,), L (q_y, q_y)): data-unit future inputs u = T v map the fit's scaled future
    inputs v, outputs y = L (Sy * fitted targets) (L accumulates increments, identity for samples)."""
    m, p, tf = predictor.m, predictor.p, predictor.t_f
    scale = np.asarray(predictor.options["channel_scale"], float)
    Du = np.diag(np.tile(scale[:m], tf))
    Sy = np.tile(scale[m:], tf)
    if layout.t_ini == predictor.t_ini:
        return Du, Sy, np.eye(p * tf)
    K = np.kron(np.eye(tf) - np.eye(tf, k=-1), np.eye(m))  # u_f -> du_f (given u_ini[-1])
    return np.linalg.solve(K, Du), Sy, np.kron(np.tril(np.ones((tf, tf))), np.eye(p))


def hessian_model(problem) -> HessianModel:
    """The steering QP's Hessian P (n_u x n_u, a :class:`~ddpc_codegen.design.problem.SteeringProblem`) as
    T^T P T = Gf^T W Gf + P_fixed of the fit-domain G, with P_fixed = T^T (P - prediction part) T fixed."""
    pr, c = problem.predictor, problem.config
    P = np.asarray(problem.P, float)
    if P.shape != (pr.Gy_u.shape[1],) * 2:
        raise DataError(f"the QP Hessian has shape {P.shape}, not the predictor's future inputs "
                        f"{pr.Gy_u.shape[1]}: the Hessian check knows the unblocked QP only")
    lay = fit_layout(pr)
    T, Sy, L = _fit_congruence(pr, lay)
    Qb = np.kron(np.eye(c.t_f), c.Q)
    pred = 2.0 * (pr.Gy_u.T @ Qb @ pr.Gy_u + c.lambda_sigma * (pr.Gs_u.T @ pr.Gs_u))  # CasADi's hessian of J
    W = np.zeros((lay.q_y + lay.q_s,) * 2)
    W[: lay.q_y, : lay.q_y] = 2.0 * (Sy[:, None] * (L.T @ Qb @ L) * Sy[None, :])
    if lay.q_s:
        Ss = np.tile(np.asarray(pr.options["channel_scale"], float)[c.m:], c.t_ini)
        W[lay.q_y :, lay.q_y :] = 2.0 * c.lambda_sigma * np.diag(Ss * Ss)
    return HessianModel(W=W, P_fixed=T.T @ (P - pred) @ T)


def adapter(problem, settings: AdaptSettings) -> Adapter:
    """The interpreted online update of a steering problem's predictor (its fit statistic, scale, options)."""
    pr = problem.predictor
    R, lay = fit_statistic(pr)
    o = pr.options
    return Adapter(lay, R, np.asarray(o["channel_scale"], float), settings, slack_weight=float(o["slack_weight"]),
                   ridge=float(o["ridge"]), rcond=float(o["rcond"]), hessian=hessian_model(problem))
