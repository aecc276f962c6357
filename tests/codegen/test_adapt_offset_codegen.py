"""The generated output-offset update (``[adapt] offset``) equals the numpy reference (design/adapter.py): the
estimate, its verification and what a swap installs; absurd columns install no offset in either."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.codegen.artifact import compile_alone
from ddpc_codegen.design.adaptation import AdaptiveProblem
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.fit import fit_incremental
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.values.adapt import OFFSET_COUNTS, REJECTIONS, AdaptSettings
from support.lti import random_lti

pytestmark = pytest.mark.compiler
# one solver name for every build (as in test_adapt_codegen.py): sources that do not differ are compiled once
NAME = "ad"


def _problem(form: str, knots=None) -> SteeringProblem:
    sys_ = random_lti(4, 2, 2, 0)
    rng = np.random.default_rng(0)
    u = rng.standard_normal((400, 2)) * [0.3, 2.0]
    y, _ = sys_.simulate(u, np.zeros(4))
    ds = IODataset(u, y + 1e-3 * rng.standard_normal(y.shape), 0.01)
    pred = fit_incremental(ds, 5, 6, "lsq", ridge=1e-5) if form == "incremental" else \
        fit_predictor(ds, 4, 6, "pem", ridge=1e-5)
    cfg = SteeringConfig(t_ini=pred.t_ini, t_f=6, m=2, p=2, Q=[10.0, 3.0], R=[1.0, 0.5], R_mode="offset",
                         lambda_sigma=50.0, knots=knots, du_max=[0.05, 0.5], predictor={"method": pred.method})
    return SteeringProblem(pred, cfg)


def _arr(ffi, ptr, n):
    return np.frombuffer(ffi.buffer(ptr, 8 * n), dtype=np.float64).copy()


def _close(got, want, tol=1e-9):
    return got.shape == want.shape and np.abs(got - want).max() <= tol * max(1.0, np.abs(want).max())


@pytest.mark.parametrize("form, knots, gain", [("absolute", None, 0.0), ("incremental", [0, 2, 5], np.inf)])
def test_generated_offset_equals_the_numpy_reference(form, knots, gain, tmp_path):
    """Windows from a changed system with a constant output disturbance: at every re-solve C and numpy estimate
    the same offset (clipped alike on the second output) whatever the verdict on G (gain 0: every G refused),
    verify it alike, install the same parts, count alike, and steer alike after each swap and after a reset
    (1e-9)."""
    prob = _problem(form, knots)
    st = AdaptSettings(enabled=True, forgetting=0.99, window=40, max_change=0.3, min_excitation=1e-4,
                       max_gain_change=gain, offset=True, max_offset=(1.0, 0.02))
    name = NAME
    ffi, lib = compile_alone(prob, st, tmp_path, name)
    twin = AdaptiveProblem(prob, st, solver="fast")
    ref = twin.adapter
    fn = {k: getattr(lib, f"{name}_{k}") for k in ("adapt_init", "adapt_push", "adapt_snapshot", "adapt_resolve",
                                                   "adapt_swap", "init", "solve", "reset")}
    ws, sws = ffi.new(f"{name}_adapt_workspace *"), ffi.new(f"{name}_workspace *")
    assert fn["adapt_init"](ws) == 0 and fn["init"](sws) == 0
    lay, n_y = ref.layout, prob.predictor.Gy_w.shape[0]
    rng = np.random.default_rng(1)
    u = rng.standard_normal((400, 2)) * [0.3, 2.0]
    y, _ = random_lti(4, 2, 2, 7).simulate(u, np.zeros(4))
    y = y + [0.4, -0.1]  # a constant disturbance (a payload): an offset the fit has no term for
    sig = np.hstack([np.diff(u, axis=0), np.diff(y, axis=0)]) if form == "incremental" else np.hstack([u, y])
    thetas = rng.standard_normal((8, prob.n_theta)) * 0.05
    out = np.empty(prob.n_u)
    verdicts, answers = [], 0
    for k in range(300):
        win = np.ascontiguousarray(sig[k : k + lay.depth])
        assert fn["adapt_push"](ws, ffi.from_buffer("double[]", win)) == int(ref.push(win))
        if k % 40 != 39:
            continue
        fn["adapt_snapshot"](ws)
        res, verdict = fn["adapt_resolve"](ws), ref.resolve()
        verdicts.append(verdict)
        assert res == (0 if verdict == "accepted" else 1 + REJECTIONS.index(verdict))
        assert ws.off_pending == (ref.pending_offset is not None)
        staged = _arr(ffi, ws.yoff, 2 * n_y)[ws.off_spare * n_y : (ws.off_spare + 1) * n_y]
        assert _close(staged, ref.offset_estimate), np.abs(staged - ref.offset_estimate).max()
        for key in ("offset_error_candidate", "offset_error_current"):
            assert abs(getattr(ws.counts, key) - ref.counts[key]) <= 1e-9 * max(1.0, ref.counts[key])
        assert fn["adapt_swap"](ws, sws) == twin.adapt_swap().code
        if ref.counts["offset_swaps"]:  # the half the swap flipped away from is the one in use
            used = _arr(ffi, ws.yoff, 2 * n_y)[(1 - ws.off_spare) * n_y : (2 - ws.off_spare) * n_y]
            assert _close(used, ref.offset)
        for th in thetas:  # the steering after the swap aims at y_des - b in both
            for again in (False, True):
                if again:
                    fn["reset"](sws)  # a reset (a failed tick) keeps the offset in use
                st_c = fn["solve"](sws, ffi.from_buffer("double[]", th), ffi.from_buffer("double[]", out), ffi.NULL)
                r = twin.solve_theta(th)
                assert (st_c == 0) == (r.status == "solved"), (st_c, r.status)
                if st_c == 0:
                    answers += 1
                    assert _close(out, r.u.reshape(-1)), np.abs(out - r.u.reshape(-1)).max()
    c = ws.counts
    assert {k: getattr(c, k) for k in OFFSET_COUNTS} == {k: ref.counts[k] for k in OFFSET_COUNTS}
    assert abs(c.offset_norm - ref.counts["offset_norm"]) <= 1e-9 * max(1.0, ref.counts["offset_norm"])
    assert ref.counts["offset_swaps"] + ref.counts["offset_rejected"] == len(verdicts)
    assert ref.counts["offset_swaps"] > 0 and ref.counts["offset_clipped"] > 0
    assert answers > 0 and np.abs(ref.offset).max() > 0.01  # the offsets and the steering were exercised
    if gain == 0.0:
        assert set(verdicts) == {"gain"} and ref.counts["swaps"] == 0  # offsets alone
    else:
        assert ref.counts["swaps"] > 0  # the offset after a G swap is the new G's


def test_plain_adaptive_build_without_offset_never_shifts(tmp_path):
    """offset = false: the C stages no offset and steers as the twin without one after its swaps."""
    prob = _problem("absolute")
    st = AdaptSettings(enabled=True, forgetting=0.99, window=40, max_change=0.3, min_excitation=1e-4,
                       max_gain_change=np.inf)
    ffi, lib = compile_alone(prob, st, tmp_path, NAME)
    twin = AdaptiveProblem(prob, st, solver="fast")
    ws, sws = ffi.new("ad_adapt_workspace *"), ffi.new("ad_workspace *")
    assert lib.ad_adapt_init(ws) == 0 and lib.ad_init(sws) == 0
    rng = np.random.default_rng(3)
    th, out = rng.standard_normal(prob.n_theta) * 0.05, np.empty(prob.n_u)
    for _ in range(3):
        for _ in range(45):
            win = np.ascontiguousarray(rng.standard_normal((10, 4)) + 0.5)  # an offset the fit has no term for
            lib.ad_adapt_push(ws, ffi.from_buffer("double[]", win))
            twin.adapter.push(win)
        lib.ad_adapt_snapshot(ws)
        lib.ad_adapt_resolve(ws)
        twin.adapt_resolve()
        lib.ad_adapt_swap(ws, sws)
        twin.adapt_swap()
        assert ws.off_pending == 0 and ws.counts.offset_swaps == 0 and not np.any(twin.adapt_offset())
        assert lib.ad_solve(sws, ffi.from_buffer("double[]", th), ffi.from_buffer("double[]", out), ffi.NULL) == 0
        assert _close(out, twin.solve_theta(th).u.reshape(-1))


def _same(got: float, want: float) -> bool:
    """Equal to 1e-9, or both the same non-finite (the sums of 1e300 columns)."""
    if not np.isfinite(want):
        return not np.isfinite(got) and (np.isnan(want) == np.isnan(got))
    return abs(got - want) <= 1e-9 * max(1.0, abs(want))


_ABSURD = AdaptSettings(enabled=True, forgetting=0.99, window=100, offset=True, max_gain_change=0.0)


@pytest.fixture(scope="module")
def absurd_build(tmp_path_factory):
    """The absolute-form problem and its build with _ABSURD, compiled once for both probes (each test makes its
    own workspaces and twin)."""
    prob = _problem("absolute")
    return prob, compile_alone(prob, _ABSURD, tmp_path_factory.mktemp("absurd"), NAME)


@pytest.mark.parametrize("probe", ["outliers", "1e300"])
def test_absurd_columns_install_no_offset_in_c_either(probe, absurd_build):
    """A genuine output offset is installed (C and numpy alike, the default finite max_offset); then 1 % outliers
    of 1e7 or 1e300 samples in the recent window: the estimate is refused by both, the offset in use stays, and
    the solver still solves."""
    prob, (ffi, lib) = absurd_build
    st = _ABSURD
    name = NAME
    twin = AdaptiveProblem(prob, st, solver="fast")
    ref = twin.adapter
    assert np.all(np.isfinite(ref.max_offset))
    fn = {k: getattr(lib, f"{name}_{k}") for k in ("adapt_init", "adapt_push", "adapt_snapshot", "adapt_resolve",
                                                   "adapt_swap", "init", "solve")}
    ws, sws = ffi.new(f"{name}_adapt_workspace *"), ffi.new(f"{name}_workspace *")
    assert fn["adapt_init"](ws) == 0 and fn["init"](sws) == 0
    lay, n_y = ref.layout, prob.predictor.Gy_w.shape[0]
    rng = np.random.default_rng(5)
    u = rng.standard_normal((600, 2)) * [0.3, 2.0]
    y, _ = random_lti(4, 2, 2, 0).simulate(u, np.zeros(4))  # the fitted system, with a payload's offset
    y = y + 1e-3 * rng.standard_normal(y.shape) + [0.3, -0.1]
    if probe == "outliers":
        y[50::100] += 1e7  # 1 % of the samples, one in the last window at least
    else:
        y[-20:] = 1e300
    sig = np.hstack([u, y])
    codes = []
    for half in (0, 1):
        for k in range(half * 300, (half + 1) * 300 - lay.depth + 1):
            win = np.ascontiguousarray(sig[k : k + lay.depth])
            if half == 0 and np.abs(win).max() > 1e6:
                continue  # the first half: genuine windows only
            assert fn["adapt_push"](ws, ffi.from_buffer("double[]", win)) == int(ref.push(win))
        fn["adapt_snapshot"](ws)
        fn["adapt_resolve"](ws)
        ref.resolve()
        assert ws.off_pending == (ref.pending_offset is not None)
        for key in ("offset_error_candidate", "offset_error_current"):
            assert _same(getattr(ws.counts, key), ref.counts[key]), (key, getattr(ws.counts, key), ref.counts[key])
        code = fn["adapt_swap"](ws, sws)
        assert code == twin.adapt_swap().code
        codes.append(code)
        used = _arr(ffi, ws.yoff, 2 * n_y)[(1 - ws.off_spare) * n_y : (2 - ws.off_spare) * n_y]
        assert _close(used, ref.offset)
    assert codes == [2, 0]  # the genuine offset installed, the absurd estimate not (no G: max_gain_change 0)
    assert ref.counts["offset_swaps"] == 1 and ref.counts["offset_rejected"] == 1
    assert np.abs(ref.offset).max() < 1.0  # the payload's, not the outliers'
    th, out = rng.standard_normal(prob.n_theta) * 0.05, np.empty(prob.n_u)
    assert fn["solve"](sws, ffi.from_buffer("double[]", th), ffi.from_buffer("double[]", out), ffi.NULL) == 0
    assert _close(out, twin.solve_theta(th).u.reshape(-1))
