"""Emit the online predictor update of an adaptive solver (``<name>_adapt.{h,c}``, issue 30).

Only when adaptation is enabled: the non-adaptive folder is unchanged. The C is the twin of
:class:`ddpc_codegen.design.adapter.Adapter` (sizes fixed here, state in a caller-owned workspace):
the shipped R factor, the channel scale and the QP model (:func:`ddpc_codegen.design.adaptation.qp_model`: the
maps from G to the solver's Hessian, linear-term map, output rows and gain) are its constant data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ddpc_codegen.codegen.render import c_float, render_ctx
from ddpc_codegen.codegen.tables import Tables, write_tables
from ddpc_codegen.design.adaptation import adapter
from ddpc_codegen.design.adapter import OFFSET_MARGIN
from ddpc_codegen.values.adapt import AdaptSettings

__all__ = ["emit_adapt", "context"]

RES_BLOCK = 4  # window columns per pass of the C residuals over G (G read once for them)
FACTOR_BLOCK = 4  # vectors per pass of a C factor update (U loaded and stored once for them)


def _pairs(M: np.ndarray) -> tuple[np.ndarray, list[int], int]:
    """(values, [i0, j0, i1, j1, ...], count) of the nonzeros of M, row by row (C has no empty arrays:
    a zero matrix gives one unread pair)."""
    i, j = np.nonzero(M)
    idx = [v for pair in zip(i.tolist(), j.tolist()) for v in pair] or [0, 0]
    return M[i, j], idx, int(i.size)


def context(ad, problem, name: str, banner: str) -> dict:
    """Template values of the update of ``ad`` (an :class:`~ddpc_codegen.design.adapter.Adapter` with a
    QP model) for the solver of ``problem``."""
    lay, s, qp = ad.layout, ad.settings, ad.qp
    w, q, nu = lay.width, lay.q_y + lay.q_s, lay.u_rows.size
    n_z, n_g1, n_th = problem.n_z, max(1, problem.n_g), problem.n_theta
    n_o, n_wu = qp.Lm.shape[0], qp.Rm.shape[1]
    qp_words = 2 * (n_z * n_z + 2 * n_g1 * n_z + 2 * n_z * n_th + n_g1 * n_th) + n_o * (lay.r + n_wu + 2 * n_z)
    # the held-out window, the period's columns a re-solve folds in, and two more periods of slack (a re-solve still
    # running when the next period comes) before a full queue refuses columns
    ring = s.window + 3 * s.period_ticks
    ws_words = 2 * w * w + w + lay.r + 1 + 3 * q * lay.r + 2 * ring * w + (3 + 2 * FACTOR_BLOCK) * w + nu * nu + qp_words + n_z * n_z + n_z * n_th + RES_BLOCK * lay.q_y + 3 * qp.n_y
    sparse = {k: _pairs(M) for k, M in (("lm", qp.Lm), ("rm", qp.Rm), ("c0", qp.C0), ("b", qp.B), ("wd", qp.Wd))}
    return {"banner": banner, "name": name, "NAME": name.upper(), "m": lay.m, "p": lay.p, "t_ini": lay.t_ini,
            "t_f": lay.t_f, "depth": lay.depth, "width": w, "r": lay.r, "q": q, "q_y": lay.q_y, "q_s": lay.q_s,
            "window": s.window, "forgetting": c_float(s.forgetting), "period_ticks": s.period_ticks,
            "w2": w * w, "qr": q * lay.r, "ring": ring * w, "ring_cols": ring, "res_block": RES_BLOCK, "nb": FACTOR_BLOCK, "rb": RES_BLOCK * lay.q_y, "nu2": nu * nu, "n_urows": nu,
            "ws_kib": int(ws_words * 8 / 1024) + 1, "slack_weight": c_float(ad.slack_weight), "ridge": c_float(ad.ridge),
            "rcond": c_float(ad.rcond), "max_change": c_float(s.max_change), "min_excitation": c_float(s.min_excitation),
            "min_improvement": c_float(s.min_improvement),
            "n_z": n_z, "n_g": problem.n_g, "n_g1": n_g1, "n_theta": n_th, "n_w": problem.n_w, "n_y": qp.n_y,
            "n_o": n_o, "n_wu": n_wu, "n_gy": int(qp.y_rows.size),
            "y_rows": qp.y_rows.tolist() or [0],
            "check_gain": int(qp.S0 is not None), "max_gain_change": c_float(min(qp.max_gain_change, 1e300)),
            "offset": int(s.offset), "max_offset": ad.max_offset.tolist(), "offset_margin": c_float(OFFSET_MARGIN),
            "p_data": problem.config.p, "t_ini_data": problem.config.t_ini,
            "win_idx": lay.row_order().tolist(),
            "nz2": n_z * n_z, "ngz": n_g1 * n_z, "nzth": n_z * n_th, "ngth": n_g1 * n_th,
            "n_lg": n_o * lay.r, "n_gd": n_o * n_wu, "n_gu": n_o * n_z,
            **{f"{k}_ij": v[1] for k, v in sparse.items()}, **{f"n_{k}": v[2] for k, v in sparse.items()},
            "_sparse": {k: v[0] for k, v in sparse.items()}}


def _padded(R: np.ndarray, width: int) -> np.ndarray:
    """R (k <= width rows) with zero rows below: square."""
    full = np.zeros((width, width))
    full[: R.shape[0]] = R
    return full


def data_arrays(ad, ctx: dict) -> Tables:
    """Constant arrays of the update (suffix -> (values, comment))."""
    lay, qp = ad.layout, ad.qp
    sp = ctx["_sparse"]
    return {
        "R0": (_padded(ad.R0, lay.width),
                     f"shipped R factor of the scaled fit data (no ridge rows), row-major {lay.width} x {lay.width}"),
        "SCALE": (ad.scale, "channel scale (u then y) of the fit"),
        "LM": (sp["lm"], "nonzeros of Lm: data-unit predictor rows of the fit's targets"),
        "RM": (sp["rm"], "nonzeros of Rm: fit regressors -> data-unit [w; u] columns"),
        "C0": (sp["c0"], "nonzeros of C0: the constant part of the data-unit predictor"),
        "B": (sp["b"], "nonzeros of the knot basis u = B z"),
        "WD": (sp["wd"], "nonzeros of Wd: the cost's weight on the predicted [y; sigma]"),
        "PFIX": (qp.P_fixed, "the part of P independent of G, row-major n_z x n_z"),
        "FFIX": (qp.F_fixed.T, "the part of F_q independent of G, column-major n_z x n_theta"),
        "S0": (qp.S0 if qp.S0 is not None else np.zeros((lay.p, lay.m)),
                     "shipped steady-state gain (outputs per constant reference), row-major p x m"),
    }


def emit_adapt(problem, settings: AdaptSettings, out_dir: Path, name: str, banner: str) -> list[Path]:
    """Write ``<name>_adapt.{h,c}`` (the API: ring, re-solve, verification, swap), ``<name>_adapt_factor.c`` (R
    and G from it), ``<name>_adapt_rebuild.c`` (the QP data of a G), ``<name>_adapt_impl.h`` (what they share) and
    ``<name>_adapt_data.{h,c}`` into ``out_dir``; returns the compilation units."""
    ad = adapter(problem, settings)
    ctx = context(ad, problem, name, banner)
    data_unit = write_tables(data_arrays(ad, ctx), out_dir, banner, name, f"{name}_adapt_data")
    for stem in ("adapt.h", "adapt_impl.h", "adapt.c", "adapt_factor.c", "adapt_rebuild.c"):
        (out_dir / f"{name}_{stem}").write_text(render_ctx(f"{stem}.in", ctx))
    return [out_dir / f"{name}_{stem}.c" for stem in ("adapt", "adapt_factor", "adapt_rebuild")] + [data_unit]

