"""Emit the online predictor update of an adaptive solver (``<name>_adapt.{h,c}``, issue 30).

Only when adaptation is enabled: the non-adaptive folder is unchanged. The C is the twin of
:class:`ddpc_codegen.runtime.adaptation.Adapter` (sizes fixed here, state in a caller-owned workspace):
the shipped R factor, the channel scale and the QP Hessian model (:func:`ddpc_codegen.design.adaptation.hessian_model`)
are its constant data.
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
from pathlib import Path

import numpy as np

from ddpc_codegen.codegen.render import placeholders, render
from ddpc_codegen.design.adaptation import adapter
from ddpc_codegen.runtime.adaptation import AdaptSettings

__all__ = ["emit_adapt", "cdef_text", "context", "compile_alone"]


def _c(x: float) -> str:
    r = repr(float(x))
    return r if ("." in r or "e" in r) else r + ".0"


def context(ad, name: str, banner: str) -> dict:
    """Template values of the update of ``ad`` (an :class:`~ddpc_codegen.runtime.adaptation.Adapter`)."""
    lay, s = ad.layout, ad.settings
    w, q, nu, nf = lay.width, lay.q_y + lay.q_s, lay.u_rows.size, lay.m * lay.t_f
    ws_words = 2 * w * w + 2 * q * lay.r + s.window * w + w + nu * nu + nf * nf
    return {"banner": banner, "name": name, "NAME": name.upper(), "m": lay.m, "p": lay.p, "t_ini": lay.t_ini,
            "t_f": lay.t_f, "depth": lay.depth, "width": w, "r": lay.r, "q": q, "q_y": lay.q_y, "q_s": lay.q_s,
            "window": s.window, "forgetting": _c(s.forgetting), "period_ticks": s.period_ticks,
            "w2": w * w, "qr": q * lay.r, "ring": s.window * w, "nu2": nu * nu, "nf2": nf * nf, "n_urows": nu,
            "ws_kib": int(ws_words * 8 / 1024) + 1, "slack_weight": _c(ad.slack_weight), "ridge": _c(ad.ridge),
            "rcond": _c(ad.rcond), "max_change": _c(s.max_change), "min_excitation": _c(s.min_excitation),
            "check_hessian": int(ad.hessian is not None)}


def data_arrays(ad) -> dict[str, tuple[np.ndarray, str]]:
    """Constant arrays of the update (suffix -> (values, comment))."""
    lay = ad.layout
    q, nf = lay.q_y + lay.q_s, lay.m * lay.t_f
    hm = ad.hessian
    return {
        "ADAPT_R0": (ad.R, f"shipped R factor of the scaled fit data, row-major {lay.width} x {lay.width}"),
        "ADAPT_SCALE": (ad.scale, "channel scale (u then y) of the fit"),
        "ADAPT_WH": (hm.W if hm is not None else np.zeros((q, q)), f"Hessian model W, row-major {q} x {q}"),
        "ADAPT_PFIX": (hm.P_fixed if hm is not None else np.zeros((nf, nf)), f"Hessian model P_fixed, {nf} x {nf}"),
    }


def emit_adapt(problem, settings: AdaptSettings, out_dir: Path, name: str, banner: str, data_files) -> list[Path]:
    """Write ``<name>_adapt.{h,c}`` and ``<name>_adapt_data.{h,c}`` into ``out_dir``; returns the compilation
    units. ``data_files(arrays, ctx, stem)`` renders constant arrays (emit's helper)."""
    ad = adapter(problem, settings)
    ctx = context(ad, name, banner)
    h, c = data_files(data_arrays(ad), ctx, f"{name}_adapt_data")
    (out_dir / f"{name}_adapt_data.h").write_text(h)
    (out_dir / f"{name}_adapt_data.c").write_text(c)
    for tpl, fname in (("adapt.h.in", "adapt.h"), ("adapt.c.in", "adapt.c")):
        (out_dir / f"{name}_{fname}").write_text(render(tpl, **{k: ctx[k] for k in placeholders(tpl)}))
    return [out_dir / f"{name}_adapt.c", out_dir / f"{name}_adapt_data.c"]


def cdef_text(name: str) -> str:
    """The update's C API as cffi declares it."""
    return f"""
typedef struct {{ int updates; int skipped; int resolves; int accepted; int swaps; int clipped; int rejected[6];
                 double error_current; double error_candidate; double excitation; }} {name}_adapt_counts;
typedef struct {{ double R[...]; double Ra[...]; double G[...]; double Gc[...]; double ring[...]; double x[...];
                 double Rx[...]; double H[...]; int head; int n_ring; int pending; {name}_adapt_counts counts; ...; }}
        {name}_adapt_workspace;
int {name}_adapt_init({name}_adapt_workspace *ws);
int {name}_adapt_push({name}_adapt_workspace *ws, const double *window);
int {name}_adapt_resolve({name}_adapt_workspace *ws);
int {name}_adapt_swap({name}_adapt_workspace *ws);
"""


def compile_alone(problem, settings: AdaptSettings, folder: Path, name: str):
    """Emit and compile the update on its own (cffi, the package's portable flags) for tests and the
    benchmark; returns the module's (ffi, lib). A solver's own extension carries it via ``generate(adapt=)``."""
    import cffi

    from ddpc_codegen.codegen.build import PORTABLE_FLAGS
    from ddpc_codegen.codegen.emit import BANNER, data_files

    folder = Path(folder)
    units = emit_adapt(problem, settings, folder, name, BANNER, data_files)
    ffi = cffi.FFI()
    ffi.cdef(cdef_text(name))
    module = f"_adapt_alone_{name}"
    ffi.set_source(module, f'#include "{name}_adapt.h"\n', sources=[str(u) for u in units],
                   include_dirs=[str(folder)], libraries=["m"], extra_compile_args=PORTABLE_FLAGS)
    built = ffi.compile(tmpdir=tempfile.mkdtemp(dir=folder))
    spec = importlib.util.spec_from_file_location(module, built)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[module] = mod
    spec.loader.exec_module(mod)
    return mod.ffi, mod.lib
