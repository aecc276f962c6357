"""Load a generated solver and call it with the same API as the interpreted SteeringProblem."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

from ddpc_codegen.runtime.manifest import read_manifest, sha256_file
from ddpc_codegen.design.config import SteeringConfig
from ddpc_codegen.errors import DataError, ManifestError
from ddpc_codegen.design.result import SteeringResult, stack_window

__all__ = ["GeneratedSolver", "load_solver"]

_STATUS = {0: "solved", -1: "infeasible", -2: "max_iter", -3: "nonfinite", -4: "solver_error"}


_NAN = float("nan")


class _Prediction:
    """Deferred y_pred / sigma of one result (computed in C on first access)."""

    __slots__ = ("solver", "theta", "u")

    def __init__(self, solver, theta, u):
        self.solver, self.theta, self.u = solver, theta, u

    def __call__(self):
        s = self.solver
        if self.theta is None:
            return np.full((s.t_f, s.p), np.nan), np.full((s.t_ini, s.p), np.nan)
        return s._predict(self.theta, self.u)


class GeneratedSolver:
    """A compiled steering solver. ``solve`` has the signature and result of SteeringProblem.solve."""

    def __init__(self, folder: Path, manifest: dict, module) -> None:
        self.folder = folder
        self.manifest = manifest
        self._ffi, self._lib = module.ffi, module.lib
        d = manifest["dims"]
        self.m, self.p, self.t_ini, self.t_f = d["m"], d["p"], d["t_ini"], d["t_f"]
        self.n_u, self.n_theta, self.n_y, self.n_sigma = d["n_u"], d["n_theta"], d["n_y"], d["n_sigma"]
        self.has_nominal = bool(manifest["has_nominal"])
        self.backend = manifest["backend"]
        self.name = manifest["name"]
        dims = self._ffi.new("int[4]")
        self._lib.ddpc_dims(dims)
        if tuple(dims) != (self.n_u, self.n_theta, self.n_y, self.n_sigma):
            raise ManifestError(
                f"{folder}: the compiled extension has dims {tuple(dims)} but manifest.json says "
                f"{(self.n_u, self.n_theta, self.n_y, self.n_sigma)}; regenerate the solver"
            )
        if self._lib.ddpc_init() != 0:
            raise ManifestError(f"{folder}: the solver workspace failed to initialise")
        self._theta = np.empty(self.n_theta)
        self._u = np.empty(self.n_u)
        self._info = self._ffi.new("double[4]")
        fb = self._ffi.from_buffer
        self._pt, self._pu, self._pi = fb("double[]", self._theta), fb("double[]", self._u), self._info
        self._shape_u = (self.t_f, self.m)

    def __repr__(self) -> str:
        return f"GeneratedSolver({self.name!r}, backend={self.backend!r}, n_u={self.n_u}, n_theta={self.n_theta})"

    def reset(self) -> None:
        """Drop the warm start."""
        self._lib.ddpc_reset()

    def theta(self, u_ini, y_ini, y_des, u_nom=None) -> np.ndarray:
        """Stack and validate the parameters (same layout as SteeringProblem.theta)."""
        parts = [stack_window(u_ini, self.t_ini, self.m, "u_ini", check_finite=False), stack_window(y_ini, self.t_ini, self.p, "y_ini", check_finite=False),
                 stack_window(y_des, self.t_f, self.p, "y_des", check_finite=False)]
        if self.has_nominal:
            if u_nom is None:
                raise DataError("R_mode 'offset' needs u_nom, the nominal (unsteered) references over the horizon")
            parts.append(stack_window(u_nom, self.t_f, self.m, "u_nom", check_finite=False))
        th = np.concatenate(parts)
        if not np.isfinite(th).all():
            bad = [w for w, p in zip(("u_ini", "y_ini", "y_des", "u_nom"), parts) if not np.isfinite(p).all()]
            raise DataError(f"{', '.join(bad)} contains NaN or inf; refusing to steer on it")
        return th

    def solve(self, u_ini, y_ini, y_des, u_nom=None) -> SteeringResult:
        """One tick: steered references u (Tf, m), predicted y (Tf, p), status, iterations, time."""
        return self.solve_theta(self.theta(u_ini, y_ini, y_des, u_nom), _checked=True)

    def solve_theta(self, theta: np.ndarray, _checked: bool = False) -> SteeringResult:
        """Like :meth:`solve`, from a stacked parameter vector (n_theta,)."""
        if not _checked:
            theta = np.asarray(theta, dtype=float)
            if theta.shape != (self.n_theta,):
                raise DataError(f"theta must have shape ({self.n_theta},); got {theta.shape}")
            if not math.isfinite(theta.sum()):  # any NaN/inf makes the sum non-finite
                raise DataError("theta contains NaN or inf; refusing to steer on it")
        self._theta[:] = theta
        st = self._lib.ddpc_step(self._pt, self._pu, self._ffi.NULL, self._ffi.NULL, self._pi)
        info = self._info
        u = self._u.reshape(self._shape_u)  # a fresh view...
        u = u.copy()  # ...and its own data: the buffer is reused next tick
        if st == 0:
            predict = _Prediction(self, self._theta.copy(), u)
            status = "solved"
        else:
            predict = _Prediction(self, None, u)
            status = _STATUS.get(st, f"status_{st}")
        return SteeringResult(u, None, None, status, int(info[0]), info[2] * 1e-6, _NAN, info[1] == 1.0,
                              {"raw_status": int(info[3])}, predict)

    def _predict(self, theta: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        y = np.empty(self.n_y)
        s = np.empty(max(1, self.n_sigma))
        fb = self._ffi.from_buffer
        self._lib.ddpc_predict(fb("double[]", theta), fb("double[]", np.ascontiguousarray(u, dtype=float)),
                               fb("double[]", y), fb("double[]", s))
        return y.reshape(self.t_f, self.p), s[: self.n_sigma].reshape(self.t_ini, self.p)

    def step_u(self, theta: np.ndarray) -> tuple[int, np.ndarray]:
        """Lowest-overhead call for loops: (status code, u (n_u,) view, valid until the next call).
        theta must be a float64 array of n_theta finite entries (not checked)."""
        self._theta[:] = theta
        return self._lib.ddpc_step(self._pt, self._pu, self._ffi.NULL, self._ffi.NULL, self._pi), self._u

    def bench(self, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Run every row of ``thetas`` (n, n_theta) in C; returns (times in µs, status codes)."""
        th = np.ascontiguousarray(thetas, dtype=float)
        n = th.shape[0]
        times, sts = np.empty(n), np.empty(n, dtype=np.int32)
        self._lib.ddpc_bench(self._ffi.from_buffer("double[]", th), n, self._ffi.from_buffer("double[]", times),
                             self._ffi.from_buffer("int[]", sts))
        return times, sts


def load_solver(path: str | Path, config: SteeringConfig | str | Path | None = None,
                predictor_hash: str | None = None) -> GeneratedSolver:
    """Load a generated solver folder (checks manifest.json, sources and the binary).

    Args:
        config: when given (a SteeringConfig or a TOML path), its hash must equal the one the
            solver was generated from; a mismatch is refused with a ManifestError.
        predictor_hash: likewise for the predictor (``Predictor.digest``).
    """
    folder = Path(path)
    man = read_manifest(folder)
    if config is not None:
        cfg = config if isinstance(config, SteeringConfig) else SteeringConfig.from_toml(config)
        if cfg.digest != man["config_hash"]:
            raise ManifestError(
                f"{folder} was generated from a different configuration (config hash {man['config_hash'][:12]}…, "
                f"given {cfg.digest[:12]}… from {cfg.source}); regenerate with `ddpc-codegen codegen`"
            )
    if predictor_hash is not None and predictor_hash != man["predictor_hash"]:
        raise ManifestError(
            f"{folder} was generated from a different predictor ({man['predictor_hash'][:12]}… vs {predictor_hash[:12]}…)"
        )
    for rel, digest in man["sources"].items():
        f = folder / rel
        if not f.exists():
            raise ManifestError(f"{folder}: source {rel} listed in manifest.json is missing")
        if sha256_file(f) != digest:
            raise ManifestError(f"{folder}: source {rel} differs from the one the solver was built from (edited?); regenerate")
    ext = folder / man["extension"]
    if not ext.exists():
        raise ManifestError(f"{folder}: compiled extension {man['extension']} is missing; regenerate (make codegen)")
    if sha256_file(ext) != man["extension_sha256"]:
        raise ManifestError(f"{folder}: {man['extension']} is not the binary manifest.json describes; regenerate")
    module = sys.modules.get(man["module"])
    if module is None or getattr(module, "__file__", None) != str(ext):
        spec = importlib.util.spec_from_file_location(man["module"], ext)
        if spec is None or spec.loader is None:  # pragma: no cover
            raise ManifestError(f"cannot load {ext}")
        module = importlib.util.module_from_spec(spec)
        try:
            spec.loader.exec_module(module)
        except ImportError as e:
            raise ManifestError(f"{ext} does not load on this machine ({e}); regenerate it here") from e
        sys.modules[man["module"]] = module
    return GeneratedSolver(folder, man, module)
