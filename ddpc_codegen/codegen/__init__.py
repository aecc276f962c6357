"""Code generation: a SteeringProblem -> self-contained C folder + compiled extension + manifest.json.

The entry is :func:`generate` (defined in :mod:`ddpc_codegen.codegen.artifact`); the names below are
re-exported lazily, so importing a submodule (emit, build, ...) never imports the others through this package.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "generate": "ddpc_codegen.codegen.artifact",
    "compile_alone": "ddpc_codegen.codegen.artifact",
    "BACKENDS": "ddpc_codegen.codegen.constants",
    "OnlineCompletion": "ddpc_codegen.codegen.artio",
    "read_manifest": "ddpc_codegen.runtime.manifest",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
