"""The results pages and the README table, rendered from reports/*.json: what each page says of a small
report, what it says of a missing one, and that the committed pages are the render of the stored reports."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from ddpc_codegen.docsgen import results, results_format, results_sitl

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()

SUMMARY = {"flying": {"baseline": {"rmse_z": 0.09, "rmse_pitch": 0.002}, "steered": {"rmse_z": 0.0017, "rmse_pitch": 0.0021},
                      "solve_us": {"median": 9.5, "p99": 20.25}, "fallbacks": 0},
           "meta": {"wall_time_s": 12.5, "machine": "x86_64", "python": "3.11", "mass_error_kg": -0.2,
                    "figures": ["reports/flying.png"]}}
# one flying condition against the simple fixes, in summary.json's layout (the steering is summary.json's "ddpc")
BASELINES = {"flying": {"metric": "rmse_z", "ilc": {"metric_per_iteration": [0.09, 0.002], "iterations_to_settle": 1},
                        "conditions": {"push": {"passthrough": {"rmse_z": 0.09}, "ctrl_ff": {"rmse_z": 0.06},
                                                "prefilter": {"rmse_z": 0.012}, "ilc": {"rmse_z": 0.0117},
                                                "ddpc": {"rmse_z": 0.008}, "ilc_learned_here": False}}}}
# one SITL condition where a simple fix beats the steering on the true height, one where the steering wins
SITL_COND = {"rmse_z": {"passthrough": 0.054, "ctrl_ff": 0.056, "prefilter": 0.053, "ilc": None, "steered": 0.0092},
             "rmse_z_truth": {"passthrough": 0.0796, "ctrl_ff": 0.1212, "prefilter": 0.107, "ilc": None, "steered": 0.1131},
             "estimator_rms": {"steered": 0.1119}}


def test_every_results_page_says_what_is_not_measured_yet():
    pages = results.pages({})
    assert set(pages) == set(results.PAGES)
    for name, target in results.REPORTS.items():
        assert f"Not measured yet -- run `{target}` (it writes `reports/{name}`" in pages["index.md"]
    assert "Not measured yet -- run `make adapt-eval`" in pages["adaptation.md"]
    assert "Not measured yet -- run `make sitl-adapt`" in pages["adaptation.md"]


def test_the_simulator_page_and_the_readme_block_render_a_small_summary():
    page = results.pages({"summary.json": SUMMARY})["simulator.md"]
    assert "| RMSE z [mm] | 90.0 | 1.7 | 52.94 |" in page and "| solver call median / p99 [µs] | -- | 9.5 / 20.2 | -- |" in page
    assert "![flying](../figures/flying.png)" in page and "```" not in page  # no console text
    block = results.readme_block({"summary.json": SUMMARY})
    assert block.startswith(results.BEGIN) and block.endswith(results.END)
    assert "| flying | nominal | RMSE z [mm] | 90.00 | -- | 1.70 | -- |" in block  # no baselines: nothing judged
    judged = results.readme_block({"summary.json": {**SUMMARY, "baselines": BASELINES}})
    assert "| flying | push | RMSE z [mm] | 90.00 | 11.70 (ILC) | 8.00 | 0.68 |" in judged
    assert "below 1 (the steering better than every simple fix) in 1 of 1 conditions" in judged
    sim = results.pages({"summary.json": {**SUMMARY, "baselines": BASELINES}})["simulator.md"]
    assert "| push | 90.00 | 60.00 | 12.00 | 11.70* | 8.00 | ILC | 0.68 |" in sim  # *: ILC learned elsewhere
    assert "ILC on the periodic flying case: 90.00, 2.00 mm per iteration" in sim


def test_the_headline_names_steered_over_the_best_simple_fix_on_the_true_height():
    won = {**SITL_COND, "rmse_z_truth": {**SITL_COND["rmse_z_truth"], "steered": 0.0097}}
    sitl = {"px4": {"conditions": {"steps": SITL_COND, "wind": {"skipped": "no wind parameter"}}},
            "ardupilot": {"conditions": {"steps": won}}}
    index = results.index_page({"sitl.json": sitl})
    # PX4 steps: 113.1 mm steered against the prefilter's 107.0: 1.06, the steering worse, said so
    assert "| steps | 79.6 | 107.0 (prefilter) | 113.1 | 1.06 | 1.01 |" in index
    assert "below 1 (the steering better than every simple fix) in 0 of 1 conditions" in index
    assert "| steps | 79.6 | 107.0 (prefilter) | 9.7 | 0.09 | 0.09 |" in index
    assert "[SITL page](sitl.md#px4)" in index and "[SITL page](sitl.md#ardupilot)" in index


def test_the_bench_page_and_headline_render_a_small_report():
    daqp = {"median_us": 7.0, "p99_us": 30.0, "c_median_us": 1.0, "max_err": 1e-14, "fast_path_fraction": 0.8,
            "speedup_vs_osqp_interp_1e-6": 11.4}
    bench = {"flying": {"daqp": daqp, "cvxpygen": {"median_us": 518.0, "p99_us": 2000.0, "max_err": 0.38},
                        "osqp": {"skipped": "no osqp"}, "active_fraction": {"value": 0.17}},
             "meta": {"ticks": 100, "machine": "x86_64", "date": "2026-12-04"}}
    index = results.index_page({"bench.json": bench})
    assert "| flying | 7.0 / 30.0 | 1.0 | 74 | 11 | 1.0e-14 |" in index  # CVXPYgen 518 / 7.0 µs
    page = results.pages({"bench.json": bench})["bench.md"]
    assert "| daqp | 7.0 | 30.0 | 1.0 | 1.0e-14 | 80 |" in page and "| osqp | skipped: no osqp |" in page
    assert "```" not in page and "## Online adaptation" not in page  # no console text; nothing not measured


def test_the_sitl_page_renders_each_autopilots_conditions():
    cond = {"rmse_z": {"passthrough": 0.07, "ctrl_ff": 0.05, "prefilter": 0.016, "ilc": None, "steered": 0.008},
            "rmse_z_truth": {"passthrough": 0.07, "ctrl_ff": 0.054, "prefilter": 0.0168, "ilc": None, "steered": 0.0084},
            "estimator_rms": {"passthrough": 0.009, "steered": 0.0056},
            "thrust_step_rms": {"passthrough": 0.0002, "steered": 0.0005},
            "max_ref_step": {"steered": 0.006}, "fallbacks": {"steered": 0.0}, "solve_us_p99": {"steered": 612.0}}
    ap = {"conditions": {"steps": cond, "wind": {"skipped": "no wind parameter"}}}
    truth = results_sitl._methods_table(ap, "rmse_z_truth", judged=True)
    assert "| steps | 70.0 | 54.0 | 16.8 | -- | 8.4 | prefilter | 0.50 |" in truth.splitlines()
    assert "| steps | 5.6 | -- | 1.50 |" in results_sitl._estimator_table(ap)  # no constant part recorded
    assert results_sitl._split_table(ap) == ""  # a report from before the split near path changes / steady
    assert "| steps | 6.0 | 2.5 | 0 | -- | -- | 0.61 |" in results_sitl._loop_activity_table(ap)
    cond["rmse_z_truth_changing"] = {"steered": 0.0107, "prefilter": 0.0219}
    cond["rmse_z_truth_steady"] = {"steered": 0.0009, "prefilter": 0.0057}
    assert "| steps | 10.7 | 0.9 | 21.9 | 5.7 |" in results_sitl._split_table(ap)
    del cond["solve_us_p99"]  # a report from before the figure
    cond["estimator_bias_rms"] = {"steered": 0.0049}
    cond["stalls"], cond["guard_saturations"] = {"steered": 1.5}, {"steered": 0.0}
    assert "| steps | 6.0 | 2.5 | 0 | 1.5 | 0 | -- |" in results_sitl._loop_activity_table(ap)
    assert "| steps | 5.6 | 4.9 | 1.50 |" in results_sitl._estimator_table(ap)
    assert "- wind: no wind parameter" in results_sitl._autopilot_section("px4", ap)


def test_the_adaptation_page_renders_adapt_eval():
    adaptation = {"scenario": "flying", "duration_s": 25.0, "t_change_s": 10.0, "window_s": 10.0, "adapt": {"forgetting": 0.999},
                  "conditions": {"mass": {"what": "+0.4 kg", "static": 0.0134, "adapted": 0.0067, "offset_only": 0.0061,
                                          "prefilter": 0.104, "adapted_crashed": False, "adapted_over_static": 0.5,
                                          "adaptation": {"swaps": 10, "rejected_gain": 14, "offset_swaps": 24}}}}
    page = results.pages({"summary.json": {**SUMMARY, "adaptation": adaptation}})["adaptation.md"]
    assert "| mass | +0.4 kg | 13.4 | 6.7 | 6.1 | 104.0 | 2.00 |" in page and "| mass | 10 | 14 | 24 |" in page
    assert "Not measured yet -- run `make adapt-eval`" in results.pages({"summary.json": SUMMARY})["adaptation.md"]


def test_the_sitl_page_renders_the_steps_against_the_front():
    model = {"passthrough": {"error_rms": 0.048, "rate_ratio": 1.0, "front_error_at_this_rate": 0.0131},
             "steered": {"error_rms": 0.0065, "rate_ratio": 1.923, "front_error_at_this_rate": 0.0064}}
    front = {"config": "sitl_ardupilot.toml", "model": model, "flown_rate_ratio": 1.87, "front_at_flown": 0.0066}
    table = results_sitl.front_table([("ardupilot", front, {"rmse_z": {"steered": 0.0071}})])
    assert "| ArduPilot | 48.0 (13.1) | 6.5 at 1.92x | 6.4 | 1.87x, 6.6, 7.1 | -- |" in table.splitlines()
    model["step_gain"] = {"chained": 0.596, "predicted": 0.869}
    no_flight = results_sitl.front_table([("px4", {**front, "flown_rate_ratio": None}, {"rmse_z": {}})])
    assert no_flight.splitlines()[-1].endswith("| 6.4 | -- | 0.60 / 0.87 |")
    assert results_sitl.front_table([]) == ""


def test_a_table_escapes_pipes_inside_cells():
    assert results_format.table(["a", "mean |apex err| [mm]"], [["x", "1"]]) == (
        "| a | mean \\|apex err\\| [mm] |\n|---|---|\n| x | 1 |\n")


def test_the_committed_results_pages_and_readme_table_are_the_rendered_reports():
    """docs/results/*.md and the README's table are exactly what the stored reports render: a hand-edited
    figure (or a report re-measured without re-rendering) fails here."""
    reports = results.load_reports(ROOT / "reports")
    for name, text in results.pages(reports).items():
        assert (ROOT / "docs" / "results" / name).read_text() == text, f"docs/results/{name}: run {results.__name__}"
    assert results.replace_block(README, results.readme_block(reports)) == README
    assert not (ROOT / "docs" / "results.md").exists()


def test_replace_block_and_its_error():
    text = f"intro\n{results.BEGIN}\nold\n{results.END}\noutro\n"
    assert results.replace_block(text, "NEW") == "intro\nNEW\noutro\n"
    with pytest.raises(ValueError, match=re.escape("no results markers in the text: expected")):
        results.replace_block("no markers", "NEW")


def test_load_reports_names_a_broken_report(tmp_path):
    (tmp_path / "bench.json").write_text("{not json")
    (tmp_path / "summary.json").write_text(json.dumps(SUMMARY))
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path / 'bench.json'}: not valid JSON (")):
        results.load_reports(tmp_path)
    (tmp_path / "bench.json").unlink()
    assert results.load_reports(tmp_path) == {"summary.json": SUMMARY}


def test_main_rewrites_pages_readme_and_figures(tmp_path):
    reports, docs = tmp_path / "reports", tmp_path / "docs"
    reports.mkdir()
    (reports / "flying.png").write_bytes(b"png")
    summary = {**SUMMARY, "meta": {**SUMMARY["meta"], "figures": [str(reports / "flying.png")]}}
    (reports / "summary.json").write_text(json.dumps(summary))
    readme = tmp_path / "README.md"
    readme.write_text(f"top\n{results.BEGIN}\nstale\n{results.END}\nbottom\n")
    assert results.main(["--reports", str(reports), "--docs", str(docs), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert "stale" not in text and "| flying | nominal | RMSE z [mm] | 90.00 |" in text and text.endswith("bottom\n")
    assert (docs / "figures" / "flying.png").read_bytes() == b"png"
    assert sorted(p.name for p in (docs / "results").iterdir()) == sorted(results.PAGES)
    assert "# Simulator" in (docs / "results" / "simulator.md").read_text()
    readme.write_text("no markers")
    assert results.main(["--reports", str(reports), "--docs", str(docs), "--readme", str(readme)]) == 2
    (reports / "summary.json").unlink()  # make bench / make sitl-demo alone: the README's table is left as it is
    assert results.main(["--reports", str(reports), "--docs", str(docs), "--readme", str(readme)]) == 0
    assert readme.read_text() == "no markers"
    assert "Not measured yet -- run `make demo`" in (docs / "results" / "index.md").read_text()




def _proxy_run(truth_mm: float, est_mm: float, rewritten: int = 0, delay: float = 0.0) -> dict:
    counts = {"received": 1000, "forwarded": 1000, "rewritten": rewritten, "dropped": 0, "seq_gaps": 0,
              "send_errors": 0}
    return {"rmse_z_truth_mm": truth_mm, "rmse_z_mm": est_mm, "estimator_rms_mm": 2.0, "samples": 900,
            "delay_s": delay, "proxy": {"app_to_vehicle": counts, "vehicle_to_app": {**counts, "rewritten": 0},
                                       "latency_us": {"app_to_vehicle": {"p50": 120.0, "p99": 480.0},
                                                      "vehicle_to_app": {"p50": 50.0, "p99": 90.0}},
                                       "steering": None}}


def test_the_proxy_page_says_which_preview_wins_on_each_path():
    rep = {"ardupilot": {"setup": "lab", "collect": {"path": "wander", "seconds": 60, "dither_m": 0.15},
                         "paths": {"helix": {"direct": {**_proxy_run(40.0, 39.0), "proxy": None},
                                             "passthrough": _proxy_run(41.0, 40.0),
                                             "steer_local": _proxy_run(12.0, 11.0, 990),
                                             "steer_delay": _proxy_run(8.0, 7.5, 1000, 0.5)}},
                         "proxy_death": {"failsafe_s": 0.5, "mode_before": "OFFBOARD", "mode_after": "LOITER",
                                         "timed_by": "CURRENT_MODE, sent on a change"}}}
    rep["ardupilot"]["paths"]["helix"]["steer_local"]["app_stops"] = {
        "proxy_last_out_s": 0.0004, "failsafe_s": None, "mode_before": "GUIDED", "mode_after": None,
        "timed_by": "heartbeats every 18 ms"}
    rep["ardupilot"]["paths"]["helix"]["steer_local"]["proxy"]["steering"] = {
        "mode": "steer", "ticks": 1000, "model_mismatch": 250, "prediction_watch": {"trips": 2}}
    page = results.pages({"proxy.json": rep})["proxy.md"]
    assert "| helix | steered, local preview | 12.0 | 11.0 | 2.0 | 3.33 | 25 % (2 trips) |" in page
    assert "| helix | steered, local preview | 0 | -- | GUIDED -> unchanged | heartbeats every 18 ms |" in page
    assert "| (any) | the proxy killed mid-flight | -- | 500 | OFFBOARD -> LOITER | CURRENT_MODE, sent on a change |" in page
    assert "- helix: the declared delay wins (8.0 mm against 12.0 mm; the app alone 40.0 mm)." in page
    assert "| helix | steered, delay 0.5 s | 8.0 | 7.5 | 2.0 | 5.00 |" in page
    assert "| helix | steered, local preview | 1000 | 1000 | 990 | 0 | 0 | 0 | 0 | 120 | 480 |" in page
    assert "The steered app (its best preview) below the app alone on 1 of 1 paths." in page
    assert "The true preview (the delayed stream) against the local guess: -33 % to -33 % of the error" in page
    assert "The path file (`--preview-file`) was not flown in this report." in page
    index = results.pages({"proxy.json": rep})["index.md"]
    assert "| helix | 40.0 | 8.0 (steered, delay) | 5.00 |" in index


def test_the_proxy_page_says_where_steering_made_it_worse():
    runs = {"direct": {**_proxy_run(40.0, 39.0), "proxy": None}, "passthrough": _proxy_run(41.0, 40.0),
            "steer_local": _proxy_run(50.0, 49.0, 990), "steer_delay": _proxy_run(52.0, 51.0, 1000, 0.5)}
    rep = {"px4": {"setup": "lab", "collect": {"path": "wander", "seconds": 60, "dither_m": 0.15},
                   "paths": {"steps": runs}}}
    page = results.pages({"proxy.json": rep})["proxy.md"]
    assert "- steps: the local preview wins (50.0 mm against 52.0 mm; the app alone 40.0 mm: the steering made it " \
           "worse)." in page
    assert "below the app alone on 0 of 1 paths" in page
    assert "+4 % to +4 % of the error" in page and "deviation coordinates" not in page


def test_the_proxy_page_says_which_of_three_previews_wins_and_how_much_the_file_matched():
    """A report with the path-file flight (its preview's counts) and the steering in deviation coordinates: each
    path's winner among the three previews, from the figures; the file's matched share beside its flight; the best
    steered flight in the headline; what deviation coordinates make of a preview."""
    def file_run(truth: float, matched: int, losses: int) -> dict:
        r = _proxy_run(truth, truth - 1.0, 1000)
        r["proxy"]["steering"] = {"mode": "steer", "ticks": 1000, "model_mismatch": 0, "prediction_watch": None,
                                  "preview": {"kind": "file", "matched": matched, "fallback": 1000 - matched,
                                              "losses": losses}}
        return r

    paths = {"helix": {"direct": {**_proxy_run(40.0, 39.0), "proxy": None}, "steer_local": _proxy_run(12.0, 11.0, 990),
                       "steer_delay": _proxy_run(10.0, 9.0, 1000, 0.5), "steer_file": file_run(6.0, 900, 0)},
             "steps": {"direct": {**_proxy_run(40.0, 39.0), "proxy": None}, "steer_local": _proxy_run(20.0, 19.0, 990),
                       "steer_delay": _proxy_run(30.0, 29.0, 1000, 0.5), "steer_file": file_run(25.0, 450, 2)}}
    rep = {"ardupilot": {"setup": "lab", "collect": {"path": "wander", "seconds": 60, "dither_m": 0.05,
                                                     "coordinates": "deviation"}, "paths": paths}}
    page = results.pages({"proxy.json": rep})["proxy.md"]
    assert ("- helix: the path file wins (6.0 mm against 12.0 mm (the local preview) and 10.0 mm (the declared "
            "delay); the app alone 40.0 mm).") in page
    assert ("- steps: the local preview wins (20.0 mm against 30.0 mm (the declared delay) and 25.0 mm (the path "
            "file); the app alone 40.0 mm).") in page
    assert "| helix | steered, path file (90 % of ticks matched, 0 losses) | 6.0 | 5.0 | 2.0 | 6.67 |" in page
    assert "| steps | steered, path file (45 % of ticks matched, 2 losses) | 25.0 |" in page
    assert "The path file (the same preview without the delay) against the local guess: -50 % to +25 %" in page
    assert "not flown" not in page and "the local preview and the path file steer alike" in page
    assert "| helix | steered, path file | 1000 | 1000 | 1000 |" in page  # its messages and latency row
    index = results.pages({"proxy.json": rep})["index.md"]
    assert "| helix | 40.0 | 6.0 (steered, path file) | 6.67 |" in index


def _run(cond: dict, estimator: str = "") -> dict:
    """One setup's run of one autopilot (the ellipse flight's loop figures and one condition)."""
    return {"rate_hz": 200.0, "missed_ticks": 0, "engaged_fraction": 0.99, "engaged_share": 0.98, "fallbacks": 0,
            "wall_s": 600.0, "latency_us": {"p50": 2300.0, "p99": 4700.0}, "conditions": {"steps": cond},
            "setup": {"estimator": estimator}}


def test_the_sitl_page_shows_both_setups_side_by_side_and_says_which_figure_judges():
    """A synthetic report with PX4 flown outdoors and in the lab: the page names the lab's true height as the
    judged figure, puts both setups' steered, best simple fix and measurement error in one table, renders the lab's
    own tables (the EKF's error beside the mocap's), and the headline is the lab's."""
    lab_cond = {"rmse_z": {"passthrough": 0.05, "ctrl_ff": 0.03, "prefilter": 0.02, "ilc": None, "steered": 0.004},
                "rmse_z_truth": {"passthrough": 0.051, "ctrl_ff": 0.031, "prefilter": 0.021, "ilc": None,
                                 "steered": 0.0045},
                "estimator_rms": {"steered": 0.0012}, "ekf_rms": {"steered": 0.116}}
    lab = _run(lab_cond, "the motion capture itself")
    sitl = {"px4": {**_run(SITL_COND), "lab": lab}}
    page = results_sitl.sitl_page(sitl)
    assert "## Which figure judges the steering" in page and "The true height in the **lab** setup judges" in page
    assert "| the ellipse flight | PX4 | PX4 lab |" in page
    assert "| engaged share of the trajectory's ticks [%] | 98.0 | 98.0 |" in page
    # side by side: outdoor steered 113.1 vs the prefilter's 107.0, the EKF 111.9 off; lab 4.5 vs 21.0, 1.2 off
    assert "| steps | 113.1 | 107.0 (prefilter) | 111.9 | 4.5 | 21.0 (prefilter) | 1.2 |" in page
    assert page.index("### True height RMSE") < page.index("### Lab: True height RMSE")
    assert "### Lab: Height RMSE on the lab setup's measured height" in page
    assert "(the loop's measurement: the motion capture itself)" in page
    assert "| steps | 1.2 | -- | 3.75 | 116.0 |" in page  # the mocap's error, the EKF's beside
    index = results.index_page({"sitl.json": sitl})
    assert "The lab setup (the height measured on the motion capture)." in index
    assert "| steps | 51.0 | 21.0 (prefilter) | 4.5 | 0.21 | 3.75 |" in index
    # a report without a lab run: the outdoor page, saying the lab one is not flown
    outdoor = results_sitl.sitl_page({"px4": _run(SITL_COND)})
    assert "Only the outdoor setup is flown here (`make sitl-demo --setups lab`" in outdoor and "Lab:" not in outdoor
    # a lab-only entry (no outdoor run stored yet): only the lab's tables
    only_lab = results_sitl.sitl_page({"px4": {"lab": lab}})
    assert "| the ellipse flight | PX4 lab |" in only_lab and "### True height RMSE" not in only_lab


def test_the_proxy_page_gives_the_repeated_failsafe_trials_and_the_interval_of_their_difference():
    arm = lambda m: {"n": 10, "mean_s": m, "median_s": m - 0.001, "std_s": 0.0061, "min_s": m - 0.02,  # noqa: E731
                     "max_s": m + 0.03}
    rep = {"px4": {"setup": "outdoor", "collect": {}, "paths": {},
                   "failsafe_repeats": {"app_rate_hz": 50.0, "stream_s": 1.5, "trials": [{}] * 20,
                                        "params": {"COM_OBL_RC_ACT": 5.0, "COM_OF_LOSS_T": 1.0},
                                        "proxy_last_out_s": [-0.00024, None, 0.0004],
                                        "stats": {"direct": arm(1.04), "proxy": arm(1.0452), "mean_diff_s": 0.0052,
                                                  "ci95_s": [-0.0004, 0.0108], "ci_method": "Welch t",
                                                  "target_s": 0.03, "verdict": "within target"}}}}
    page = results.pages({"proxy.json": rep})["proxy.md"]
    assert "over 20 trials of one flight" in page and "COM_OBL_RC_ACT 5 (Hold), COM_OF_LOSS_T 1.0 s" in page
    assert "| direct | 10 | 1040.0 | 1039.0 | 6.1 | 1020-1070 |" in page
    assert "| proxy | 10 | 1045.2 | 1044.2 | 6.1 | 1025-1075 |" in page
    assert ("Through the proxy minus direct: +5.2 ms (95 % interval -0.4 to +10.8 ms, Welch t); the issue's target, "
            "within 30 ms (one app period + 10 ms): shown (the interval lies inside +-30 ms)") in page
    assert "against the app's own stamp after its last send: -0.24 to +0.40 ms." in page
    rep["px4"]["failsafe_repeats"]["stats"]["verdict"] = "unresolved"
    assert "not resolved (the interval crosses +-30 ms" in results.pages({"proxy.json": rep})["proxy.md"]


def test_the_proxy_page_gives_the_share_the_jerk_guard_paused():
    runs = {"direct": {**_proxy_run(88.0, 87.0), "proxy": None}, "steer_local": _proxy_run(83.0, 82.0, 990),
            "steer_delay": _proxy_run(40.0, 39.0, 1000, 0.5)}
    for k, n, preview in (("steer_local", 550, 0.0), ("steer_delay", 620, 0.5)):
        runs[k]["proxy"]["steering"] = {"mode": "steer", "ticks": 1000, "model_mismatch": 0, "beyond_jerk": n,
                                        "prediction_watch": None,
                                        "jerk_bound": {"max_jerk": 5.0, "preview_s": preview, "jumps": 24,
                                                       "smoothed": 700 if preview else 0}}
    rep = {"ardupilot": {"setup": "lab", "collect": {"path": "wander", "seconds": 60, "dither_m": 0.05},
                         "paths": {"steps": runs}}}
    page = results.pages({"proxy.json": rep})["proxy.md"]
    assert "| steps | steered, local preview | 83.0 | 82.0 | 2.0 | 1.06 | -- | 55 % (24 jumps) |" in page
    assert "| steps | steered, delay 0.5 s | 40.0 | 39.0 | 2.0 | 2.20 | -- | 62 % (24 jumps, 700 setpoints spread) |" \
        in page
