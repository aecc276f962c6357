"""The package layout's import rules (data flows one way; the robot side stays light).

Checked statically on every module's AST (imports inside functions count too) and, for the
robot side, dynamically in a fresh interpreter.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# (modules the rule applies to, forbidden import prefixes, why); no exemptions
RULES: list[tuple[tuple[str, ...], tuple[str, ...], str]] = [
    (("ddpc_codegen.design",), ("ddpc_codegen.sim", "ddpc_codegen.robot", "ddpc_codegen.experiments",
                                "ddpc_codegen.cli", "ddpc_codegen.testbed", "firmware_bridge"),
     "the design layer is upstream of the simulator, the robot side and the bridge"),
    (("ddpc_codegen.sim",), ("ddpc_codegen.codegen", "ddpc_codegen.experiments", "ddpc_codegen.cli",
                             "ddpc_codegen.testbed", "firmware_bridge"),
     "the simulator is a plant; it never generates code"),
    (("ddpc_codegen.runtime", "ddpc_codegen.robot"),
     ("casadi", "osqp", "ddpc_codegen.sim", "ddpc_codegen.codegen", "ddpc_codegen.design.problem",
      "ddpc_codegen.design.deepc", "ddpc_codegen.experiments", "ddpc_codegen.testbed", "firmware_bridge"),
     "what the robot runs carries no design stack"),
    (("firmware_bridge",), ("casadi", "osqp", "ddpc_codegen.sim", "ddpc_codegen.codegen",
                            "ddpc_codegen.design.problem", "ddpc_codegen.design.deepc",
                            "ddpc_codegen.experiments", "ddpc_codegen.testbed", "ddpc_codegen.cli"),
     "the bridge runs on the companion computer: no design stack, simulator or test bed"),
    (("ddpc_codegen.experiments", "ddpc_codegen.codegen", "ddpc_codegen.logs"), ("ddpc_codegen.testbed",),
     "the test bed sits downstream of the toolchain"),
]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(source: str, module: str) -> set[str]:
    """Absolute names of every module ``source`` imports (relative imports resolved)."""
    found: set[str] = set()
    package = module.split(".")
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + (0 if module.endswith("__init__") else 0)]
                                + ([base] if base else []))
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)
    return found


def violations(source: str, module: str) -> list[str]:
    """Rule violations of one module's source, as readable lines."""
    out = []
    for scope, forbidden, why in RULES:
        if not any(module == s or module.startswith(s + ".") for s in scope):
            continue
        for name in sorted(imports_of(source, module)):
            if any(name == f or name.startswith(f + ".") for f in forbidden):
                out.append(f"{module} imports {name}: {why}")
    return out


def package_modules() -> list[Path]:
    return sorted(p for pkg in ("ddpc_codegen", "firmware_bridge") for p in (ROOT / pkg).rglob("*.py"))


def test_every_module_follows_the_import_rules():
    bad = [v for p in package_modules() for v in violations(p.read_text(), module_name(p))]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("module, line", [
    ("ddpc_codegen.design.predictor", "from ddpc_codegen.sim.plant import PogoXPlant"),
    ("ddpc_codegen.design.config", "import firmware_bridge.bridge"),
    ("ddpc_codegen.sim.loop", "from ddpc_codegen.codegen import generate"),
    ("ddpc_codegen.runtime.loader", "import casadi"),
    ("firmware_bridge.bridge", "def f():\n    from ddpc_codegen.sim import simulate"),
])
def test_the_check_catches_a_forbidden_import(module, line):
    path = ROOT / (module.replace(".", "/") + ".py")
    assert not violations(path.read_text(), module)
    assert violations(path.read_text() + "\n" + line + "\n", module)


def test_robot_side_imports_load_no_casadi_and_no_simulator():
    code = ("import sys, firmware_bridge.bridge, firmware_bridge.cli, ddpc_codegen.runtime.loader, "
            "ddpc_codegen.runtime.steerer, ddpc_codegen.robot.controller\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('casadi', 'osqp') or m.startswith('ddpc_codegen.sim'))\n"
            "print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "", f"loaded on the robot side: {out.stdout.strip()}"
