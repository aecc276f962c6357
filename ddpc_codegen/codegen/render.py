"""Strict template rendering for every emitted file: ``string.Template`` placeholders; a name the
template uses but the context lacks is a CodegenError, and so is a context key the template never uses
(a typo on either side must not silently emit wrong C)."""

from __future__ import annotations

import string
from importlib import resources

from ddpc_codegen.errors import CodegenError


def template_text(fname: str) -> str:
    """Text of ``templates/<fname>`` (package data)."""
    return resources.files("ddpc_codegen.codegen").joinpath("templates", fname).read_text()


def placeholders(fname: str) -> set[str]:
    """The names ``templates/<fname>`` uses."""
    tpl = string.Template(template_text(fname))
    return {m.group("named") or m.group("braced") for m in tpl.pattern.finditer(tpl.template)} - {None}


def render(fname: str, **context) -> str:
    """Render ``templates/<fname>`` with exactly the names it uses."""
    tpl = string.Template(template_text(fname))
    used = placeholders(fname)
    missing, unused = used - context.keys(), context.keys() - used
    if missing or unused:
        raise CodegenError(f"template {fname}: missing values {sorted(missing)}, unused values {sorted(unused)}")
    try:
        return tpl.substitute(context)
    except ValueError as e:  # a stray '$' in the template
        raise CodegenError(f"template {fname}: {e}") from e
