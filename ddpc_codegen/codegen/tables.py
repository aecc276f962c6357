"""Constant data tables of a generated folder (``<stem>.{h,c}``): numpy arrays -> rows of C literals that
round-trip exactly, rendered by ``data.h.in`` / ``data.c.in``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ddpc_codegen.codegen.render import c_float, render

__all__ = ["Tables", "table_rows", "write_tables"]

# suffix -> (values, comment): the arrays of one data file, in the order they are written
Tables = dict[str, tuple[np.ndarray, str]]
PER_ROW = 6  # literals per line of a table


def table_rows(a: np.ndarray) -> list[str]:
    """The literals of ``a`` (flattened, C order) as lines of ``PER_ROW`` comma-separated values."""
    flat = np.ascontiguousarray(a, dtype=float).reshape(-1)
    if flat.size == 0:
        flat = np.zeros(1)  # C has no empty arrays; sized 1 and never read
    vals = [c_float(v) for v in flat.tolist()]  # Python floats: numpy scalars format ~5x slower
    return [", ".join(vals[i : i + PER_ROW]) for i in range(0, len(vals), PER_ROW)]


def write_tables(arrays: Tables, out_dir: Path, banner: str, name: str, stem: str) -> Path:
    """Write ``<stem>.h`` and ``<stem>.c`` (the tables of solver ``name``) into ``out_dir``; returns the source."""
    tables = [{"key": key, "size": max(1, int(np.asarray(a).size)), "comment": comment, "rows": table_rows(a)}
              for key, (a, comment) in arrays.items()]
    common = {"banner": banner, "name": name, "stem": stem, "tables": tables}
    (out_dir / f"{stem}.h").write_text(render("data.h.in", **common))
    source = out_dir / f"{stem}.c"
    source.write_text(render("data.c.in", **common))
    return source
