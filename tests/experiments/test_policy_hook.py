"""The one simulator hook (experiments/policy_hook.py): any Policy, flying and hopping, with the
ground phase observed and a liftoff-clocked table restarted at every liftoff."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.values.phases import GROUND
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.runtime.baselines import FeedforwardPolicy, PassthroughPolicy
from ddpc_codegen.sim import simulate


def test_bad_scenario_and_hopping_steering_arguments_on_a_baseline_are_refused():
    with pytest.raises(ValueError, match=r"^scenario must be 'flying' or 'hopping'; got 'walking'$"):
        PolicyHook(PassthroughPolicy(), "walking")
    with pytest.raises(ValueError, match=r"^window and g_eff are the hopping steering's; PassthroughPolicy takes "
                                         r"neither$"):
        PolicyHook(PassthroughPolicy(), "hopping", g_eff=9.0)


def test_flying_passthrough_decides_every_tick():
    pol = PassthroughPolicy()
    hook = PolicyHook(pol, "flying")
    res = simulate("flying", 0.5, reference_hook=hook, seed=0)
    assert hook.counts == {"ticks": res.n} and pol.summary() == {"ticks": res.n}
    np.testing.assert_array_equal(res.u, res.r_nom)
    assert hook.solver_us == []  # nothing solved


def test_hopping_table_on_the_liftoff_clock_restarts_at_every_liftoff():
    n_rows = 40
    delta = np.zeros((n_rows, 3))
    delta[:, 0] = 1e-4 * np.arange(1, n_rows + 1)  # row j adds (j + 1) * 0.1 mm to z_ref
    pol = FeedforwardPolicy(delta, 0.005, "liftoff")
    hook = PolicyHook(pol, "hopping")
    res = simulate("hopping", 2.5, reference_hook=hook, seed=0)
    ground = res.phase == GROUND
    lifts = np.flatnonzero(ground[:-1] & ~ground[1:]) + 1
    assert lifts.size >= 2 and hook.counts["ground"] == int(ground.sum())
    # The independent expectation: r_nom on the ground and before the first liftoff; in the air the
    # row of the ticks since the last liftoff (the last row held beyond the table).
    want = np.zeros_like(res.u)
    for k in range(res.n):
        before = lifts[lifts <= k]
        if not ground[k] and before.size:
            want[k] = delta[min(k - before[-1], n_rows - 1)]
    np.testing.assert_allclose(res.u - res.r_nom, want, atol=1e-12)
    assert np.all(want[lifts, 0] == 1e-4)  # every liftoff starts at row 0
