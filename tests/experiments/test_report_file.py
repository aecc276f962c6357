"""Shared JSON reports (ddpc_codegen.experiments.report_file): a target replaces its sections, keeps the others'."""

from __future__ import annotations

import json

import pytest

from ddpc_codegen.experiments.report_file import nan_as_null, update_report


def test_a_demo_run_keeps_adapt_evals_section_and_replaces_its_own(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"flying": {"old": 1}, "adaptation": {"conditions": {"push": 1}}}))
    update_report(path, {"flying": {"new": 2}, "meta": {"wall_time_s": 1.0}})
    got = json.loads(path.read_text())
    assert got == {"flying": {"new": 2}, "adaptation": {"conditions": {"push": 1}}, "meta": {"wall_time_s": 1.0}}


def test_a_new_file_holds_the_updates_alone(tmp_path):
    path = tmp_path / "sub" / "summary.json"
    assert update_report(path, {"flying": {}}) == {"flying": {}}
    assert json.loads(path.read_text()) == {"flying": {}}


@pytest.mark.parametrize("text", ["{not json", "[1, 2]"])
def test_a_file_that_is_not_a_json_object_is_refused_and_left_alone(tmp_path, text):
    path = tmp_path / "summary.json"
    path.write_text(text)
    with pytest.raises(ValueError, match="summary.json"):
        update_report(path, {"flying": {}})
    assert path.read_text() == text


def test_the_sitl_default_writes_other_objects_as_their_text(tmp_path):
    path = tmp_path / "sitl.json"
    update_report(path, {"px4": {"log": tmp_path}}, default=nan_as_null)
    assert json.loads(path.read_text()) == {"px4": {"log": str(tmp_path)}}
    assert nan_as_null(float("nan")) is None
