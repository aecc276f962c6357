"""The docs site's generated pages: the results pages and the README's results table (from
``reports/*.json``), and the reference pages that follow the code (CLI from the argparse parsers,
config schema from the validators, C API from the header templates).

Run ``python -m ddpc_codegen.docsgen.results`` after a measuring make target; the reference pages
are generated while ``mkdocs build`` runs (``mkdocs_hooks.py``), never written into ``docs/``.
"""
