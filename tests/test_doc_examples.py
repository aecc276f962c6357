"""Every ```python block of the README and the docs site runs as written (tests/test_docs.py checks the
shell blocks: make targets, commands and flags). A block runs in a scratch folder holding what its page
says it starts from: a recorded ``data/flying.npz``, the shipped ``configs/``, and a window of the
recording as ``u_ini``/``y_ini``/``y_des``/``u_nom`` (the names the pages use for the per-tick inputs)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def python_blocks() -> list[tuple[str, str]]:
    """(page:line, code) of each ```python block."""
    out = []
    for page in PAGES:
        text = page.read_text()
        for m in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M):
            line = text.count("\n", 0, m.start()) + 1
            out.append((f"{page.relative_to(ROOT)}:{line}", m.group(1)))
    return out


BLOCKS = python_blocks()


def test_the_docs_have_python_examples():
    assert BLOCKS, "no ```python block found: the runner below would test nothing"


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    """A folder with data/flying.npz (30 s of excited, noisy flying), configs/ (the shipped files), generated/."""
    from ddpc_codegen.sim import simulate

    d = tmp_path_factory.mktemp("doc_examples")
    (d / "data").mkdir()
    (d / "generated").mkdir()
    (d / "configs").symlink_to(ROOT / "configs")
    simulate("flying", 30.0, excitation=True, seed=3, noise=True).to_dataset().save(d / "data" / "flying.npz")
    return d


def per_tick_inputs(data_file: Path, t_ini: int = 20, t_f: int = 15) -> dict[str, np.ndarray]:
    """A window of the recording in the shapes the pages name: u_ini (Tini, m), y_ini (Tini, p),
    y_des (Tf, p) = the recorded future outputs, u_nom (Tf, m) = the recorded future inputs."""
    from ddpc_codegen import IODataset

    ds = IODataset.load(data_file)
    u, y = ds.u[0], ds.y[0]  # one trajectory was recorded
    k = 400
    return {"u_ini": u[k - t_ini:k], "y_ini": y[k - t_ini:k], "y_des": y[k:k + t_f], "u_nom": u[k:k + t_f]}


@pytest.mark.compiler
@pytest.mark.parametrize("where, code", BLOCKS, ids=[w for w, _ in BLOCKS])
def test_python_example_runs(where, code, scratch, monkeypatch):
    monkeypatch.chdir(scratch)
    ns: dict = {"__name__": "__doc_example__", **per_tick_inputs(scratch / "data" / "flying.npz")}
    exec(compile(code, where, "exec"), ns)  # noqa: S102 -- the project's own documentation
