"""The site's generated assets: MathJax from an installed package (so neither the build nor a reader's
browser reaches a CDN) and the block diagrams drawn by :mod:`ddpc_codegen.docsgen.diagrams`."""

from __future__ import annotations

from collections.abc import Callable
from importlib import resources

from ddpc_codegen.docsgen.diagrams import steering_loop_svg

MATHJAX_SCRIPT = "assets/javascripts/mathjax/tex-svg.js"
MATHJAX_CONFIG = "assets/javascripts/mathjax-config.js"

# pymdownx.arithmatex (generic mode) wraps math in \( \) and \[ \] inside elements of class "arithmatex":
# MathJax typesets those elements only
_CONFIG_JS = """window.MathJax = {
  tex: {inlineMath: [["\\\\(", "\\\\)"]], displayMath: [["\\\\[", "\\\\]"]], processEscapes: true,
        processEnvironments: true},
  options: {ignoreHtmlClass: ".*|", processHtmlClass: "arithmatex"},
  svg: {fontCache: "global"}
};
"""


def mathjax_config_js() -> str:
    """The MathJax configuration the site loads before MathJax itself."""
    return _CONFIG_JS


def mathjax_root():  # noqa: ANN201 -- an importlib.resources Traversable
    """MathJax 3's ``es5`` folder (its components), from the ``django-static-mathjax`` package (docs extra)."""
    try:
        root = resources.files("mathjax")
    except ModuleNotFoundError as exc:
        raise RuntimeError("the docs need MathJax: pip install -e '.[docs]' (package django-static-mathjax)") from exc
    return root / "static" / "mathjax" / "es5"


def mathjax_js() -> str:
    """MathJax 3's single-file TeX-to-SVG component, the one the site serves."""
    return (mathjax_root() / "tex-svg.js").read_text(encoding="utf-8")


# asset path inside the site -> its renderer
ASSETS: dict[str, Callable[[], str]] = {
    MATHJAX_CONFIG: mathjax_config_js,
    MATHJAX_SCRIPT: mathjax_js,
    "figures/steering-loop.svg": steering_loop_svg,
}
