"""CLI subcommands (registered on a fresh parser) and figures."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from ddpc_codegen import IODataset
from ddpc_codegen.errors import ConfigError
from ddpc_codegen.cli import sim as sim_cli
from ddpc_codegen.sim import simulate
from ddpc_codegen.sim.plots import plot_result, plot_tracking, save_figure


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ddpc-codegen")
    sub = p.add_subparsers(dest="command")
    sim_cli.register(sub)
    return p


def _run(argv):
    args = _parser().parse_args(argv)
    return args.func(args)


def test_cli_is_registered_in_the_main_command():
    import ddpc_codegen.cli.main as main_cli

    assert "ddpc_codegen.cli.sim" in main_cli._COMMAND_MODULES


def test_simulate_json(capsys, tmp_path):
    png = tmp_path / "hop.png"
    rc = _run(["simulate", "--scenario", "hopping", "--duration", "3", "--json", "--no-progress", "--plot", str(png)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["scenario"] == "hopping" and out["crashed"] is False
    assert png.exists() and png.stat().st_size > 1000


def test_collect_writes_dataset(capsys, tmp_path):
    path = tmp_path / "fly.npz"
    rc = _run(["collect", "--scenario", "flying", "--duration", "6", "-o", str(path), "--json", "--no-progress",
               "--amplitude", "0.04,0.02", "--noise", "--push", "4,5,0,0,0.1"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    ds = IODataset.load(path)
    assert ds.m == 2 and ds.p == 2 and ds.input_names == ("z_ref", "pitch_ref")
    assert out["n_samples"] == ds.n_samples
    assert ds.metadata["excitation"]["amplitude"] == [0.04, 0.02]


def test_cli_errors_are_config_errors():
    with pytest.raises(ConfigError):
        _run(["collect", "--scenario", "hopping", "-o", "x.npz", "--amplitude", "1,2", "--no-progress"])
    with pytest.raises(ConfigError):
        _run(["simulate", "--push", "1,2", "--no-progress"])


def test_figures(tmp_path):
    r = simulate("flying", 3.0)
    f1 = save_figure(plot_result([r, r], labels=["a", "b"]), tmp_path / "a.png", dpi=50)
    f2 = save_figure(plot_tracking(r), tmp_path / "b.png", dpi=50)
    assert f1.exists() and f2.exists()
    assert np.isfinite(r.y).all()
