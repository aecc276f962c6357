"""The same emitted sources cross-compiled for aarch64 (a companion computer's CPU) and run under
qemu: the example reproduces the recorded vectors, and agrees with the x86-64 build."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.codegen import standalone
from support.cc_cache import cross_wrapper

pytestmark = pytest.mark.compiler


@pytest.fixture(scope="module")
def arm_tools():
    tools = standalone.aarch64_tools()
    if tools is None:
        pytest.skip(standalone.MISSING_AARCH64)
    # the cross compiler through the session's compile cache too: the three builds share the library objects
    return cross_wrapper(tools[0]), tools[1]


# hopping x osqp is left out: ADMM on its hard vectors costs about a minute under emulation
@pytest.mark.parametrize("key", [("flying", "daqp"), ("hopping", "daqp"), ("flying", "osqp")])
def test_aarch64_build_under_qemu_reproduces_the_vectors(generated, arm_tools, tmp_path, key):
    cc, qemu = arm_tools
    folder = standalone.relocated_copy(generated[key], tmp_path)
    vectors = folder / f"{folder.name}_vectors.txt"
    arm = standalone.run_example(standalone.make_example(folder, cc=cc, build="build-aarch64"), vectors, qemu=qemu,
                                 dump=tmp_path / "arm.txt", ticks=1)
    assert arm.returncode == 0 and arm.mismatches == 0, arm.output
    assert arm.max_err <= (1e-9 if key[1] == "daqp" else 1e-6)
    host = standalone.run_example(standalone.make_example(folder), vectors, dump=tmp_path / "host.txt", ticks=1)
    st_a, u_a = standalone.read_dump(tmp_path / "arm.txt")
    st_h, u_h = standalone.read_dump(tmp_path / "host.txt")
    assert host.returncode == 0 and st_a == st_h
    diff = np.abs(np.array(u_a) - np.array(u_h))
    assert np.nanmax(diff) <= 1e-9
