"""The online update's C timing program (make bench): built natively and for aarch64 (run under qemu), it times
the pushes and re-solves the Python build times, agrees with it and with itself across the two builds, and
refuses to report a time when a result is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.codegen import standalone
from ddpc_codegen.codegen.emit import DEFAULTS, emit_sources
from ddpc_codegen.design.adaptation import adapter, fit_layout
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.errors import CodegenError
from ddpc_codegen.experiments import bench_adapt_cross as cross
from ddpc_codegen.experiments.bench_adapt import adapt_lines
from ddpc_codegen.values.adapt import REJECTIONS, AdaptSettings
from support.cc_cache import cross_wrapper
from support.lti import random_lti

pytestmark = pytest.mark.compiler
# the solver name of tests/codegen/test_adapt_codegen.py's builds of this problem: a source that comes out the
# same is compiled once in a test run (tests/support/cc_cache.py)
NAME = "ad"


def _problem() -> SteeringProblem:
    """The small absolute-form problem of tests/codegen/test_adapt_codegen.py (m = p = 2, Tini 4, Tf 6)."""
    sys_ = random_lti(4, 2, 2, 0)
    rng = np.random.default_rng(0)
    u = rng.standard_normal((400, 2)) * [0.3, 2.0]
    y, _ = sys_.simulate(u, np.zeros(4))
    pred = fit_predictor(IODataset(u, y + 1e-3 * rng.standard_normal(y.shape), 0.01), 4, 6, "pem", ridge=1e-5)
    cfg = SteeringConfig(t_ini=pred.t_ini, t_f=6, m=2, p=2, Q=[10.0, 3.0], R=[1.0, 0.5], R_mode="offset",
                         lambda_sigma=50.0, predictor={"method": pred.method})
    return SteeringProblem(pred, cfg)


def test_missing_tools_give_no_figures_and_say_why(monkeypatch, tmp_path):
    monkeypatch.setattr(standalone, "aarch64_tools", lambda: None)
    said = []
    assert cross.cross_figures(tmp_path, np.zeros((1, 4)), 1, log=said.append) is None
    assert standalone.MISSING_AARCH64 in said[0]
    row = {"size": "flying", "width": 1, "update_us_median": 1.0, "update_us_p99": 2.0, "resolve_ms_median": 1.0,
           "resolve_ms_max": 1.0, "aarch64_qemu": None, "aarch64_qemu_note": standalone.MISSING_AARCH64}
    assert adapt_lines([row])[-1].endswith(standalone.MISSING_AARCH64)


def test_aarch64_timing_under_qemu_agrees_with_the_native_build(tmp_path, monkeypatch):
    tools = standalone.aarch64_tools()
    if tools is None:
        pytest.skip(standalone.MISSING_AARCH64)
    # the cross compiler through the session's compile cache (the library objects of tests/codegen/test_cross.py)
    tools = (cross_wrapper(tools[0]), tools[1])
    monkeypatch.setattr(standalone, "aarch64_tools", lambda: tools)
    prob, st = _problem(), AdaptSettings(enabled=True, offset=True, window=40)
    lay = fit_layout(prob.predictor)
    wins = np.random.default_rng(0).standard_normal((300, lay.depth * (lay.m + lay.p))) * 0.05  # the bench's recipe
    name = NAME
    emit_sources(prob, tmp_path, name, "daqp", dict(DEFAULTS["daqp"]), adapt=st)
    ref = adapter(prob, st)  # the numpy twin: what the C must compute
    assert all(ref.push(w.reshape(lay.depth, lay.m + lay.p)) for w in wins)
    verdict = [ref.resolve() for _ in range(3)][-1]
    verdict = 0 if verdict == "accepted" else 1 + REJECTIONS.index(verdict)
    figs = cross.cross_figures(tmp_path, wins, 3, verdict)
    assert figs["pushes"] == 300 and figs["resolves"] == 3 and figs["verdict"] == verdict
    for k in ("push_us_median", "push_us_max", "resolve_ms_median", "resolve_ms_max", "native_push_us_median", "fold_us_median",
              "native_resolve_ms_median", "qemu_over_native_push", "qemu_over_native_resolve"):
        assert np.isfinite(figs[k]) and figs[k] > 0, k
    assert figs["push_us_median"] <= figs["push_us_max"]
    row = {"size": "small", "aarch64_qemu": figs}
    assert "aarch64 (qemu), median/max: update us" in cross.cross_line("small", row)

    # the two builds (already made: make and the link are incremental) computed the same thing
    data = tmp_path / "adapt_bench_windows.bin"
    native_exe = tmp_path / "build-adapt-bench-native" / f"{name}_adapt_bench"
    native = cross.run_timer(native_exe, data, 3)
    arm = cross.run_timer(tmp_path / "build-adapt-bench-aarch64" / f"{name}_adapt_bench", data, 3, qemu=tools[1])
    assert native["verdict"] == arm["verdict"] == verdict and native["updates"] == arm["updates"] == 300
    for k in ("sum_abs_g", "sum_abs_r", "error_candidate"):
        assert arm[k] == pytest.approx(native[k], rel=1e-9, abs=1e-12), k
    assert native["sum_abs_r"] == pytest.approx(np.abs(ref.R).sum(), rel=1e-9)
    if verdict == 0:
        assert native["sum_abs_g"] == pytest.approx(np.abs(ref.pending).sum(), rel=1e-9)

    # a window with a NaN is not taken: the program exits non-zero and reports no time
    bad = wins[:5].copy()
    bad[2, 0] = np.nan
    bad.tofile(tmp_path / "bad.bin")
    with pytest.raises(CodegenError, match="window 2 .* not taken"):
        cross.run_timer(native_exe, tmp_path / "bad.bin", 1)


def _small_windows(prob: SteeringProblem, n: int = 300) -> np.ndarray:
    lay = fit_layout(prob.predictor)
    return np.random.default_rng(0).standard_normal((n, lay.depth * (lay.m + lay.p))) * 0.05  # the bench's recipe


def test_native_timing_program_stamps_every_phase_of_a_resolve(tmp_path):
    """Natively (no aarch64 tools needed): the library built with the phase clock stamps the re-solve's phases;
    each is positive, they nest inside the timed call, and the row's figures and table line carry them."""
    from ddpc_codegen.experiments.bench_adapt import _phase_figures, adapt_lines

    prob, st = _problem(), AdaptSettings(enabled=True, offset=True, window=40)
    emit_sources(prob, tmp_path, NAME, "daqp", dict(DEFAULTS["daqp"]), adapt=st)
    native = cross.native_figures(tmp_path, _small_windows(prob), 5, runs=3)
    assert native["runs"] == 3 and native["verdict"] in (0, 5)  # verified to the end (accepted, or refused by the prediction check)
    ph = native["phase_ns_median"]
    assert tuple(ph) == cross.PHASES
    assert all(ph[k] > 0 for k in ("g_solve", "qp_rebuild", "excitation", "prediction")), ph
    assert ph["fold"] >= 0 and ph["offset"] > 0  # no column handed over to the repeated snapshot: ~0
    assert sum(ph.values()) <= native["resolve_ns_max"]
    row = {"size": "small", "width": 1, "update_us_median": 1.0, "update_us_p99": 2.0, "resolve_ms_median": 1.0,
           "resolve_ms_max": 1.0, **_phase_figures(native)}
    assert row["g_rebuild_ms_median"] == pytest.approx((ph["g_solve"] + ph["qp_rebuild"]) * 1e-6, abs=2e-3)
    line = [ln for ln in adapt_lines([row]) if "re-solve phases" in ln]
    assert len(line) == 1 and "G + QP rebuild" in line[0] and "target <= 2" in line[0] and "3 processes" in line[0]
    with pytest.raises(CodegenError, match="verdict"):
        cross.native_figures(tmp_path, _small_windows(prob), 1, verdict=native["verdict"] + 1)


def test_a_build_without_the_clock_stamps_nothing(tmp_path):
    from ddpc_codegen.codegen.artifact import compile_alone

    prob, st = _problem(), AdaptSettings(enabled=True, offset=True, window=40)
    ffi, lib = compile_alone(prob, st, tmp_path, NAME)
    ws = ffi.new("ad_adapt_workspace *")
    assert lib.ad_adapt_init(ws) == 0
    for w in _small_windows(prob, 120):
        lib.ad_adapt_push(ws, ffi.from_buffer("double[]", np.ascontiguousarray(w)))
    lib.ad_adapt_snapshot(ws)
    lib.ad_adapt_resolve(ws)
    assert ws.counts.resolves == 1 and list(ws.phase_ns) == [0] * 7


def test_native_figures_refuse_a_bad_run_count_and_runs_that_disagree(tmp_path, monkeypatch):
    for bad in (0, -1, 2.0, True, "3"):
        with pytest.raises(ValueError, match="runs must be an integer >= 1"):
            cross.native_figures(tmp_path, np.zeros((1, 4)), 1, runs=bad)
    monkeypatch.setattr(cross, "build_timer", lambda *a, **k: tmp_path / "exe")
    base = {"pushes": 3, "resolves": 1, "verdict": 5, "updates": 3, "sum_abs_g": 1.0, "sum_abs_r": 2.0,
            "error_candidate": 0.5, "push_ns_median": 1.0, "push_ns_max": 2.0, "resolve_ns_median": 3.0,
            "resolve_ns_max": 4.0, "phase_ns_median": [1.0] * 6}
    outs = iter([base, {**base, "sum_abs_g": 1.1}])
    monkeypatch.setattr(cross, "run_timer", lambda *a, **k: dict(next(outs)))
    with pytest.raises(CodegenError, match="runs of the same timing program disagree"):
        cross.native_figures(tmp_path, np.zeros((1, 4)), 1, runs=2)
    outs = iter([base, {**base, "resolve_ns_median": 5.0, "resolve_ns_max": 9.0}, base])
    agg = cross.native_figures(tmp_path, np.zeros((1, 4)), 1, runs=3)  # medians of the runs' medians, max of maxes
    assert agg["runs"] == 3 and agg["resolve_ns_median"] == 3.0 and agg["resolve_ns_max"] == 9.0
    assert agg["phase_ns_median"] == dict(zip(cross.PHASES, [1.0] * 6))
