"""Vehicle changes during a simulated run (simulate(changes=...)): applied once, at the first tick at or after t."""

from __future__ import annotations

from ddpc_codegen.sim import simulate


def test_a_change_is_applied_once_at_its_tick():
    seen = []

    def heavier(stepper):
        seen.append(stepper.plant.t)
        stepper.plant._m += 0.5

    res = simulate("flying", 1.0, changes=[(0.5, heavier)], excitation=False)
    assert len(seen) == 1 and abs(seen[0] - 0.5) < 1e-9
    base = simulate("flying", 1.0, excitation=False)
    k = int(round(0.5 / res.dt))
    # identical before the change; the heavier vehicle sinks below the nominal one afterwards
    assert (res.y_true[: k + 1] == base.y_true[: k + 1]).all()
    assert res.y_true[-1, 0] < base.y_true[-1, 0] - 1e-3
