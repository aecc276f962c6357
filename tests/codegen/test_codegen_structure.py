"""The code generator's structure: its modules import one way (no circle, project imports at the top), and the
Python that orchestrates the emission writes no C (every line of C is in ``codegen/templates``)."""

from __future__ import annotations

import ast
from pathlib import Path

import ddpc_codegen.codegen as codegen_pkg

CODEGEN = Path(codegen_pkg.__file__).parent
C_MARKERS = ("ws->", "#include", "#define", "typedef", "double ", "matvec(", "call_casadi", "};", "extern ")


def _modules() -> dict[str, ast.Module]:
    return {p.stem: ast.parse(p.read_text()) for p in sorted(CODEGEN.glob("*.py")) if p.stem != "__init__"}


def _codegen_imports(body: list[ast.stmt]) -> set[str]:
    out = set()
    for node in body:
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module.startswith("ddpc_codegen.codegen."):
                out.add(node.module.rsplit(".", 1)[1])
            elif node.module == "ddpc_codegen.codegen":
                out.update(a.name for a in node.names)
    return out


def _not_c(tree: ast.Module) -> set[int]:
    """The string constants that are not output: docstrings, and patterns that read C (``re.compile``)."""
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                ids.add(id(first.value))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "compile":
            ids.update(id(a) for a in node.args)
    return ids


def test_codegen_modules_import_one_way_at_module_level():
    mods = _modules()
    graph = {name: _codegen_imports(tree.body) & mods.keys() for name, tree in mods.items()}
    inside = sorted(f"{name}.{fn.name}" for name, tree in mods.items() for fn in ast.walk(tree)
                    if isinstance(fn, ast.FunctionDef)
                    for node in ast.walk(fn) if isinstance(node, (ast.Import, ast.ImportFrom))
                    and any(n.startswith("ddpc_codegen") for n in
                            ([node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names])))
    assert inside == []
    done: set[str] = set()

    def visit(name: str, path: tuple[str, ...]) -> None:
        assert name not in path, f"import circle: {' -> '.join(path + (name,))}"
        if name not in done:
            for dep in graph[name]:
                visit(dep, path + (name,))
            done.add(name)

    for name in graph:
        visit(name, ())


def test_the_orchestrating_python_writes_no_c():
    for stem in ("emit", "artio", "adapt", "build", "tables", "libs", "artifact"):
        tree = ast.parse((CODEGEN / f"{stem}.py").read_text())
        skip = _not_c(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
                found = [m for m in C_MARKERS if m in node.value]
                assert not found, f"{stem}.py:{node.lineno} writes C in a string ({found}): {node.value[:80]!r}"
