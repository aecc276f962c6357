"""Code generation: a SteeringProblem -> self-contained C folder + compiled extension + manifest.json.

The entry is :func:`~ddpc_codegen.codegen.generate.generate`; the names below are re-exported lazily, so
importing a submodule (emit, build, ...) never imports the others through this package.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any

_EXPORTS = {
    "generate": "ddpc_codegen.codegen.generate",
    "BACKENDS": "ddpc_codegen.codegen.emit",
    "OnlineCompletion": "ddpc_codegen.codegen.artio",
    "read_manifest": "ddpc_codegen.runtime.manifest",
}

__all__ = list(_EXPORTS)


class _Package(types.ModuleType):
    """``codegen.generate`` is the function, also after its module ``codegen/generate.py`` was imported
    (the import system then sets the package attribute of that name to the module: ignored here)."""

    @property
    def generate(self):  # noqa: D401 - the re-exported function
        return importlib.import_module("ddpc_codegen.codegen.generate").generate

    @generate.setter
    def generate(self, value) -> None:
        pass


sys.modules[__name__].__class__ = _Package


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
