"""The artifact a user ships: a SteeringProblem -> self-contained C folder + compiled extension + manifest.json,
built in a temporary folder that replaces the old solver only once it works (:func:`generate`, the one entry of
code generation; :func:`compile_alone` for tests and benchmarks that need no vectors or manifest).

A rebuild never destroys what a user had: the new solver is emitted, compiled and made to replay its own
test vectors in ``.<name>.build-*`` next to the target; only then is the old folder swapped out (two
renames on one file system). A failed compile or a vector mismatch leaves the old folder as it was.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import itertools
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ddpc_codegen.codegen import vectors as test_vectors
from ddpc_codegen.codegen.artio import OnlineCompletion, manifest_entry
from ddpc_codegen.codegen.build import compile_extension
from ddpc_codegen.codegen.constants import BACKENDS, DEFAULTS, VECTOR_TOL, VECTORS_FILE
from ddpc_codegen.codegen.emit import check_name, emit_sources
from ddpc_codegen.codegen.manifest import build_manifest, write_manifest
from ddpc_codegen.codegen.tuning import choose_rho
from ddpc_codegen.design.adaptation import ship_fit_statistic
from ddpc_codegen.values.adapt import AdaptSettings
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.errors import CodegenError
from ddpc_codegen.runtime.loader import load_solver

__all__ = ["generate", "verify_vectors", "replace_folder", "compile_alone"]

_SERIAL = itertools.count()  # compile_alone: a process cannot dlopen two builds under one module name


def _settings(problem: SteeringProblem, backend: str, max_iter, eps) -> dict:
    cfg = problem.config
    settings = dict(DEFAULTS[backend])
    for key, val in (("max_iter", max_iter if max_iter is not None else cfg.codegen.get("max_iter")),
                     ("eps", eps if eps is not None else cfg.codegen.get("eps")),
                     ("rho", cfg.codegen.get("rho"))):
        if val is not None and key in settings:
            settings[key] = val
    if settings.get("rho") == "auto":
        settings["rho"] = choose_rho(problem, settings)
    return settings


def generate(
    problem: SteeringProblem,
    out_dir: str | Path,
    backend: str | None = None,
    *,
    name: str | None = None,
    compile: bool = True,
    march_native: bool | None = None,
    max_iter: int | None = None,
    eps: float | None = None,
    n_vectors: int = 48,
    verbose: bool = False,
    artificial_io: OnlineCompletion | None = None,
    provenance: dict | None = None,
    adapt: AdaptSettings | None = None,
) -> Path:
    """Emit (and compile) the steering solver of ``problem`` into the folder ``out_dir``.

    Args:
        backend: ``"daqp"`` (exact dense active set) or ``"osqp"`` (embedded OSQP, parameters='vectors',
            with active-set refinement); default: the config's ``[codegen] backend``.
        name: C/Python identifier of the solver (prefix of every C symbol); default: the config's name.
        compile: build the Python-loadable extension (needs a C compiler; no network) and check that it
            replays its test vectors.
        march_native: add ``-march=native`` (opt-in: the binary then only runs on this CPU family).
        max_iter, eps: solver settings; default from the config, then the backend's defaults.
        n_vectors: number of recorded test vectors (``<name>_vectors.txt``).
        artificial_io: hopping: the online artificial-IO completion to generate with the solver
            (``<name>_artio.h``; in Python ``solver.artificial_io``); its noise level must be > 0.
        provenance: what the data were (JSON-able; manifest ``dataset``), e.g. the bridge's
            ``thrust_field``, which the bridge checks against the vehicle before flying the solver.
        adapt: online predictor updates; default: the config's ``[adapt]``. When enabled (daqp backend only),
            ``<name>_adapt.{h,c}`` are emitted and compiled in, listed in CMakeLists/Makefile, the G-dependent
            QP data are read through the workspace (the non-adaptive folder is unchanged byte for byte); the
            manifest's ``fit_statistic`` and ``adapt`` record them.
    Returns:
        the solver folder (with manifest.json), loadable by :func:`ddpc_codegen.load_solver`; it also
        builds without Python (CMakeLists.txt, Makefile, example_main.c).
    Raises:
        CodegenError: unknown backend, bad name, failed compile or vectors not reproduced; ``out_dir``
            is then exactly as it was.
    """
    cfg = problem.config
    backend = backend or cfg.codegen.get("backend", "daqp")
    if backend not in BACKENDS:
        raise CodegenError(f"unknown backend {backend!r}; choose one of {list(BACKENDS)}")
    name = check_name(name or cfg.name)  # before any folder is made
    out = Path(out_dir).resolve()
    if out.exists() and not out.is_dir():
        raise CodegenError(f"{out} exists and is not a folder; give a folder for the solver")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.build-", dir=out.parent))
    try:
        _build(problem, tmp, name, backend, compile, march_native, max_iter, eps, n_vectors, verbose,
               artificial_io, provenance, adapt)
    except BaseException as e:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(e, CodegenError):
            kept = "the previous solver there is kept" if out.exists() else "nothing was written there"
            raise CodegenError(f"{out} not replaced ({kept}): {e}") from e
        raise
    replace_folder(tmp, out)
    return out


def _build(problem: SteeringProblem, out: Path, name: str, backend: str, compile: bool, march_native,
           max_iter, eps, n_vectors: int, verbose: bool, artificial_io, provenance, adapt=None) -> None:
    """Emit, compile, write the manifest and replay the vectors, all inside ``out`` (a fresh folder)."""
    cfg = problem.config
    settings = _settings(problem, backend, max_iter, eps)
    native = bool(cfg.codegen.get("march_native", False) if march_native is None else march_native)
    t0 = time.perf_counter()
    adapt = cfg.adapt if adapt is None else adapt
    adaptive = adapt.enabled
    units = emit_sources(problem, out, name, backend, settings, artificial_io, adapt)
    vec = test_vectors.record(problem, n_vectors)
    vec_file = out / VECTORS_FILE.format(name=name)
    vec_sha = test_vectors.write(vec_file, name, vec)
    if not compile:
        return
    # The module (and file) name changes with anything that changes the binary: a process cannot
    # dlopen a rebuilt library under a path it has already loaded.
    art_key = None
    if artificial_io is not None:
        art_key = [hashlib.sha256(artificial_io.art.basis.tobytes()).hexdigest(), manifest_entry(artificial_io)]
    if adaptive:
        art_key = [art_key, dataclasses.asdict(adapt)]
    ident = hashlib.sha256(json.dumps([problem.predictor.digest, cfg.digest, backend, settings, native, name, art_key],
                                      sort_keys=True, default=str).encode()).hexdigest()[:12]
    module = f"_ddpc_{name}_{ident}"
    ext, flags = compile_extension(out, name, module, units, backend, march_native=native, verbose=verbose,
                                   artio=artificial_io is not None, adapt=adaptive)
    settings["build_seconds"] = round(time.perf_counter() - t0, 3)
    sources = sorted(p for p in out.rglob("*") if p.is_file() and p.suffix in (".c", ".h")
                     and not any(part.startswith("build") for part in p.relative_to(out).parts))
    extra = {"vectors": {"file": vec_file.name, "sha256": vec_sha, **vec.summary()},
             "artificial_io": None if artificial_io is None else manifest_entry(artificial_io),
             "dataset": dict(provenance or {}),
             "fit_statistic": ship_fit_statistic(problem.predictor, out, name, adapt),  # for online updates
             **({"adapt": dataclasses.asdict(adapt)} if adaptive else {})}
    write_manifest(out, build_manifest(problem, name, backend, module, ext, sources, out, settings, flags, extra))
    verify_vectors(out, vec, VECTOR_TOL[backend])


def verify_vectors(folder: Path, vec: test_vectors.Vectors, tol: float) -> None:
    """The compiled solver in ``folder`` replays ``vec`` in order on one instance (warm starts as the
    C example): same status everywhere, max |u - u_recorded| <= ``tol`` where solved; CodegenError otherwise."""
    solver = load_solver(folder)
    for i, (th, u_rec, st) in enumerate(zip(vec.theta, vec.u, vec.status)):
        r = solver.solve_theta(th)
        got = test_vectors.STATUS_CODES.get(r.status, -4)
        if got != int(st):
            raise CodegenError(f"solver '{solver.name}' fails its test vector {i}: status {r.status!r}, "
                               f"recorded {int(st)}")
        err = float(np.max(np.abs(r.u.ravel() - u_rec))) if got == 0 else 0.0
        if not err <= tol:
            raise CodegenError(f"solver '{solver.name}' fails its test vector {i}: max |u - recorded| {err:.3g} "
                               f"> {tol:g}")


def replace_folder(new: Path, out: Path) -> None:
    """Put the finished folder ``new`` at ``out``; an old ``out`` is moved aside first and removed last,
    so at every moment one complete solver is on disk."""
    if not out.exists():
        new.replace(out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
    old.rmdir()
    out.replace(old)
    try:
        new.replace(out)
    except OSError:
        old.replace(out)  # put the user's solver back before reporting
        raise
    shutil.rmtree(old, ignore_errors=True)


def compile_alone(problem: SteeringProblem, settings: AdaptSettings, folder: Path, name: str):
    """Emit the adaptive solver (daqp backend) into ``folder`` and compile it with cffi (the package's portable
    flags) without test vectors or manifest, for tests and the benchmark; returns the module's (ffi, lib)."""
    folder = Path(folder)
    settings = dataclasses.replace(settings, enabled=True)
    units = emit_sources(problem, folder, name, "daqp", dict(DEFAULTS["daqp"]), adapt=settings)
    module = f"_adapt_alone_{name}_{next(_SERIAL)}"
    ext, _ = compile_extension(folder, name, module, units, "daqp", adapt=True)
    spec = importlib.util.spec_from_file_location(module, ext)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[module] = mod
    spec.loader.exec_module(mod)
    return mod.ffi, mod.lib
