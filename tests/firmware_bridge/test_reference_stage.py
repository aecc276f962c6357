"""The tick's reference stage (firmware_bridge/reference_stage.py), built alone around a real steering policy
on a stand-in solver: holds pass the nominal reference, steered ticks give a typed TickReference, a guard trip
carries its candidate, the history takes the applied reference; the baselines and collect behind it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ddpc_codegen.runtime.baselines import PassthroughPolicy
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer
from ddpc_codegen.values.solve_result import SteeringResult
from firmware_bridge.excitation import Excitation
from firmware_bridge.reference_stage import ReferenceStage, TickReference

T_INI, T_F, M = 3, 4, 2
DT = 0.005


class OffsetSolver:
    """Steers every reference by ``offset`` (the nominal horizon plus a constant)."""

    def __init__(self, offset: float) -> None:
        self.offset = offset
        self.calls = 0

    def solve(self, u_ini, y_ini, y_des, u_nom):
        self.calls += 1
        return SteeringResult(np.asarray(u_nom) + self.offset)


def desired(t: np.ndarray) -> np.ndarray:
    return np.column_stack([1.0 + 0.1 * t, 0.0 * t])


def _steer(offset: float = 0.01, max_step=None) -> tuple[ReferenceStage, ReferenceSteerer]:
    steerer = ReferenceSteerer(OffsetSolver(offset), T_INI, T_F, M, M, max_step=max_step)
    policy = SteeringPolicy(steerer, ramp_ticks=0)
    return ReferenceStage("steer", desired, DT, policy=policy, ahead=DT * np.arange(T_F), steerer=steerer), steerer


def test_the_product_is_a_frozen_typed_value():
    stage, _ = _steer()
    ref = stage.step(np.array([1.0, 0.0]), np.array([1.0, 0.0]), 0.0)
    assert isinstance(ref, TickReference) and ref.reason == "warmup" and ref.observed
    with pytest.raises(dataclasses.FrozenInstanceError):
        ref.reason = "steered"


@pytest.mark.parametrize("hold", ["no_heartbeat", "inactive", "stale", "blend", "takeoff"])
def test_a_hold_passes_the_nominal_reference(hold):
    stage, steerer = _steer()
    r, y = np.array([1.0, 0.1]), np.array([0.9, 0.0])
    ref = stage.step(r, y, 0.0, hold)
    assert ref.reason == hold and ref.u is r and ref.u_steered is None and ref.solve_us != ref.solve_us
    # a blend fills the history meanwhile (no extra warm-up after it)
    assert ref.observed == (hold == "blend") and np.array_equal(steerer.window()[0][-1], r) == (hold == "blend")


def test_steered_ticks_after_the_warm_up():
    stage, steerer = _steer(offset=0.01)
    y = np.array([1.0, 0.0])
    refs = [stage.step(np.array([1.0, 0.0]), y, k * DT) for k in range(T_INI + 2)]
    assert [r.reason for r in refs] == ["warmup"] * T_INI + ["steered"] * 2
    assert np.allclose(refs[-1].u, [1.01, 0.01]) and refs[-1].u_steered is refs[-1].u
    assert refs[-1].solve_us >= 0 and refs[-1].candidate is None


def test_a_guard_trip_carries_its_candidate_and_the_history_holds_the_applied_reference():
    stage, steerer = _steer(offset=0.2, max_step=[0.05, 0.05])
    y = np.array([1.0, 0.0])
    for k in range(T_INI):
        stage.step(np.array([1.0, 0.0]), y, k * DT)
    ref = stage.step(np.array([1.0, 0.0]), y, T_INI * DT)
    assert ref.reason == "step_too_large" and np.allclose(ref.candidate, [1.2, 0.2])
    applied = np.array([1.05, 0.05])  # what the gate made of it
    stage.applied(ref, applied)
    assert np.array_equal(steerer.window()[0][-1], applied)


def test_reset_forgets_the_history():
    stage, steerer = _steer()
    for k in range(T_INI + 1):
        stage.step(np.array([1.0, 0.0]), np.array([1.0, 0.0]), k * DT)
    stage.reset()
    assert not steerer.ready and stage.step(np.array([1.0, 0.0]), np.array([1.0, 0.0]), 0.0).reason == "warmup"


def test_passthrough_and_collect_behind_the_same_stage():
    stage = ReferenceStage("passthrough", desired, DT, policy=PassthroughPolicy(), ahead=np.zeros(1))
    r = np.array([1.0, 0.1])
    ref = stage.step(r, np.array([1.0, 0.0]), 0.3)
    assert ref.reason == "passthrough" and np.array_equal(ref.u, r) and stage.summary() == {}
    exc = Excitation(M, [0.05, 0.1], hold=4, seed=3)
    collect = ReferenceStage("collect", desired, DT, excitation=exc)
    ref = collect.step(r, np.array([1.0, 0.0]), 0.0)
    assert ref.reason == "collect" and np.allclose(ref.u, r + ref.excitation) and np.all(ref.excitation != 0)
    with pytest.raises(ValueError, match="needs its excitation"):
        ReferenceStage("collect", desired, DT)
