"""How well a fitted predictor predicts data it was not fitted on (``ddpc-codegen codegen --holdout``).

The last ``share`` of every trajectory long enough for it is kept out of a second fit with the same settings
(the shipped predictor is still fitted on everything). Data in stretches too short for that (a collect split
by gaps) keep whole stretches out instead: the last ones, about ``share`` of the samples. That predictor then predicts every Tf-sample horizon of
the held-out parts from the Tini samples before it and the inputs that were really sent, as the steering uses
it. Figures per output, in its units: the RMSE one sample ahead, at the horizon's end and over the whole
horizon; the same for persistence (the output held at its last value: what any predictor must beat); and the
fit percentage ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` over the horizon (as MATLAB's ``compare``
reports it). A predictor that does worse than persistence on an output is warned about.

Hopping data (artificial IO over the ground phases) and fleet fits are not checked here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.predictor import Predictor

__all__ = ["HoldoutFigures", "split_holdout", "hold_out_whole", "holdout_figures", "holdout_check"]

MIN_WINDOWS = 20  # horizons a held-out part must give (fewer: no figure, said so)


@dataclass(frozen=True)
class HoldoutFigures:
    """Held-out prediction figures, one entry per output (output units; ``fit_pct`` in percent)."""

    outputs: tuple[str, ...]
    rmse_first: list[float]
    rmse_last: list[float]
    rmse: list[float]
    persistence_rmse: list[float]
    fit_pct: list[float]
    windows: int
    samples_held_out: int

    def as_dict(self) -> dict:
        """JSON-ready (the manifest's provenance and ``--json`` reports)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def split_holdout(ds: IODataset, share: float, min_part: int) -> tuple[IODataset, list[tuple[np.ndarray, np.ndarray]]]:
    """(fit part, held-out parts): each trajectory's last ``share`` (0 < share < 1) held out where both parts
    keep at least ``min_part`` samples; shorter trajectories stay whole in the fit part."""
    if not 0.0 < share < 1.0:
        raise ValueError(f"the held-out share must be in (0, 1); got {share}")
    fit_u, fit_y, held = [], [], []
    for u, y in ds.trajectories():
        n_held = int(round(share * u.shape[0]))
        if n_held >= min_part and u.shape[0] - n_held >= min_part:
            cut = u.shape[0] - n_held
            fit_u.append(u[:cut])
            fit_y.append(y[:cut])
            held.append((u[cut:], y[cut:]))
        else:
            fit_u.append(u)
            fit_y.append(y)
    fit_ds = IODataset(fit_u, fit_y, ds.dt, input_names=ds.input_names, output_names=ds.output_names,
                       input_units=ds.input_units, output_units=ds.output_units, metadata=dict(ds.metadata))
    return fit_ds, held


def hold_out_whole(ds: IODataset, share: float, min_len: int) -> tuple[IODataset, list[tuple[np.ndarray, np.ndarray]]]:
    """(fit part, held-out parts) with whole trajectories held out: from the last one back, each of at least
    ``min_len`` samples, until ``share`` of all samples is held out, while the fit part keeps at least half of
    them; the first trajectory always stays in the fit part (no held-out part when only one trajectory exists)."""
    tr = ds.trajectories()
    total = sum(u.shape[0] for u, _ in tr)
    target = share * total
    held_idx, n = set(), 0
    for i in range(len(tr) - 1, 0, -1):
        if n >= target:
            break
        if tr[i][0].shape[0] >= min_len and total - n - tr[i][0].shape[0] >= 0.5 * total:
            held_idx.add(i)
            n += tr[i][0].shape[0]
    keep = [t for i, t in enumerate(tr) if i not in held_idx]
    fit_ds = IODataset([u for u, _ in keep], [y for _, y in keep], ds.dt, input_names=ds.input_names,
                       output_names=ds.output_names, input_units=ds.input_units, output_units=ds.output_units,
                       metadata=dict(ds.metadata))
    return fit_ds, [tr[i] for i in sorted(held_idx)]


def holdout_figures(pred: Predictor, parts: list[tuple[np.ndarray, np.ndarray]], stride: int = 5) -> HoldoutFigures | None:
    """The figures of ``pred`` over every horizon (every ``stride`` samples) of the held-out ``parts``
    ((T, m) inputs, (T, p) outputs each); None if they give fewer than ``MIN_WINDOWS`` horizons."""
    ti, tf = pred.t_ini, pred.t_f
    err, pers, truth = [], [], []
    for u, y in parts:
        for k in range(ti, u.shape[0] - tf + 1, stride):
            yp, _ = pred.predict(u[k - ti:k], y[k - ti:k], u[k:k + tf])
            err.append(yp - y[k:k + tf])
            pers.append(y[k - 1] - y[k:k + tf])
            truth.append(y[k:k + tf])
    if len(err) < MIN_WINDOWS:
        return None
    e, pe, yt = np.asarray(err), np.asarray(pers), np.asarray(truth)  # (windows, Tf, p)
    rms = lambda a, ax: np.sqrt(np.mean(a * a, axis=ax))  # noqa: E731
    spread = np.sqrt(np.sum((yt - yt.mean(axis=(0, 1))) ** 2, axis=(0, 1)))
    fit = 100.0 * (1.0 - np.sqrt(np.sum(e * e, axis=(0, 1))) / np.where(spread > 0, spread, np.nan))
    return HoldoutFigures(tuple(pred.output_names) or tuple(f"y{i}" for i in range(e.shape[2])),
                          rms(e[:, 0], 0).tolist(), rms(e[:, -1], 0).tolist(), rms(e, (0, 1)).tolist(),
                          rms(pe, (0, 1)).tolist(), [float(v) for v in fit], int(e.shape[0]),
                          int(sum(u.shape[0] for u, _ in parts)))


def holdout_check(config, ds: IODataset, fit: Callable[[object, IODataset], Predictor], share: float = 0.2,
                  ) -> tuple[HoldoutFigures | None, list[str], list[str]]:
    """(figures or None, report lines, warnings) of the predictor ``fit(config, ·)`` gives when the last
    ``share`` of each trajectory of ``ds`` is held out of it (units: the config's output units)."""
    depth = config.t_ini + config.t_f
    fit_ds, parts = split_holdout(ds, share, min_part=2 * depth)
    what = f"the last {share:.0%} of the data"
    if not parts:  # stretches too short to split: whole ones held out
        fit_ds, parts = hold_out_whole(ds, share, min_len=depth)
        what = f"{len(parts)} whole stretch{'es' * (len(parts) != 1)} of the data"
    if not parts:
        return None, [f"held-out check skipped: no trajectory is long enough to keep {share:.0%} of it "
                      f"(>= {2 * depth} samples) out of the fit, nor a second one of >= {depth} samples to hold "
                      "out whole"], []
    figs = holdout_figures(fit(config, fit_ds), parts)
    if figs is None:
        return None, [f"held-out check skipped: the held-out {share:.0%} gives fewer than {MIN_WINDOWS} "
                      "horizons"], []
    units = tuple(config.output_units) or ("",) * len(figs.outputs)
    lines = [f"held-out prediction ({what}, {figs.windows} horizons, predictor fitted without it):"]
    warnings = []
    for i, name in enumerate(figs.outputs):
        unit = f" {units[i]}" if i < len(units) and units[i] else ""
        lines.append(f"  {name}{f' [{unit.strip()}]' if unit else ''}: RMSE {figs.rmse_first[i]:.3g} one sample "
                     f"ahead, {figs.rmse_last[i]:.3g} at the horizon's end, {figs.rmse[i]:.3g} over it (holding the "
                     f"last value: {figs.persistence_rmse[i]:.3g}); fit {figs.fit_pct[i]:.1f} %")
        if figs.rmse[i] > figs.persistence_rmse[i]:
            warnings.append(f"warning: on held-out data the predictor predicts {name} worse than holding its last "
                            f"value ({figs.rmse[i]:.3g} vs {figs.persistence_rmse[i]:.3g}{unit} over the horizon): "
                            "more or more exciting data, another [predictor] ridge or form")
    return figs, lines, warnings
