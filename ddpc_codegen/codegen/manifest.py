"""manifest.json of a generated solver: what it is, what it was built from, what built it."""

from __future__ import annotations

import json
import platform
from pathlib import Path

import casadi
import numpy as np
import osqp

from ddpc_codegen import __version__
from ddpc_codegen.codegen.constants import FEAS_TOL, VECTOR_TOL
from ddpc_codegen.codegen.libs import DAQP_VERSION
from ddpc_codegen.runtime.manifest import FORMAT, VERSION, sha256_file


def _inf_list(a) -> list:
    """JSON has no infinity: unbounded entries are null."""
    return [None if not np.isfinite(x) else float(x) for x in np.ravel(a)]


def build_manifest(problem, name: str, backend: str, module: str, extension: Path, sources: list[Path],
                   out_dir: Path, settings: dict, flags: list[str], extra: dict | None = None) -> dict:
    """Everything about a generated solver (dims and bounds are also compiled into its binary; the
    runtime takes them from there and refuses a manifest that disagrees)."""
    c, pr = problem.config, problem.predictor
    library = {"daqp": f"DAQP {DAQP_VERSION} (PyPI source distribution, MIT)",
               "osqp": f"OSQP {osqp.__version__} embedded code generation (Apache-2.0)"}[backend]
    return {
        **(extra or {}),
        "feas_tol": FEAS_TOL,
        "vector_tol": VECTOR_TOL[backend],
        "library": library,
        "format": FORMAT,
        "format_version": VERSION,
        "name": name,
        "backend": backend,
        "module": module,
        "extension": extension.name,
        "dims": {"m": c.m, "p": c.p, "t_ini": c.t_ini, "t_f": c.t_f, "n_u": problem.n_u, "n_z": problem.n_z,
                 "n_theta": problem.n_theta, "n_g": problem.n_g, "n_y": c.p * c.t_f, "n_sigma": c.p * c.t_ini},
        "signals": {"inputs": list(c.input_names), "outputs": list(c.output_names), "dt": c.dt},
        "R_mode": c.R_mode,
        # the QP variable: the references at these samples, linear in between (null: every sample)
        "knots": None if c.knots is None else list(c.knots),
        "has_nominal": problem.has_nominal,
        "bounds": {"u_min": _inf_list(c.u_min), "u_max": _inf_list(c.u_max), "y_min": _inf_list(c.y_min),
                   "y_max": _inf_list(c.y_max), "du_max": _inf_list(c.du_max)},
        "weights": {"Q": c.Q.tolist(), "R": c.R.tolist(), "R_du": c.R_du.tolist(), "R_ddu": c.R_ddu.tolist(),
                    "R_doffset": c.R_doffset.tolist(),
                    "R_de": c.R_de.tolist(),
                    "lambda_sigma": c.lambda_sigma},
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
    """Write manifest.json (sorted keys: regenerating gives the same bytes)."""
    path = Path(folder) / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    return path
