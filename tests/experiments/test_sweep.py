"""Sweeps: the spec's errors, the points, serial vs Ray tables, resume, a bad point recorded."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ddpc_codegen.cli.main import build_parser
from ddpc_codegen.errors import ConfigError
from ddpc_codegen.experiments.sweep import TIMING_COLUMNS, read_results, run_sweep
from ddpc_codegen.experiments.sweep_report import pareto_mask
from ddpc_codegen.experiments.sweep_spec import SweepSpec

ROOT = Path(__file__).resolve().parents[2]

TINY = f"""
[sweep]
scenario = "flying"
config = "{ROOT / 'configs' / 'flying.toml'}"
duration = 4.0   # 3 s settle time + 1 s scored
seeds = [0]

[data]
duration = 20.0

[space]
"cost.R" = [[0.5, 0.5], [0.3, 0.3], [-1.0, 0.5]]   # the last one is not a valid weight
"""


def _spec(tmp_path: Path, text: str, name: str = "spec.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _table(path: Path) -> list[dict[str, str]]:
    """The results table without the columns that time this machine."""
    return [{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in read_results(path)]


# ----------------------------------------------------------------------------- spec
@pytest.mark.parametrize("body, where", [
    ('[sweep]\nscenaro = "flying"', "[sweep] scenaro"),
    ('[sweep]\nscenario = "rolling"', "'rolling'"),
    ('[space]\n"cost.Rr" = [1.0]', "'cost.Rr'"),
    ('[space]\n"signals.inputs" = [["a", "b"]]', "'signals.inputs'"),
    ('[space]\n"cost.R" = {log_uniform = [0.1, 1.0]}', "grid search"),
    ('[sweep]\nsearch = "random"\n[space]\n"predictor.ridge" = {log_uniform = [0.0, 1.0]}', "low > 0"),
    ('[conditions.windy]\npushes = [[1.0, 2.0]]', "[conditions.windy] pushes"),
    ('[conditions.heavy]\nmass_error = "lots"', "[conditions.heavy] mass_error"),
    ('[sweep]\nobjective = "apex_error_mean_abs"', "not a flying metric"),
    ('[data]\nduraton = 3.0', "[data] duraton"),
])
def test_spec_errors_name_the_file_key_and_value(tmp_path, body, where):
    path = _spec(tmp_path, body)
    with pytest.raises(ConfigError) as e:
        SweepSpec.from_toml(path)
    assert str(path) in str(e.value) and where in str(e.value), str(e.value)


def test_grid_and_random_points(tmp_path):
    grid = SweepSpec.from_toml(_spec(tmp_path, TINY + '\n[conditions.nominal]\n[conditions.noisy]\nnoise = true\n'))
    pts = grid.points()
    # baselines per condition x seed, then 3 variants x 2 conditions x 1 seed
    assert [p.kind for p in pts] == ["baseline"] * 2 + ["steered"] * 6
    assert len({p.id for p in pts}) == len(pts) and [p.index for p in pts] == list(range(8))
    assert pts[2].condition.name == "nominal" and pts[3].condition.run_kwargs()["noise"] is True
    rnd = '[sweep]\nsearch = "random"\nsamples = 5\nseed = 3\n[space]\n"predictor.ridge" = {log_uniform = [1e-4, 1e-1]}\n"horizon.t_f" = {int_uniform = [10, 20]}\n"cost.R_mode" = ["offset", "increment"]\n'
    a = SweepSpec.from_toml(_spec(tmp_path, rnd, "r.toml")).variants()
    assert a == SweepSpec.from_toml(_spec(tmp_path, rnd, "r.toml")).variants()  # seeded: reproducible
    assert len(a) == 5 and all(1e-4 <= dict(v)["predictor.ridge"] <= 1e-1 and 10 <= dict(v)["horizon.t_f"] <= 20 for v in a)


def test_pareto_mask():
    v = np.array([[1.0, 5.0], [2.0, 2.0], [3.0, 3.0], [5.0, 1.0], [np.nan, 0.0]])
    assert pareto_mask(v).tolist() == [True, True, False, True, False]


@pytest.mark.parametrize("scenario, duration", [("flying", 3.5), ("hopping", 1.5)])
def test_table_metrics_are_the_runs_metrics(scenario, duration):
    """The table's metric names are scenario_metrics' (a rename there must show up here)."""
    from ddpc_codegen.experiments.evaluate import run
    from ddpc_codegen.experiments.sweep_spec import METRICS

    res = run(None, scenario, duration, steer=False)
    assert set(METRICS[scenario]) <= set(res.metrics), set(METRICS[scenario]) - set(res.metrics)


def test_cli_registers_sweep():
    a = build_parser().parse_args(["sweep", "s.toml", "--workers", "2", "--resume", "--address", "auto"])
    assert a.func.__name__ == "_cmd_sweep" and a.workers == 2 and a.resume and a.address == "auto"


# ----------------------------------------------------------------------------- runs
@pytest.fixture(scope="module")
def tiny_spec(tmp_path_factory):
    """One spec file for the serial and the parallel sweeps (error messages name its path)."""
    return _spec(tmp_path_factory.mktemp("spec"), TINY)


@pytest.fixture(scope="module")
def serial(tiny_spec, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "out"
    summary = run_sweep(tiny_spec, out, workers=1, progress=False)
    return out, summary


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray runtime (127.0.0.1, 2 CPUs) for the module; shut down after it."""
    pytest.importorskip("ray")
    from ddpc_codegen.cluster import engine

    with engine(2, quiet=True) as eng:
        yield eng


@pytest.mark.compiler
@pytest.mark.slow
def test_bad_point_is_recorded_and_the_sweep_goes_on(serial):
    out, summary = serial
    rows = read_results(out / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "ok", "ok", "error"] and summary["errors"] == 1
    assert "ConfigError" in rows[3]["error"] and "[cost] R" in rows[3]["error"] and "-1.0" in rows[3]["error"]
    base, steered = float(rows[0]["rmse_z"]), float(rows[2]["rmse_z"])
    assert steered * 3 < base and rows[2]["solver"] == "generated:daqp" and float(rows[2]["solve_us_p50"]) > 0
    # the best configuration is a codegen-ready TOML next to its dataset
    from ddpc_codegen.values.config import SteeringConfig

    best = SteeringConfig.from_toml(out / "best.toml")
    assert best.R.diagonal().tolist() == [0.3, 0.3] and Path(best.dataset).exists()
    assert (out / "pareto.png").stat().st_size > 0


@pytest.mark.compiler
@pytest.mark.slow
def test_ray_sweep_equals_serial_and_resumes_after_an_interruption(serial, tiny_spec, local_ray, tmp_path):
    out_serial, _ = serial
    spec = tiny_spec
    out = tmp_path / "out"
    seen: list[str] = []

    def interrupt_after_two(row):
        seen.append(row["id"])
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, out, workers=2, progress=False, on_row=interrupt_after_two)
    assert len(read_results(out / "results.csv")) == 2  # the finished points are on disk
    with pytest.raises(ConfigError, match="--resume"):
        run_sweep(spec, out, workers=2, progress=False)
    again: list[str] = []
    summary = run_sweep(spec, out, workers=2, progress=False, resume=True, on_row=lambda r: again.append(r["id"]))
    assert summary["resumed_from"] == 2 and summary["ran"] == 2 and not set(again) & set(seen)
    assert _table(out / "results.csv") == _table(out_serial / "results.csv")  # bit for bit, timing aside


def test_spread_variants_starts_workers_on_different_variants():
    from ddpc_codegen.experiments.sweep import spread_variants
    from ddpc_codegen.experiments.sweep_spec import Point

    pts = [Point(i, "steered", (("cost.R", [v, 1.0]),), None, s) for i, (v, s) in
           enumerate((v, s) for v in range(5) for s in range(3))]
    assert spread_variants(pts, 1) == pts  # serial: unchanged
    for w in (2, 3, 4):
        out = spread_variants(pts, w)
        assert sorted(p.index for p in out) == list(range(len(pts)))  # a permutation
        assert len({p.variant for p in out[:w]}) == w  # the first w workers get w different variants
