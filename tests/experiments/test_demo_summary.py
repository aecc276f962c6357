"""make demo's summary.json writer (ddpc_codegen.experiments.demo.write_summary): another target's section survives."""

from __future__ import annotations

import json

from ddpc_codegen.experiments.demo import write_summary


def test_a_demo_run_keeps_adapt_evals_section_and_replaces_its_own(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"flying": {"old": 1}, "adaptation": {"conditions": {"push": 1}}, "stale": 2}))
    write_summary(path, {"flying": {"new": 2}, "meta": {"wall_time_s": 1.0}})
    got = json.loads(path.read_text())
    assert got == {"flying": {"new": 2}, "meta": {"wall_time_s": 1.0}, "adaptation": {"conditions": {"push": 1}}}


def test_without_a_file_or_with_a_broken_one_it_writes_the_demo_alone(tmp_path):
    path = tmp_path / "summary.json"
    write_summary(path, {"flying": {}})
    assert json.loads(path.read_text()) == {"flying": {}}
    path.write_text("{not json")
    write_summary(path, {"hopping": {}})
    assert json.loads(path.read_text()) == {"hopping": {}}
