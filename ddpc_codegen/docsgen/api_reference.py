"""The Python API page: one mkdocstrings entry per public name of ``ddpc_codegen`` (its
``__all__``), under the module that defines it, so a new export is documented without editing a page."""

from __future__ import annotations

import importlib

__all__ = ["public_objects", "python_api_page"]


def public_objects() -> dict[str, list[str]]:
    """Defining module -> the public names of ``ddpc_codegen`` it defines (in ``__all__`` order)."""
    package = importlib.import_module("ddpc_codegen")
    out: dict[str, list[str]] = {}
    for name in package.__all__:
        out.setdefault(getattr(package, name).__module__, []).append(name)
    return out


def python_api_page() -> str:
    """The Python API reference page (Markdown with mkdocstrings directives)."""
    out = ["# Python API\n", "<!-- generated from ddpc_codegen.__all__ while the docs build -->\n",
           "Every public name of `ddpc_codegen` (importable as `from ddpc_codegen import NAME`; the package "
           "imports them lazily, so `import ddpc_codegen` loads neither CasADi nor the simulator), grouped "
           "by the module that defines it.\n"]
    for module, names in public_objects().items():
        out.append(f"## `{module}`\n")
        out += [f"::: {module}.{name}\n" for name in names]
    return "\n".join(out)
