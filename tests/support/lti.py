"""Random discrete-time LTI systems with exactly known responses (scipy.signal is the simulator)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LTI", "random_lti", "height_loop"]


@dataclass
class LTI:
    """x[k+1] = A x[k] + B u[k], y[k] = C x[k] + D u[k] (time step 1)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    @property
    def n(self) -> int:
        return self.A.shape[0]

    def simulate(self, u: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact response to u (T, m) from x0 (n,): (y (T, p), x[T] (n,))."""
        from scipy.signal import dlsim  # here: scipy.signal costs ~1.5 s, every pytest process loads this module

        u = np.asarray(u, dtype=float)
        _, y, x = dlsim((self.A, self.B, self.C, self.D, 1.0), u, x0=np.asarray(x0, dtype=float))
        y = np.asarray(y).reshape(u.shape[0], self.C.shape[0])
        x_last = np.asarray(x).reshape(u.shape[0], self.n)[-1]
        return y, self.A @ x_last + self.B @ u[-1]


def random_lti(n: int, m: int, p: int, seed: int, radius: float = 0.9, feedthrough: bool = False) -> LTI:
    """A random stable system: spectral radius ``radius``, D = 0 unless ``feedthrough``."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    A *= radius / np.max(np.abs(np.linalg.eigvals(A)))
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((p, n))
    D = rng.standard_normal((p, m)) if feedthrough else np.zeros((p, m))
    return LTI(A, B, C, D)


def height_loop() -> LTI:
    """Two decoupled closed loops with unit steady-state gain: a damped second-order one (a height loop's
    slow answer to its reference: poles 0.8 +- 0.1j) and a first-order lag (0.7)."""
    a1, a2 = 1.6, -0.65
    A = np.array([[a1, a2, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.7]])
    B = np.array([[1.0 - a1 - a2, 0.0], [0.0, 0.0], [0.0, 0.3]])
    return LTI(A, B, np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.zeros((2, 2)))
