"""The figures of ``make demo`` (PNG, matplotlib via :mod:`ddpc_codegen.sim.plots`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ddpc_codegen.experiments.evaluate import RunResult, offset_step
from ddpc_codegen.sim.metrics import hop_apexes
from ddpc_codegen.values.phases import GROUND

__all__ = ["demo_figures"]


def demo_figures(out: Path, runs: dict[str, tuple[RunResult, RunResult]],
                 noisy: dict[str, RunResult] | None = None) -> list[str]:
    """The demo's PNGs in ``out``: per scenario the baseline vs steered run (``runs``: name ->
    (baseline, steered)); hopping also the apex error per hop and, given the steered run under sensor
    noise (``noisy``), the steering offset and thrust next to the noise-free steered run. Returns the paths."""
    from ddpc_codegen.sim.plots import _mpl, plot_result, save_figure

    written = []
    labels = ["without steering", "with steering"]
    if "flying" in runs:
        b, s = runs["flying"]
        written.append(str(save_figure(plot_result([b.sim, s.sim], labels), out / "flying.png")))
    if "hopping" in runs:
        b, s = runs["hopping"]
        t1 = float(s.sim.t[-1])
        written.append(str(save_figure(_hopping_figure(b.sim, s.sim, labels, (max(0.0, t1 - 4.0), t1)),
                                       out / "hopping.png")))
        plt = _mpl()
        fig, ax = plt.subplots(figsize=(7, 3.2))
        target = s.sim.config.apex_height

        for r, lab, c in ((b, labels[0], "tab:green"), (s, labels[1], "tab:blue")):
            ta, za = hop_apexes(r.sim)
            ax.plot(ta, (za - target) * 1e3, "o-", color=c, ms=3, lw=1, label=lab)
        ax.axhline(0.0, color="k", ls="--", lw=1, label="target apex")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("apex - target [mm]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title("hopping: apex height error per hop")
        fig.tight_layout()
        written.append(str(save_figure(fig, out / "hopping_apex.png")))
        if noisy and "hopping" in noisy:
            written.append(str(save_figure(_jitter_figure(s, noisy["hopping"]), out / "hopping_offset.png")))
    return written


def _hopping_figure(base, steered, labels, t_range):
    """z, roll, pitch vs time; each run against its *own* desired outputs (the hop timing of the
    two runs differs, so one shared desired curve would mislead). Ground phases shaded."""
    from ddpc_codegen.sim.plots import _mpl

    plt = _mpl()
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.2), sharex=True)
    scale, units = (1.0, 180 / np.pi, 180 / np.pi), ("m", "deg", "deg")
    g = steered.phase == GROUND
    edges = np.flatnonzero(np.diff(np.r_[0, g.astype(int), 0]))
    for j, ax in enumerate(axes):
        for a, b_ in zip(edges[0::2], edges[1::2]):
            ax.axvspan(steered.t[a], steered.t[min(b_, steered.n - 1)], color="0.9", lw=0)
        for r, lab, c in ((base, labels[0], "tab:green"), (steered, labels[1], "tab:blue")):
            air = np.where(r.phase != GROUND, r.y_des[:, j], np.nan)  # desired is defined in the air
            ax.plot(r.t, air * scale[j], "--", color=c, lw=0.9, alpha=0.8, label=f"desired ({lab})")
            if r is steered:
                ax.plot(r.t, r.u[:, j] * scale[j], ":", color=c, lw=1.0, label=f"reference u ({lab})")
            ax.plot(r.t, r.y_true[:, j] * scale[j], "-", color=c, lw=1.3, label=f"realized ({lab})")
        ax.set_ylabel(f"{steered.output_names[j]} [{units[j]}]")
        ax.grid(True, alpha=0.3)
        ax.set_xlim(*t_range)
    axes[0].legend(loc="upper right", fontsize=7, ncol=2)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("hopping: without (green) and with (blue) reference steering; grey = ground phase (steered run)")
    fig.tight_layout()
    return fig


def _jitter_figure(clean: RunResult, noisy: RunResult, seconds: float = 2.5):
    """The steering offset u - r_nom on z_ref and the thrust it commands, the last ``seconds`` of the
    noise-free and the noisy steered hopping run (each with its own hop timing; ground phases of the
    noisy run shaded), labelled with each run's ``offset_step_rms``: why the noisy hops' velocity
    suffers (README, Results)."""
    from ddpc_codegen.sim.plots import _mpl

    plt = _mpl()
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.2), sharex=True)
    for run, lab, c in ((clean, "steered, noise-free", "tab:blue"), (noisy, "steered, sensor noise", "tab:red")):
        r = run.sim
        keep = r.t >= r.t[-1] - seconds
        t = r.t[keep] - r.t[-1] + seconds
        off = np.where(r.phase != GROUND, r.u[:, 0] - r.r_nom[:, 0], np.nan)[keep]
        jit = offset_step(run.metrics)
        txt = "" if jit is None else f" (step rms {jit * 1e3:.1f} mm)"
        axes[0].plot(t, off * 1e3, "-", color=c, lw=1.0, label=lab + txt)
        axes[1].plot(t, r.setpoint_thrust[keep], "-", color=c, lw=1.0, label=lab)
    n = noisy.sim
    keep = n.t >= n.t[-1] - seconds
    edges = np.flatnonzero(np.diff(np.r_[0, (n.phase == GROUND)[keep].astype(int), 0]))
    tn = n.t[keep] - n.t[-1] + seconds
    for ax in axes:
        for a, b_ in zip(edges[0::2], edges[1::2]):
            ax.axvspan(tn[a], tn[min(b_, tn.size - 1)], color="0.9", lw=0)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[0].set_ylabel("z_ref - r_nom [mm]")
    axes[1].set_ylabel("thrust [normalized]")
    axes[1].set_xlabel(f"t [s] (last {seconds:g} s of each run)")
    fig.suptitle("hopping: the steering offset and its thrust, noise-free vs sensor noise; grey = ground (noisy run)")
    fig.tight_layout()
    return fig
