"""Online adaptation in the loop (runtime/adapt_loop.py, the policy's hook) on the interpreted twin."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddpc_codegen.design.adaptation import AdaptiveProblem
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.runtime.adapt_loop import OnlineAdaptation
from ddpc_codegen.values.adapt import AdaptSettings, Swapped
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer
from support.lti import random_lti

T_INI, T_F = 3, 4


def _twin(**settings) -> AdaptiveProblem:
    sys_ = random_lti(3, 1, 1, 2)
    u = np.random.default_rng(2).standard_normal((400, 1))
    y, _ = sys_.simulate(u, np.zeros(3))
    pred = fit_predictor(IODataset(u, y, 0.01), T_INI, T_F, "lsq", ridge=1e-6)
    cfg = SteeringConfig(t_ini=T_INI, t_f=T_F, m=1, p=1, Q=[10.0], R=[1.0], R_mode="offset")
    return AdaptiveProblem(SteeringProblem(pred, cfg), AdaptSettings(enabled=True, **settings))


def test_only_runs_of_steered_ticks_update_and_a_reset_tick_breaks_the_window():
    twin = _twin(window=30, period_ticks=1000)
    ad = OnlineAdaptation(twin)
    depth = T_INI + T_F
    steered = [True] * 10 + [False] + [True] * 8
    rng = np.random.default_rng(0)
    what = [ad.tick(rng.standard_normal(1), rng.standard_normal(1), s) for s in steered]
    # 10 steered: 4 columns (ticks 7..10); the skip clears; 8 more: 2 columns
    assert twin.adapt_counts()["updates"] == (10 - depth + 1) + (8 - depth + 1) == 6
    assert what[:depth - 1] == ["warmup"] * (depth - 1) and what[10] == "skip" and what[-1] == "update"


def test_a_column_the_solver_refuses_is_refused_not_warmup():
    """A full window with a NaN output: the solver does not take its column (counted ``skipped``); the tick says
    "refused" (the tick log's code), and the next clean window is an update again."""
    twin = _twin(window=30, period_ticks=1000)
    ad = OnlineAdaptation(twin)
    rng = np.random.default_rng(1)
    what = [ad.tick(rng.standard_normal(1), rng.standard_normal(1), True) for _ in range(T_INI + T_F)]
    assert what[-1] == "update"
    assert ad.tick(np.zeros(1), np.full(1, np.nan), True) == "refused" and twin.adapt_counts()["skipped"] == 1
    assert ad.tick(np.zeros(1), np.zeros(1), True) == "refused"  # the NaN is still in the window
    what = [ad.tick(rng.standard_normal(1), rng.standard_normal(1), True) for _ in range(T_INI + T_F)]
    assert what[-1] == "update" and "warmup" not in what


def test_a_re_solve_every_period_updates_is_recorded_and_swapped_in():
    twin = _twin(window=20, period_ticks=25, forgetting=0.98, min_excitation=1e-6, max_change=0.5, max_gain_change=1e3)
    ad = OnlineAdaptation(twin)
    other = random_lti(3, 1, 1, 9)
    u = np.random.default_rng(5).standard_normal((200, 1))
    y, _ = other.simulate(u, np.zeros(3))
    for k in range(200):
        ad.tick(u[k], y[k], True)
    ev = ad.summary()["events"]
    assert [e[0] for e in ev] == [T_INI + T_F - 2 + 25 * (i + 1) for i in range(len(ev))]
    c = twin.adapt_counts()
    assert c["resolves"] == len(ev) == (200 - T_INI - T_F + 1) // 25
    assert c["swaps"] == sum(e[2] for e in ev) > 0 and twin.problem is not twin.shipped
    # each verdict of the error check carries the candidate's error over the current G's (< 1 when accepted)
    ratios = [e[6] for e in ev if e[1] == "accepted"]
    assert ratios and all(0.0 < r < 1.0 for r in ratios)
    assert all(math.isnan(e[6]) for e in ev if e[1] not in ("accepted", "prediction"))


def test_dither_is_bounded_applied_only_on_steered_ticks_and_logged_through_the_policy():
    twin = _twin(window=30, period_ticks=1000, dither=0.02)
    ad = OnlineAdaptation(twin, seed=3)
    u = np.array([0.5])
    d = np.array([ad.perturb(u, True) - u for _ in range(200)])
    assert np.all(np.abs(np.abs(d) - 0.02) < 1e-15) and {1.0, -1.0} == set(np.sign(d).ravel())
    assert ad.perturb(u, False) is u
    steerer = ReferenceSteerer.for_solver(twin, u_min=[-10.0], u_max=[10.0])
    policy = SteeringPolicy(steerer, ramp_ticks=0, adaptation=OnlineAdaptation(twin, seed=3))
    y_des = np.zeros((T_F, 1))
    for k in range(12):
        out = policy.decide(np.array([0.01 * k]), np.array([0.0]), y_des)
    assert out.steered and policy.adaptation.last == "update"
    np.testing.assert_array_equal(steerer.window()[0][-1], out.u)  # the history holds the dithered reference


@pytest.mark.parametrize("bad, message", [({"period_ticks": 0}, r"^period_ticks must be >= 1; got 0$"),
                                          ({"dither": -1.0}, r"^dither must be finite and >= 0; got -1.0$")])
def test_bad_loop_settings_are_refused(bad, message):
    with pytest.raises(ValueError, match=message):
        OnlineAdaptation(_twin(), **bad)


class _GatedSolver:
    """The adaptation API with a re-solve that waits for the test (a background re-solve of known length)."""

    def __init__(self, period: int = 3) -> None:
        import threading

        self.adapt_settings = AdaptSettings(enabled=True, period_ticks=period)
        self.gate, self.calls, self.snapshots, self.swaps = threading.Event(), [], 0, 0
        self.in_call = threading.Event()

    def adapt_push(self, u, y) -> bool:
        return True

    def adapt_clear(self) -> None:
        pass

    def adapt_snapshot(self) -> None:
        self.snapshots += 1

    def adapt_resolve(self, snapshot: bool = True) -> str:
        self.calls.append(snapshot)
        self.in_call.set()
        assert self.gate.wait(5.0)
        return "prediction" if len(self.calls) % 2 else "accepted"

    def adapt_swap(self) -> Swapped:
        self.swaps += 1
        return Swapped(g=len(self.calls) % 2 == 0)

    def adapt_refused(self) -> int:
        return 0

    def adapt_counts(self) -> dict:
        return {"resolves": len(self.calls), "offset_norm": 0.0}


def test_background_resolve_runs_off_the_tick_lands_on_the_first_update_tick_after_it_and_is_never_queued():
    from ddpc_codegen.runtime.adapt_loop import SNAP_BUSY, SNAP_TAKEN

    s = _GatedSolver(period=3)
    ad = OnlineAdaptation(s, background=True)
    z = np.zeros(1)
    assert [ad.tick(z, z, True) for _ in range(2)] == ["update"] * 2
    assert ad.tick(z, z, True) == "update" and ad.last_snap == SNAP_TAKEN and s.snapshots == 1
    assert s.in_call.wait(5.0) and s.calls == [False]  # from the snapshot, in the worker, while the ticks go on
    out = [(ad.tick(z, z, True), ad.last_snap) for _ in range(3)]
    assert out == [("update", 0), ("update", 0), ("update", SNAP_BUSY)] and ad.busy == 1 and s.swaps == 0
    s.gate.set()
    ad._running[0].result(5.0)
    assert ad.tick(z, z, False) == "skip" and s.swaps == 0  # a verdict lands only on an update tick
    assert ad.tick(z, z, True) == "prediction" and s.swaps == 1
    e = ad.events[0]
    assert (e.tick, e.verdict, e.swapped, e.snapshot_tick) == (7, "prediction", False, 2) and e.resolve_ms >= 0
    for _ in range(2):  # the next period takes a new snapshot (the worker is free again)
        ad.tick(z, z, True)
    assert ad.last_snap == SNAP_TAKEN and s.snapshots == 2
    summary = ad.summary()  # joins the running re-solve and drops it: no tick follows to swap it in
    assert summary["discarded"] == 1 and summary["busy"] == 1 and summary["background"] is True
    assert summary["events"][-1][:3] == [-1, "accepted", False] and summary["events"][-1][4] == 9
    assert s.swaps == 1 and ad._pool is None


def test_background_schedule_on_the_twin_equals_its_snapshot_semantics():
    """The twin in the background (a real worker thread): every re-solve read the snapshot of its tick, so a
    synchronous replay (snapshot at that tick, pushes, re-solve from it, swap at the landing tick) gives the same
    verdicts, swaps and final G."""
    import time

    bg, ref = _twin(period_ticks=15, window=8, min_excitation=0.0), _twin(period_ticks=15, window=8, min_excitation=0.0)
    rng = np.random.default_rng(4)
    us, ys = rng.standard_normal((160, 1)), rng.standard_normal((160, 1))
    ad = OnlineAdaptation(bg, background=True)
    for u, y in zip(us, ys):
        ad.tick(u, y, True)
        time.sleep(0.001 if ad._running is None else 0.004)  # let a re-solve finish within a few ticks
    ad.close()
    landed = [e for e in ad.events if e.tick >= 0]
    assert len(landed) >= 3 and all(e.snapshot_tick < e.tick for e in landed)
    snaps, lands = {e.snapshot_tick: e for e in landed}, {e.tick: e for e in landed}
    verdicts = []
    for k, (u, y) in enumerate(zip(us, ys)):
        if k in lands:
            verdicts.append((ref.adapt_resolve(False), ref.adapt_swap().g))
        ref.adapt_push(u, y)
        if k in snaps:
            ref.adapt_snapshot()
    assert verdicts == [(e.verdict, e.swapped) for e in landed]
    np.testing.assert_array_equal(ref.adapter.G, bg.adapter.G)
