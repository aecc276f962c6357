"""Reading manifest.json of a generated solver (the robot side: no CasADi, no OSQP).

Every way a manifest can be malformed -- not JSON, not an object, another format, a missing or
mistyped key, listed files missing or edited -- is a ManifestError naming the file and the key.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from ddpc_codegen.errors import ManifestError
from ddpc_codegen.values.files import MAX_TEXT_BYTES, MiB, checked_input_path, load_json_bounded

__all__ = ["FORMAT", "VERSION", "read_manifest", "sha256_file", "check_files"]

FORMAT = "ddpc-codegen-solver"
VERSION = 2  # 2: per-name C symbols, caller-owned workspace, test vectors, self-contained sources
# a generated source or extension is kilobytes to tens of MiB (the data tables of a large problem)
ARTIFACT_MAX_BYTES = 4096 * MiB

_DIM_KEYS = ("m", "p", "t_ini", "t_f", "n_u", "n_theta", "n_g", "n_y", "n_sigma")
_BOUND_KEYS = ("u_min", "u_max", "y_min", "y_max", "du_max")
# key -> expected JSON type(s) of the value
_SCHEMA = {"name": str, "backend": str, "module": str, "extension": str, "dims": dict, "bounds": dict,
           "has_nominal": bool, "sources": dict, "extension_sha256": str, "config_hash": str,
           "predictor_hash": str, "feas_tol": float, "vectors": dict}

# hopping solvers: the generated artificial-IO completion (null otherwise)
_ART_SCHEMA = {"depth": int, "rank": int, "m": int, "p": int, "n_columns": int, "noise_level": float,
               "lambda": float, "feas_tol": float, "lo": list, "hi": list, "t_d_online": int, "min_ascent": int,
               "denoise_online": bool, "refit_residual": float}


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file's bytes, read in chunks (a regular file of at most :data:`ARTIFACT_MAX_BYTES`)."""
    p = checked_input_path(path, "solver file", ARTIFACT_MAX_BYTES, error=ManifestError)
    h = hashlib.sha256()
    with open(p, "rb") as f:
        for chunk in iter(lambda: f.read(MiB), b""):
            h.update(chunk)
    return h.hexdigest()


def _check_schema(path: Path, man: object) -> dict:
    if not isinstance(man, dict):
        raise ManifestError(f"{path}: expected a JSON object, got {type(man).__name__}; regenerate the solver")
    if man.get("format") != FORMAT or man.get("format_version") != VERSION:
        raise ManifestError(
            f"{path}: format {man.get('format')!r} v{man.get('format_version')} is not {FORMAT!r} v{VERSION}; "
            "regenerate the solver"
        )
    for key, typ in _SCHEMA.items():
        if key not in man:
            raise ManifestError(f"{path}: key {key!r} is missing; regenerate the solver")
        if not isinstance(man[key], typ) or (typ is not bool and isinstance(man[key], bool)):
            raise ManifestError(f"{path}: {key!r} must be a {typ.__name__}, got {man[key]!r}")
    for key in _DIM_KEYS:
        v = man["dims"].get(key)
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            raise ManifestError(f"{path}: dims.{key} must be a non-negative integer, got {v!r}")
    for key in _BOUND_KEYS:
        v = man["bounds"].get(key)
        if not isinstance(v, list) or not all(x is None or isinstance(x, (int, float)) for x in v):
            raise ManifestError(f"{path}: bounds.{key} must be a list of numbers or null, got {v!r}")
    knots = man.get("knots")  # absent in solvers generated before knots existed: every sample free
    if knots is not None and (not isinstance(knots, list) or not all(
            isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in knots)):
        raise ManifestError(f"{path}: 'knots' must be a list of sample indices or null, got {knots!r}")
    art = man.get("artificial_io")
    if art is not None:
        if not isinstance(art, dict):
            raise ManifestError(f"{path}: 'artificial_io' must be an object or null, got {art!r}")
        for key, typ in _ART_SCHEMA.items():
            if not isinstance(art.get(key), typ) or (typ is not bool and isinstance(art.get(key), bool)):
                raise ManifestError(f"{path}: artificial_io.{key} must be a {typ.__name__}, got {art.get(key)!r}")
    if not all(isinstance(k, str) and isinstance(v, str) for k, v in man["sources"].items()):
        raise ManifestError(f"{path}: 'sources' must map file names to sha256 strings")
    return man


def read_manifest(folder: Path) -> dict:
    """manifest.json of a solver folder, structurally checked; ManifestError otherwise."""
    path = Path(folder) / "manifest.json"
    if not path.exists() and not path.is_symlink():
        raise ManifestError(f"{folder} has no manifest.json: not a generated solver (run `ddpc-codegen codegen` first)")
    return _check_schema(path, load_json_bounded(path, "manifest", MAX_TEXT_BYTES, error=ManifestError))


def check_files(folder: Path, man: dict) -> Path:
    """Every listed source and the extension exist with the recorded hashes; returns the extension path."""
    folder = Path(folder)
    for rel, digest in man["sources"].items():
        f = folder / rel
        if not f.is_file():
            raise ManifestError(f"{folder}: source {rel} listed in manifest.json is missing")
        if sha256_file(f) != digest:
            raise ManifestError(f"{folder}: source {rel} differs from the one the solver was built from (edited?); "
                                "regenerate")
    ext = folder / man["extension"]
    if not ext.is_file():
        raise ManifestError(f"{folder}: compiled extension {man['extension']} is missing; regenerate (make codegen)")
    if sha256_file(ext) != man["extension_sha256"]:
        raise ManifestError(f"{folder}: {man['extension']} is not the binary manifest.json describes; regenerate")
    return ext
