"""make sitl-adapt's pieces without a SITL: the second link, the per-window scoring of a tick log (through
flight_metrics), the adaptation counters, the rounds' summary, the report merge and the results table."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ddpc_codegen.docsgen.results_adapt import adaptation_page, sitl_adaptation
from ddpc_codegen.docsgen.results_sitl import sitl_page
from ddpc_codegen.flight_metrics import rms
from ddpc_codegen.runtime.adapt_loop import ADAPT_CODES
from ddpc_codegen.testbed.sitl import Sitl
from ddpc_codegen.testbed.sitl_adapt import (MidFlightChange, _started, adapt_tick_counts, change_cost, format_adaptation,
                                             merge_report,
                                             rescore, second_link, summarize, window_figures)
from firmware_bridge.ticklog import TickRecorder, reason_code

A = {k: i for i, k in enumerate(ADAPT_CODES)}


def test_second_link_is_serial1_on_ardupilot_and_the_gcs_link_on_px4():
    ap = Sitl("ardupilot", ["x"], "tcp:127.0.0.1:5770", 3)
    px = Sitl("px4", ["x"], "udpin:127.0.0.1:14541", 12, sysid=2)
    assert second_link(ap).url == "tcp:127.0.0.1:5772" and ap.url == "tcp:127.0.0.1:5770"
    assert second_link(px).url == "udpin:127.0.0.1:14550" and second_link(px).sysid == 2


def test_the_change_thread_reports_a_flight_that_never_started(tmp_path):
    ch = MidFlightChange(Sitl("px4", ["x"], "udpin:127.0.0.1:14540", 12), tmp_path / "f.out", {"SIH_MASS": 1.2})
    (tmp_path / "f.out").write_text("[bridge    1.000] arming (--arm), attempt 1\n")
    ch.start()
    ch.done.set()
    ch.join(5.0)
    assert ch.result == {"error": "the flight ended before its trajectory started"}


def test_the_start_event_is_the_end_of_the_approach_not_the_engaged_line():
    engaged = ("[bridge    4.224] engaged (OFFBOARD, armed): take-off to z = 0.90 m at 0.5 m/s, then trajectory starts, "
               "collect; frame start: heading 90.5 deg ENU, heights from z0 = -0.19 m (EKF)\n")
    assert not _started(engaged)
    assert _started(engaged + "[bridge    5.499] at the trajectory's start height: trajectory starts\n")
    assert _started("[bridge 25.0] WARNING: did not hold ... (height error now +0.300 m: ...): trajectory starts anyway\n")


def test_adapt_counts_over_the_flight_and_after_the_change():
    t = np.array([np.nan, 1.0, 2.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0])
    codes = np.array([0, A["warmup"], A["update"], A["accepted"], A["update"], A["gain"], A["accepted"], A["gain"],
                      A["refused"]])
    c = adapt_tick_counts(codes, t, 10.0)
    assert c["updates"] == 6 and c["resolves"] == 4 and c["accepted"] == 2 and c["rejected"] == {"gain": 2}
    assert c["refused"] == c["refused_after"] == 1
    assert c["updates_after"] == 4 and c["resolves_after"] == 3 and c["accepted_after"] == 1
    assert c["rejected_after"] == {"gain": 2}


@pytest.fixture()
def log(tmp_path):
    """A 20 s tick log at 100 Hz: EKF error 10 mm, true error 20 mm before t = 10 s, 50 / 80 mm after; inactive
    ticks with a huge error (never scored); adapt codes with one accepted swap after the change."""
    t = np.arange(-1.0, 20.0, 0.01)
    rec = TickRecorder(2, 2, capacity=t.size)
    for k, tk in enumerate(t):
        i = rec.new_row()
        a = rec.arrays
        a["t_traj"][i] = np.nan if tk < 0 else tk
        active = not (5.0 <= tk < 5.5)
        after = tk >= 10.0
        a["y_des"][i] = (1.0, 0.0)
        a["y"][i] = (1.0 + (0.05 if after else 0.01) + (0.0 if active else 9.0), 0.0)
        a["truth_position"][i, 2] = 1.0 + (0.08 if after else 0.02)
        a["active"][i] = a["event"][i] = active
        a["reason"][i] = reason_code("steered")
        a["adapt"][i] = A["accepted"] if abs(tk - 12.0) < 1e-6 else (A["update"] if tk >= 0 else 0)
    return rec.to_log(dt=0.01, input_names=("z_ref", "pitch_ref"), output_names=("z", "pitch")).save(tmp_path / "f.npz")


def test_window_figures_score_before_and_after_the_change(log):
    f = window_figures(log, t_change=10.0, window=5.0, settle=3.0)
    b, a = f["before"], f["after"]
    assert b["ticks"] == 650 and a["ticks"] == 500  # [3, 10) without the 0.5 s inactive; [10, 15)
    assert b["rmse_z"] == pytest.approx(0.01) and b["rmse_z_truth"] == pytest.approx(0.02)
    assert a["rmse_z"] == pytest.approx(0.05) and a["rmse_z_truth"] == pytest.approx(0.08)
    assert a["estimator_rms"] == pytest.approx(rms([0.03]))
    # the first LEARN_S (2 s) of the 5 s window alone, as an RMS over the whole window
    assert f["floor"] == pytest.approx(0.08 * np.sqrt(200 / 500))
    assert f["adapt"]["accepted"] == f["adapt"]["accepted_after"] == 1 and f["adapt"]["rejected"] == {}


def test_rescore_scores_every_flight_again_from_its_files(log, tmp_path):
    d = tmp_path / "sitl_adapt_px4"
    d.mkdir()
    for m in ("static", "adapted"):
        (d / f"px4_adapt_heavy_{m}_r0.npz").write_bytes(log.read_bytes())
        events = [[400, "prediction", False, 0.0, 399, 80.0, 0.97], [600, "rank", False, 0.0, 599, 80.0, float("nan")],
                  [800, "accepted", True, 0.0, 799, 80.0, 0.81234567]]  # the bridge summary's re-solve events
        (d / f"px4_adapt_heavy_{m}_r0.json").write_text(json.dumps({"fallbacks": 1, "missed_ticks": 7, "max_gap_ms": 70.0,
                                                                   "steering": {"adaptation": {"events": events}}}))
    old = {"t_change_s": 10.0, "autopilots": {"px4": {"wall_s": 1.0, "conditions": {"heavy": {
        "params": {"SIH_MASS": 1.2}, "rounds": [{m: {"change": {"sent_s": 10.0}} for m in ("static", "adapted")}]}}}}}
    new = rescore(old, tmp_path)
    c = new["autopilots"]["px4"]["conditions"]["heavy"]
    assert c["static"]["after"]["rmse_z_truth"] == pytest.approx(0.08) and c["static"]["missed_ticks"] == 7
    assert c["adapted"]["adapt"]["accepted"] == 1 and c["params"] == {"SIH_MASS": 1.2}
    assert c["rounds"][0]["adapted"]["error_ratios"] == [0.97, 0.8123]  # the error check's verdicts, in order
    assert c["rounds"][0]["adapted"]["accepted_ratios"] == [0.8123] and c["adapted"]["accepted_ratio_range"] == [0.8123] * 2
    assert c["rounds"][0]["static"]["change"] == {"sent_s": 10.0} and c["static_over_adapted"]["after"] == 1.0
    assert new["t_change_s"] == 10.0 and new["autopilots"]["px4"]["wall_s"] == 1.0
    assert old["autopilots"]["px4"]["conditions"]["heavy"]["rounds"][0]["static"] == {"change": {"sent_s": 10.0}}


def _flight(after: float, before: float, accepted: int = 0, rejected: dict | None = None) -> dict:
    w = lambda v: {"rmse_z": v / 2, "rmse_z_truth": v, "estimator_rms": 0.005, "ticks": 100}  # noqa: E731
    return {"before": w(before), "after": w(after), "floor": after / 3, "fallbacks": 0, "missed_ticks": 5, "max_gap_ms": 10.0 + accepted,
            "adapt": {"updates": 100, "accepted": accepted, "rejected": dict(rejected or {})}}


def test_summarize_means_the_rounds_sums_the_counts_and_gives_the_ratio():
    rounds = [{"static": _flight(0.03, 0.01), "adapted": _flight(0.02, 0.01, 1, {"gain": 3}),
               "prefilter": _flight(0.05, 0.04)},
              {"static": _flight(0.05, 0.01), "adapted": _flight(0.02, 0.02, 0, {"gain": 2, "prediction": 1}),
               "prefilter": _flight(0.07, 0.04)}]
    s = summarize(rounds)
    assert s["static"]["after"]["rmse_z_truth"] == pytest.approx(0.04)
    assert s["adapted"]["before"]["rmse_z_truth"] == pytest.approx(0.015)
    assert s["prefilter"]["after"]["rmse_z"] == pytest.approx(0.03) and s["static"]["flights"] == 2
    assert s["adapted"]["adapt"] == {"updates": 200, "accepted": 1, "rejected": {"gain": 5, "prediction": 1}}
    assert s["static_over_adapted"]["after"] == pytest.approx(2.0)
    assert s["static_over_adapted"]["before"] == pytest.approx(0.01 / 0.015)
    assert "adapt" not in s["static"] and s["rounds"] == rounds
    assert s["adapted"]["missed_ticks"] == 10 and s["adapted"]["max_gap_ms"] == 11.0
    assert s["adapted"]["accepted_ratio_range"] is None  # no round recorded an accepted swap's ratio
    rounds[0]["adapted"]["accepted_ratios"], rounds[1]["adapted"]["accepted_ratios"] = [0.8, 0.85], [0.78]
    assert summarize(rounds)["adapted"]["accepted_ratio_range"] == [0.78, 0.85]


def test_summarize_gives_none_where_a_round_has_no_truth():
    r = [{"static": _flight(0.03, 0.01), "adapted": _flight(0.02, 0.01)}, {"static": _flight(0.03, 0.01),
                                                                           "adapted": _flight(0.02, 0.01)}]
    r[1]["static"]["after"]["rmse_z_truth"] = None
    s = summarize(r)
    assert s["static"]["after"]["rmse_z_truth"] is None and s["static_over_adapted"]["after"] is None
    assert "prefilter" not in s


def test_merge_report_replaces_only_the_adaptation_key(tmp_path):
    path = tmp_path / "sitl.json"
    path.write_text(json.dumps({"px4": {"rate_hz": 200.0}, "adaptation": {"old": 1}}))
    merge_report(path, {"new": 2})
    assert json.loads(path.read_text()) == {"px4": {"rate_hz": 200.0}, "adaptation": {"new": 2}}
    merge_report(tmp_path / "fresh" / "sitl.json", {"new": 3})
    assert json.loads((tmp_path / "fresh" / "sitl.json").read_text()) == {"adaptation": {"new": 3}}
    path.write_text("[]")
    with pytest.raises(ValueError, match="expected a JSON object"):
        merge_report(path, {})
    # flying one autopilot keeps the other's figures
    path.write_text(json.dumps({"adaptation": {"rounds": 2, "autopilots": {"px4": {"a": 1}, "ardupilot": {"a": 2}}}}))
    merge_report(path, {"rounds": 1, "autopilots": {"ardupilot": {"a": 3}}})
    assert json.loads(path.read_text())["adaptation"] == {"rounds": 1, "autopilots": {"px4": {"a": 1}, "ardupilot": {"a": 3}}}
    # make sitl-demo's write replaces the autopilots and keeps the adaptation
    from ddpc_codegen.experiments.report_file import update_report

    path.write_text(json.dumps({"px4": {"rate_hz": 200.0}, "adaptation": {"new": 2}}))
    update_report(path, {"px4": {"rate_hz": 199.0}, "ardupilot": {}})
    assert json.loads(path.read_text()) == {"px4": {"rate_hz": 199.0}, "ardupilot": {}, "adaptation": {"new": 2}}


def _adaptation() -> dict:
    s = summarize([{"static": _flight(0.03, 0.01), "adapted": {**_flight(0.02, 0.01, 1, {"gain": 3}),
                                                               "accepted_ratios": [0.812]},
                    "prefilter": _flight(0.05, 0.04)}])
    nominal = summarize([{"static": _flight(0.02, 0.01), "adapted": _flight(0.02, 0.01)}])
    return {"t_change_s": 10.0, "window_s": 10.0, "settle_s": 3.0, "rounds": 1, "learn_s": 2.0,
            "autopilots": {"px4": {"conditions": {"nominal": nominal, "heavy": s}}}}


def test_the_results_table_and_the_printed_lines():
    table = sitl_adaptation(_adaptation())
    rows = [line for line in table.splitlines() if line.startswith("| PX4 | heavy |")]
    assert rows == ["| PX4 | heavy | 30.0 | 20.0 | 50.0 | 1.50 | 10.0 | 1.50 / 1.50 |",  # after the change
                    "| PX4 | heavy | 10.0 / 10.0 / 40.0 | 15.0 / 10.0 | 5.0 / 5.0 | 5 / 5 |",  # before, the estimator
                    "| PX4 | heavy | 100 | 1 | 0.81-0.81 | gain 3 |"]  # the adapted flights' counters
    assert "static's first 2.0 s alone" in table
    text = format_adaptation(_adaptation())
    assert "static / adapted 1.50" in text and "1 swaps accepted (error ratio 0.81-0.81)" in text
    nominal = [line for line in table.splitlines() if line.startswith("| PX4 | nominal |")][-1]
    assert "| 0 | -- |" in nominal  # no swap, no ratio
    # the floor of any learner (static 30 mm over a 10 mm first-2-s floor) and the change's cost to static (30 / 20)
    assert "static / any learner <= 3.00" in text and "in nominal flight: true 1.50x, EKF 1.50x" in text


def test_change_cost_needs_the_condition_and_the_nominal_flights():
    s = lambda v: {"static": {"after": {"rmse_z_truth": v, "rmse_z": v and v / 2}}}  # noqa: E731
    assert change_cost({"nominal": s(0.02), "motor": s(0.03)}, "motor") == pytest.approx((1.5, 1.5))
    assert change_cost({"motor": s(0.03)}, "motor") == (None, None)
    assert change_cost({"nominal": s(0.02), "motor": s(None)}, "motor") == (None, None)


def test_the_sitl_section_does_not_take_adaptation_for_an_autopilot():
    page = sitl_page({"adaptation": _adaptation()})
    assert "adaptation" not in page.lower().split("-->", 1)[1] and "found no SITL" in page
    assert "| PX4 | heavy | 30.0 |" in adaptation_page(None, {"adaptation": _adaptation()})


def test_the_report_names_the_adapt_settings_the_solver_was_built_with(tmp_path):
    from ddpc_codegen.testbed.sitl_adapt import adapt_settings

    assert adapt_settings(tmp_path) is None  # no solver there
    (tmp_path / "manifest.json").write_text(json.dumps({"adapt": {"enabled": True, "dither": 0.0}, "config_hash": "x"}))
    assert adapt_settings(tmp_path) == {"enabled": True, "dither": 0.0}
