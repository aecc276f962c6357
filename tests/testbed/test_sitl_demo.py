"""make sitl-demo / make sitl-adapt's command-line plumbing: comma lists, the autopilots a run can fly."""

from __future__ import annotations

import pytest

from ddpc_codegen.testbed.sitl_demo import available_autopilots, comma_list, main


def test_comma_lists_drop_blanks_and_spaces():
    assert comma_list(" steps, wind,,heavy ") == ["steps", "wind", "heavy"] and comma_list(" , ") == []


def test_a_missing_sitl_is_said_and_skipped(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("DDPC_PX4_SITL", str(tmp_path / "no_px4"))
    monkeypatch.setenv("DDPC_ARDUPILOT_SITL", str(tmp_path / "no_arducopter"))
    assert available_autopilots(None, "sitl-x") == [] and available_autopilots(["px4"], "sitl-x") == []
    out = capsys.readouterr().out.splitlines()
    assert [ln.split(":")[0] for ln in out] == ["[sitl-x] px4", "[sitl-x] ardupilot", "[sitl-x] px4"]
    assert all(": skipped: " in ln for ln in out)


def test_rescore_without_a_run_names_the_missing_report(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["--rescore", "--out", str(tmp_path)])
    assert e.value.code == 2 and f"{tmp_path / 'sitl.json'} not found" in capsys.readouterr().err
