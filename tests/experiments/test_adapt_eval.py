"""The in-process adaptation measurement (experiments/adapt_eval.py): its conditions change what they say."""

from __future__ import annotations

import numpy as np

from ddpc_codegen.experiments.adapt_eval import _rmse_after, conditions
from ddpc_codegen.sim import PogoXParams, simulate
from ddpc_codegen.sim.stepper import Stepper


def test_conditions_change_the_vehicle_as_described():
    p = PogoXParams()
    c = conditions(2.0)
    assert set(c) == {"nominal", "mass", "thrust", "push"} and not c["nominal"]["changes"]
    st = Stepper(p, [0.0, 0.0, 1.0])
    (t, fn), = c["mass"]["changes"]
    fn(st)
    assert t == 2.0 and abs(st.plant._m - (p.mass + 0.4)) < 1e-12
    st = Stepper(p, [0.0, 0.0, 1.0])
    kf, km = st.plant._kf, st.plant._km
    c["thrust"]["changes"][0][1](st)
    assert abs(st.plant._kf / kf - 0.85) < 1e-12 and abs(st.plant._km / km - 0.85) < 1e-12
    push, = c["push"]["pushes"]
    assert (push.t, push.force, push.duration) == (2.0, (0.0, 0.0, -5.0), 3.0)
    # the push stays inside the thrust margin: weight + push below the maximum thrust
    assert p.mass * p.g + 5.0 < p.max_thrust


def test_rmse_after_is_over_the_window_and_none_for_a_lost_run():
    res = simulate("flying", 2.0, excitation=False)
    e = res.y_true[:, 0] - res.extras["z_des"]
    w = (res.t >= 1.0) & (res.t < 1.5)
    assert _rmse_after(res, 1.0, 0.5) == float(np.sqrt(np.mean(e[w] ** 2)))
    res.crashed = True
    assert _rmse_after(res, 1.0, 0.5) is None
