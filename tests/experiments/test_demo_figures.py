"""make demo's figures (ddpc_codegen.experiments.demo_figures): written, and the jitter they state."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ddpc_codegen.values.phases import ASCENT, GROUND
from ddpc_codegen.experiments.demo_figures import _jitter_figure, demo_figures
from ddpc_codegen.experiments.evaluate import run
from ddpc_codegen.stats import step_rms


def _hopping_run(jitter: float, seed: int) -> SimpleNamespace:
    """A stand-in steered run (a RunResult's .sim and .metrics): 3 s at 200 Hz, ground every 0.8 s for
    0.1 s, a z_ref offset of +-``jitter`` alternating per tick in the air."""
    t = np.arange(600) * 0.005
    phase = np.where((t % 0.8) < 0.1, GROUND, ASCENT).astype(np.int8)
    r_nom = np.zeros((600, 3))
    u = r_nom.copy()
    u[:, 0] = 0.03 + jitter * (-1.0) ** np.arange(600)
    thrust = 0.4 + np.random.default_rng(seed).normal(0.0, 0.01, 600)
    sim = SimpleNamespace(t=t, phase=phase, u=u, r_nom=r_nom, setpoint_thrust=thrust)
    return SimpleNamespace(sim=sim, metrics={"offset_step_rms": step_rms(u - r_nom, phase != GROUND)})


def test_jitter_figure_labels_each_run_with_its_step_rms():
    fig = _jitter_figure(_hopping_run(0.0, 1), _hopping_run(0.005, 2))
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    # +-5 mm alternating: every aerial step is 10 mm; the ground ticks are not counted
    assert labels == ["steered, noise-free (step rms 0.0 mm)", "steered, sensor noise (step rms 10.0 mm)"]
    assert len(fig.axes) == 2


def test_demo_figures_writes_the_hopping_set(tmp_path):
    base = run(None, "hopping", 3.0, steer=False, seed=1)
    steered = base  # a passthrough run stands in (offset 0: "step rms 0.0 mm")
    noisy = run(None, "hopping", 3.0, steer=False, seed=1, noise=True)
    files = demo_figures(tmp_path, {"hopping": (base, steered)}, {"hopping": noisy})
    assert [f.rsplit("/", 1)[-1] for f in files] == ["hopping.png", "hopping_apex.png", "hopping_offset.png"]
    assert all((tmp_path / f.rsplit("/", 1)[-1]).stat().st_size > 10_000 for f in files)
    assert len(demo_figures(tmp_path, {"hopping": (base, steered)})) == 2  # without the noisy run: no offset figure
