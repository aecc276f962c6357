"""The fuzzer of ``make fuzz`` (testbed/fuzz*.py), small: its mutants are the seed's, its verdicts are computed
the way the docstrings say, a few accepted mutants fly in-process lock-step against the simulated vehicle and
once as ``ddpc-vehicle`` + ``ddpc-bridge`` processes, and the link attacks change nothing the vehicle flies."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddpc_codegen.robot.profile import Envelope
from ddpc_codegen.testbed.bridge_flights import free_udp_port
from ddpc_codegen.testbed.fuzz import format_table, run_mutant
from ddpc_codegen.testbed.fuzz_flight import (REFUSALS, TRACK_MARGIN_M, FlightCheck, accept, envelope_excess,
                                              fly_in_process, fly_processes, rate_ratio)
from ddpc_codegen.testbed.fuzz_link import STARTUP_STAMP, fly_link_attack, forged_packets
from ddpc_codegen.testbed.fuzz_mutants import KINDS, make_mutant, mutate_bytes, mutate_number
from firmware_bridge.events import EventLog
from firmware_bridge.link import mavlink
from support.bridge_helpers import flying_solver  # noqa: F401 (fixture)

QUICK_SEEDS = range(1, 25)  # drawn by the quick variant: every kind, refused and accepted ones


def test_a_mutant_is_its_seed(tmp_path):
    a, b = make_mutant(7, tmp_path / "a"), make_mutant(7, tmp_path / "b")
    assert a.kind == b.kind and a.changes == b.changes
    assert [x.replace(str(tmp_path / "a"), "") for x in a.args] == [x.replace(str(tmp_path / "b"), "") for x in b.args]
    for fa, fb in zip(a.files, b.files):
        assert fa.read_bytes() == fb.read_bytes()
    assert {make_mutant(s, tmp_path / f"k{s}").kind for s in range(60)} == set(KINDS) - {"steer"}
    assert {make_mutant(s, tmp_path / f"s{s}", solver="gen/x").kind for s in range(60)} == set(KINDS)


def test_number_and_byte_mutations_are_seeded_and_change_something():
    rng1, rng2 = np.random.default_rng(3), np.random.default_rng(3)
    assert [mutate_number(rng1, 1.5) for _ in range(20)] == [mutate_number(rng2, 1.5) for _ in range(20)]
    rng = np.random.default_rng(0)
    data = b"t,x,z\n0,0,1\n1,0.5,1.2\n"
    outs = [mutate_bytes(rng, data) for _ in range(40)]
    assert sum(out != data for out, _ in outs) >= 35 and all(isinstance(what, str) for _, what in outs)


def test_excess_is_the_distance_outside_the_box_and_rate_the_step_over_its_bound():
    env = Envelope(z_min=0.5, z_max=2.0, radius=1.0)
    pos = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 2.1], [0.0, 0.0, 0.7]])
    excess, (lo, hi), rad = envelope_excess(pos, (0.0, 0.0), env)
    assert math.isclose(excess, 0.1) and (lo, hi) == (0.7, 2.1) and rad == 0.6
    excess, _, rad = envelope_excess(pos + [1.5, 0.0, 0.0], (0.0, 0.0), env)
    assert math.isclose(excess, 1.1) and rad == 2.1                      # 2.1 m from the start, radius 1
    assert math.isclose(envelope_excess(pos[[0]], (0.0, 0.0), env)[0], -0.5)  # inside: the closest edge, negative
    u = np.array([[1.0, 0.0], [1.1, 0.0], [1.1, -0.5]])
    assert math.isclose(rate_ratio(u, np.array([0.2, 1.0])), 0.5)
    # a reference the vehicle never flew (disarmed, in its own mode) is no step: the first flown tick starts anew
    jump = np.array([[0.9, 0.0], [0.0, 0.0], [0.01, 0.0]])
    assert math.isclose(rate_ratio(jump, np.array([0.02, 1.0]), np.array([False, True, True])), 0.5)
    assert math.isclose(rate_ratio(jump, np.array([0.02, 1.0])), 45.0)
    assert FlightCheck("flown", excess_m=TRACK_MARGIN_M + 0.01).violation
    assert FlightCheck("flown", rate_ratio=1.01).violation and not FlightCheck("flown", rate_ratio=1.0).violation
    assert not FlightCheck("refused", excess_m=5.0).violation


def test_refusals_are_one_line_naming_the_flag_or_file(tmp_path):
    with pytest.raises(REFUSALS) as e:
        accept(["--mode", "collect", "--excitation", "1e308,1e308"], free_udp_port(), 1.0)
    assert "\n" not in str(e.value) and str(e.value).startswith("--excitation")
    refused = [run_mutant(s, tmp_path, 1.0, fly=False) for s in QUICK_SEEDS]
    assert {r["status"] for r in refused} <= {"refused", "accepted"}, [r for r in refused if r["status"] == "defect"]
    assert all(r["message"] and "\n" not in r["message"] for r in refused if r["status"] == "refused")


def test_the_table_says_every_figure():
    s = {"generated": 10, "refused": 6, "refused_before_arming": 1, "accepted": 4, "flown": 3, "process_flights": 1,
         "link_flights": 7, "violations": 0, "defects": [], "findings": [], "max_excess_m": -0.2, "margin_m": 0.3,
         "max_rate_ratio": 0.9, "seconds": 12.0}
    table = format_table(s)
    for word in ("mutants generated", "refused", "accepted", "flown", "violations", "-0.200", "0.900", "margin 0.3"):
        assert word in table


def test_forged_packets_decode_as_what_they_claim():
    rng = np.random.default_rng(1)
    parser = mavlink.MAVLink(None)
    for kind in ("absurd", "plausible", "stamps", "peer", "far"):
        for pkt in forged_packets(kind, rng, 5000):
            msg = parser.parse_char(pkt)
            assert msg is not None and msg.get_srcSystem() == 1, kind


@pytest.mark.e2e
def test_accepted_mutants_fly_inside_their_envelope(tmp_path):
    """The quick variant of ``make fuzz``'s first part: every accepted mutant of a few seeds flown in-process."""
    records = [run_mutant(s, tmp_path, 1.0) for s in QUICK_SEEDS[:12]]
    flown = [r for r in records if r["flight"] and r["flight"]["outcome"] == "flown"]
    assert len(flown) >= 3, [r["status"] for r in records]
    for r in flown:
        f = r["flight"]
        assert not f["violation"], r
        # a second flown (200 ticks) after the off-board switch; the vehicle blends to a path that starts elsewhere
        assert f["ticks"] > 200 and f["engaged_ticks"] > 0 and f["exit_code"] == 0, r
        assert f["rate_ratio"] <= 1.0 + 1e-6 and f["excess_m"] <= TRACK_MARGIN_M


@pytest.mark.e2e
def test_hopping_mutants_hop_inside_their_envelope(tmp_path):
    seeds = [s for s in range(1, 200) if make_mutant(s, tmp_path / f"k{s}").kind == "hopping"][:6]
    records = [run_mutant(s, tmp_path, 1.0) for s in seeds]
    flown = [r for r in records if r["flight"] and r["flight"]["outcome"] == "flown"]
    assert len(flown) >= 2 and all(r["status"] != "defect" for r in records), records
    for r in flown:
        assert not r["flight"]["violation"] and r["flight"]["exit_code"] == 0, r
        assert r["flight"]["z_range"][0] < 0.45  # it hopped: the body came down over its leg


@pytest.mark.e2e
@pytest.mark.compiler
def test_steered_mutants_fly_inside_their_envelope(tmp_path, flying_solver):  # noqa: F811
    """Steered mutants (the step guard, its hold, injected solver failures and NaN solutions) with a solver."""
    solver = str(flying_solver)
    seeds = [s for s in range(1, 80) if make_mutant(s, tmp_path / f"k{s}", solver=solver).kind == "steer"][:8]
    records = [run_mutant(s, tmp_path, 1.0, solver=solver) for s in seeds]
    flown = [r for r in records if r["flight"] and r["flight"]["outcome"] == "flown"]
    assert len(flown) >= 2 and all(r["status"] != "defect" for r in records), records
    for r in flown:
        assert not r["flight"]["violation"] and r["flight"]["exit_code"] == 0, r


@pytest.mark.e2e
def test_an_accepted_mutant_flies_as_two_processes(tmp_path):
    seed = next(s for s in QUICK_SEEDS if run_mutant(s, tmp_path, 1.0, fly=False)["status"] == "accepted")
    m = make_mutant(seed, tmp_path / "p")
    check = fly_processes(m.args, accept(m.args, free_udp_port(), 1.0), tmp_path, sim_time=3.0, seed=seed)
    assert check.outcome == "flown" and check.engaged_ticks > 100 and not check.violation, check.as_dict()


@pytest.mark.e2e
@pytest.mark.parametrize("attack", ["foreign_same_ids", "foreign_first_pinned", "same_address_absurd",
                                    "same_address_signed"])
def test_a_link_attack_changes_nothing_the_vehicle_flies(tmp_path, attack):
    r = fly_link_attack(attack, 3, 1.5, tmp_path)
    assert r["defect"] == "" and not r["flight"]["violation"], r
    assert r["flight"]["engaged_ticks"] > 200
    if attack.startswith("foreign"):
        assert r["peer_sent"] > 0 and r["peer_received"] == 0 and r["flight"]["counts"]["foreign_packets"] > 0
    else:
        assert r["injected"] > 0
    if attack == "same_address_absurd":
        assert r["flight"]["counts"]["telemetry_dropped"] > 0
    if attack == "same_address_signed":  # the forgeries are unsigned: dropped before they are parsed as messages
        assert r["flight"]["counts"]["unsigned"] > 0 and r["flight"]["counts"]["telemetry_dropped"] == 0


@pytest.mark.e2e
def test_a_controller_model_that_sank_the_vehicle_is_refused_before_arming(tmp_path):
    """The regression of make fuzz's profile mutant 2456 (max_thrust 187 N, the model's hover thrust 0.18 against
    the vehicle's 0.80): flown, its height loop sank the vehicle to the ground below z_min with every reference
    inside the envelope. Refused now when the vehicle's hover thrust is read (path_checks.check_model_hover)."""
    profile = tmp_path / "model.toml"
    profile.write_text('extends = "pogox"\n[controller]\nmax_thrust = 186.9\n[envelope]\nz_min = 0.6\nz_max = 2.3\n')
    cfg = accept(["--controller", str(profile), "--mode", "passthrough"], free_udp_port(), 1.0)
    check = fly_in_process(cfg, tmp_path, sim_time=3.0, seed=1)
    assert check.outcome == "refused" and "would settle 3.35 m below every reference" in check.notes[0], check


@pytest.mark.e2e
@pytest.mark.realtime
def test_stamps_forged_ahead_from_the_vehicles_address_keep_the_vehicle_in_its_envelope(tmp_path):
    """The regression of the defect this fuzzer found (plausibility.CLOCK_SLACK_S was 0.5 s): a real-time flight."""
    r = fly_link_attack("same_address_stamps", 0, 2.0, tmp_path)
    assert r["defect"] == "" and not r["flight"]["violation"], r
    assert r["injected"] > 50 and r["flight"]["counts"]["telemetry_dropped"] > 0 and r["flight"]["counts"]["reboots"] == 0


@pytest.mark.e2e
def test_a_far_stamp_at_start_up_does_not_keep_the_bridge_on_the_ground(tmp_path, monkeypatch):
    """The regression of a finding of this fuzzer: samples stamped 2**32 - 1 ms from the vehicle's address before
    its first real one anchored the telemetry's time line (every real sample dropped as back in time), and once
    that line was re-lined onto the real samples, the first tick's setpoint had still anchored the stream's
    vehicle-time length on the forged stamp: OFFBOARD was never asked for (exit 8). Stamps are used only on a
    confirmed time line (five samples advanced on it); the forged one is re-lined, with an event."""
    said: list[str] = []
    record = EventLog.__call__
    monkeypatch.setattr(EventLog, "__call__", lambda self, what: (said.append(what), record(self, what))[1])
    r = fly_link_attack(STARTUP_STAMP, 0, 1.0, tmp_path)
    assert r["defect"] == "" and not r["flight"]["violation"], r
    assert r["injected"] > 0 and r["flight"]["engaged_ticks"] > 100 and r["flight"]["exit_code"] == 0, r
    assert r["flight"]["counts"]["reboots"] == 0 and r["flight"]["counts"]["telemetry_dropped"] > 0, r
    relined = [e for e in said if "telemetry re-lined from 4294967.295 s" in e]
    assert relined and not any("left its time line" in e for e in said), said
