"""Figures like the paper's: x-z path, and z(t) / leg angles(t) with desired, commanded, realized.

Each function takes one or more :class:`SimResult` (e.g. without and with steering, labelled)
and returns a matplotlib Figure; :func:`save_figure` writes it (Agg backend, no display needed).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ddpc_codegen.values.phases import GROUND

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ddpc_codegen.sim.run_result import SimResult

__all__ = ["plot_result", "plot_xz", "plot_tracking", "save_figure"]

_COLORS = ("tab:green", "tab:blue", "tab:orange", "tab:purple")


def _mpl():
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg"):
        try:
            matplotlib.use("Agg")
        except Exception:  # pragma: no cover - backend already fixed by the user
            pass
    import matplotlib.pyplot as plt

    return plt


def _runs(results: "SimResult | Sequence[SimResult]", labels: Sequence[str] | None) -> tuple[list, list[str]]:
    rs = [results] if hasattr(results, "t") else list(results)
    if labels is None:
        labels = [""] if len(rs) == 1 else [f"run {i}" for i in range(len(rs))]
    return rs, list(labels)


def _lab(kind: str, lab: str) -> str:
    return f"{kind} ({lab})" if lab else kind


def _shade_ground(ax, r: "SimResult") -> None:
    g = r.phase == GROUND
    if not g.any():
        return
    edges = np.flatnonzero(np.diff(np.r_[0, g.astype(int), 0]))
    for a, b in zip(edges[0::2], edges[1::2]):
        ax.axvspan(r.t[a], r.t[min(b, r.n - 1)], color="0.9", lw=0)


def plot_xz(results, labels: Sequence[str] | None = None, ax=None) -> "Figure":
    """Sagittal x-z path: desired (flying: the ellipse) and realized."""
    plt = _mpl()
    rs, labels = _runs(results, labels)
    if ax is None:
        fig, ax = plt.subplots(figsize=(6, 4))
    else:
        fig = ax.figure
    r0 = rs[0]
    if "x_des" in r0.extras:
        ax.plot(r0.extras["x_des"], r0.extras["z_des"], "k--", lw=1.2, label="desired")
    for i, (r, lab) in enumerate(zip(rs, labels)):
        ax.plot(r.state[:, 0], r.state[:, 2], color=_COLORS[i % len(_COLORS)], lw=1.2, label=lab or "realized")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    if r0.scenario == "flying":
        ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{r0.scenario}: x-z path")
    return fig


def plot_tracking(results, labels: Sequence[str] | None = None, t_range: tuple[float, float] | None = None) -> "Figure":
    """Outputs vs time: desired (black dashed), commanded reference u (dotted), realized (solid)."""
    plt = _mpl()
    rs, labels = _runs(results, labels)
    r0 = rs[0]
    p = r0.y.shape[1]
    fig, axes = plt.subplots(p, 1, figsize=(9, 2.2 * p + 0.6), sharex=True)
    axes = np.atleast_1d(axes)
    for j, ax in enumerate(axes):
        _output_panel(ax, j, rs, labels, t_range)
    axes[0].legend(loc="upper right", fontsize=7, ncol=2)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{r0.scenario}: outputs (grey = ground phase)" if r0.scenario == "hopping" else f"{r0.scenario}: outputs")
    fig.tight_layout()
    return fig


def _output_panel(ax, j: int, rs, labels, t_range) -> None:
    """Output j of every run vs time: desired, reference sent, realized (z in m, angles in deg)."""
    r0 = rs[0]
    scale, unit = (1.0, "m") if j == 0 else (180.0 / np.pi, "deg")
    _shade_ground(ax, r0)
    ax.plot(r0.t, r0.y_des[:, j] * scale, "k--", lw=1.0, label="desired")
    for i, (r, lab) in enumerate(zip(rs, labels)):
        c = _COLORS[i % len(_COLORS)]
        ax.plot(r.t, r.u[:, j] * scale, ":", color=c, lw=1.0, label=_lab("reference u", lab))
        ax.plot(r.t, r.y_true[:, j] * scale, "-", color=c, lw=1.2, label=_lab("realized y", lab))
    ax.set_ylabel(f"{r0.output_names[j]} [{unit}]")
    ax.grid(True, alpha=0.3)
    if t_range is not None:
        ax.set_xlim(*t_range)


def plot_result(results, labels: Sequence[str] | None = None, t_range: tuple[float, float] | None = None) -> "Figure":
    """One figure: x-z path on the left, outputs vs time on the right."""
    plt = _mpl()
    rs, labels = _runs(results, labels)
    r0 = rs[0]
    p = r0.y.shape[1]
    fig = plt.figure(figsize=(14, 2.2 * p + 1.0))
    gs = fig.add_gridspec(p, 2, width_ratios=[1, 1.6])
    ax_xz = fig.add_subplot(gs[:, 0])
    plot_xz(rs, labels, ax=ax_xz)
    first = None
    for j in range(p):
        ax = fig.add_subplot(gs[j, 1], sharex=first)
        first = first or ax
        _output_panel(ax, j, rs, labels, t_range)
        if j == 0:
            ax.legend(loc="upper right", fontsize=7, ncol=2)
        if j == p - 1:
            ax.set_xlabel("t [s]")
    fig.tight_layout()
    return fig


def save_figure(fig: "Figure", path: str | Path, dpi: int = 110) -> Path:
    """Write a figure (format from the suffix) and close it."""
    plt = _mpl()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
