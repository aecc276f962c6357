"""The package layout's import rules: layers that run one way, no circles, and a module's header shows its edges.

Checked statically on every module's AST (imports inside functions count too) and, for the robot side,
dynamically in a fresh interpreter:

* forbidden edges between layers (``RULES``), the value layer importing nothing of the project but itself and
  ``errors`` (``SELF_CONTAINED``), nothing importing the command line (``CLI_READERS`` aside);
* no import circle among the project's modules (module level and inside functions alike);
* project imports inside a function only where ``IN_FUNCTION`` names them, each with its reason (an optional
  heavy dependency that the importing module must load without).
"""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PROJECT = ("ddpc_codegen", "firmware_bridge")

# (modules the rule applies to, forbidden import prefixes, why); no exemptions
RULES: list[tuple[tuple[str, ...], tuple[str, ...], str]] = [
    (("ddpc_codegen.design",), ("ddpc_codegen.runtime", "ddpc_codegen.sim", "ddpc_codegen.robot",
                                "ddpc_codegen.experiments", "ddpc_codegen.pipeline", "ddpc_codegen.cli",
                                "ddpc_codegen.testbed", "firmware_bridge"),
     "the design layer is upstream of the runtime, the simulator, the robot side and the bridge"),
    (("ddpc_codegen.sim",), ("ddpc_codegen.codegen", "ddpc_codegen.pipeline", "ddpc_codegen.experiments",
                             "ddpc_codegen.cli", "ddpc_codegen.testbed", "firmware_bridge"),
     "the simulator is a plant; it never generates code"),
    (("ddpc_codegen.runtime", "ddpc_codegen.robot"),
     ("casadi", "osqp", "ddpc_codegen.sim", "ddpc_codegen.codegen", "ddpc_codegen.design", "ddpc_codegen.pipeline",
      "ddpc_codegen.experiments", "ddpc_codegen.testbed", "firmware_bridge"),
     "what the robot runs carries no design stack"),
    (("firmware_bridge",), ("casadi", "osqp", "ddpc_codegen.sim", "ddpc_codegen.codegen",
                            "ddpc_codegen.design.problem", "ddpc_codegen.design.deepc", "ddpc_codegen.pipeline",
                            "ddpc_codegen.experiments", "ddpc_codegen.testbed", "ddpc_codegen.cli"),
     "the bridge runs on the companion computer: no design stack, simulator or test bed"),
    (("ddpc_codegen.codegen",), ("ddpc_codegen.pipeline", "ddpc_codegen.experiments"),
     "the generator is a step of the build path, not its driver"),
    (("ddpc_codegen.experiments", "ddpc_codegen.codegen", "ddpc_codegen.pipeline", "ddpc_codegen.logs"),
     ("ddpc_codegen.testbed",),
     "the test bed sits downstream of the toolchain"),
]

# (package, the only project prefixes it may import, why)
SELF_CONTAINED: list[tuple[str, tuple[str, ...], str]] = [
    ("ddpc_codegen.values", ("ddpc_codegen.values", "ddpc_codegen.errors"),
     "the values both sides share import nothing of either side (numpy only)"),
]

# the command line is the outermost layer: only these modules outside it read it (to render its --help)
CLI_READERS = ("ddpc_codegen.docsgen.cli_reference",)

# project imports inside functions: (importing module, imported module) -> why it cannot be at the top
IN_FUNCTION: dict[tuple[str, str], str] = {
    ("ddpc_codegen.cli.sim", "ddpc_codegen.sim.plots"): "matplotlib, only for --plot",
    ("ddpc_codegen.experiments.demo", "ddpc_codegen.sim.plots"): "matplotlib, only when the demo draws figures",
    ("ddpc_codegen.experiments.demo_figures", "ddpc_codegen.sim.plots"): "matplotlib, only when a figure is drawn",
    ("ddpc_codegen.experiments.sweep_report", "ddpc_codegen.sim.plots"): "matplotlib, only for the sweep's plot",
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package_modules() -> list[Path]:
    return sorted(p for pkg in PROJECT for p in (ROOT / pkg).rglob("*.py"))


def _imports(source: str, module: str, is_package: bool) -> list[tuple[str, bool, int]]:
    """(absolute name, inside a function?, line) of every import in ``source``: ``import a.b`` gives a.b,
    ``from a import b`` gives a and a.b (relative imports resolved)."""
    package = module.split(".") if is_package else module.split(".")[:-1]
    found: list[tuple[str, bool, int]] = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                found.extend((a.name, inner, child.lineno) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    base = ".".join(package[: len(package) - child.level + 1] + ([base] if base else []))
                found.append((base, inner, child.lineno))
                found.extend((f"{base}.{a.name}", inner, child.lineno) for a in child.names)
            visit(child, inner)

    visit(ast.parse(source), False)
    return found


def imports_of(source: str, module: str, is_package: bool = False) -> set[str]:
    """Absolute names of every module ``source`` imports (relative imports resolved)."""
    return {name for name, _, _ in _imports(source, module, is_package)}


def _under(name: str, prefixes: tuple[str, ...] | str) -> bool:
    return any(name == p or name.startswith(p + ".") for p in ((prefixes,) if isinstance(prefixes, str) else prefixes))


def violations(source: str, module: str) -> list[str]:
    """Layer-rule violations of one module's source, as readable lines."""
    names = sorted(imports_of(source, module))
    out = []
    for scope, forbidden, why in RULES:
        if _under(module, scope):
            out += [f"{module} imports {n}: {why}" for n in names if _under(n, forbidden)]
    for package, allowed, why in SELF_CONTAINED:
        if _under(module, package):
            out += [f"{module} imports {n}: {why}" for n in names if _under(n, PROJECT) and not _under(n, allowed)]
    if not _under(module, "ddpc_codegen.cli") and module not in CLI_READERS:
        out += [f"{module} imports {n}: nothing imports the command line (move what it needs below it)"
                for n in names if _under(n, "ddpc_codegen.cli")]
    return out


def test_every_module_follows_the_import_rules():
    bad = [v for p in package_modules() for v in violations(p.read_text(), module_name(p))]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("module, line", [
    ("ddpc_codegen.design.predictor", "from ddpc_codegen.sim.plant import PogoXPlant"),
    ("ddpc_codegen.values.config", "import firmware_bridge.bridge"),
    ("ddpc_codegen.sim.loop", "from ddpc_codegen.codegen import generate"),
    ("ddpc_codegen.runtime.loader", "import casadi"),
    ("firmware_bridge.bridge", "def f():\n    from ddpc_codegen.sim import simulate"),
    ("ddpc_codegen.design.problem", "def f():\n    from ddpc_codegen.runtime.loader import load_solver"),
    ("ddpc_codegen.values.solve_result", "from ddpc_codegen.design.data import IODataset"),
    ("ddpc_codegen.testbed.sitl_front", "from ddpc_codegen.cli.front import register"),
    ("ddpc_codegen.runtime.steerer", "from ddpc_codegen.design import hankel"),
])
def test_the_check_catches_a_forbidden_import(module, line):
    path = ROOT / (module.replace(".", "/") + ".py")
    assert not violations(path.read_text(), module)
    assert violations(path.read_text() + "\n" + line + "\n", module)


# ----------------------------------------------------------------------------- the module graph
def _resolve(name: str, modules: set[str]) -> str | None:
    """The project module an imported name loads (``a.b.f`` -> ``a.b``), or None outside the project."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def module_graph(sources: dict[str, tuple[str, bool]]) -> dict[str, dict[str, tuple[bool, int]]]:
    """module -> {imported project module: (inside a function only?, line)} from module -> (source, is package)."""
    modules = set(sources)
    graph: dict[str, dict[str, tuple[bool, int]]] = {}
    for module, (source, is_package) in sources.items():
        edges: dict[str, tuple[bool, int]] = {}
        for name, in_function, line in _imports(source, module, is_package):
            target = _resolve(name, modules) if _under(name, PROJECT) else None
            if target and target != module and (target not in edges or edges[target][0] and not in_function):
                edges[target] = (in_function, line)
        graph[module] = edges
    return graph


def project_sources() -> dict[str, tuple[str, bool]]:
    return {module_name(p): (p.read_text(), p.name == "__init__.py") for p in package_modules()}


@functools.cache
def project_graph() -> dict[str, dict[str, tuple[bool, int]]]:
    """The project's module graph as it is on disk (read once per session; the tests only read it)."""
    return module_graph(project_sources())


def import_cycles(graph: dict[str, dict[str, tuple[bool, int]]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan, iterative), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, {})))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return sorted(found)


def _describe(cycle: list[str], graph: dict[str, dict[str, tuple[bool, int]]]) -> str:
    edges = [f"    {a}:{graph[a][b][1]} -> {b}{' (inside a function)' if graph[a][b][0] else ''}"
             for a in cycle for b in cycle if b in graph[a]]
    return "circle of " + ", ".join(cycle) + ":\n" + "\n".join(edges)


def test_no_import_circles():
    graph = project_graph()
    cycles = import_cycles(graph)
    assert not cycles, "\n".join(_describe(c, graph) for c in cycles)


def package_of(module: str) -> str:
    """A module's layer: its subpackage of ddpc_codegen (a top-level module is its own), or firmware_bridge."""
    parts = module.split(".")
    return parts[0] if parts[0] != "ddpc_codegen" or len(parts) == 1 else ".".join(parts[:2])


def package_graph(graph: dict[str, dict[str, tuple[bool, int]]]) -> dict[str, dict[str, tuple[bool, int]]]:
    """The module graph collapsed onto layers (one example edge each, as its line and its module)."""
    out: dict[str, dict[str, tuple[bool, int]]] = {}
    for m, edges in graph.items():
        row = out.setdefault(package_of(m), {})
        for t, edge in edges.items():
            if package_of(t) != package_of(m):
                row.setdefault(package_of(t), edge)
    return out


def test_layers_run_one_way():
    cycles = import_cycles(package_graph(project_graph()))
    graph = project_graph()
    lines = [f"{a} -> {b}: " + ", ".join(f"{m}:{graph[m][t][1]} -> {t}" for m in graph if package_of(m) == a
                                          for t in graph[m] if package_of(t) == b)
             for c in cycles for a in c for b in c if a != b and any(
                 package_of(m) == a and package_of(t) == b for m in graph for t in graph[m])]
    assert not cycles, "layers importing each other:\n" + "\n".join(lines)


def test_the_check_catches_an_import_circle():
    sources = project_sources()
    assert ["ddpc_codegen.runtime.steerer", "ddpc_codegen.values.solve_result"] not in import_cycles(project_graph())
    source, is_package = sources["ddpc_codegen.values.solve_result"]
    sources["ddpc_codegen.values.solve_result"] = (
        source + "\ndef f():\n    from ddpc_codegen.runtime.steerer import ReferenceSteerer\n", is_package)
    assert ["ddpc_codegen.runtime.steerer", "ddpc_codegen.values.solve_result"] in import_cycles(module_graph(sources))
    # two layers importing each other without a module circle
    sources = project_sources()
    source, is_package = sources["ddpc_codegen.values.phases"]
    sources["ddpc_codegen.values.phases"] = (source + "\nfrom ddpc_codegen.robot.frames import quat_from_euler\n",
                                             is_package)
    assert ["ddpc_codegen.robot", "ddpc_codegen.values"] not in import_cycles(package_graph(project_graph()))
    assert ["ddpc_codegen.robot", "ddpc_codegen.values"] in import_cycles(package_graph(module_graph(sources)))


def in_function_imports(graph: dict[str, dict[str, tuple[bool, int]]]) -> list[str]:
    """Project imports made only inside functions that ``IN_FUNCTION`` does not name, as readable lines."""
    return [f"{m}:{line} -> {t}" for m in sorted(graph) for t, (inside, line) in sorted(graph[m].items())
            if inside and (m, t) not in IN_FUNCTION]


def test_project_imports_inside_functions_only_where_listed():
    bad = in_function_imports(project_graph())
    by_package: dict[str, list[str]] = {}
    for line in bad:
        by_package.setdefault(".".join(line.split(":")[0].split(".")[:2]), []).append(line)
    assert not bad, (f"{len(bad)} project imports inside functions that IN_FUNCTION does not name: move each to the "
                     "top of its module, or name it there with its reason (optional heavy dependencies only)\n") + "\n".join(
        f"[{pkg}: {len(lines)}]\n" + "\n".join(lines) for pkg, lines in sorted(by_package.items()))


def test_the_in_function_list_is_current():
    graph = project_graph()
    stale = [f"{m} -> {t}" for m, t in IN_FUNCTION if not graph.get(m, {}).get(t, (False,))[0]]
    assert not stale, "IN_FUNCTION names imports that are no longer inside functions: " + ", ".join(stale)


def test_the_check_catches_an_unlisted_import_inside_a_function():
    sources = project_sources()
    source, is_package = sources["ddpc_codegen.runtime.steerer"]
    sources["ddpc_codegen.runtime.steerer"] = (source + "\ndef f():\n    from ddpc_codegen.stats import percentiles\n"
                                               "    from ddpc_codegen.errors import DataError\n", is_package)
    bad = in_function_imports(module_graph(sources))
    assert any(line.startswith("ddpc_codegen.runtime.steerer:") and line.endswith("-> ddpc_codegen.errors") for line in bad)
    # an import that is also at the top of the module is no hidden edge
    assert not any(line.startswith("ddpc_codegen.runtime.steerer:") and line.endswith("-> ddpc_codegen.stats")
                   for line in bad)


# ----------------------------------------------------------------------------- loaded modules
def test_robot_side_imports_load_no_casadi_and_no_simulator():
    code = ("import sys, firmware_bridge.bridge, firmware_bridge.cli, ddpc_codegen.runtime.loader, "
            "ddpc_codegen.runtime.steerer, ddpc_codegen.robot.controller\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('casadi', 'osqp') or m.startswith('ddpc_codegen.sim'))\n"
            "print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "", f"loaded on the robot side: {out.stdout.strip()}"


def test_the_value_layer_loads_numpy_only():
    code = ("import sys, pkgutil, importlib, ddpc_codegen.values as v\n"
            "[importlib.import_module(f'ddpc_codegen.values.{m.name}') for m in pkgutil.iter_modules(v.__path__)]\n"
            "own = sorted(m for m in sys.modules if m.split('.')[0] in ('ddpc_codegen', 'firmware_bridge') and not "
            "(m == 'ddpc_codegen' or m.startswith('ddpc_codegen.values') or m == 'ddpc_codegen.errors'))\n"
            "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('casadi', 'osqp', 'scipy', 'matplotlib'))\n"
            "print(','.join(own + heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "", f"loaded by the value layer: {out.stdout.strip()}"


def test_no_two_test_files_share_a_name():
    """The test folders are not packages (``pythonpath = ["tests"]``): pytest imports each test file by its basename,
    and refuses a session holding two files of the same name ("import file mismatch")."""
    seen: dict[str, list[str]] = {}
    for path in (ROOT / "tests").rglob("test_*.py"):
        seen.setdefault(path.name, []).append(str(path.relative_to(ROOT)))
    assert not {k: v for k, v in seen.items() if len(v) > 1}
