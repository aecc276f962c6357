"""The steady-state gain check of the online update (design/adapt_qp.steady_state_gain)."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.adapt_qp import steady_state_gain
from support.lti import random_lti


@pytest.mark.parametrize("seed, m, p", [(0, 2, 2), (3, 1, 3), (5, 3, 1)])
def test_steady_state_gain_of_an_exact_predictor_is_the_systems_dc_gain(seed, m, p):
    """Noise-free data, the least-squares predictor is exact: S = C (I - A)^-1 B (+ D), the system's own."""
    sys_ = random_lti(4, m, p, seed)
    u = np.random.default_rng(seed).standard_normal((600, m))
    y, _ = sys_.simulate(u, np.zeros(4))
    pred = fit_predictor(IODataset(u, y, 0.01), 6, 5, "lsq")
    Gd = np.block([[pred.Gy_w, pred.Gy_u], [pred.Gs_w, pred.Gs_u]])
    dc = sys_.C @ np.linalg.solve(np.eye(4) - sys_.A, sys_.B) + sys_.D
    np.testing.assert_allclose(steady_state_gain(Gd, m, p, 6, 5), dc, rtol=1e-6, atol=1e-8)


def test_a_predictor_that_holds_any_output_has_no_steady_state_gain():
    """y_f = y_ini[-1] (an integrator at rest): I - B is singular."""
    m, p, ti, tf = 1, 2, 3, 2
    Gd = np.zeros((p * tf, (m + p) * ti + m * tf))
    for k in range(tf):
        Gd[k * p : (k + 1) * p, m * ti + (ti - 1) * p : m * ti + ti * p] = np.eye(p)
    assert steady_state_gain(Gd, m, p, ti, tf) is None
