"""Strict template rendering for every emitted file (Jinja2, ``templates/*.in``).

A name a rendered branch uses but the context lacks is a CodegenError (``StrictUndefined``), and so is a
context key that no part of the template (its includes counted) ever uses: a typo on either side must not
silently emit wrong C. Block tags sit on lines of their own and leave no blank line behind (``trim_blocks``,
``lstrip_blocks``); a file's final newline is kept.
"""

from __future__ import annotations

import math
from functools import lru_cache

import jinja2
from jinja2 import meta

from ddpc_codegen.errors import CodegenError

__all__ = ["ENV", "c_float", "template_text", "placeholders", "render", "render_ctx"]


def c_float(x: float) -> str:
    """A C double literal that round-trips exactly (shortest repr), INFINITY for infinities."""
    x = float(x)
    if math.isinf(x):
        return "INFINITY" if x > 0 else "-INFINITY"
    r = repr(x)
    return r if ("." in r or "e" in r or "n" in r) else r + ".0"


ENV = jinja2.Environment(
    loader=jinja2.PackageLoader("ddpc_codegen.codegen", "templates"),
    undefined=jinja2.StrictUndefined,
    keep_trailing_newline=True,
    trim_blocks=True,
    lstrip_blocks=True,
    autoescape=False,
)
ENV.filters["c_float"] = c_float


def template_text(fname: str) -> str:
    """Text of ``templates/<fname>`` (package data)."""
    return ENV.loader.get_source(ENV, fname)[0]


@lru_cache(maxsize=None)
def placeholders(fname: str) -> frozenset[str]:
    """The context names ``templates/<fname>`` and the templates it includes can read (every branch)."""
    ast = ENV.parse(template_text(fname))
    names = set(meta.find_undeclared_variables(ast))
    for inc in meta.find_referenced_templates(ast):
        if inc is None:
            raise CodegenError(f"template {fname}: an include whose name is computed (name it literally)")
        names |= placeholders(inc)
    return frozenset(names)


def render(fname: str, **context) -> str:
    """Render ``templates/<fname>``: every key of ``context`` must be used somewhere in it, and every name the
    rendered branches read must be given."""
    unused = context.keys() - placeholders(fname)
    if unused:
        raise CodegenError(f"template {fname}: unused values {sorted(unused)}")
    try:
        return ENV.get_template(fname).render(context)
    except jinja2.UndefinedError as e:
        raise CodegenError(f"template {fname}: missing value ({e})") from e
    except jinja2.TemplateError as e:
        raise CodegenError(f"template {fname}: {e}") from e


def render_ctx(fname: str, ctx: dict) -> str:
    """Render a template from the names of ``ctx`` it can read (one it reads and ``ctx`` lacks: CodegenError)."""
    names = placeholders(fname)
    return render(fname, **{k: v for k, v in ctx.items() if k in names})
