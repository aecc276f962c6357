"""The embedded OSQP backend's rho (codegen/tuning.py): the pruned search picks what trying every candidate
on every sample picks."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.codegen import tuning
from ddpc_codegen.codegen.emit import DEFAULTS
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from support.lti import random_lti


def _problem(seed: int, bounded: bool) -> SteeringProblem:
    sys_ = random_lti(3, 2, 2, seed)
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((300, 2))
    y, _ = sys_.simulate(u, np.zeros(3))
    pred = fit_predictor(IODataset(u, y, 0.01), 4, 8, "lsq", ridge=1e-6)
    rows = dict(u_min=[-0.5, -1.0], u_max=[0.5, 1.0], y_min=[-0.2, -0.2], y_max=[0.2, 0.2]) if bounded else \
        dict(du_max=[0.1, 0.1])
    cfg = SteeringConfig(t_ini=4, t_f=8, m=2, p=2, Q=[10.0, 3.0], R=[1.0, 0.5], R_mode="offset", lambda_sigma=50.0,
                         predictor={"method": "lsq"}, **rows)
    return SteeringProblem(pred, cfg)


def _exhaustive(problem: SteeringProblem, settings: dict) -> float:
    vecs = [problem.qp_vectors(th) for th in tuning.sample_thetas(problem, 16, 0)]
    scores = [tuning._score(problem, settings, rho, vecs, None) for rho in tuning.RHO_CANDIDATES]
    return tuning.RHO_CANDIDATES[min(range(len(scores)), key=lambda i: (scores[i], i))]


@pytest.mark.parametrize("seed, bounded, max_iter", [(0, True, 4000), (1, False, 4000), (2, True, 40)])
def test_pruned_rho_search_equals_the_exhaustive_one(seed, bounded, max_iter):
    prob = _problem(seed, bounded)
    settings = dict(DEFAULTS["osqp"], max_iter=max_iter)  # 40: many solves fail, the first count decides
    assert tuning.choose_rho(prob, settings) == _exhaustive(prob, settings)
