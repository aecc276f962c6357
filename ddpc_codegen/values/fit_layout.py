"""The row layout of a predictor fit's data matrix (:class:`FitLayout`): one definition for the offline
TSQR fit (:mod:`ddpc_codegen.design.predictor`) and the online update (:mod:`ddpc_codegen.design.adapter`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ddpc_codegen.errors import DataError

__all__ = ["FitLayout"]


@dataclass(frozen=True)
class FitLayout:
    """Columns of the TSQR data matrix X = [Z^T | target^T] of a fit (one row per Hankel column).

    Z = [Up; Yp; Uf] has r = (m+p) Tini + m Tf rows; the targets are Yf (q_y = p Tf rows) and, for
    ``pem``, the slack (q_s = p Tini rows, zero on data). R factors of X are at most (width, width),
    width = r + q_y + q_s. The offline fit and the online update share it.
    """

    m: int
    p: int
    t_ini: int
    t_f: int
    method: str

    @property
    def depth(self) -> int:
        return self.t_ini + self.t_f

    @property
    def min_window(self) -> int:
        """The fewest recent columns an online update's verification may use: m (Tini + Tf), one per row of the
        input block of a Hankel column (fewer cannot show excitation)."""
        return self.m * self.depth

    @property
    def r(self) -> int:
        return (self.m + self.p) * self.t_ini + self.m * self.t_f

    @property
    def q_y(self) -> int:
        return self.p * self.t_f

    @property
    def q_s(self) -> int:
        return self.p * self.t_ini if self.method == "pem" else 0

    @property
    def width(self) -> int:
        return self.r + self.q_y + self.q_s

    @property
    def u_rows(self) -> np.ndarray:
        """Indices of the input rows ([Up; Uf]) of Z."""
        n_up, n_yp = self.m * self.t_ini, self.p * self.t_ini
        return np.r_[0:n_up, n_up + n_yp : self.r]

    def row_order(self) -> np.ndarray:
        """Indices taking a time-major window (depth, m+p) flattened to the order [Up; Yp; Uf; Yf]."""
        d, m = self.m + self.p, self.m
        ui = [t * d + c for t in range(self.depth) for c in range(m)]
        yi = [t * d + m + c for t in range(self.depth) for c in range(self.p)]
        nu, ny = m * self.t_ini, self.p * self.t_ini
        return np.array(ui[:nu] + yi[:ny] + ui[nu:] + yi[ny:])

    def data_rows(self, blk: np.ndarray) -> np.ndarray:
        """Hankel column block (b, depth*(m+p)) -> rows (b, width) of X as [Up Yp Uf Yf (0)]."""
        rows = blk[:, self.row_order()]
        return np.hstack([rows, np.zeros((rows.shape[0], self.q_s))]) if self.q_s else rows

    def column(self, window: np.ndarray, scale: np.ndarray) -> np.ndarray:
        """Time-major window (depth, m+p) in data units -> the data row x (width,) of X (scaled; slack 0)."""
        w = np.asarray(window, dtype=float)
        if w.shape != (self.depth, self.m + self.p):
            raise DataError(f"an adaptation window must have shape ({self.depth}, {self.m + self.p}) "
                            f"(depth Tini+Tf, channels u then y); got {w.shape}")
        x = np.zeros(self.width)
        x[: self.r + self.q_y] = (w / scale).reshape(-1)[self.row_order()]
        return x
