"""mkdocs hook (``hooks:`` in ``mkdocs.yml``): the reference pages that follow the code are
generated while the site builds and added as virtual files, so ``docs/`` holds none of them; so are the
site's assets (MathJax from an installed package, the block diagrams)."""

from __future__ import annotations

from collections.abc import Callable

from ddpc_codegen.docsgen.api_reference import python_api_page
from ddpc_codegen.docsgen.assets import ASSETS
from ddpc_codegen.docsgen.c_api import c_api_page
from ddpc_codegen.docsgen.cli_reference import cli_page
from ddpc_codegen.docsgen.config_reference import config_page

# page path inside the site -> its renderer
GENERATED: dict[str, Callable[[], str]] = {
    "reference/cli.md": cli_page,
    "reference/config.md": config_page,
    "reference/c-api.md": c_api_page,
    "reference/python-api.md": python_api_page,
}


def on_files(files, config):  # noqa: ANN001 -- mkdocs' Files and MkDocsConfig
    """Add every generated reference page and asset to the site's files."""
    from mkdocs.structure.files import File

    for path, render in {**GENERATED, **ASSETS}.items():
        files.append(File.generated(config, path, content=render()))
    return files
