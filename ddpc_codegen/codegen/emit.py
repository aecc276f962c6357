"""Emit the generated folder of a steering solver: every file rendered from ``templates/``.

This module only orchestrates: it computes what the templates see -- one context dict (:func:`context`),
written next to the sources as ``codegen_context.json`` so that a reader can inspect exactly what was
rendered -- and which files to render; every line of C (and of the build files) is in the templates.
Emitting twice from the same inputs gives byte-identical files: floats are written with ``repr`` (shortest
round-trip), and the one timestamp OSQP's generator writes is normalised away.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.sparse as sp

from ddpc_codegen.codegen import libs
from ddpc_codegen.codegen.adapt import emit_adapt
from ddpc_codegen.codegen.artio import emit_artio
from ddpc_codegen.codegen.build import include_dirs_of
from ddpc_codegen.codegen.constants import (BACKENDS, BANNER, DAQP_PRIMAL_TOL, DAQP_STRUCT_WORDS, DEFAULTS,
                                            FEAS_TOL, MAX_REFINE, VECTOR_TOL, VECTORS_FILE)
from ddpc_codegen.codegen.render import c_float, render_ctx
from ddpc_codegen.codegen.tables import Tables, write_tables
from ddpc_codegen.codegen.tuning import osqp_embedded_solver
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.errors import CodegenError

# the constants are re-exported: callers read them from here
__all__ = ["BACKENDS", "BANNER", "DEFAULTS", "FEAS_TOL", "VECTOR_TOL", "VECTORS_FILE", "c_float", "check_name",
           "context", "data_arrays", "emit_sources"]

# single "_" between letters/digits only: CasADi reserves names with "__" (and "<name>_" + "_x" makes one)
_NAME_RE = re.compile(r"[A-Za-z](?:_?[A-Za-z0-9])*")


def check_name(name: str) -> str:
    """The solver name becomes a C identifier prefix and a Python module name."""
    if not isinstance(name, str) or len(name) > 41 or not _NAME_RE.fullmatch(name):
        raise CodegenError(
            f"solver name {name!r} must start with a letter, contain only letters, digits and single '_' "
            "between them, not end in '_', and have at most 41 characters "
            "(it becomes a C identifier prefix and a Python module name)"
        )
    return name


def _sparse_dm(a: np.ndarray) -> ca.DM:
    """DM with structural zeros dropped, so generated products skip them."""
    csc = sp.csc_matrix(np.where(a == 0.0, 0.0, a))
    csc.eliminate_zeros()
    csc.sort_indices()
    sparsity = ca.Sparsity(csc.shape[0], csc.shape[1], csc.indptr.tolist(), csc.indices.tolist())
    return ca.DM(sparsity, csc.data.tolist())


def data_arrays(problem: SteeringProblem, adaptive: bool = False) -> Tables:
    """Constant arrays (suffix -> (values, comment)); layouts as the C code reads them. ``adaptive``: also the
    parameter maps as matrices (an adaptive solver applies rebuilt ones instead of CasADi's baked C)."""
    pr, c = problem.predictor, problem.config
    width = problem.ug0 - problem.lg0
    bounds = np.concatenate([c.u_min, c.u_max, c.y_min, c.y_max, c.du_max]).astype(float)
    knots = {} if problem.B is None else {"B": (problem.B.T, "knot basis u = B z, column-major n_u x n_z")}
    return {
        **knots,
        "K": (problem.K.T, "unconstrained gain, column-major n_z x n_theta"),
        "K0": (problem.k0, "unconstrained offset"),
        "LB_U": (problem.lb_u, "simple bounds on z (u at the knots)"),
        "UB_U": (problem.ub_u, "simple bounds on z (u at the knots)"),
        "A_G": (problem.A_g, "general rows, row-major"),
        "A_G_CM": (problem.A_g.T, "general rows, column-major"),
        "WIDTH_G": (width, "u_g - l_g of each general row (independent of theta)"),
        "P": (problem.P, "Hessian, row-major"),
        "P_CHOL": (np.linalg.cholesky(problem.P), "lower Cholesky factor of P, row-major"),
        "GY": (np.hstack([pr.Gy_w, pr.Gy_u]).T, "y predictor [Gy_w Gy_u], column-major"),
        "GS": (np.hstack([pr.Gs_w, pr.Gs_u]).T, "slack predictor [Gs_w Gs_u], column-major"),
        "BOUNDS": (bounds, "u_min, u_max, y_min, y_max, du_max per channel"),
        **({"F_Q_CM": (problem.F_q.T, "linear-term map q = F_q theta + q0, column-major n_z x n_theta"),
            "Q0": (problem.q0, "linear term at theta = 0"),
            "F_G_CM": (problem.F_g.T, "row-bound map l_g = F_g theta + lg0, column-major n_g x n_theta"),
            "LG0": (problem.lg0, "l_g at theta = 0"), "UG0": (problem.ug0, "u_g at theta = 0")} if adaptive else {}),
    }


def context(problem: SteeringProblem, name: str, backend: str, settings: dict) -> dict:
    """Every value the templates use (besides the data arrays, the library file lists and the variant flags)."""
    c = problem.config
    n_z, n_g = problem.n_z, problem.n_g  # the QP's size; n_u: the references over the horizon
    blocked = problem.B is not None
    ctx = {
        "banner": BANNER, "name": name, "NAME": name.upper(), "backend": backend,
        "backend_id": BACKENDS.index(backend),
        "m": c.m, "p": c.p, "t_ini": c.t_ini, "t_f": c.t_f, "n_u": problem.n_u, "n_z": n_z,
        "blocked": int(blocked), "n_u_ws": problem.n_u if blocked else 1,
        "knots": list(c.knots) if blocked else [], **_knot_tables(problem.B, c.m),
        "n_theta": problem.n_theta, "has_nominal": bool(problem.has_nominal),
        "n_g": n_g, "n_g1": max(1, n_g), "n_c": n_z + n_g, "n_w": problem.n_w, "n_y": c.p * c.t_f,
        "n_sigma": c.p * c.t_ini, "n_bounds": 3 * c.m + 2 * c.p + 1,
        "feas_tol": repr(FEAS_TOL), "vector_tol": repr(VECTOR_TOL[backend]),
        "max_iter": int(settings["max_iter"]), "vectors_file": VECTORS_FILE.format(name=name),
    }
    if backend == "daqp":
        ctx.update(daqp_version=libs.DAQP_VERSION, daqp_primal_tol=repr(DAQP_PRIMAL_TOL), daqp_words=DAQP_STRUCT_WORDS)
    else:
        ctx.update(rho=repr(float(settings["rho"])), eps=repr(float(settings["eps"])), n_uu=n_z * n_z,
                   max_refine=MAX_REFINE)
    return ctx


def _knot_tables(B: np.ndarray | None, m: int) -> dict:
    """Read off the knot basis B (m Tf x m n_knots, :func:`ddpc_codegen.design.blocking.knot_basis`): per tick k
    of the horizon the segment j and the weight a of its right knot, u_k = (1 - a) z_j + a z_{j+1} -- tables
    for the C instead of a division per tick, the very doubles B holds (printed round-trip)."""
    if B is None:
        return {"knot_seg": [0], "knot_wgt": [0.0]}  # C has no empty arrays: one unread entry
    n_knots = B.shape[1] // m
    seg, wgt = [], []
    for k in range(B.shape[0] // m):
        j = min(int(np.flatnonzero(B[k * m])[0]) // m, n_knots - 2)  # a knot itself: a = 0, the last one a = 1
        seg.append(j)
        wgt.append(float(B[k * m, (j + 1) * m]))
    return {"knot_seg": seg, "knot_wgt": wgt}


def _param_maps(problem: SteeringProblem, name: str, out_dir: Path) -> dict:
    """CasADi-generated C of q(theta) and the general-row bounds (l_g, u_g)(theta); returns work sizes."""
    # The maps are affine in theta; dense MX products of their Jacobians keep the C small and quick to
    # compile, unlike a fully expanded SX graph.
    th = ca.MX.sym("theta", problem.n_theta)
    lin = ca.Function(f"{name}_param_map_q", [th], [ca.mtimes(_sparse_dm(problem.F_q), th) + ca.DM(problem.q0)],
                      ["theta"], ["q"])
    # only the entries of theta the rows read (a rate row reads the last applied input): the product then
    # loops over those columns, not all n_theta, on every tick
    used = np.flatnonzero(np.any(problem.F_g != 0.0, axis=0)).tolist() if problem.n_g else []
    ft = (ca.mtimes(_sparse_dm(problem.F_g[:, used]), th[used]) if used
          else ca.MX(problem.n_g, 1) if problem.n_g else ca.MX(0, 1))
    bnd = ca.Function(f"{name}_bounds_map", [th], [ft + ca.DM(problem.lg0), ft + ca.DM(problem.ug0)],
                      ["theta"], ["l_g", "u_g"])
    cg = ca.CodeGenerator(f"{name}_param_map.c", {"with_header": True, "with_export": False})
    cg.add(lin)
    cg.add(bnd)
    cg.generate(str(out_dir) + "/")
    return {"casadi_arg": max(1, lin.sz_arg(), bnd.sz_arg()), "casadi_res": max(2, lin.sz_res(), bnd.sz_res()),
            "casadi_iw": max(1, lin.sz_iw(), bnd.sz_iw()), "casadi_w": max(1, lin.sz_w(), bnd.sz_w())}


def _check_variants(problem: SteeringProblem, backend: str, artio, adaptive: bool) -> None:
    """Refuse a combination the templates do not generate, before anything slow is emitted."""
    if backend not in BACKENDS:
        raise CodegenError(f"unknown backend {backend!r}; choose one of {list(BACKENDS)}")
    if adaptive and backend != "daqp":
        raise CodegenError(f"online adaptation ([adapt] enabled) needs the daqp backend; got {backend!r} (the "
                           "embedded OSQP bakes the Hessian and the constraint matrix into its generated workspace)")
    if artio is not None:
        artio.check()
        if (artio.art.m, artio.art.p) != (problem.config.m, problem.config.p):
            raise CodegenError(f"the artificial-IO operator has m={artio.art.m}, p={artio.art.p} but the steering "
                               f"config m={problem.config.m}, p={problem.config.p}: build both from the same data")


def emit_sources(problem: SteeringProblem, out_dir: Path, name: str, backend: str, settings: dict,
                 artio=None, adapt=None) -> list[Path]:
    """Write every source and build file of the solver into ``out_dir``; returns the library's
    compilation units (what CMake, the Makefile and the Python extension all compile).
    ``artio`` (an :class:`~ddpc_codegen.codegen.artio.OnlineCompletion`, hopping): also emit the
    generated artificial-IO completion (with DAQP's sources, whatever the steering backend).
    ``adapt`` (an enabled :class:`~ddpc_codegen.values.adapt.AdaptSettings`): also emit the online
    update (``<name>_adapt.{h,c}``) and read the G-dependent QP data through the workspace (daqp only)."""
    adaptive = adapt is not None and adapt.enabled
    _check_variants(problem, backend, artio, adaptive)
    out_dir.mkdir(parents=True, exist_ok=True)
    ctx = context(problem, name, backend, settings)
    ctx.update(_param_maps(problem, name, out_dir), adaptive=adaptive, artio=artio is not None)
    lib_units = libs.emit_daqp(out_dir, name) if backend == "daqp" or artio is not None else []
    if backend == "osqp":
        lib_units += libs.emit_osqp_library(osqp_embedded_solver(problem, settings), out_dir, name)
    data_unit = write_tables(data_arrays(problem, adaptive), out_dir, ctx["banner"], name, f"{name}_data")
    for tpl, fname in (("solver.h.in", "solver.h"), ("solver.c.in", "solver.c"), ("qp.h.in", "qp.h"),
                       (f"qp_{backend}.c.in", "qp.c")):
        (out_dir / f"{name}_{fname}").write_text(render_ctx(tpl, ctx))
    units = [out_dir / f"{name}_solver.c", out_dir / f"{name}_qp.c", data_unit,
             out_dir / f"{name}_param_map.c"] + lib_units
    if artio is not None:
        units += emit_artio(artio, out_dir, ctx)
    if adaptive:
        units += emit_adapt(problem, adapt, out_dir, name, ctx["banner"])
    ctx.update(sources=[u.relative_to(out_dir).as_posix() for u in units],
               includes=include_dirs_of(backend, artio is not None) or ["."])
    for tpl in ("CMakeLists.txt", "Makefile", "example_main.c"):
        (out_dir / tpl).write_text(render_ctx(f"{tpl}.in", ctx))
    (out_dir / "codegen_context.json").write_text(json.dumps(ctx, indent=1, sort_keys=True) + "\n")
    return units
