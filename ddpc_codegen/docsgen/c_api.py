"""The generated C API reference, read from the header templates the code generator renders.

Each public header template (``solver.h.in``; ``artio.h.in`` for hopping artifacts, ``adapt.h.in`` for adaptive
ones) gives a table of its macros and functions with the comments written beside them, and the header itself
with the solver's name left as ``<name>``: the page shows what every generated folder's header declares.
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["TEMPLATES", "HEADERS", "declarations", "c_api_page"]

TEMPLATES = Path(__file__).resolve().parents[1] / "codegen" / "templates"
# header template -> what it is
HEADERS = {"solver.h.in": "`<name>_solver.h`: the steering solver (every artifact)",
           "artio.h.in": "`<name>_artio.h`: the artificial ground-phase IO (hopping artifacts; "
                         "included by `<name>_solver.h`)",
           "adapt.h.in": "`<name>_adapt.h`: online predictor updates (artifacts generated with `[adapt]`)"}


def _names(text: str) -> str:
    """Template placeholders as a reader sees them: ``{{ name }}`` -> ``<name>``, ``{{ NAME }}`` -> ``<NAME>``;
    the template's own lines (``{% ... %}`` branches and includes, ``{# ... #}`` notes) are left out."""
    text = re.sub(r"^[ \t]*\{[%#].*?[%#]\}[ \t]*\n", "", text, flags=re.M | re.S)
    return re.sub(r"\{\{ (\w+) \}\}", r"<\1>", text)


def _comment(block: str) -> str:
    return " ".join(ln.strip(" /*") for ln in block.splitlines()).strip()


def declarations(template: str) -> list[tuple[str, str, str]]:
    """(kind, name, comment) of every function prototype and ``#define`` macro of a header template.

    A function's comment is the block comment right above it; a macro's the one on its line, else
    the block above it.
    """
    text = _names((TEMPLATES / template).read_text())
    out = []
    func = re.compile(r"(?:/\*(?P<doc>(?:(?!\*/).)*)\*/\s*)?\n(?P<decl>(?:int|void|const char \*|double)\s*"
                      r"(?P<name><name>_\w+)\((?:[^;{])*\);)", re.S)
    for m in func.finditer(text):
        out.append(("function", m.group("name"), _comment(m.group("doc") or "")))
    macro = re.compile(r"(?:/\*(?P<above>(?:(?!\*/).)*)\*/\n)?#define (?P<name><NAME>_\w+) [^\n/]*(?:/\*(?P<side>.*?)\*/)?")
    for m in macro.finditer(text):
        if m.group("name").endswith("_H"):
            continue
        out.append(("macro", m.group("name"), _comment(m.group("side") or m.group("above") or "")))
    return out


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("<", "&lt;")


def c_api_page() -> str:
    """The C API reference page (Markdown)."""
    out = ["# Generated C API\n", "<!-- generated from ddpc_codegen/codegen/templates while the docs build -->\n",
           "Every generated folder `generated/<name>/` declares the API below, with `<name>` the solver's name "
           "(`name` in its config) and `<NAME>` its upper-case form. Generated while the docs build from the "
           "header templates in `ddpc_codegen/codegen/templates/`. How to build and link it: "
           "[the generated C/C++ on the robot](../guides/c-on-the-robot.md).\n"]
    for template, what in HEADERS.items():
        decls = declarations(template)
        out += [f"## {what}\n", "| kind | name | what |", "|---|---|---|"]
        out += [f"| {kind} | `{name}` | {_cell(doc)} |" for kind, name, doc in decls]
        out += ["", "??? note \"the whole header\"", "", "    ```c"]
        out += ["    " + ln if ln else "" for ln in _names((TEMPLATES / template).read_text()).splitlines()]
        out += ["    ```", ""]
    return "\n".join(out)
