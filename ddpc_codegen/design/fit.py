"""The predictor a steering configuration asks for, fitted from a dataset.

Two forms (``[predictor] form``):

* ``"absolute"`` (default): the fit of :func:`~ddpc_codegen.design.predictor.fit_predictor` on the
  samples themselves.
* ``"incremental"`` (offset-free, ``lsq`` only): the same fit on the increments du[k] = u[k] - u[k-1],
  dy[k] = y[k] - y[k-1] of every trajectory (Tini - 1 past increments, Tf future ones), then
  y_f = y_ini[-1] + cumsum(dy_f). A constant offset on the outputs (a mass error, a drifting height
  estimate) is carried into the prediction exactly instead of being explained by the inputs, and the
  ridge shrinks towards "the output stays where it is" instead of towards zero. The composition is
  linear in (u_ini, y_ini, u_f), so the result is an ordinary :class:`Predictor` (lsq, zero slack)
  and every downstream stage (QP, code generation, runtime) is unchanged.

Why: an offset the data never saw (a different hover thrust, a payload) is an input-independent
term that the absolute predictor must explain with its inputs; the incremental one carries it.
The held-out check of ``ddpc-codegen codegen`` reports both predictors' errors on a dataset.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.predictor import Predictor, fit_predictor
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.values.config_values import incremental_problem

__all__ = ["fit_configured", "fit_incremental", "difference_dataset", "compose_increments"]


def fit_configured(config, dataset: IODataset) -> Predictor:
    """The predictor of a :class:`~ddpc_codegen.values.config.SteeringConfig` (its ``[predictor]``
    table: method, form, slack_weight, ridge, rcond) fitted on ``dataset``."""
    opts = dict(config.predictor)
    method, form = opts.pop("method"), opts.pop("form", "absolute")
    if form == "incremental":
        return fit_incremental(dataset, config.t_ini, config.t_f, method, **opts)
    return fit_predictor(dataset, config.t_ini, config.t_f, method, **opts)


def difference_dataset(dataset: IODataset) -> IODataset:
    """Per trajectory, (du, dy)[k] = (u, y)[k+1] - (u, y)[k] (T - 1 samples; phases of the later sample).

    Raises:
        DataError: no trajectory has two samples.
    """
    keep = [i for i, n in enumerate(dataset.lengths) if n >= 2]
    if not keep:
        raise DataError("the incremental predictor needs trajectories of at least 2 samples; every one has 1")
    tr = dataset.trajectories()
    return IODataset([np.diff(tr[i][0], axis=0) for i in keep], [np.diff(tr[i][1], axis=0) for i in keep],
                     dataset.dt, input_names=dataset.input_names, output_names=dataset.output_names,
                     input_units=dataset.input_units, output_units=dataset.output_units,
                     phases=None if dataset.phases is None else [dataset.phases[i][1:] for i in keep],
                     metadata={**dataset.metadata, "increments_of": "samples"})


def fit_incremental(dataset: IODataset, t_ini: int, t_f: int, method: str = "lsq", **opts) -> Predictor:
    """Fit on the increments and compose the absolute predictor (see the module docstring).

    Args:
        dataset: the IO data (samples, not increments).
        t_ini: past samples of the composed predictor (>= 2; the increment fit sees t_ini - 1).
        t_f: horizon.
        method: must be ``"lsq"`` (pem's slack on y_ini has no meaning on increments).
        **opts: ridge, rcond, ... as :func:`fit_predictor`.
    """
    why = incremental_problem(method, t_ini)
    if why:
        raise ConfigError(f"[predictor] form = \"incremental\" {why}")
    inc = fit_predictor(difference_dataset(dataset), int(t_ini) - 1, int(t_f), "lsq", **opts)
    return compose_increments(inc)


def compose_increments(inc: Predictor) -> Predictor:
    """The absolute predictor (t_ini = inc.t_ini + 1) equal to: difference the window, predict the
    increments with ``inc``, accumulate them from y_ini[-1]. Matrices on time-major stacked windows."""
    m, p, ti, tf = inc.m, inc.p, inc.t_ini + 1, inc.t_f
    Im, Ip = np.eye(m), np.eye(p)
    D = np.diff(np.eye(ti), axis=0)                         # (ti-1, ti): window -> its increments
    E = np.eye(tf) - np.eye(tf, k=-1)                       # (tf, tf): u_f -> du_f after the first
    L = np.kron(np.tril(np.ones((tf, tf))), Ip)             # accumulate dy_f
    last_u = np.kron(np.eye(1, ti, ti - 1), Im)             # (m, m*ti): picks u_ini[-1]
    last_y = np.kron(np.eye(1, ti, ti - 1), Ip)
    first_u = np.kron(np.eye(tf, 1), Im)                    # (m*tf, m): du_f[0] = u_f[0] - u_ini[-1]
    nu = m * inc.t_ini
    Wu, Wy, V = inc.Gy_w[:, :nu], inc.Gy_w[:, nu:], inc.Gy_u
    Gu = L @ (Wu @ np.kron(D, Im) - V @ first_u @ last_u)
    Gy = L @ (Wy @ np.kron(D, Ip)) + np.kron(np.ones((tf, 1)), Ip) @ last_y
    Gf = L @ V @ np.kron(E, Im)
    opts = {**inc.options, "form": "incremental"}
    return dataclasses.replace(
        inc, t_ini=ti, Gy_w=np.ascontiguousarray(np.hstack([Gu, Gy])), Gy_u=np.ascontiguousarray(Gf),
        Gs_w=np.zeros((p * ti, (m + p) * ti)), Gs_u=np.zeros((p * ti, m * tf)), options=opts)
