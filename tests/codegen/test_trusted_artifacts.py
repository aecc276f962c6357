"""The runtime trusts the compiled binary, not the editable manifest: dims, bounds and the tolerance
come from ``<name>_describe`` and any disagreement, malformed manifest or foreign binary is a
ManifestError naming the problem."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from ddpc_codegen import ManifestError, load_solver
from ddpc_codegen.runtime.manifest import sha256_file

pytestmark = pytest.mark.compiler


@pytest.fixture
def folder(generated, tmp_path):
    dst = tmp_path / "flying_daqp"
    shutil.copytree(generated[("flying", "daqp")], dst)
    return dst


def _edit(folder, fn):
    path = folder / "manifest.json"
    man = json.loads(path.read_text())
    man = fn(man)
    path.write_text(json.dumps(man))


def test_bounds_and_dims_come_from_the_binary(folder, problems):
    s = load_solver(folder)
    c = problems["flying"].config
    np.testing.assert_array_equal(s.bounds["u_max"], c.u_max)
    np.testing.assert_array_equal(s.bounds["du_max"], c.du_max)
    assert s.feas_tol == s.manifest["feas_tol"] and (s.n_u, s.n_theta) == (c.m * c.t_f, problems["flying"].n_theta)


@pytest.mark.parametrize("edit, message", [
    (lambda m: m["bounds"].update(du_max=[0.5, 0.5]) or m, r"bounds.du_max = \[0.5, 0.5\] differ from the compiled"),
    (lambda m: m["bounds"].update(u_min=[None, -0.3]) or m, r"bounds.u_min .* differ from the compiled"),
    (lambda m: m["dims"].update(n_u=31) or m, r"the compiled solver has dims .* but manifest.json says"),
    (lambda m: m.update(backend="osqp") or m, r"backend daqp\) but manifest.json says"),
    (lambda m: m.update(feas_tol=1e-3) or m, r"feas_tol 0.001 differs from the binary's 1e-08"),
    (lambda m: m.update(has_nominal=False) or m, r"has_nominal=False in manifest.json does not match"),
])
def test_an_edited_manifest_is_refused(folder, edit, message):
    _edit(folder, edit)
    with pytest.raises(ManifestError, match=message):
        load_solver(folder)


@pytest.mark.parametrize("content, message", [
    ("[1, 2]", "expected a JSON object, got list"),
    ('"solver"', "expected a JSON object, got str"),
    (b"\xff\xfe{", "is not valid JSON"),
])
def test_a_manifest_that_is_not_an_object_is_refused(folder, content, message):
    path = folder / "manifest.json"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(ManifestError, match=message):
        load_solver(folder)


@pytest.mark.parametrize("key", ["dims", "bounds", "sources", "extension", "name", "vectors"])
def test_a_missing_key_is_named(folder, key):
    _edit(folder, lambda m: {k: v for k, v in m.items() if k != key})
    with pytest.raises(ManifestError, match=f"key '{key}' is missing"):
        load_solver(folder)


def test_mistyped_values_are_named(folder):
    _edit(folder, lambda m: m["dims"].update(n_u="30") or m)
    with pytest.raises(ManifestError, match=r"dims.n_u must be a non-negative integer, got '30'"):
        load_solver(folder)
    _edit(folder, lambda m: m["dims"].update(n_u=30) or m["bounds"].update(u_max="big") or m)
    with pytest.raises(ManifestError, match=r"bounds.u_max must be a list of numbers or null, got 'big'"):
        load_solver(folder)


def test_a_foreign_or_damaged_binary_is_refused(folder, generated):
    man = json.loads((folder / "manifest.json").read_text())
    ext = folder / man["extension"]
    other = next(generated[("hopping", "daqp")].glob("_ddpc_*"))
    for replacement in (other.read_bytes(), b"\x7fELF" + bytes(200)):
        ext.unlink()  # a new inode: rewriting a shared object that was mapped once would crash the process
        ext.write_bytes(replacement)
        _edit(folder, lambda m: m.update(extension_sha256=sha256_file(ext)) or m)  # a consistent-looking manifest
        with pytest.raises(ManifestError, match="does not load on this machine or is not solver 'flying_daqp'"):
            load_solver(folder)
