"""The companion package's shape (issue 45): its parts are owned, not mixed in. No class of firmware_bridge
has more than one base defined in the package (no mixins), none is over 300 lines, none has more than 25
instance attributes (``self.X = ...`` anywhere in the class), and the tick's
product is a typed value."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2] / "firmware_bridge"
MAX_LINES, MAX_ATTRIBUTES = 300, 25


def _classes() -> list[tuple[str, ast.ClassDef]]:
    return [(f"{p.name}:{node.name}", node) for p in sorted(ROOT.rglob("*.py"))
            for node in ast.walk(ast.parse(p.read_text())) if isinstance(node, ast.ClassDef)]


CLASSES = _classes()
PROJECT_CLASSES = {node.name for _, node in CLASSES}


def instance_attributes(cls: ast.ClassDef) -> set[str]:
    """Names assigned as ``self.X`` in the class's methods (a settings record's dataclass fields are not
    state the class keeps: ``BridgeConfig`` is the command line's values)."""
    names: set[str] = set()
    for node in ast.walk(cls):
        targets = []
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, (ast.AnnAssign, ast.AugAssign)):
            targets = [node.target]
        for t in targets:
            for sub in ast.walk(t):
                if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name) and sub.value.id == "self":
                    names.add(sub.attr)
    return names


def test_the_package_has_classes_to_check():
    assert len(CLASSES) > 20 and "Bridge" in PROJECT_CLASSES


@pytest.mark.parametrize("where, cls", CLASSES, ids=[w for w, _ in CLASSES])
def test_no_mixins(where, cls):
    bases = [b.id for b in cls.bases if isinstance(b, ast.Name) and b.id in PROJECT_CLASSES]
    assert len(bases) <= 1, f"{where} mixes in {bases}: own the parts instead"


@pytest.mark.parametrize("where, cls", CLASSES, ids=[w for w, _ in CLASSES])
def test_classes_stay_small(where, cls):
    lines = cls.end_lineno - cls.lineno + 1
    assert lines <= MAX_LINES, f"{where}: {lines} lines (at most {MAX_LINES})"
    attrs = instance_attributes(cls)
    assert len(attrs) <= MAX_ATTRIBUTES, f"{where}: {len(attrs)} instance attributes {sorted(attrs)}"


def test_the_bridge_owns_its_parts():
    from firmware_bridge.bridge import Bridge

    assert Bridge.__bases__ == (object,)


def test_the_ticks_product_is_a_frozen_dataclass():
    from firmware_bridge.reference_stage import ReferenceStage, TickReference

    assert dataclasses.is_dataclass(TickReference) and TickReference.__dataclass_params__.frozen
    assert ReferenceStage.step.__annotations__["return"] in ("TickReference", TickReference)


def test_the_counter_counts():
    src = "class A:\n    x: int = 0\n    def f(self):\n        self.a, (self.b, c) = 1, (2, 3)\n        self.d += 1\n"
    assert instance_attributes(ast.parse(src).body[0]) == {"a", "b", "d"}
