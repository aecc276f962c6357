"""The preview figure's closed loop: knots track like the free long horizon, and better than the short one."""

import numpy as np
import pytest

from ddpc_codegen import SteeringProblem
from ddpc_codegen.experiments.bench_problems import build_problem
from ddpc_codegen.experiments.bench_preview import track


@pytest.mark.slow
def test_knots_track_like_the_free_horizon_and_better_than_tf15():
    knots, plant = build_problem("preview")
    short, _ = build_problem("flying")
    free = SteeringProblem(knots.predictor, knots.config.replace(knots=None))

    class Fast:  # the interpreted solver with the generated solver's call
        def __init__(self, prob):
            self.prob = prob

        def solve_theta(self, th):
            return self.prob.solve_theta(th, solver="fast")

    n = 500  # a step of of the desired trajectory after the settle
    r = {k: track(p, plant, Fast(p), n) for k, p in (("short", short), ("knots", knots), ("free", free))}
    assert np.allclose(r["knots"]["rmse"], r["free"]["rmse"], rtol=0.05)
    assert all(k < s for k, s in zip(r["knots"]["rmse"], r["short"]["rmse"]))
    assert r["knots"]["tick_median_us"] > 0
