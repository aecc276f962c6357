"""Emit the generated artificial-IO completion operator of a hopping solver (``<name>_artio.{h,c}``).

The online completion of :class:`~ddpc_codegen.design.artificial_io.ArtificialIO` (``complete`` with the
online noise level fixed at generation time) as C next to the steering solver: the basis B and its Gram
matrix G = B B^T as data, the regularised least-squares fill in its dual form and, when a fill leaves
the bounds, the bounded QP solved with DAQP (compiled into every hopping artifact, whatever the steering
backend). sigma = 0 (the exact least-norm fill with a null-space elimination) is refused: the online
windows are measurements, and lambda > 0 keeps every factorisation positive definite.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ddpc_codegen.codegen import libs
from ddpc_codegen.codegen.constants import DAQP_PRIMAL_TOL, DAQP_STRUCT_WORDS
from ddpc_codegen.codegen.render import c_float, render_ctx
from ddpc_codegen.codegen.tables import Tables, write_tables
from ddpc_codegen.design.artificial_io import ArtificialIO
from ddpc_codegen.values.solve_result import BOUND_TOL
from ddpc_codegen.errors import CodegenError

__all__ = ["OnlineCompletion", "emit_artio", "manifest_entry"]


@dataclass(frozen=True)
class OnlineCompletion:
    """What the generated completion is built from.

    art: the completion operator (aerial-data basis, bounds); noise_level: the online sigma [m / rad]
    compiled in (lambda = art.n_columns * sigma^2); t_d_online, min_ascent, denoise_online, refit_residual:
    the online window's settings (recorded in the manifest for the runtime's HoppingWindow).
    """

    art: ArtificialIO
    noise_level: float
    t_d_online: int = 0
    min_ascent: int = 10
    denoise_online: bool = False
    refit_residual: float = 0.0

    @classmethod
    def from_spec(cls, art: ArtificialIO, spec) -> "OnlineCompletion":
        """From the operator and its :class:`~ddpc_codegen.design.hopping_data.ArtificialIOSpec`."""
        return cls(art, spec.noise_level_online, spec.t_d_online, spec.min_ascent, spec.denoise_online,
                   spec.refit_residual)

    @property
    def lam(self) -> float:
        """Tikhonov weight, computed exactly as ``ArtificialIO.complete`` does."""
        return self.art.n_columns * float(self.noise_level) * float(self.noise_level)

    def check(self) -> None:
        if not (np.isfinite(self.noise_level) and self.noise_level > 0 and self.lam > 0):
            raise CodegenError(
                f"the generated artificial-IO operator needs an online noise level > 0 (got noise_level_online = "
                f"{self.noise_level}): the exact least-norm fill (sigma = 0) is not generated; set "
                f"[artificial_io] noise_level_online > 0 (default 2e-3)")


def data_arrays(oc: OnlineCompletion) -> Tables:
    """Constant arrays of the completion (suffix -> (values, comment))."""
    B = np.ascontiguousarray(oc.art.basis, dtype=float)
    G = B @ B.T
    # The Cholesky factor of a leading block is the leading block of the factor: one factor of G + lambda I
    # serves every window whose first n entries are all known (the denoised windows, every tick under
    # noise), so those need no factorization at run time (O(n^2) instead of O(n^3): 5 ms at depth 66).
    chol = np.linalg.cholesky(G + oc.lam * np.eye(G.shape[0]))
    return {
        "B": (B, f"basis B, row-major {B.shape[0]} x {B.shape[1]} (H = B W^T, W orthonormal)"),
        "G": (G, f"Gram matrix G = B B^T, row-major {B.shape[0]} x {B.shape[0]}"),
        "GCHOL": (chol, f"lower Cholesky factor of G + lambda I, row-major {B.shape[0]} x {B.shape[0]}"),
        "LO": (oc.art.lo, "lower bound per sample entry [u; y] (-INFINITY: none)"),
        "HI": (oc.art.hi, "upper bound per sample entry [u; y] (INFINITY: none)"),
    }


def context(oc: OnlineCompletion, base: dict) -> dict:
    """Template values of the completion (``base``: the steering solver's context)."""
    art = oc.art
    rows, r = art.depth * art.d, art.rank
    ctx = {k: base[k] for k in ("banner", "name", "NAME", "max_iter")}
    ctx.update(depth=art.depth, rank=r, m=art.m, p=art.p, d=art.d, rows=rows, rows_sq=rows * rows, rows_sq4=rows * rows // 4 + 1,
               rank_sq=r * r, n_m=r * rows, n_vals=2 * art.d + 3, n_columns=art.n_columns,
               sigma=c_float(oc.noise_level), lam=c_float(oc.lam), feas_tol=repr(BOUND_TOL),
               daqp_version=libs.DAQP_VERSION, daqp_primal_tol=repr(DAQP_PRIMAL_TOL), daqp_words=DAQP_STRUCT_WORDS)
    ws_words = (4 * rows + 5 * rows + 2.25 * rows * rows + r + r * r + r + r * rows  # arrays of the header
                + 3 * r * rows + (r + 1) * (r + 2) // 2 + r * (r + 1) // 2 + 12 * (r + 1) + 8 * rows)
    ctx["ws_kib"] = int(ws_words * 8 / 1024) + 1
    return ctx


def emit_artio(oc: OnlineCompletion, out_dir: Path, base: dict) -> list[Path]:
    """Write ``<name>_artio.h``, ``<name>_artio.c`` and its data files; returns the compilation units."""
    oc.check()
    ctx = context(oc, base)
    name = base["name"]
    data_unit = write_tables(data_arrays(oc), out_dir, ctx["banner"], name, f"{name}_artio_data")
    (out_dir / f"{name}_artio.h").write_text(render_ctx("artio.h.in", ctx))
    (out_dir / f"{name}_artio.c").write_text(render_ctx("artio.c.in", ctx))
    return [out_dir / f"{name}_artio.c", data_unit]


def _inf_list(a) -> list:
    return [None if not np.isfinite(x) else float(x) for x in np.ravel(a)]


def manifest_entry(oc: OnlineCompletion) -> dict:
    """manifest.json ``artificial_io``: what the compiled completion is (the loader checks it against the binary)."""
    art = oc.art
    return {"depth": art.depth, "rank": art.rank, "m": art.m, "p": art.p, "n_columns": art.n_columns,
            "noise_level": float(oc.noise_level), "lambda": oc.lam, "feas_tol": BOUND_TOL,
            "lo": _inf_list(art.lo), "hi": _inf_list(art.hi), "t_d_online": int(oc.t_d_online),
            "min_ascent": int(oc.min_ascent), "denoise_online": bool(oc.denoise_online),
            "refit_residual": float(oc.refit_residual), "rcond": art.rcond}

