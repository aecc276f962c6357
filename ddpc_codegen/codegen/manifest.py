"""manifest.json of a generated solver: what it is, what it was built from, what built it."""

from __future__ import annotations

import json
import platform
from pathlib import Path

import casadi
import numpy as np
import osqp

from ddpc_codegen import __version__
from ddpc_codegen.runtime.manifest import FORMAT, VERSION, sha256_file



def _inf_list(a) -> list:
    return [None if not np.isfinite(x) else float(x) for x in np.ravel(a)]


def build_manifest(problem, name: str, backend: str, module: str, extension: Path, sources: list[Path],
                   out_dir: Path, settings: dict, flags: list[str]) -> dict:
    c, pr = problem.config, problem.predictor
    return {
        "format": FORMAT,
        "format_version": VERSION,
        "name": name,
        "backend": backend,
        "module": module,
        "extension": extension.name,
        "dims": {"m": c.m, "p": c.p, "t_ini": c.t_ini, "t_f": c.t_f, "n_u": problem.n_u,
                 "n_theta": problem.n_theta, "n_g": problem.n_g, "n_y": c.p * c.t_f, "n_sigma": c.p * c.t_ini},
        "signals": {"inputs": list(c.input_names), "outputs": list(c.output_names), "dt": c.dt},
        "R_mode": c.R_mode,
        "has_nominal": problem.has_nominal,
        "bounds": {"u_min": _inf_list(c.u_min), "u_max": _inf_list(c.u_max), "y_min": _inf_list(c.y_min),
                   "y_max": _inf_list(c.y_max), "du_max": _inf_list(c.du_max)},
        "weights": {"Q": c.Q.tolist(), "R": c.R.tolist(), "R_du": c.R_du.tolist(), "lambda_sigma": c.lambda_sigma},
        "settings": settings,
        "config_hash": c.digest,
        "predictor_hash": pr.digest,
        "predictor": {"method": pr.method, "rank": pr.rank, "n_columns": pr.n_columns,
                      **{k: v for k, v in pr.options.items() if not k.startswith("_")}},
        "versions": {"ddpc_codegen": __version__, "casadi": casadi.__version__, "osqp": osqp.__version__,
                     "numpy": np.__version__, "python": platform.python_version()},
        "compiler": {"flags": flags, "platform": platform.machine()},
        "sources": {str(p.relative_to(out_dir)): sha256_file(p) for p in sorted(sources)},
        "extension_sha256": sha256_file(extension),
    }


def write_manifest(folder: Path, manifest: dict) -> Path:
    path = Path(folder) / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    return path
