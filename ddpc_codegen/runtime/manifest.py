"""Reading manifest.json of a generated solver (the robot side: no CasADi, no OSQP)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from ddpc_codegen.errors import ManifestError

__all__ = ["FORMAT", "VERSION", "read_manifest", "sha256_file"]

FORMAT = "ddpc-codegen-solver"
VERSION = 1


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def read_manifest(folder: Path) -> dict:
    """manifest.json of a solver folder; ManifestError when missing, not JSON or another format."""
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
