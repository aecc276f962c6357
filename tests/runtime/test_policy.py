"""ddpc_codegen.runtime.policy.SteeringPolicy: the per-tick decision every loop shares."""

import numpy as np
import pytest

from ddpc_codegen.values.solve_result import SteeringResult
from ddpc_codegen.runtime.policy import SteeringPolicy, nominal_horizon
from ddpc_codegen.runtime.steerer import ReferenceSteerer


class _Recorder:
    """Returns u = u_nom + 0.01 and records what it was asked."""

    has_nominal = True

    def __init__(self):
        self.calls = []

    def solve(self, u_ini, y_ini, y_des, u_nom=None):
        self.calls.append((np.array(u_ini), np.array(y_ini), np.array(y_des), np.array(u_nom)))
        return SteeringResult(np.asarray(u_nom) + 0.01, status="solved")


def _policy(**kw) -> tuple[SteeringPolicy, _Recorder]:
    rec = _Recorder()
    return SteeringPolicy(ReferenceSteerer(rec, t_ini=3, t_f=4, m=2, p=2), **{"ramp_ticks": 0, "fallback_decay": 0.0, **kw}), rec


def test_nominal_horizon_is_y_des_with_r_nom_first():
    y_des = np.arange(8.0).reshape(4, 2)
    u_nom = nominal_horizon(y_des, np.array([-1.0, -2.0]))
    np.testing.assert_array_equal(u_nom[0], [-1.0, -2.0])
    np.testing.assert_array_equal(u_nom[1:], y_des[1:])
    assert y_des[0, 0] == 0.0  # not modified in place


def test_warmup_then_steered_and_the_window_holds_the_decided_pairs():
    pol, rec = _policy()
    y_des = np.ones((4, 2))
    outs = [pol.decide(np.array([k, -k], float), np.array([0.5, 0.5]), y_des) for k in range(5)]
    assert [o.reason for o in outs] == ["warmup"] * 3 + ["steered"] * 2
    np.testing.assert_array_equal(outs[0].u, [0.5, 0.5])  # the fallback is exactly r_nom
    u_ini, y_ini, yd, un = rec.calls[-1]  # tick 4 saw the pairs of ticks 1..3
    np.testing.assert_array_equal(y_ini[:, 0], [1, 2, 3])
    np.testing.assert_allclose(u_ini[-1], [0.51, 0.51])  # tick 3 was steered (r_nom + 0.01): its u is in the history
    np.testing.assert_array_equal(un[0], [0.5, 0.5])
    np.testing.assert_array_equal(yd, y_des)


def test_a_few_lost_ticks_are_bridged_a_long_hole_resets():
    pol, _ = _policy(max_gap_fill=2)
    for k in range(4):
        pol.decide(np.array([k, k], float), np.zeros(2), np.zeros((4, 2)))
    pol.lost(2, np.array([6.0, 6.0]))
    assert pol.steerer.ready and pol.summary()["gap_filled_ticks"] == 2
    pol.lost(3, np.array([9.0, 9.0]))
    assert not pol.steerer.ready
    assert pol.decide(np.zeros(2), np.zeros(2), np.zeros((4, 2))).reason == "warmup"


def test_offset_fades_in_after_a_reset_and_decays_after_a_fallback():
    rec = _Recorder()
    pol = SteeringPolicy(ReferenceSteerer(rec, t_ini=3, t_f=4, m=2, p=2), ramp_ticks=4, fallback_decay=0.5)
    r_nom, y_des = np.array([1.0, 0.0]), np.zeros((4, 2))
    us = [pol.decide(np.zeros(2), r_nom, y_des).u - r_nom for _ in range(9)]
    # warm-up (3 ticks: exactly r_nom), then the solver's +0.01 offset at 1/5, 2/5, ... of its size
    np.testing.assert_allclose([u[0] for u in us], [0, 0, 0, 0.002, 0.004, 0.006, 0.008, 0.01, 0.01])
    pol.steerer.max_step = np.array([1e-3, 1e-3])  # every solution now "too large": fallbacks
    outs = [pol.decide(np.zeros(2), r_nom, y_des) for _ in range(3)]
    assert [o.reason for o in outs] == ["step_too_large"] * 3
    np.testing.assert_allclose([o.u[0] - 1.0 for o in outs], [0.005, 0.0025, 0.00125])
    _, _, _, _ = rec.calls[-1]
    u_hist, _ = pol.steerer.window()
    np.testing.assert_allclose(u_hist[-1], outs[-1].u)  # the applied, decayed u is in the history
    pol.reset()
    pol.steerer.max_step = None
    us = [pol.decide(np.zeros(2), r_nom, y_des).u - r_nom for _ in range(4)]
    assert us[-1][0] == pytest.approx(0.002)  # fades in again after the reset


def test_bad_ramp_and_decay_are_refused():
    st = ReferenceSteerer(_Recorder(), t_ini=3, t_f=4, m=2, p=2)
    with pytest.raises(ValueError, match="ramp_ticks must be an integer >= 0"):
        SteeringPolicy(st, ramp_ticks=-1)
    with pytest.raises(ValueError, match=r"fallback_decay must be in \[0, 1\)"):
        SteeringPolicy(st, fallback_decay=1.0)


def test_every_policy_class_is_a_policy_with_the_protocols_signatures():
    import inspect

    from ddpc_codegen.values.prefilter import PrefilterModel
    from ddpc_codegen.runtime.baselines import FeedforwardPolicy, PassthroughPolicy, PrefilterPolicy
    from ddpc_codegen.runtime.policy import Policy

    steering, _ = _policy()
    pols = [PassthroughPolicy(), PrefilterPolicy(PrefilterModel((0.5, 1.0), (0.0, 0.0), (2, 0), 0.005)),
            FeedforwardPolicy(np.zeros((3, 2))), steering]
    for pol in pols:
        assert isinstance(pol, Policy), type(pol).__name__
        for name in ("decide", "observe", "reset", "summary"):
            want = list(inspect.signature(getattr(Policy, name)).parameters)[1:]
            assert list(inspect.signature(getattr(pol, name)).parameters) == want, (type(pol).__name__, name)
        assert isinstance(pol.horizon, int) and pol.horizon >= 1
        out = pol.decide(np.zeros(2), np.array([1.0, 0.1]), np.zeros((pol.horizon, 2)))
        assert out.u.shape == (2,) and isinstance(pol.summary(), dict)
    assert [p.horizon for p in pols] == [1, 3, 1, 4]  # the steering needs its Tf ahead

    class NoHorizon:
        def decide(self, y, r_nom, y_des): ...
        def observe(self, u_applied, y): ...
        def reset(self): ...
        def summary(self): ...

    assert not isinstance(NoHorizon(), Policy)
