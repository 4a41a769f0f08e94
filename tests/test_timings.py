"""Timing records (results/timings/) and the headline metrics (results/metrics.json)."""

from __future__ import annotations

import json

import torch

from mop_core.report.headline import headline_metrics
from mop_core.storage.timings import stage_time_table, write_timing


def test_a_timing_record_has_the_seconds_the_extras_and_the_machine(tmp_path):
    record = write_timing(tmp_path / "t.json", 12.345, "cpu", steps=10, steps_per_second=0.8)
    assert json.loads((tmp_path / "t.json").read_text()) == record
    assert record["seconds"] == 12.3 and record["steps"] == 10 and record["device"] == "cpu"
    assert record["threads"] >= 1 and record["cpus"] >= 1 and "torch==" in record["versions"] and record["cpu"]
    assert record["cpu_capability"] == torch.backends.cpu.get_cpu_capability() != ""  # AVX512 on this machine


def test_the_time_table_sums_matrix_runs_in_pipeline_order(tmp_path):
    write_timing(tmp_path / "eval.json", 5.0)
    write_timing(tmp_path / "collect.json", 100.0)
    for name, seconds in (("a", 10.0), ("b", 20.5)):
        write_timing(tmp_path / "teachers" / f"{name}.json", seconds)
    rows = stage_time_table(tmp_path).splitlines()
    assert rows[2:5] == ["| collect | 1 | 100 |", "| teachers | 2 | 30 |", "| eval | 1 | 5 |"]
    assert rows[-1].startswith("| **total** | | **136**")


def test_the_headline_keeps_groups_and_layers_and_leaves_out_cross_task_groups_and_absent_parts():
    evaluation = {"stand": {"student_mse_medium": {"normalised": {"mean": 41.234}, "mean": 400.0},
                            "student_mse_medium_to_teacher": 0.9,
                            "cross_medium_walk": {"normalised": {"mean": 3.0}}},
                  "normalisation": {"stand": {"random_return": 1.0}}}
    shared = {"groups": {"mse_medium": {"pairs": {"stand-walk": {
        "layer1": {"per_state_tau_a_mean": 0.123456, "per_state_tau_b_mean": 0.2},
        "layer2": {"per_state_tau_a_mean": 0.05, "per_state_tau_b_mean": 0.07}}}}}}
    out = headline_metrics(evaluation, shared, ["stand"])
    assert out["normalised_return"] == {"student_mse_medium": {"stand": 41.23}}
    assert out["per_state_tau_a"] == {"mse_medium": {"stand-walk": {"layer1": 0.1235, "layer2": 0.05}}}
    assert out["per_state_tau_b"]["mse_medium"]["stand-walk"]["layer2"] == 0.07
    assert headline_metrics(None, None, ["stand"]) == {}
