"""Recorded test vectors: a refused vector is recorded as infeasible exactly when no answer satisfies the
constraints (OSQP's own infeasibility certificate as the independent judge)."""

import numpy as np

from ddpc_codegen.codegen import vectors
from codegen.conftest import sized_problem


def test_refused_vectors_are_infeasible_exactly_when_osqp_certifies_it():
    prob = sized_problem("flying")  # y bounds +-0.25: some recorded draws admit no answer
    rec = vectors.record(prob, 48)
    assert (rec.status == vectors.STATUS_CODES["infeasible"]).sum() > 0 and (rec.status == 0).sum() > 24
    for th, st in zip(rec.theta, rec.status):
        osqp_status = prob.solve_theta(th, solver="osqp", eps=1e-9).status
        assert (st == vectors.STATUS_CODES["infeasible"]) == (osqp_status == "primal_infeasible")
        assert vectors.feasible(prob, th) == (st != vectors.STATUS_CODES["infeasible"])
    assert all(prob.check(prob.to_z(u), th) == "solved" for u, th, st in zip(rec.u, rec.theta, rec.status) if st == 0)
    assert np.all(np.isnan(rec.u[rec.status != 0]))
