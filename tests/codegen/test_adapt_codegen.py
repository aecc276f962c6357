"""The generated online update (``<name>_adapt.c``) equals the numpy reference (runtime/adaptation.py)."""

from __future__ import annotations

import dataclasses
import subprocess

import numpy as np
import pytest

from ddpc_codegen.codegen.artifact import compile_alone
from ddpc_codegen.design.adaptation import AdaptiveProblem, adapter
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.fit import fit_incremental
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.values.adapt import REJECTIONS, AdaptSettings
from support.lti import random_lti

# every test but test_adaptation_needs_the_daqp_backend compiles the generated update (cffi)
pytestmark = pytest.mark.compiler
# One solver name for every build of this file: a generated source that does not depend on the problem (or one
# of the same problem) is then the same source, which the test run's compile cache reuses
# (tests/support/cc_cache.py); each build still loads as its own module (compile_alone).
NAME = "ad"


def _dataset(seed: int, T: int = 400) -> IODataset:
    sys_ = random_lti(4, 2, 2, seed)
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((T, 2)) * [0.3, 2.0]
    y, _ = sys_.simulate(u, np.zeros(4))
    return IODataset(u, y + 1e-3 * rng.standard_normal(y.shape), 0.01)


def _problem(form: str, knots=None, bounded: bool = False) -> SteeringProblem:
    ds = _dataset(0)
    pred = fit_incremental(ds, 5, 6, "lsq", ridge=1e-5) if form == "incremental" else \
        fit_predictor(ds, 4, 6, "pem", ridge=1e-5)
    rows = dict(y_min=[-0.05, -np.inf], y_max=[0.05, 0.5], du_max=[0.05, 0.5]) if bounded else {}
    cfg = SteeringConfig(t_ini=pred.t_ini, t_f=6, m=2, p=2, Q=[10.0, 3.0], R=[1.0, 0.5], R_mode="offset",
                         lambda_sigma=50.0, knots=knots, predictor={"method": pred.method}, **rows)
    return SteeringProblem(pred, cfg)


def _arr(ffi, ptr, n):
    return np.frombuffer(ffi.buffer(ptr, 8 * n), dtype=np.float64).copy()


def _qp_buffer(ffi, qd, prob) -> dict:
    """The QP data a C qpdata view points at, as numpy arrays of the problem's shapes."""
    nz, ng, nth = prob.n_z, prob.n_g, prob.n_theta
    g1 = max(1, ng)
    return {"P": _arr(ffi, qd.P, nz * nz).reshape(nz, nz),
            "A_g": _arr(ffi, qd.A_G, g1 * nz).reshape(g1, nz)[:ng],
            "F_q": _arr(ffi, qd.F_Q_CM, nz * nth).reshape(nth, nz).T,
            "F_g": _arr(ffi, qd.F_G_CM, g1 * nth).reshape(nth, g1).T[:ng],
            "K": _arr(ffi, qd.K, nz * nth).reshape(nth, nz).T}


def _r_of(ffi, lib, name, ws, w):
    """The C update's current R factor (w, w), through its public reader ``<name>_adapt_r``."""
    out = ffi.new(f"double[{w * w}]")
    getattr(lib, f"{name}_adapt_r")(ws, out)
    return _arr(ffi, out, w * w).reshape(w, w)


def _close(got, want, tol=1e-9):
    return got.shape == want.shape and (want.size == 0 or np.abs(got - want).max() <= tol * max(1.0, np.abs(want).max()))


MARGIN = 0.2  # [adapt] min_improvement of the case with a margin: between this system's smallest and largest cut


@pytest.mark.parametrize("form, knots, bounded, gain, margin", [
    ("absolute", None, False, 1e3, 0.0), ("incremental", None, True, 1e3, 0.0), ("absolute", [0, 2, 5], True, 1e3, 0.0),
    ("absolute", None, False, 0.0, 0.0), ("absolute", None, False, 1e3, MARGIN)])
def test_generated_update_equals_the_numpy_reference(form, knots, bounded, gain, margin, tmp_path):
    """Windows from a changed system, a re-solve every 40: R, G, the verdicts, the counters (the errors of the
    last check too), the rebuilt QP data (P, F_q, output rows, K) and the steering answers after each swap of C
    and numpy agree to 1e-9."""
    prob = _problem(form, knots, bounded)
    # the gain bound between the changes of this system and the swaps it needs: both verdicts occur
    st = AdaptSettings(enabled=True, forgetting=0.99, window=40, max_change=0.3, min_excitation=1e-4,
                       max_gain_change=gain, min_improvement=margin)
    name = NAME
    ffi, lib = compile_alone(prob, st, tmp_path, name)
    twin = AdaptiveProblem(prob, st, solver="fast")
    ref = twin.adapter
    ws = ffi.new(f"{name}_adapt_workspace *")
    sws = ffi.new(f"{name}_workspace *")
    assert getattr(lib, f"{name}_adapt_init")(ws) == 0 and getattr(lib, f"{name}_init")(sws) == 0
    lay = ref.layout
    w, q = lay.width, lay.q_y + lay.q_s
    np.testing.assert_allclose(_arr(ffi, ws.G, q * lay.r).reshape(q, lay.r), ref.G, rtol=0, atol=1e-12)
    other = random_lti(4, 2, 2, 7)
    rng = np.random.default_rng(1)
    u = rng.standard_normal((400, 2)) * [0.3, 2.0]
    y, _ = other.simulate(u, np.zeros(4))
    sig = np.hstack([np.diff(u, axis=0), np.diff(y, axis=0)]) if form == "incremental" else np.hstack([u, y])
    thetas = rng.standard_normal((12, prob.n_theta)) * 0.05
    solve, out = getattr(lib, f"{name}_solve"), np.empty(prob.n_u)
    verdicts, solved = [], 0
    for k in range(300):
        win = np.ascontiguousarray(sig[k : k + lay.depth])
        if k == 50:
            win = win.copy()
            win[3, 1] = np.nan  # skipped by both
        c_ok = getattr(lib, f"{name}_adapt_push")(ws, ffi.from_buffer("double[]", win))
        assert c_ok == int(ref.push(win))
        if k % 40 != 39:
            continue
        getattr(lib, f"{name}_adapt_snapshot")(ws)  # the synchronous re-solve: snapshot, resolve, swap
        res = getattr(lib, f"{name}_adapt_resolve")(ws)
        verdict = ref.resolve()
        verdicts.append(verdict)
        assert res == (0 if verdict == "accepted" else 1 + REJECTIONS.index(verdict))
        if verdict == "accepted":
            np.testing.assert_allclose(_arr(ffi, ws.Gc, q * lay.r).reshape(q, lay.r), ref.pending,
                                       rtol=0, atol=1e-9 * np.abs(ref.pending).max())
            built = _qp_buffer(ffi, ws.qd[ws.spare], prob)
            for key, got in built.items():
                assert _close(got, getattr(ref.pending_qp, key)), key
        assert getattr(lib, f"{name}_adapt_swap")(ws, sws) == twin.adapt_swap().code
        np.testing.assert_allclose(_arr(ffi, ws.G, q * lay.r).reshape(q, lay.r), ref.G, rtol=0,
                                   atol=1e-9 * np.abs(ref.G).max())
        for th in thetas:  # the steering after the swap: C on the swapped-in buffer, numpy on the rebuild
            st_c = solve(sws, ffi.from_buffer("double[]", th), ffi.from_buffer("double[]", out), ffi.NULL)
            r = twin.solve_theta(th)
            assert (st_c == 0) == (r.status == "solved"), (st_c, r.status)
            if st_c == 0:
                solved += 1
                assert _close(out, r.u.reshape(-1)), np.abs(out - r.u.reshape(-1)).max()
    R_c = _r_of(ffi, lib, name, ws, w)
    np.testing.assert_allclose(R_c, ref.R, rtol=0, atol=1e-9 * np.abs(ref.R).max())
    c = ws.counts
    assert (c.updates, c.skipped, c.resolves, c.accepted, c.swaps, c.clipped) == tuple(
        ref.counts[k] for k in ("updates", "skipped", "resolves", "accepted", "swaps", "clipped"))
    assert [c.rejected[i + 1] for i in range(len(REJECTIONS))] == [ref.counts[f"rejected_{r}"] for r in REJECTIONS]
    for k in ("error_current", "error_candidate"):
        assert _close(np.array([getattr(c, k)]), np.array([ref.counts[k]])), k
    if margin > 0:  # the margin refuses some candidates that cut the error by less, and lets a larger cut through
        assert "prediction" in verdicts and "accepted" in verdicts and solved > 0
    elif gain > 0:
        assert "accepted" in verdicts and solved > 0  # the changed system is learnt: at least one verified swap
        assert twin.problem is not prob and not _close(twin.problem.P, prob.P, 1e-6)  # and it changed the QP
    else:  # no steady-state gain may move: every candidate that gets that far is refused, nothing swapped
        assert "gain" in verdicts and "accepted" not in verdicts and twin.problem is prob and c.swaps == 0


def test_rank_deficient_factor_is_refused_at_init(tmp_path):
    """ridge 0 on noise-free data: R11 is singular, the C init refuses (as the reference does)."""
    sys_ = random_lti(2, 1, 1, 3)
    u = np.random.default_rng(3).standard_normal((300, 1))
    y, _ = sys_.simulate(u, np.zeros(2))
    pred = fit_predictor(IODataset(u, y, 0.01), 4, 3, "lsq")
    prob = SteeringProblem(pred, SteeringConfig(t_ini=4, t_f=3, m=1, p=1, Q=[1.0], R=[1.0], R_mode="offset",
                                                predictor={"method": "lsq"}))
    from ddpc_codegen.errors import DataError

    with pytest.raises(DataError, match=r"^the shipped R factor is rank deficient"):
        compile_alone(prob, AdaptSettings(window=10), tmp_path, NAME)


@pytest.mark.slow
def test_generate_with_adaptation_emits_the_update_into_every_build_file(tmp_path):
    """generate(adapt=...) and the config's [adapt]: the extension carries <name>_adapt_*, the manifest the fit
    statistic and the settings, CMakeLists and Makefile list the update's sources; adapt disabled emits exactly
    the plain build; a plain solver refuses the adaptation API with a precise message."""
    import json

    from ddpc_codegen.codegen import generate
    from ddpc_codegen.errors import DataError
    from ddpc_codegen.runtime.loader import load_solver

    prob = _problem("incremental")
    st = AdaptSettings(enabled=True, forgetting=0.995, window=40)
    on_cfg = SteeringProblem(prob.predictor, prob.config.replace(adapt={"enabled": True, "forgetting": 0.995,
                                                                        "window": 40}))
    # "off" is compared with "plain" source for source: what is emitted, so it is not compiled
    folders = {k: generate(p, tmp_path / k, name="adsolver", n_vectors=4, adapt=a, compile=k != "off")
               for k, p, a in (("plain", prob, None), ("off", prob, AdaptSettings()), ("on", prob, st),
                               ("config", on_cfg, None))}
    files = {k: sorted(p.name for p in f.iterdir() if p.suffix in (".c", ".h", ".txt") or p.name == "Makefile")
             for k, f in folders.items()}
    assert files["plain"] == files["off"]
    assert all((folders["plain"] / f).read_bytes() == (folders["off"] / f).read_bytes() for f in files["plain"])
    man = {k: json.loads((f / "manifest.json").read_text()) for k, f in folders.items() if k != "off"}
    extra = set(man["on"]["sources"]) - set(man["plain"]["sources"])
    units = {f"adsolver_{s}.c" for s in ("adapt", "adapt_factor", "adapt_rebuild", "adapt_data")}
    assert extra == units | {"adsolver_adapt.h", "adsolver_adapt_impl.h", "adsolver_adapt_data.h"}
    for build_file in ("CMakeLists.txt", "Makefile"):
        text = (folders["on"] / build_file).read_text()
        assert all(u in text for u in units)
        assert "adsolver_adapt" not in (folders["plain"] / build_file).read_text()
    # the folder builds without Python (strict C99) with the update in its library, and replays its vectors
    make = subprocess.run(["make", "-C", str(folders["on"]), "check", "BUILD=build-check"], capture_output=True,
                          text=True, timeout=600)
    assert make.returncode == 0, make.stdout[-2000:] + make.stderr[-2000:]
    built = " ".join(p.name for p in (folders["on"] / "build-check").iterdir())
    assert all(u.replace(".c", ".o") in built for u in units)
    assert man["on"]["adapt"] == man["config"]["adapt"] == dataclasses.asdict(st) and "adapt" not in man["plain"]
    fs = man["on"]["fit_statistic"]
    assert fs["adapt"]["forgetting"] == 0.995 and fs["signal"] == "increments"
    np.testing.assert_array_equal(np.load(folders["on"] / fs["file"]), adapter(prob, st).R0)  # data only
    solver = load_solver(folders["on"])
    assert solver.adapt_settings == st and solver.adapt_counts()["updates"] == 0
    assert not solver.adapt_swap() and solver.adapt_resolve() in REJECTIONS  # nothing pushed: no excitation
    rng = np.random.default_rng(0)
    assert any(solver.adapt_push(rng.standard_normal(2), rng.standard_normal(2)) for _ in range(200))
    assert solver.adapt_refused() == 0 and not solver.adapt_push(np.zeros(2), np.full(2, np.nan))
    assert solver.adapt_refused() == 1 == solver.adapt_counts()["skipped"]  # a full window's column, refused
    plain = load_solver(folders["plain"])
    assert plain.adaptation is None
    with pytest.raises(DataError, match=r"^solver 'adsolver' was generated without \[adapt\] enabled: it has no "
                                        r"online update$"):
        plain.adapt_push(np.zeros(2), np.zeros(2))


def test_adaptation_needs_the_daqp_backend(tmp_path):
    from ddpc_codegen.codegen import generate
    from ddpc_codegen.errors import CodegenError

    with pytest.raises(CodegenError, match=r"online adaptation \(\[adapt\] enabled\) needs the daqp backend; got "
                                           r"'osqp' \(the embedded OSQP bakes the Hessian and the constraint matrix "
                                           r"into its generated workspace\)$"):
        generate(_problem("absolute"), tmp_path / "o", name="adosqp", backend="osqp", compile=False,
                 adapt=AdaptSettings(enabled=True))


# ---- the re-solve off the tick path: snapshot, later pushes, re-solve, later pushes, swap (issue 30 follow-up)
_SPLIT = AdaptSettings(enabled=True, forgetting=0.99, window=40, max_change=0.3, min_excitation=1e-4,
                       max_gain_change=1e3, offset=True, max_offset=(1.0, 0.02))


@pytest.fixture(scope="module")
def split_build(tmp_path_factory):
    """An unbounded absolute-form problem with the output offset, built once; its windows from a changed system."""
    prob = _problem("absolute")
    ffi, lib = compile_alone(prob, _SPLIT, tmp_path_factory.mktemp("split"), NAME)
    rng = np.random.default_rng(5)
    u = rng.standard_normal((700, 2)) * [0.3, 2.0]
    y, _ = random_lti(4, 2, 2, 7).simulate(u, np.zeros(4))
    return prob, ffi, lib, np.hstack([u, y + [0.3, -0.05]])


def test_resolve_from_an_earlier_snapshot_equals_the_numpy_reference(split_build):
    """Hypothesis draws the schedule: pushes, a snapshot, more pushes (the ticks a background re-solve spans), the
    re-solve from the snapshot, more pushes, the swap. Verdicts, candidate G, staged offset, G and the offset in
    use after the swap, R and every counter of C and numpy agree to 1e-9; the re-solve saw the snapshot, not the
    later columns (a re-solve of the current state differs once columns came in between)."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as hs

    prob, ffi, lib, sig = split_build
    fn = {k: getattr(lib, f"ad_adapt_{k}") for k in ("init", "push", "snapshot", "resolve", "swap")}
    rounds = hs.lists(hs.tuples(hs.integers(0, 45), hs.integers(0, 30), hs.integers(0, 8)), min_size=1, max_size=4)

    @settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))
    @given(rounds)
    def check(schedule):
        twin = AdaptiveProblem(prob, _SPLIT, solver="fast")
        ref, lay = twin.adapter, twin.adapter.layout
        q, n_y = lay.q_y + lay.q_s, prob.predictor.Gy_w.shape[0]
        ws, sws = ffi.new("ad_adapt_workspace *"), ffi.new("ad_workspace *")
        assert fn["init"](ws) == 0 and lib.ad_init(sws) == 0
        k = 0

        def push(n):
            nonlocal k
            for _ in range(n):
                win = np.ascontiguousarray(sig[k % 600 : k % 600 + lay.depth])
                assert fn["push"](ws, ffi.from_buffer("double[]", win)) == int(ref.push(win))
                k += 1

        for before, between, after in schedule:
            push(before)
            fn["snapshot"](ws)
            ref.snapshot()
            push(between)
            res, verdict = fn["resolve"](ws), ref.resolve(snapshot=False)
            assert res == (0 if verdict == "accepted" else 1 + REJECTIONS.index(verdict))
            if verdict == "accepted":
                assert _close(_arr(ffi, ws.Gc, q * lay.r).reshape(q, lay.r), ref.pending)
            assert ws.off_pending == (ref.pending_offset is not None)
            if ref.offset_estimate is not None:
                staged = _arr(ffi, ws.yoff, 2 * n_y)[ws.off_spare * n_y : (ws.off_spare + 1) * n_y]
                assert _close(staged, ref.offset_estimate)
            push(after)
            assert fn["swap"](ws, sws) == twin.adapt_swap().code
            assert _close(_arr(ffi, ws.G, q * lay.r).reshape(q, lay.r), ref.G)
            if ref.counts["offset_swaps"]:
                assert _close(_arr(ffi, ws.yoff, 2 * n_y)[(1 - ws.off_spare) * n_y : (2 - ws.off_spare) * n_y],
                              ref.offset)
        w = lay.width
        assert _close(_r_of(ffi, lib, NAME, ws, w), ref.R)
        c = ws.counts
        assert {k: getattr(c, k) for k in ("updates", "skipped", "resolves", "accepted", "swaps", "clipped",
                                           "offset_swaps", "offset_clipped", "offset_rejected")} == \
            {k: ref.counts[k] for k in ("updates", "skipped", "resolves", "accepted", "swaps", "clipped",
                                        "offset_swaps", "offset_clipped", "offset_rejected")}
        assert [c.rejected[i + 1] for i in range(len(REJECTIONS))] == [ref.counts[f"rejected_{r}"] for r in REJECTIONS]

    check()
    # the snapshot matters: 30 columns after it, the re-solve of the snapshot and of the current state differ
    ref = AdaptiveProblem(prob, _SPLIT, solver="fast").adapter
    for j in range(60):
        ref.push(sig[j : j + ref.layout.depth])
    ref.snapshot()
    for j in range(60, 90):
        ref.push(sig[j : j + ref.layout.depth])
    ref.resolve(snapshot=False)
    old = ref.offset_estimate
    ref.resolve()
    assert not _close(old, ref.offset_estimate)


def test_a_resolve_in_another_thread_releases_the_gil_while_the_tick_thread_pushes(tmp_path):
    """A bigger build (a re-solve of some ms): one re-solve in a worker thread while the main thread keeps pushing
    windows. Pushes complete during the C call (cffi released the GIL), and the result equals the numpy twin's
    re-solve of the snapshot taken before those pushes (1e-9)."""
    import threading
    import time

    ds = _dataset(2, 1200)
    pred = fit_predictor(ds, 10, 30, "pem", ridge=1e-5)
    cfg = SteeringConfig(t_ini=10, t_f=30, m=2, p=2, Q=[10.0, 3.0], R=[1.0, 0.5], R_mode="offset", lambda_sigma=50.0,
                         predictor={"method": "pem"})
    prob = SteeringProblem(pred, cfg)
    st = dataclasses.replace(_SPLIT, window=100)
    ffi, lib = compile_alone(prob, st, tmp_path, NAME)
    ref = adapter(prob, st)
    ws = ffi.new("ad_adapt_workspace *")
    assert lib.ad_adapt_init(ws) == 0
    u = np.random.default_rng(9).standard_normal((2000, 2)) * [0.3, 2.0]
    y, _ = random_lti(4, 2, 2, 7).simulate(u, np.zeros(4))
    sig, d = np.hstack([u, y]), ref.layout.depth
    wins = [np.ascontiguousarray(sig[j : j + d]) for j in range(1900)]
    for j in range(150):
        lib.ad_adapt_push(ws, ffi.from_buffer("double[]", wins[j]))
        ref.push(wins[j])
    lib.ad_adapt_snapshot(ws)
    ref.snapshot()
    spans, codes, stamps, j = [], [], [], 150
    pushing = threading.Event()

    def work():
        # The same snapshot re-solves to the same answer, so a loaded machine (the main thread not scheduled
        # during one ~2 ms call) gets more calls, until one call has pushes completing inside it (50 calls were
        # not always enough with four test workers and other jobs on two cores).
        pushing.wait(10.0)
        for _ in range(300):
            t0 = time.perf_counter()
            codes.append(lib.ad_adapt_resolve(ws))
            spans.append((t0, time.perf_counter()))
            if sum(t0 < t < spans[-1][1] for t in list(stamps)) >= 3:
                return

    th = threading.Thread(target=work)
    th.start()
    while th.is_alive() and j < len(wins):
        lib.ad_adapt_push(ws, ffi.from_buffer("double[]", wins[j]))
        ref.push(wins[j])
        stamps.append(time.perf_counter())
        pushing.set()
        j += 1
    th.join()
    inside = max(sum(a < t < b for t in stamps) for a, b in spans)
    assert inside >= 3, (inside, j - 150, len(spans))
    assert len(set(codes)) == 1  # every call on the snapshot gave the same verdict
    out = {"code": codes[0]}
    verdict = ref.resolve(snapshot=False)
    assert out["code"] == (0 if verdict == "accepted" else 1 + REJECTIONS.index(verdict))
    lay = ref.layout
    q = lay.q_y + lay.q_s
    if verdict == "accepted":
        assert _close(_arr(ffi, ws.Gc, q * lay.r).reshape(q, lay.r), ref.pending)
    assert ws.counts.updates == ref.counts["updates"] == j
    assert _close(_r_of(ffi, lib, NAME, ws, lay.width), ref.R)


def test_the_tick_only_queues_columns_and_the_resolve_folds_them_into_r(tmp_path):
    """push() leaves R (d, U) alone (O(width) in the tick); the re-solve folds exactly the columns its snapshot
    handed over, those older than the held-out window (R then equals the numpy twin's after those columns, not
    after the ones pushed meanwhile); <name>_adapt_r folds the rest but the window; a full queue refuses columns
    (counted) instead of overwriting one R lacks."""
    prob = _problem("absolute")
    st = AdaptSettings(enabled=True, window=40, period_ticks=20, min_excitation=1e-4)
    name = NAME
    ffi, lib = compile_alone(prob, st, tmp_path, name)
    ref = adapter(prob, st)
    lay = ref.layout
    w, ring = lay.width, st.window + 3 * st.period_ticks
    ws = ffi.new(f"{name}_adapt_workspace *")
    assert getattr(lib, f"{name}_adapt_init")(ws) == 0
    push = lambda win: getattr(lib, f"{name}_adapt_push")(ws, ffi.from_buffer("double[]", win))  # noqa: E731
    factor = lambda: (_arr(ffi, ws.U, w * w), _arr(ffi, ws.d, w))  # noqa: E731
    rng = np.random.default_rng(4)
    wins = np.ascontiguousarray(rng.standard_normal((200, lay.depth, lay.m + lay.p)) * 0.1)
    before = factor()
    for win in wins[:60]:
        assert push(win) == 1 and ref.push(win)
    after_60 = ref.R.copy()  # the 20 oldest: the window (40) held out
    assert all(np.array_equal(a, b) for a, b in zip(factor(), before))  # the tick never touched R
    assert (ws.counts.updates, ws.counts.folded, ws.queued) == (60, 0, 60)
    getattr(lib, f"{name}_adapt_snapshot")(ws)
    assert ws.queued == 40  # the 20 oldest handed over; the window's columns stay queued: not in R
    for win in wins[60:70]:  # pushed while the re-solve would run in the worker
        assert push(win) == 1 and ref.push(win)
    getattr(lib, f"{name}_adapt_resolve")(ws)
    assert ws.counts.folded == 20 and ws.queued == 50
    U, d = factor()
    R = np.sqrt(d)[:, None] * (np.triu(U.reshape(w, w), 1) + np.eye(w))  # R = diag(sqrt(d)) U, U unit triangular
    assert _close(R, after_60)  # the re-solve folded the handed-over columns, not those pushed meanwhile
    assert _close(_r_of(ffi, lib, name, ws, w), ref.R) and ws.counts.folded == 30 and ws.queued == 40
    for k, win in enumerate(wins[70 : 70 + ring - 40 + 5]):  # no re-solve takes the queue: full after `ring`
        taken = push(win)
        assert taken == int(k < ring - 40)
        if taken:
            ref.push(win)
    assert (ws.counts.updates, ws.counts.dropped) == (70 + ring - 40, 5)
    assert _close(_r_of(ffi, lib, name, ws, w), ref.R)  # nothing taken was lost, nothing dropped got in
    assert push(wins[-1]) == 1  # the queue holds only the window again
