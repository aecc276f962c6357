"""One generated solver instance per thread: a call on an instance another thread is inside is refused
(SolverBusyError), never a crash nor another call's answer; real threads hammer one instance, bounded in time."""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

from ddpc_codegen import IODataset, SteeringConfig, SteeringProblem, fit_predictor, load_solver
from ddpc_codegen.codegen import generate
from ddpc_codegen.runtime.guard import SolverBusyError
from ddpc_codegen.values.adapt import AdaptSettings
from support.lti import random_lti

pytestmark = pytest.mark.compiler

SECONDS = 1.5  # each hammer's wall-time bound (the threads stop at it, or after CALLS calls)
CALLS = 4000


def _problem() -> SteeringProblem:
    sys_ = random_lti(3, 2, 2, 5)
    rng = np.random.default_rng(5)
    u = rng.standard_normal((300, 2))
    y, _ = sys_.simulate(u, np.zeros(3))
    cfg = SteeringConfig(t_ini=4, t_f=5, m=2, p=2, Q=[1.0, 2.0], R=[0.1, 0.1], u_min=[-2.0, -2.0],
                         u_max=[2.0, 2.0], du_max=[0.4, 0.4], name="thr")
    return SteeringProblem(fit_predictor(IODataset(u, y, 0.01), 4, 5, "lsq", ridge=1e-6), cfg)


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, object]:
    prob, root = _problem(), tmp_path_factory.mktemp("threads")
    return {b: generate(prob, root / f"thr_{b}", backend=b, name=f"thr_{b}", n_vectors=4) for b in ("daqp", "osqp")}


def _hammer(solvers: list, thetas: np.ndarray, want: list) -> tuple[list[int], list[int], list[str]]:
    """Two threads call solve_theta on solvers[0] and solvers[1] (the same instance or two) as fast as they can,
    each over the thetas in its own order; (answers, refusals, wrong answers or other errors) per thread."""
    answers, refusals, bad = [0, 0], [0, 0], []
    start = threading.Barrier(2)

    def run(k: int) -> None:
        s, n = solvers[k], len(thetas)
        start.wait()
        stop = time.monotonic() + SECONDS
        for i in range(CALLS):
            if time.monotonic() > stop:
                break
            j = (3 * i + k) % n
            try:
                r = s.solve_theta(thetas[j])
            except SolverBusyError as e:
                refusals[k] += 1
                if "one instance per thread" not in str(e):
                    bad.append(f"refusal without the rule: {e}")
                time.sleep(0)  # as a caller would back off (else it only ever runs while the other is in C)
                continue
            except Exception as e:  # noqa: BLE001 -- any other error is a failure of the guard
                bad.append(f"{type(e).__name__}: {e}")
                continue
            answers[k] += 1
            st, u = want[j]
            if r.status != st or (st == "solved" and not np.allclose(r.u, u, rtol=0, atol=1e-7)):
                bad.append(f"theta {j}: {r.status} {r.u.ravel()[:3]} instead of {st} {u.ravel()[:3]}")

    threads = [threading.Thread(target=run, args=(k,), daemon=True) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=SECONDS + 30)
        assert not t.is_alive(), "a hammering thread hung"
    return answers, refusals, bad


def _thetas(solver, n: int = 16) -> tuple[np.ndarray, list]:
    thetas = np.random.default_rng(1).standard_normal((n, solver.n_theta)) * 0.3
    want = []
    for th in thetas:
        solver.reset()
        r = solver.solve_theta(th)
        want.append((r.status, r.u.copy()))
    assert all(st == "solved" for st, _ in want)
    return thetas, want


@pytest.mark.parametrize("backend", ["daqp", "osqp"])
def test_two_threads_on_one_instance_get_their_own_answers_or_a_refusal(folders, backend):
    solver = load_solver(folders[backend])
    thetas, want = _thetas(solver)
    answers, refusals, bad = _hammer([solver, solver], thetas, want)
    assert not bad, bad[:5]
    assert sum(answers) > 0 and sum(refusals) > 0, (answers, refusals)  # they did collide
    solver.reset()
    assert solver.solve_theta(thetas[0]).status == "solved"  # the guard was given back after every call


def test_osqp_instances_of_one_folder_share_the_guard_daqp_ones_do_not(folders):
    """OSQP's workspace is static in the extension: two osqp instances of one folder are one for the guard (the
    hammer on two instances refuses, never mixes); two daqp instances solve concurrently."""
    a, b = load_solver(folders["osqp"]), load_solver(folders["osqp"])
    assert a._guard is b._guard
    thetas, want = _thetas(a)
    answers, refusals, bad = _hammer([a, b], thetas, want)
    assert not bad, bad[:5]
    assert sum(answers) > 0 and sum(refusals) > 0, (answers, refusals)
    c, d = load_solver(folders["daqp"]), load_solver(folders["daqp"])
    assert c._guard is not d._guard
    thetas, want = _thetas(c)
    answers, refusals, bad = _hammer([c, d], thetas, want)
    assert not bad and min(answers) > 0 and refusals == [0, 0]


def test_every_workspace_call_is_refused_while_another_thread_is_inside(folders):
    solver = load_solver(folders["daqp"])
    th = np.zeros(solver.n_theta)
    calls = {"solve": lambda: solver.solve_theta(th), "step_u": lambda: solver.step_u(th),
             "reset": solver.reset, "bench": lambda: solver.bench(th[None])}
    inside, leave = threading.Event(), threading.Event()

    def hold() -> None:
        with solver._guard.held("test"):
            inside.set()
            leave.wait(10)

    t = threading.Thread(target=hold, daemon=True)
    t.start()
    assert inside.wait(10)
    try:
        for what, call in calls.items():
            with pytest.raises(SolverBusyError, match=rf"^solver 'thr_daqp': {what} called while another thread is "
                                                      r"inside a call on this instance; a generated solver is one "
                                                      r"instance per thread \(load_solver again for another "
                                                      r"thread\)$"):
                call()
    finally:
        leave.set()
        t.join(10)
    assert solver.step_u(th)[0] == 0 and solver.solve_theta(th).status == "solved"


def test_the_adaptation_keeps_to_its_thread_contract(tmp_path):
    """A re-solve may run beside push and solve (the bridge's schedule); snapshot, swap and a second re-solve
    while one runs are refused, as is a push while the solver is inside a call."""
    prob = _problem()
    folder = generate(prob, tmp_path / "thr_ad", name="thr_ad", n_vectors=4,
                      adapt=AdaptSettings(enabled=True, window=30, period_ticks=10))
    solver = load_solver(folder)
    ad = solver.adaptation
    th = np.zeros(solver.n_theta)
    rng = np.random.default_rng(0)
    for _ in range(60):
        solver.adapt_push(rng.standard_normal(2), rng.standard_normal(2))
    solver.adapt_snapshot()
    with ad._resolving.held("test"):  # as if a re-solve ran in the worker
        assert solver.solve_theta(th).status == "solved"
        solver.adapt_push(rng.standard_normal(2), rng.standard_normal(2))
        for what, call in (("adapt_snapshot", solver.adapt_snapshot), ("adapt_swap", solver.adapt_swap),
                           ("adapt_resolve", lambda: solver.adapt_resolve(False))):
            with pytest.raises(SolverBusyError, match=rf"^solver 'thr_ad': {re.escape(what)} \("):
                call()
    with solver._guard.held("test"):  # as if the tick were inside a solve
        with pytest.raises(SolverBusyError, match=r"^solver 'thr_ad': adapt_push called while"):
            solver.adapt_push(np.zeros(2), np.zeros(2))
        assert isinstance(solver.adapt_resolve(False), str)  # the re-solve needs only its own guard
    solver.adapt_swap()
    assert solver.solve_theta(th).status == "solved"
