"""The loop's signals per mode and the per-reference setting check (robot/signals.py)."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.robot.controller import ControllerConfig, HeightLegAngleController
from ddpc_codegen.robot.signals import OUTPUTS, REFERENCES, check_per_reference


def test_the_controller_names_its_loop_from_the_table():
    for mode in ("flying", "hopping"):
        ctrl = HeightLegAngleController(ControllerConfig(mode=mode))
        assert (ctrl.input_names, ctrl.output_names) == (REFERENCES[mode], OUTPUTS[mode])


def test_a_setting_per_reference_is_checked_for_the_loop():
    assert check_per_reference("max_step", None, "flying") is None
    assert check_per_reference("max_step", [0.6, 0.5], "flying") == (0.6, 0.5)
    assert check_per_reference("blend", np.array([0.0, 0.1, 0.2]), "hopping", zero_ok=True) == (0.0, 0.1, 0.2)
    bad = [([0.6], "needs 2 values on the flying loop \\(z_ref, pitch_ref\\)"), (0.6, "needs 2 values"),
           ([0.6, 0.5, 0.4], "needs 2 values"), ([0.6, float("nan")], "finite and > 0"),
           ([0.6, 0.0], "finite and > 0"), ([0.6, -1.0], "finite and > 0"), ([True, 0.5], "finite and > 0"),
           (["a", 0.5], "finite and > 0")]
    for values, msg in bad:
        with pytest.raises(ValueError, match=f"max_step {msg}" if msg.startswith("needs") else msg):
            check_per_reference("max_step", values, "flying")
    with pytest.raises(ValueError, match=">= 0"):
        check_per_reference("blend", [0.1, -0.1, 0.0], "hopping", zero_ok=True)
