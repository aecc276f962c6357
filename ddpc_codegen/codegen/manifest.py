"""manifest.json of a generated solver: what it is, what it was built from, what built it."""

from __future__ import annotations

import hashlib
import json
import platform
from pathlib import Path

import casadi
import numpy as np
import osqp

from .. import __version__
from ..errors import ManifestError

FORMAT = "ddpc-codegen-solver"
VERSION = 1


def _inf_list(a) -> list:
    return [None if not np.isfinite(x) else float(x) for x in np.ravel(a)]


def sha256_file(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


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


def read_manifest(folder: Path) -> dict:
    path = Path(folder) / "manifest.json"
    if not path.exists():
        raise ManifestError(f"{folder} has no manifest.json: not a generated solver (run `ddpc-codegen codegen` first)")
    try:
        man = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ManifestError(f"{path} is not valid JSON: {e}") from e
    if man.get("format") != FORMAT or man.get("format_version") != VERSION:
        raise ManifestError(
            f"{path}: format {man.get('format')!r} v{man.get('format_version')} is not {FORMAT!r} v{VERSION}; regenerate the solver"
        )
    return man


def write_manifest(folder: Path, manifest: dict) -> Path:
    path = Path(folder) / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    return path
