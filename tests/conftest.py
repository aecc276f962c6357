"""Shared fixtures: random LTI systems with exactly known responses."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest


@dataclass
class LTI:
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    @property
    def n(self) -> int:
        return self.A.shape[0]

    def simulate(self, u: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact response: y[k] = C x[k] + D u[k], x[k+1] = A x[k] + B u[k]. Returns (y, x_final)."""
        x = np.array(x0, dtype=float)
        ys = np.empty((u.shape[0], self.C.shape[0]))
        for k in range(u.shape[0]):
            ys[k] = self.C @ x + self.D @ u[k]
            x = self.A @ x + self.B @ u[k]
        return ys, x


def random_lti(n: int, m: int, p: int, seed: int, radius: float = 0.9, feedthrough: bool = False) -> LTI:
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    A *= radius / np.max(np.abs(np.linalg.eigvals(A)))
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((p, n))
    D = rng.standard_normal((p, m)) if feedthrough else np.zeros((p, m))
    return LTI(A, B, C, D)


@pytest.fixture
def lti_factory():
    return random_lti
