"""Design side of online predictor updates: what a generated solver ships for them.

The update itself (Givens rank-one update of R, re-solve of G, verification) is
:mod:`ddpc_codegen.design.adapter` (numpy, the reference of the generated C), its settings
:mod:`ddpc_codegen.values.adapt`; here:

* :func:`fit_statistic` -- the fit's sufficient statistic of a predictor: its data-only R factor (square,
  width x width, zero rows padded) with the layout, scale and fit options it came from;
* :func:`write_fit_statistic` -- ``<name>_fit_r.npy`` beside the manifest and the manifest's
  ``fit_statistic`` entry (shape, scale, forgetting defaults);
* :func:`qp_model` -- the steering QP's data (Hessian, linear-term map, output rows, gain) as a function of
  the re-solved G (rebuilt and checked before a swap; knots included);
* :func:`adapter` -- the interpreted :class:`~ddpc_codegen.design.adapter.Adapter` of a problem;
* :class:`AdaptiveProblem` -- the interpreted twin of an adaptive generated solver (same API).

For the incremental (offset-free) predictor the statistic is that of the increment fit (Tini - 1 past
increments): the update feeds it windows of increments.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
from pathlib import Path

import numpy as np

from ddpc_codegen.design.predictor import Predictor
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.design.adapt_qp import QPData, QPModel, steady_state_gain
from ddpc_codegen.design.adapter import AdaptLayout, Adapter
from ddpc_codegen.values.adapt import AdaptSettings, SampleWindow, Swapped

__all__ = ["fit_statistic", "fit_layout", "write_fit_statistic", "ship_fit_statistic", "qp_model", "adapter",
           "AdaptiveProblem", "installed",
           "FIT_FILE"]

FIT_FILE = "{name}_fit_r.npy"


def fit_layout(predictor: Predictor) -> AdaptLayout:
    """The layout of the fit the predictor came from (the increment fit's for ``form = "incremental"``)."""
    inc = predictor.options.get("form") == "incremental"
    method = "lsq" if inc else predictor.method
    return AdaptLayout(predictor.m, predictor.p, predictor.t_ini - (1 if inc else 0), predictor.t_f, method)


def fit_statistic(predictor: Predictor) -> tuple[np.ndarray, AdaptLayout]:
    """(R (width, width) upper triangular with a nonnegative diagonal, its layout): the data-only R factor of the scaled Hankel data
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
    full *= np.where(np.diag(full) < 0.0, -1.0, 1.0)[:, None]  # the canonical factor (the C update keeps this form)
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


def _predictor_maps(predictor: Predictor, layout: AdaptLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Lm (n_o, q), Rm (r, n_w + n_u), C0 (n_o, n_w + n_u)) with [Gy_w Gy_u; Gs_w Gs_u] = Lm G Rm + C0 for a
    fit-domain G (q, r): the channel scale (as ``predictor._unscale``) and, for an increment fit, the
    differencing of the window and the accumulation of the predicted increments (as ``fit.compose_increments``)."""
    m, p, ti, tf = predictor.m, predictor.p, predictor.t_ini, predictor.t_f
    scale = np.asarray(predictor.options["channel_scale"], float)
    su, sy = scale[:m], scale[m:]
    tl = layout.t_ini
    s_in = np.concatenate([np.tile(su, tl), np.tile(sy, tl), np.tile(su, tf)])
    s_out = np.concatenate([np.tile(sy, tf), np.tile(sy, tl) if layout.q_s else np.zeros(0)])
    n_y, n_w = p * tf, (m + p) * ti
    n_o, n_wu = n_y + p * ti, n_w + m * tf
    Lm, C0 = np.zeros((n_o, layout.q_y + layout.q_s)), np.zeros((n_o, n_wu))
    if tl == ti:  # a fit on samples: G's rows and columns are the predictor's, scaled
        Lm[: n_y + layout.q_s] = np.diag(s_out)
        return Lm, np.diag(1.0 / s_in), C0
    Im, Ip = np.eye(m), np.eye(p)
    D = np.diff(np.eye(ti), axis=0)  # window -> its increments
    last_u, last_y = np.kron(np.eye(1, ti, ti - 1), Im), np.kron(np.eye(1, ti, ti - 1), Ip)
    Lm[:n_y] = np.kron(np.tril(np.ones((tf, tf))), Ip) * s_out[None, :]  # accumulate dy_f from y_ini[-1]
    Rd = np.zeros((layout.r, n_wu))  # [u_ini; y_ini; u_f] -> [du_ini; dy_ini; du_f]
    a, b = m * tl, (m + p) * tl
    Rd[:a, : m * ti] = np.kron(D, Im)
    Rd[a:b, m * ti : n_w] = np.kron(D, Ip)
    Rd[b:, n_w:] = np.kron(np.eye(tf) - np.eye(tf, k=-1), Im)
    Rd[b:, : m * ti] = -np.kron(np.eye(tf, 1), Im) @ last_u  # du_f[0] = u_f[0] - u_ini[-1]
    C0[:n_y, m * ti : n_w] = np.kron(np.ones((tf, 1)), Ip) @ last_y
    return Lm, Rd / s_in[:, None], C0


def qp_model(problem, max_gain_change: float = np.inf) -> QPModel:
    """The steering QP's G-dependent data as a function of the fit-domain G (a
    :class:`~ddpc_codegen.design.problem.SteeringProblem`, with or without knots): fixed parts taken from the
    problem itself, so that the shipped G rebuilds the shipped QP. ``max_gain_change``: the bound of the
    steady-state gain check (:func:`~ddpc_codegen.design.adapt_qp.steady_state_gain`; inf: none).

    Raises:
        ConfigError: ``[cost] R_de`` is set (not modelled by the rebuild).
        DataError: the problem's QP has a linear term at theta = 0 (the fast-path offset would then
            depend on G; the steering QP as formed here never has one).
    """
    pr, c = problem.predictor, problem.config
    if np.any(c.R_de):
        raise ConfigError(f"{c.source}: [cost] R_de with [adapt]: the penalty on the change of u - y couples the "
                          "inputs with the predicted outputs, which the online rebuild of the QP does not model; "
                          "drop one of them")
    if np.any(problem.q0 != 0.0):
        raise DataError("the steering QP has a nonzero linear term at theta = 0; online adaptation rebuilds "
                        "the gain K only, not its offset")
    lay = fit_layout(pr)
    Lm, Rm, C0 = _predictor_maps(pr, lay)
    n_y, n_s = c.p * c.t_f, c.p * c.t_ini
    Wd = np.zeros((n_y + n_s,) * 2)
    Wd[:n_y, :n_y] = 2.0 * np.kron(np.eye(c.t_f), c.Q)  # CasADi's Hessian of the cost (J without the 1/2)
    Wd[n_y:, n_y:] = 2.0 * c.lambda_sigma * np.eye(n_s)
    y_lo, y_hi = np.tile(c.y_min, c.t_f), np.tile(c.y_max, c.t_f)
    y_rows = np.nonzero(np.isfinite(y_lo) | np.isfinite(y_hi))[0]  # the first general rows, in this order
    B = np.eye(problem.n_u) if problem.B is None else problem.B
    zero = QPModel(Lm, Rm, C0, B, Wd, np.zeros_like(problem.P), np.zeros_like(problem.F_q), y_rows,
                   problem.A_g, problem.F_g, problem.n_w, n_y)
    Gd = np.block([[pr.Gy_w, pr.Gy_u], [pr.Gs_w, pr.Gs_u]])
    Pg, Fg = zero.terms(Gd)
    dims = (c.m, c.p, c.t_ini, c.t_f)
    # the incremental form is offset-free: it holds any output at rest (no steady-state gain to keep)
    check = np.isfinite(max_gain_change) and lay.t_ini == c.t_ini
    S0 = steady_state_gain(Gd, *dims) if check else None
    if check and S0 is None:
        raise DataError("the shipped predictor has no steady state (I - sum of its output coefficients is singular): "
                        "set [adapt] max_gain_change = inf to adapt without the gain check")
    return QPModel(Lm, Rm, C0, B, Wd, problem.P - Pg, problem.F_q - Fg, y_rows, problem.A_g, problem.F_g,
                   problem.n_w, n_y, dims, S0, float(max_gain_change))


def adapter(problem, settings: AdaptSettings) -> Adapter:
    """The interpreted online update of a steering problem's predictor (its fit statistic, scale, options).

    Raises:
        ConfigError: ``offset`` with finite output bounds (the offset would have to shift them too).
    """
    pr = problem.predictor
    R, lay = fit_statistic(pr)
    o = pr.options
    qp = qp_model(problem, settings.max_gain_change)
    if settings.offset and qp.y_rows.size:
        raise ConfigError("[adapt] offset = true cannot be combined with finite output bounds ([bounds] y_min / "
                          "y_max): the estimated output offset would shift them as well; drop the output bounds or "
                          "set offset = false")
    return Adapter(lay, R, np.asarray(o["channel_scale"], float), settings, slack_weight=float(o["slack_weight"]),
                   ridge=float(o["ridge"]), rcond=float(o["rcond"]), qp=qp)


class AdaptiveProblem:
    """The interpreted twin of an adaptive generated solver: a :class:`~ddpc_codegen.design.problem.SteeringProblem`
    whose G-dependent QP data are replaced by the numpy reference's verified rebuilds, with the same adaptation
    API as :class:`~ddpc_codegen.runtime.loader.GeneratedSolver` (``adapt_push`` .. ``adapt_counts``).

    ``solver``: the interpreted solver of every tick (``"fast"``: the fast path, then the exact active set).
    """

    def __init__(self, problem, settings: AdaptSettings, solver: str = "fast") -> None:
        self.adapter = adapter(problem, settings)
        self.adapt_settings = settings
        self.problem = problem
        self.shipped = problem
        self.config, self.has_nominal, self.method = problem.config, problem.has_nominal, solver
        lay = self.adapter.layout
        self._window = SampleWindow(lay.depth, lay.m, lay.p, lay.t_ini != problem.predictor.t_ini)

    def solve(self, u_ini, y_ini, y_des, u_nom=None):
        """One tick on the current QP data (SteeringProblem.solve), aimed at y_des - the output offset."""
        off = self.adapter.offset
        if np.any(off != 0.0) and np.size(y_des) == off.size:  # a y_des of the wrong size: the problem's error
            y_des = np.asarray(y_des, dtype=float) - off.reshape(np.shape(y_des))
        return self.problem.solve(u_ini, y_ini, y_des, u_nom, solver=self.method)

    def solve_theta(self, theta, **kw):
        """Like :meth:`solve` from a stacked theta (its y_des entries shifted by the output offset)."""
        off = self.adapter.offset
        if np.any(off != 0.0) and np.shape(theta) == (self.problem.n_theta,):
            theta = np.array(theta, dtype=float)
            theta[self.problem.n_w : self.problem.n_w + off.size] -= off
        return self.problem.solve_theta(theta, **{"solver": self.method, **kw})

    def reset(self) -> None:
        self.problem.reset()

    def adapt_push(self, u, y) -> bool:
        w = self._window.push(np.asarray(u, float), np.asarray(y, float))
        return False if w is None else self.adapter.push(w)

    def adapt_clear(self) -> None:
        self._window.clear()

    def adapt_snapshot(self) -> None:
        self.adapter.snapshot()

    def adapt_resolve(self, snapshot: bool = True) -> str:
        return self.adapter.resolve(snapshot)

    def adapt_swap(self) -> Swapped:
        """Install what the last re-solve verified (G and its QP data, the output offset); what was installed."""
        done = self.adapter.swap()
        if done.g:
            self.problem = installed(self.shipped, self.adapter.qp_data)
        return done

    def adapt_refused(self) -> int:
        return self.adapter.counts["skipped"] + self.adapter.counts["dropped"]

    def adapt_counts(self) -> dict:
        return dict(self.adapter.counts)

    def adapt_offset(self) -> np.ndarray:
        """The output offset in use (p Tf,), data units, time-major."""
        return self.adapter.offset.copy()


def installed(problem, data: QPData):
    """A copy of ``problem`` solving with the rebuilt QP data (and predicting with their data-unit predictor,
    so its bound check sees the outputs the rebuilt QP bounds); warm starts dropped."""
    pr = problem.predictor
    nw, ny = problem.n_w, pr.Gy_w.shape[0]
    new = copy.copy(problem)
    new.predictor = dataclasses.replace(pr, Gy_w=data.Gd[:ny, :nw], Gy_u=data.Gd[:ny, nw:], Gs_w=data.Gd[ny:, :nw],
                                        Gs_u=data.Gd[ny:, nw:])
    new.P, new.A_g, new.F_q, new.F_g, new.K = data.P, data.A_g, data.F_q, data.F_g, data.K
    new.A = np.vstack([np.eye(problem.n_z), data.A_g])
    new.reset()
    return new
