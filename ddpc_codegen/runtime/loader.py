"""Load a generated solver and call it with the same API as the interpreted SteeringProblem.

The dims, bounds and tolerance the runtime relies on are read from the compiled binary
(``<name>_describe``) and cross-checked against manifest.json, so editing the manifest cannot change
a safety check; a binary of another solver, or one that does not load, is a ManifestError.

Threads: one instance per thread. An instance's calls that touch its C workspace (solve, step_u, bench, reset,
the adaptation's tick-side calls) are refused with :class:`SolverBusyError` while another thread is inside one
(a non-blocking guard: never a wait in the tick, never a shared workspace). The osqp backend keeps OSQP's
workspace static in the extension, so there every instance of one folder shares the guard. Load the folder once
per thread (the daqp backend) for concurrent solves.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.values.adapt import Swapped
from ddpc_codegen.values.solve_result import SteeringResult, stack_window
from ddpc_codegen.errors import DataError, ManifestError
from ddpc_codegen.runtime.manifest import check_files, read_manifest, sha256_file
from ddpc_codegen.runtime.adapt_generated import GeneratedAdaptation
from ddpc_codegen.runtime.artificial_io import GeneratedArtificialIO
from ddpc_codegen.runtime.guard import SolverBusyError, busy, workspace_guard

__all__ = ["GeneratedSolver", "SolverBusyError", "load_solver"]

STATUS = {0: "solved", -1: "infeasible", -2: "max_iter", -3: "nonfinite", -4: "solver_error", -5: "unverified"}
BACKEND_IDS = {0: "daqp", 1: "osqp"}
_NAN = float("nan")
_API = ("init", "reset", "solve", "predict", "describe", "bench", "status_string")


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


def _binary_facts(folder: Path, man: dict, lib, ffi) -> tuple[dict, dict, float]:
    """(dims, bounds, feas_tol) compiled into the binary, checked against the manifest."""
    name = man["name"]
    dims_c = ffi.new("int[10]")
    d = man["dims"]
    n_b = 3 * d["m"] + 2 * d["p"] + 1
    getattr(lib, f"{name}_describe")(dims_c, ffi.NULL)
    dims = dict(zip(("m", "p", "t_ini", "t_f", "n_u", "n_theta", "n_y", "n_sigma", "n_g"), list(dims_c)[:9]))
    backend = BACKEND_IDS.get(dims_c[9], f"backend_{dims_c[9]}")
    if dims != {k: d[k] for k in dims} or backend != man["backend"]:
        raise ManifestError(f"{folder}: the compiled solver has dims {dims} (backend {backend}) but manifest.json "
                            f"says {d} (backend {man['backend']}); regenerate the solver")
    raw = ffi.new(f"double[{n_b}]")
    getattr(lib, f"{name}_describe")(ffi.NULL, raw)
    vals = np.array(list(raw))
    m, p = d["m"], d["p"]
    cut = np.cumsum([0, m, m, p, p, m])
    bounds = {k: vals[cut[i] : cut[i + 1]] for i, k in enumerate(("u_min", "u_max", "y_min", "y_max", "du_max"))}
    for k, v in bounds.items():
        listed = np.array([np.nan if x is None else x for x in man["bounds"][k]], dtype=float)
        compiled = np.where(np.isfinite(v), v, np.nan)
        if listed.shape != compiled.shape or not np.array_equal(listed, compiled, equal_nan=True):
            raise ManifestError(f"{folder}: manifest.json bounds.{k} = {man['bounds'][k]} differ from the compiled "
                                f"solver's {v.tolist()} (edited?); the binary's bounds are the ones it enforces")
    feas_tol = float(vals[-1])
    if feas_tol != man["feas_tol"]:
        raise ManifestError(f"{folder}: manifest.json feas_tol {man['feas_tol']} differs from the binary's {feas_tol}")
    return dims, bounds, feas_tol


class GeneratedSolver:
    """A compiled steering solver instance (its own C workspace). ``solve`` has the signature and result
    of SteeringProblem.solve. Load the same folder twice for two independent instances.

    One instance per thread: a call while another thread is inside one on the same instance (or, osqp, on any
    instance of the folder) raises :class:`SolverBusyError` instead of sharing the workspace."""

    def __init__(self, folder: Path, manifest: dict, module) -> None:
        self.folder = folder
        self.manifest = manifest
        self.name = manifest["name"]
        self.backend = manifest["backend"]
        self._ffi, self._lib = module.ffi, module.lib
        self._guard = workspace_guard(module, self.backend, self.name)  # taken by every call writing the workspace
        self._take, self._give = self._guard.take, self._guard.give
        try:
            self._fn = {f: getattr(self._lib, f"{self.name}_{f}") for f in _API}
        except AttributeError as e:
            raise ManifestError(f"{folder}: {manifest['extension']} is not the binary of solver {self.name!r} "
                                f"({e}); regenerate the solver") from e
        dims, self.bounds, self.feas_tol = _binary_facts(folder, manifest, self._lib, self._ffi)
        self.m, self.p, self.t_ini, self.t_f = dims["m"], dims["p"], dims["t_ini"], dims["t_f"]
        self.n_u, self.n_theta, self.n_y, self.n_sigma = dims["n_u"], dims["n_theta"], dims["n_y"], dims["n_sigma"]
        self.has_nominal = bool(manifest["has_nominal"])
        if self.n_theta != (self.m + self.p) * self.t_ini + self.p * self.t_f + (self.m * self.t_f if self.has_nominal else 0):
            raise ManifestError(f"{folder}: has_nominal={self.has_nominal} in manifest.json does not match the "
                                f"binary's n_theta={self.n_theta}")
        self._ws = self._ffi.new(f"{self.name}_workspace *")
        if self._fn["init"](self._ws) != 0:  # the instance's workspace only (osqp: OSQP's static one untouched)
            raise ManifestError(f"{folder}: the solver workspace failed to initialise")
        self._theta = np.empty(self.n_theta)
        self._u = np.empty(self.n_u)
        self._info = self._ffi.new(f"{self.name}_info *")
        fb = self._ffi.from_buffer
        self._pt, self._pu = fb("double[]", self._theta), fb("double[]", self._u)
        self._shape_u = (self.t_f, self.m)
        self.artificial_io = None  # hopping: the generated completion (GeneratedArtificialIO), else None
        if manifest.get("artificial_io") is not None:
            self.artificial_io = GeneratedArtificialIO(folder, manifest, self._lib, self._ffi)
        elif hasattr(self._lib, f"{self.name}_artio_complete"):
            raise ManifestError(f"{folder}: the binary has an artificial-IO completion that manifest.json does not "
                                "list (edited?); regenerate the solver")
        self.adaptation = None  # online update (generated with [adapt] enabled), else None
        if hasattr(self._lib, f"{self.name}_adapt_init"):
            self.adaptation = GeneratedAdaptation(self)

    def __repr__(self) -> str:
        return f"GeneratedSolver({self.name!r}, backend={self.backend!r}, n_u={self.n_u}, n_theta={self.n_theta})"

    def reset(self) -> None:
        """Drop the warm start: the workspace returns to exactly its post-init state (an adaptive solver keeps
        the QP data it last swapped in)."""
        with self._guard.held("reset"):
            self._fn["reset"](self._ws)

    # online adaptation (issue 30): the same API as design.adaptation.AdaptiveProblem
    def _adapt(self):
        if self.adaptation is None:
            raise DataError(f"solver {self.name!r} was generated without [adapt] enabled: it has no online update")
        return self.adaptation

    @property
    def adapt_settings(self):
        """The ``[adapt]`` settings the solver was generated with."""
        return self._adapt().settings

    def adapt_push(self, u, y) -> bool:
        """One applied reference u (m,) and measured output y (p,); True when a Hankel column was folded in."""
        return self._adapt().push(u, y)

    def adapt_clear(self) -> None:
        """Forget the partial window (a tick that must not update broke the sequence)."""
        self._adapt().clear()

    def adapt_snapshot(self) -> None:
        """Copy what a re-solve reads (R, the recent columns) for :meth:`adapt_resolve` ``(False)``."""
        self._adapt().snapshot()

    def adapt_resolve(self, snapshot: bool = True) -> str:
        """Re-solve G, rebuild the QP data and verify both: "accepted" or the rejection reason. ``snapshot``:
        take the snapshot first; False: from the last :meth:`adapt_snapshot` (may run in another thread)."""
        return self._adapt().resolve(snapshot)

    def adapt_swap(self) -> Swapped:
        """Make what the last re-solve verified current (between ticks): which of G and the output offset were
        installed (neither: nothing verified was pending, or the QP backend refused the new data)."""
        return self._adapt().swap()

    def adapt_refused(self) -> int:
        """Columns the update did not take (a NaN/inf window: skipped; its queue full: dropped); cheap, and safe in
        the tick while a background re-solve runs (push's own counters)."""
        return self._adapt().refused()

    def adapt_counts(self) -> dict:
        """updates (columns taken), skipped (NaN/inf), dropped (queue full), folded (columns in R), resolves,
        accepted, swaps, clipped, rejected_<reason>, offset_swaps, offset_clipped, offset_rejected counters,
        offset_norm (the norm of the output offset in use) and the last verifications' errors."""
        return self._adapt().counts()

    def adapt_offset(self) -> np.ndarray:
        """The output offset b (p Tf,) the solver aims past (y_des - b), data units, time-major."""
        return self._adapt().offset()

    def theta(self, u_ini, y_ini, y_des, u_nom=None) -> np.ndarray:
        """Stack and validate the parameters (same layout as SteeringProblem.theta)."""
        parts = [stack_window(u_ini, self.t_ini, self.m, "u_ini", check_finite=False),
                 stack_window(y_ini, self.t_ini, self.p, "y_ini", check_finite=False),
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

    def solve_theta(self, theta: np.ndarray, _checked: bool = False, *, raw: bool = False) -> SteeringResult:
        """Like :meth:`solve`, from a stacked parameter vector (n_theta,). ``raw=True`` hands NaN / inf
        entries to the C solver (which answers "nonfinite") instead of raising DataError."""
        if not _checked:
            theta = np.asarray(theta, dtype=float)
            if theta.shape != (self.n_theta,):
                raise DataError(f"theta must have shape ({self.n_theta},); got {theta.shape}")
            if not raw and not math.isfinite(theta.sum()):  # any NaN/inf makes the sum non-finite
                raise DataError("theta contains NaN or inf; refusing to steer on it")
        try:
            self._take()
        except IndexError:
            raise busy(self.name, "solve") from None
        try:  # theta in, u and info out: the instance's buffers, read back before another call may write them
            self._theta[:] = theta
            st = self._fn["solve"](self._ws, self._pt, self._pu, self._info)
            info = self._info
            u = self._u.reshape(self._shape_u).copy()  # its own data: the buffer is reused next tick
            predict = _Prediction(self, self._theta.copy() if st == 0 else None, u)
            extra = {"raw_status": int(info.raw_status), "max_violation": float(info.max_violation),
                     "refined": bool(info.refined)}
            return SteeringResult(u, None, None, STATUS.get(st, f"status_{st}"), int(info.iterations),
                                  info.solve_time_us * 1e-6, _NAN, bool(info.fast_path), extra, predict)
        finally:
            self._give(None)

    def predict(self, u_ini, y_ini, u_f) -> np.ndarray:
        """(Tf, p) the outputs the predictor expects after the window ``u_ini`` (Tini, m), ``y_ini`` (Tini, p) under
        the references ``u_f`` (Tf, m), in the signals' units: what a result's ``y_pred`` is for the solver's own
        references, here for any (e.g. those the loop applied)."""
        nominal = np.zeros((self.t_f, self.m)) if self.has_nominal else None
        theta = self.theta(u_ini, y_ini, np.zeros((self.t_f, self.p)), nominal)
        return self._predict(theta, np.asarray(u_f, dtype=float).reshape(-1))[0]

    def _predict(self, theta: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        theta, u = np.ascontiguousarray(theta, dtype=float), np.ascontiguousarray(u, dtype=float)
        if theta.shape != (self.n_theta,) or u.size != self.n_u:  # C reads n_theta and n_u doubles
            raise DataError(f"predict needs theta ({self.n_theta},) and u of {self.n_u} entries; got {theta.shape}, "
                            f"{u.shape}")
        y = np.empty(self.n_y)
        s = np.empty(max(1, self.n_sigma))
        fb = self._ffi.from_buffer
        self._fn["predict"](fb("double[]", theta), fb("double[]", u),
                            fb("double[]", y), fb("double[]", s))
        return y.reshape(self.t_f, self.p), s[: self.n_sigma].reshape(self.t_ini, self.p)

    def step_u(self, theta: np.ndarray) -> tuple[int, np.ndarray]:
        """Lowest-overhead call for loops: (status code, u (n_u,) view, valid until the next call).
        theta must be a float64 array of n_theta entries (NaN / inf give the status "nonfinite")."""
        if getattr(theta, "shape", None) != (self.n_theta,):  # no broadcasting of a scalar or a row
            raise DataError(f"theta must have shape ({self.n_theta},); got {np.shape(theta)}")
        try:
            self._take()
        except IndexError:
            raise busy(self.name, "step_u") from None
        try:
            self._theta[:] = theta
            return self._fn["solve"](self._ws, self._pt, self._pu, self._ffi.NULL), self._u
        finally:
            self._give(None)

    def bench(self, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Run every row of ``thetas`` (n, n_theta) in C, each tick timed in C; returns
        (times in µs, status codes, u (n, n_u))."""
        th = np.ascontiguousarray(thetas, dtype=float)
        if th.ndim != 2 or th.shape[1] != self.n_theta:  # C reads n * n_theta doubles from this buffer
            raise DataError(f"thetas must have shape (n, {self.n_theta}); got {th.shape}")
        n = th.shape[0]
        times, sts, us = np.empty(n), np.empty(n, dtype=np.int32), np.empty((n, self.n_u))
        fb = self._ffi.from_buffer
        with self._guard.held("bench"):
            self._fn["bench"](self._ws, fb("double[]", th), n, fb("double[]", us), fb("double[]", times),
                              fb("int[]", sts))
        return times, sts, us


def _check_weights(folder: Path, man: dict) -> None:
    """``weights`` in manifest.json: Q (p, p), R, R_du, R_ddu, R_de and R_doffset (m, m; the last three absent in
    artifacts made before they existed) finite, lambda_sigma a number >= 0."""
    w, d = man.get("weights"), man["dims"]
    if not isinstance(w, dict):
        raise ManifestError(f"{folder}: manifest.json 'weights' must be an object with Q, R, R_du, lambda_sigma; "
                            f"got {w!r}")
    # (key, size, required): R_ddu, R_de and R_doffset are absent from artifacts generated before they existed
    for key, n, required in (("Q", d["p"], True), ("R", d["m"], True), ("R_du", d["m"], True), ("R_ddu", d["m"], False),
                             ("R_de", d["m"], False), ("R_doffset", d["m"], False)):
        if not required and key not in w:
            continue
        try:
            a = np.asarray(w.get(key), dtype=float)
        except (TypeError, ValueError):
            a = np.empty(0)
        if a.shape != (n, n) or not np.isfinite(a).all():
            raise ManifestError(f"{folder}: manifest.json weights.{key} must be a finite {n}x{n} matrix (dims); "
                                f"got {w.get(key)!r}")
    ls = w.get("lambda_sigma")
    if isinstance(ls, bool) or not isinstance(ls, (int, float)) or not math.isfinite(ls) or ls < 0:
        raise ManifestError(f"{folder}: manifest.json weights.lambda_sigma must be a number >= 0; got {ls!r}")


def _check_listing(folder: Path, man: dict) -> None:
    """What manifest.json lists is what the folder holds: every source inside the folder and every C
    source there listed; the test vectors file present with its recorded hash."""
    root = folder.resolve()
    for rel in man["sources"]:
        if Path(rel).is_absolute() or not (root / rel).resolve().is_relative_to(root):
            raise ManifestError(f"{folder}: manifest.json source {rel!r} is outside the solver folder")
    if f"{man['name']}_solver.c" not in man["sources"]:
        raise ManifestError(f"{folder}: manifest.json 'sources' does not list {man['name']}_solver.c")
    present = {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() and p.suffix in (".c", ".h")
               and not any(part.startswith(("build", ".")) for part in p.relative_to(root).parts)}
    unlisted = sorted(present - set(man["sources"]))
    if unlisted:
        raise ManifestError(f"{folder}: {unlisted[:5]} are in the folder but not in manifest.json 'sources' "
                            "(added after generation?); regenerate")
    vec = man["vectors"]
    name, digest = vec.get("file"), vec.get("sha256")
    if not isinstance(name, str) or not name or Path(name).name != name:
        raise ManifestError(f"{folder}: manifest.json vectors.file must be a file name in the folder; got {name!r}")
    if not (folder / name).is_file():
        raise ManifestError(f"{folder}: test vectors {name} listed in manifest.json are missing; regenerate")
    if sha256_file(folder / name) != digest:
        raise ManifestError(f"{folder}: test vectors {name} differ from the ones recorded at generation (edited?); "
                            "regenerate")


def _import_extension(folder: Path, man: dict, ext: Path):
    module = sys.modules.get(man["module"])
    if module is not None and getattr(module, "__file__", None) == str(ext):
        return module
    spec = importlib.util.spec_from_file_location(man["module"], ext)
    if spec is None or spec.loader is None:
        raise ManifestError(f"{ext} is not a loadable extension module; regenerate the solver")
    try:  # a foreign or damaged .so fails in create_module (no PyInit_<module>) or in exec_module
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except ImportError as e:
        raise ManifestError(f"{ext} does not load on this machine or is not solver {man['name']!r} ({e}); "
                            "regenerate it here") from e
    if not hasattr(module, "lib") or not hasattr(module, "ffi"):
        raise ManifestError(f"{ext} is not a ddpc-codegen solver extension; regenerate the solver")
    sys.modules[man["module"]] = module
    return module


def load_solver(path: str | Path, config: SteeringConfig | str | Path | None = None,
                predictor_hash: str | None = None) -> GeneratedSolver:
    """Load a generated solver folder (checks manifest.json, sources and the binary); each call returns
    a new, independent instance. One instance per thread: a call on an instance another thread is inside raises
    :class:`SolverBusyError` (osqp: any instance of the folder, its OSQP workspace being static).

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
    _check_weights(folder, man)
    _check_listing(folder, man)
    ext = check_files(folder, man)
    return GeneratedSolver(folder, man, _import_extension(folder, man, ext))
