"""The generated artificial-IO completion of a hopping solver, called from Python (no CasADi).

Duck-type compatible with :class:`ddpc_codegen.design.artificial_io.ArtificialIO` where the online
window (``HoppingWindow``) uses it: ``depth``, ``noise_level``, ``m``, ``p``, ``counts`` and
``complete(u, y, missing, *, replace_known=False, noise_level=None)`` returning a
:class:`~ddpc_codegen.design.artificial_io.Completion`. The noise level is compiled in: another one is
refused. Dims, sigma, lambda and bounds come from the binary (``<name>_artio_describe``) and must
agree with manifest.json (the binary is the authority).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ddpc_codegen.values.completion import Completion, check_window
from ddpc_codegen.errors import DataError, ManifestError
from ddpc_codegen.runtime.guard import Guard

__all__ = ["GeneratedArtificialIO", "ARTIO_STATUS"]

ARTIO_STATUS = {0: "solved", -1: "infeasible", -2: "max_iter", -3: "nonfinite", -4: "solver_error",
                -5: "unverified", -6: "bad_input"}
_API = ("init", "complete", "describe", "status_string")


def _listed(man_values: list) -> np.ndarray:
    return np.array([np.nan if x is None else x for x in man_values], dtype=float)


class GeneratedArtificialIO:
    """One instance of the compiled completion (its own C workspace; one instance per thread: a call while another
    thread is inside one raises :class:`~ddpc_codegen.runtime.guard.SolverBusyError`)."""

    def __init__(self, folder: Path, manifest: dict, lib, ffi) -> None:
        name = manifest["name"]
        entry = manifest.get("artificial_io")
        if not isinstance(entry, dict):
            raise ManifestError(f"{folder}: manifest.json has no artificial_io entry: not a hopping solver")
        try:
            self._fn = {f: getattr(lib, f"{name}_artio_{f}") for f in _API}
        except AttributeError as e:
            raise ManifestError(f"{folder}: manifest.json lists an artificial-IO completion but the binary has none "
                                f"({e}); regenerate the solver") from e
        self._ffi, self._guard = ffi, Guard(name)
        dims = ffi.new("int[5]")
        self._fn["describe"](dims, ffi.NULL)
        self.depth, self.rank, self.m, self.p, self.n_columns = (int(v) for v in dims)
        self.d = self.m + self.p
        vals = ffi.new(f"double[{2 * self.d + 3}]")
        self._fn["describe"](ffi.NULL, vals)
        v = np.array(list(vals))
        self.noise_level, self.lam = float(v[0]), float(v[1])
        self.lo, self.hi = v[2 : 2 + self.d], v[2 + self.d : 2 + 2 * self.d]
        self.feas_tol = float(v[-1])
        self._check(folder, entry)
        self.t_d_online, self.min_ascent = int(entry["t_d_online"]), int(entry["min_ascent"])
        self.denoise_online = bool(entry["denoise_online"])
        self.refit_residual = float(entry["refit_residual"])
        self._ws = ffi.new(f"{name}_artio_workspace *")
        self._fn["init"](self._ws)
        self._info = ffi.new(f"{name}_artio_info *")
        self.counts = {"calls": 0, "bounded": 0, "qp_failed": 0}
        self.last_info: dict = {}  # of the last call: C wall time [us], max relative violation, QP iterations

    def _check(self, folder: Path, entry: dict) -> None:
        compiled = {"depth": self.depth, "rank": self.rank, "m": self.m, "p": self.p, "n_columns": self.n_columns,
                    "noise_level": self.noise_level, "lambda": self.lam, "feas_tol": self.feas_tol}
        for key, val in compiled.items():
            if entry.get(key) != val:
                raise ManifestError(f"{folder}: manifest.json artificial_io.{key} = {entry.get(key)!r} differs from "
                                    f"the compiled completion's {val!r} (edited?); the binary is the authority")
        for key, val in (("lo", self.lo), ("hi", self.hi)):
            listed = _listed(entry.get(key, []))
            if listed.shape != val.shape or not np.array_equal(listed, np.where(np.isfinite(val), val, np.nan),
                                                               equal_nan=True):
                raise ManifestError(f"{folder}: manifest.json artificial_io.{key} = {entry.get(key)} differs from the "
                                    f"compiled completion's {val.tolist()} (edited?); the binary is the authority")

    def __repr__(self) -> str:
        return (f"GeneratedArtificialIO(m={self.m}, p={self.p}, depth={self.depth}, rank={self.rank}, "
                f"noise_level={self.noise_level})")

    def window_settings(self) -> dict:
        """The online window's keyword arguments as generated (``HoppingWindow(op, t_ini, **settings)``)."""
        return {"t_d": self.t_d_online, "min_ascent": self.min_ascent, "noise_level": self.noise_level,
                "denoise": self.denoise_online, "refit_residual": self.refit_residual}

    def complete(self, u: np.ndarray, y: np.ndarray, missing: np.ndarray, *, replace_known: bool = False,
                 noise_level: float | None = None) -> Completion:
        """Fill the missing samples of a window (see ``ArtificialIO.complete``; same arguments and result).

        ``noise_level`` must be None or the compiled sigma. The result's ``status`` is "solved" only when
        the fill satisfies every bound within ``feas_tol``; otherwise (bounded QP failed or unverified)
        the unbounded fill is returned clipped to the bounds, with that status.
        """
        if noise_level is not None and float(noise_level) != self.noise_level:
            raise DataError(f"the generated artificial-IO operator was compiled for noise_level = {self.noise_level}; "
                            f"got {noise_level} (regenerate with [artificial_io] noise_level_online = {noise_level})")
        u, y, mask = check_window(u, y, missing, self.m, self.p, self.depth)
        L = u.shape[0]
        w = np.ascontiguousarray(np.hstack([u, y]).reshape(-1))
        flags = np.ascontiguousarray(mask.reshape(-1), dtype=np.uint8)
        out = np.empty_like(w)
        fb = self._ffi.from_buffer
        with self._guard.held("artificial-IO complete"):  # the info struct is the instance's too
            st = self._fn["complete"](self._ws, L, fb("double[]", w), fb("unsigned char[]", flags),
                                      int(bool(replace_known)), fb("double[]", out), self._info)
            info = self._info
            status = ARTIO_STATUS.get(st, f"status_{st}")
            self.counts["calls"] += 1
            if info.bounded:
                self.counts["bounded"] += 1
                if st != 0:
                    self.counts["qp_failed"] += 1
            self.last_info = {"solve_time_us": float(info.solve_time_us), "max_violation": float(info.max_violation),
                              "iterations": int(info.iterations), "raw_status": int(info.raw_status),
                              "reduced": bool(info.reduced)}
        W = out.reshape(L, self.d)
        return Completion(W[:, : self.m].copy(), W[:, self.m :].copy(), float(info.residual), float(info.g_norm),
                          bool(info.bounded), status)
