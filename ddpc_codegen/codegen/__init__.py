"""Code generation: a SteeringProblem -> self-contained C folder + compiled extension + manifest.json."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

from ddpc_codegen.errors import CodegenError
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.codegen import vectors as test_vectors
from ddpc_codegen.codegen.artio import OnlineCompletion, manifest_entry
from ddpc_codegen.codegen.build import compile_extension
from ddpc_codegen.codegen.emit import BACKENDS, DEFAULTS, VECTORS_FILE, check_name, emit_sources
from ddpc_codegen.codegen.manifest import build_manifest, write_manifest
from ddpc_codegen.runtime.manifest import read_manifest
from ddpc_codegen.codegen.tuning import choose_rho

__all__ = ["generate", "BACKENDS", "OnlineCompletion", "read_manifest"]


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
) -> Path:
    """Emit (and compile) the steering solver of ``problem`` into the folder ``out_dir``.

    Args:
        backend: ``"daqp"`` (exact dense active set) or ``"osqp"`` (embedded OSQP, parameters='vectors',
            with active-set refinement); default: the config's ``[codegen] backend``.
        name: C/Python identifier of the solver (prefix of every C symbol); default: the config's name.
        compile: build the Python-loadable extension (needs a C compiler; no network).
        march_native: add ``-march=native`` (opt-in: the binary then only runs on this CPU family).
        max_iter, eps: solver settings; default from the config, then the backend's defaults.
        n_vectors: number of recorded test vectors (``<name>_vectors.txt``).
        artificial_io: hopping: the online artificial-IO completion to generate with the solver
            (``<name>_artio.h``; in Python ``solver.artificial_io``); its noise level must be > 0.
    Returns:
        the solver folder (with manifest.json), loadable by :func:`ddpc_codegen.load_solver`; it also
        builds without Python (CMakeLists.txt, Makefile, example_main.c).
    """
    cfg = problem.config
    backend = backend or cfg.codegen.get("backend", "daqp")
    if backend not in BACKENDS:
        raise CodegenError(f"unknown backend {backend!r}; choose one of {list(BACKENDS)}")
    name = check_name(name or cfg.name)
    out = Path(out_dir).resolve()
    settings = _settings(problem, backend, max_iter, eps)
    native = bool(cfg.codegen.get("march_native", False) if march_native is None else march_native)
    t0 = time.perf_counter()
    units = emit_sources(problem, out, name, backend, settings, artificial_io)
    vec = test_vectors.record(problem, n_vectors)
    vec_file = out / VECTORS_FILE.format(name=name)
    vec_sha = test_vectors.write(vec_file, name, vec)
    # The module (and file) name changes with anything that changes the binary: a process cannot
    # dlopen a rebuilt library under a path it has already loaded.
    art_key = None
    if artificial_io is not None:
        art_key = [hashlib.sha256(artificial_io.art.basis.tobytes()).hexdigest(), manifest_entry(artificial_io)]
    ident = hashlib.sha256(json.dumps([problem.predictor.digest, cfg.digest, backend, settings, native, name, art_key],
                                      sort_keys=True, default=str).encode()).hexdigest()[:12]
    module = f"_ddpc_{name}_{ident}"
    if not compile:
        return out
    for old in out.glob("_ddpc_*"):
        old.unlink()
    ext, flags = compile_extension(out, name, module, units, backend, march_native=native, verbose=verbose,
                                   artio=artificial_io is not None)
    settings["build_seconds"] = round(time.perf_counter() - t0, 3)
    sources = sorted(p for p in out.rglob("*") if p.is_file() and p.suffix in (".c", ".h")
                     and not any(part.startswith("build") for part in p.relative_to(out).parts))
    extra = {"vectors": {"file": vec_file.name, "sha256": vec_sha, **vec.summary()},
             "artificial_io": None if artificial_io is None else manifest_entry(artificial_io)}
    write_manifest(out, build_manifest(problem, name, backend, module, ext, sources, out, settings, flags, extra))
    return out
