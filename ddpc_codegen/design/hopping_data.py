"""Hopping data preparation, one implementation for the experiments and the CLI.

A raw hopping log with phase labels (e.g. ``SimResult.to_dataset("none")`` of a hopping run, or a
bridge tick log) -> aerial segments (the Hankel of the artificial-IO operator) and apex-to-apex hops
-> every hop's ground phase replaced by artificial IO -> the mosaic H_G the predictor is fitted on,
plus the operator itself (whose online completion the generated artifact carries).
See :mod:`ddpc_codegen.design.artificial_io` for the method.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.design.artificial_io import ArtificialIO, stitch_hops
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.values.phases import ASCENT, DESCENT, GROUND, ground_runs
from ddpc_codegen.errors import DataError

__all__ = ["ArtificialIOSpec", "HoppingData", "split_hopping", "prepare_hopping", "is_hopping_config"]


@dataclass(frozen=True)
class ArtificialIOSpec:
    """Artificial ground-phase IO settings (hopping); the config's ``[artificial_io]`` table sets any
    of them (validated by :class:`SteeringConfig`).

    Attributes:
        t_d, t_a: real descent / ascent samples around each recorded ground phase that the offline
            stitching (the mosaic H_G) is conditioned on (exact least-norm, ``noise_level``).
        t_d_online: descent samples the online fill is conditioned on (0: the ascent alone; a
            descent context makes the fill atypical and noise-sensitive online).
        min_ascent: ascent samples needed before steering starts (fewer leave the aerial state
            at liftoff under-determined, and the completed window's prediction error grows).
        ground_margin: extra samples of depth beyond the longest recorded ground phase.
        noise_level: sigma of the offline completion [m / rad] (0 = exact: clean recordings).
        noise_level_online: sigma of the online completion (measurements are noisy online).
        denoise_online: also replace windows without ground samples by their fit onto the data's
            dynamics (see :class:`~ddpc_codegen.runtime.hopping.HoppingWindow`, ``denoise``).
        refit_residual: a denoised window whose fit leaves a residual above this [m / rad] is fitted
            again over every aerial sample since the liftoff (0: never; see ``HoppingWindow``).
    """

    t_d: int = 10
    t_a: int = 20
    t_d_online: int = 0
    min_ascent: int = 10
    ground_margin: int = 10
    noise_level: float = 0.0
    noise_level_online: float = 2e-3
    denoise_online: bool = True
    refit_residual: float = 0.0

    def window_settings(self) -> dict:
        """The online window's keyword arguments (``HoppingWindow(op, t_ini, **settings)``)."""
        return {"t_d": self.t_d_online, "min_ascent": self.min_ascent, "noise_level": self.noise_level_online,
                "denoise": self.denoise_online, "refit_residual": self.refit_residual}


@dataclass
class HoppingData:
    """What :func:`prepare_hopping` makes: the stitched hops (the predictor's data), the completion
    operator, its settings and a report (depth, rank, hops used / skipped, ...)."""

    dataset: IODataset
    art: ArtificialIO
    spec: ArtificialIOSpec
    report: dict = field(default_factory=dict)


def is_hopping_config(cfg: SteeringConfig) -> bool:
    """A config is a hopping one when it has an ``[artificial_io]`` table."""
    return bool(cfg.artificial_io)


def split_hopping(raw: IODataset) -> tuple[IODataset, IODataset]:
    """(aerial segments, apex-to-apex hops) of hopping logs with phase labels.

    Aerial segments run from a liftoff to the next touchdown (complete ones only, plus the
    release arc); hops from one apex (ascent -> descent switch) to the next, each with one
    ground phase.
    """
    if raw.phases is None:
        raise DataError("hopping data need phase labels (descent / ground / ascent)")
    au, ay, ap, hu, hy, hp = [], [], [], [], [], []
    for (u, y), ph in zip(raw.trajectories(), raw.phases):
        runs = ground_runs(ph)
        starts = [0] + [b for _, b in runs]
        ends = [a for a, _ in runs] + [len(ph)]
        for a, b in zip(starts, ends):
            if b - a >= 2 and b < len(ph):  # complete aerial phases (ending in a touchdown)
                au.append(u[a:b]); ay.append(y[a:b]); ap.append(ph[a:b])
        apex = [k for k in range(1, len(ph)) if ph[k - 1] == ASCENT and ph[k] == DESCENT]
        for a, b in zip(apex[:-1], apex[1:]):
            if np.any(ph[a:b] == GROUND):
                hu.append(u[a:b]); hy.append(y[a:b]); hp.append(ph[a:b])
    kw = dict(input_names=raw.input_names, output_names=raw.output_names, input_units=raw.input_units,
              output_units=raw.output_units, metadata=raw.metadata)
    if not au or not hu:
        raise DataError("no complete aerial phase or hop in the hopping data; record longer")
    return IODataset(au, ay, raw.dt, phases=ap, **kw), IODataset(hu, hy, raw.dt, phases=hp, **kw)


def prepare_hopping(raw: IODataset, cfg: SteeringConfig, spec: ArtificialIOSpec | None = None, *,
                    where: str = "the dataset", progress: bool = False) -> HoppingData:
    """Raw hopping log (with phase labels) -> stitched hops + artificial-IO operator.

    Args:
        raw: the recorded data as logged: ground phases included, ``phases`` labelled.
        cfg: the hopping config (bounds of the artificial samples, Tini for the depth).
        spec: settings (default: the config's ``[artificial_io]`` table).
        where: how to name the data in an error message.
    Raises:
        DataError: no phase labels, data already stitched, or no complete aerial phase / hop.
    """
    if raw.phases is None:
        raise DataError(f"{where} has no phase labels, but {cfg.source} is a hopping config ([artificial_io]): give "
                        "the raw hopping log with descent / ground / ascent labels per sample (e.g. "
                        "SimResult.to_dataset('none') of a hopping run, or the raw log data/hopping_raw.npz)")
    if "artificial_io" in raw.metadata:
        raise DataError(f"{where} holds hops already stitched with artificial IO (metadata 'artificial_io'); give the "
                        "raw hopping log it was made from (ground phases as recorded), so that the completion "
                        "operator can be built from its aerial phases")
    spec = spec or ArtificialIOSpec(**cfg.artificial_io)
    aerial, hops = split_hopping(raw)
    g_max = max(b - a for ph in hops.phases for a, b in ground_runs(ph))
    depth = spec.t_d + g_max + spec.ground_margin + max(spec.t_a, cfg.t_ini)
    if progress:
        print(f"[hopping] artificial IO: Hankel of {aerial.n_trajectories} aerial segments, depth {depth}",
              file=sys.stderr, flush=True)
    art = ArtificialIO(aerial, depth, noise_level=spec.noise_level,
                       u_min=cfg.u_min, u_max=cfg.u_max, y_min=cfg.y_min, y_max=cfg.y_max)
    ds, rep = stitch_hops(hops, art, spec.t_d, spec.t_a, progress=progress)
    report = {"depth": depth, "rank": art.rank, "aerial_segments": aerial.n_trajectories,
              "aerial_columns": art.n_columns, **rep}
    return HoppingData(ds, art, spec, report)
