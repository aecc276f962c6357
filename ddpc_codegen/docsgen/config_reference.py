"""The configuration reference, generated from the validators: every key the steering-config
loader and the robot-profile loader accept, its default, and the rules each enforces.

The rules are not written twice: each key is probed with a few wrong values and the validator's
own error messages (less the offending value) are what the page lists.
"""

from __future__ import annotations

import copy
import dataclasses
import inspect
import re
import tempfile
from pathlib import Path
from typing import Any

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.profile import RobotProfile, load_profile
from ddpc_codegen.values.config import _SCHEMA, SteeringConfig  # the loader's own key table

__all__ = ["PROBES", "MINIMAL_CONFIG", "config_rules", "profile_rules", "attribute_docs", "config_page"]

# wrong values tried on every key (as Python values for the config, TOML literals for profiles)
PROBES: tuple[Any, ...] = ("?", -1, 0, 2.5, [1.0, 2.0], True)
_TOML_PROBES = ('"?"', "-1", "0", "2.5", "[1.0, 2.0]", "true")
# the smallest valid steering config (one input, one output): the base every probe edits
MINIMAL_CONFIG: dict = {"horizon": {"t_ini": 2, "t_f": 2}, "signals": {"inputs": ["u"], "outputs": ["y"]},
                        "cost": {"Q": [1.0], "R": [1.0]}}


def _rule(message: str, key: str) -> str:
    """A validator message reduced to its rule: no source, table, key or offending value."""
    text = re.sub(r";? ?got .*$", "", message.split(": ", 1)[-1]).strip()
    text = re.sub(r"^(\[[a-z_]+\] )?([A-Za-z]+\.)?" + re.escape(key) + r" ", "", text)
    return text


def _collect(messages: list[str], key: str) -> list[str]:
    rules: list[str] = []
    for m in messages:
        r = _rule(m, key)
        if r and r not in rules:
            rules.append(r)
    return rules


def config_rules() -> dict[str, dict[str, dict[str, Any]]]:
    """Per section and key of the steering config: ``required``, ``default``, ``rules``."""

    defaults = SteeringConfig.from_dict(copy.deepcopy(MINIMAL_CONFIG)).to_dict()
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for section, keys in _SCHEMA.items():
        for key in keys:
            if section == "" and key != "name":
                continue  # the other top-level keys are the sections themselves
            messages = []
            for probe in PROBES:
                raw = copy.deepcopy(MINIMAL_CONFIG)
                (raw.setdefault(section, {}) if section else raw)[key] = probe
                try:
                    SteeringConfig.from_dict(raw)
                except ConfigError as e:
                    messages.append(str(e))
            required = key in MINIMAL_CONFIG.get(section, {})
            default = defaults.get(section, {}).get(key) if isinstance(defaults.get(section), dict) \
                else defaults.get(key)
            out.setdefault(section or "top level", {})[key] = {
                "required": required, "default": None if required else default, "rules": _collect(messages, key)}
    return out


def attribute_docs(cls: type) -> dict[str, str]:
    """Field descriptions from a Google-style ``Attributes:`` docstring section (``a, b: text`` too)."""
    doc = (inspect.getdoc(cls) or "").split("Attributes:", 1)
    if len(doc) < 2:
        return {}
    out: dict[str, str] = {}
    current: list[str] = []
    for line in doc[1].splitlines():
        m = re.match(r"^ {4}([a-z_][a-z0-9_, ]*):\s*(.*)$", line)
        if m:
            current = [k.strip() for k in m.group(1).split(",")]
            for k in current:
                out[k] = m.group(2).strip()
        elif line.strip() and current:
            for k in current:
                out[k] += " " + line.strip()
        elif not line.strip() and out:
            current = []
    return out


def profile_rules() -> dict[str, dict[str, dict[str, Any]]]:
    """Per table and key of a robot profile: ``default``, ``doc``, ``rules`` (via ``load_profile``)."""
    base = load_profile("pogox")
    out: dict[str, dict[str, dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for table in ("controller", "trajectory", "contact", "steering"):
            cls = type(getattr(RobotProfile, table, None) or getattr(base, table))
            docs = attribute_docs(cls)
            for f in dataclasses.fields(cls):
                messages = []
                for i, probe in enumerate(_TOML_PROBES):
                    path = Path(tmp) / f"probe_{table}_{f.name}_{i}.toml"
                    path.write_text(f"[{table}]\n{f.name} = {probe}\n")
                    try:
                        load_profile(path)
                    except ConfigError as e:
                        messages.append(str(e))
                default = f.default if f.default is not dataclasses.MISSING else None
                out.setdefault(table, {})[f.name] = {"default": default, "doc": docs.get(f.name, ""),
                                                     "rules": _collect(messages, f.name)}
    return out


def _cell(v: Any) -> str:
    return str(v).replace("|", "\\|").replace("<", "&lt;")


def _code(v: Any) -> str:
    return "`" + str(v).replace("|", "\\|") + "`"


def _config_section() -> list[str]:
    out = ["## Steering config (`configs/*.toml`)\n",
           "Loaded by `SteeringConfig.from_toml`; an unknown table or key is an error naming it.\n"]
    for section, keys in config_rules().items():
        out += [f"### `[{section}]`\n" if section != "top level" else "### Top level\n",
                "| key | required | default | rules (the validator's messages) |", "|---|---|---|---|"]
        for key, r in keys.items():
            default = "" if r["default"] is None else _code(r["default"])
            if isinstance(r["default"], list) and all(v is None for v in r["default"]):
                default = "unbounded"
            out.append(f"| `{key}` | {'yes' if r['required'] else ''} | {default} | "
                       f"{_cell('; '.join(r['rules']) or 'any value')} |")
        out.append("")
    return out


def _profile_section() -> list[str]:
    from ddpc_codegen.robot.profile import shipped_profiles

    out = ["## Robot profile (`--profile`)\n",
           "Loaded by `load_profile`: a shipped name (" + ", ".join(f"`{p}`" for p in shipped_profiles())
           + ") or a TOML path. Top-level keys: `name`, `description`, `extends` (start from another "
           "profile and override the keys given) and the tables below.\n"]
    for table, keys in profile_rules().items():
        out += [f"### `[{table}]`\n", "| key | default | what | rules (the validator's messages) |",
                "|---|---|---|---|"]
        for key, r in keys.items():
            default = "" if r["default"] is None else _code(r["default"])
            out.append(f"| `{key}` | {default} | {_cell(r['doc'])} | {_cell('; '.join(r['rules']) or 'any value')} |")
        out.append("")
    return out


def config_page() -> str:
    """The configuration reference page (Markdown)."""
    head = ["# Configuration\n", "<!-- generated from the validators while the docs build -->\n",
            "Generated while the docs build: each key is probed with wrong values and the rules below are "
            "the loaders' own error messages.\n"]
    return "\n".join(head + _config_section() + _profile_section())
