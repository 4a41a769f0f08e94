"""benchmarks/tf32_check.py: a TF32 study against its fp32 twin, from their results directories."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
from tf32_check import Placed, compare, main, redraw_inside, report, trained_in  # noqa: E402

RECORD = ROOT / "record" / "evidence" / "results"  # a finished study (the evidence record)


def _trained(root: Path, precision: str) -> None:
    """A student timing record as a CUDA run in ``precision`` writes it (``cpu``: a CPU run's)."""
    (root / "timings" / "students").mkdir(parents=True, exist_ok=True)
    record = {"seconds": 1.0, "device": "cpu"} if precision == "cpu" else {
        "seconds": 1.0, "device": "cuda", "gpu": "H200", "cuda_matmul": precision}
    (root / "timings" / "students" / "mse-medium.json").write_text(json.dumps(record))


def _results(root: Path, verdict: str, effect: float, mean: float, precision: str) -> Path:
    """A results directory with one finding (three cells) and two evaluated groups, trained in ``precision``."""
    (root / "eval").mkdir(parents=True)
    cells = {"stand": {"value": effect, "ci_low": -1.0, "ci_high": 1.0, "n": 3, "unit": "paired training seeds"},
             "walk": {"value": 0.5, "ci_low": None, "ci_high": None, "n": 1, "unit": "training seeds"},
             "ref": {"value": 9.0, "ci_low": -1.0, "ci_high": 1.0, "n": 3,
                     "unit": "training seeds vs 15 episodes of the one run"}}  # not over runs: not placed
    (root / "verdicts.json").write_text(json.dumps({"findings": {"ds_degrades_expert": {
        "cells": cells, "verdict": verdict, "reason": "r"}}, "thesis_findings": {}}))
    groups = {"student_mse_medium": {"mean": mean, "ci_low": 400.0, "ci_high": 500.0, "ci_unit": "training_seed",
                                     "n": 3},
              "behaviour_medium": {"mean": 900.0, "ci_low": 0.0, "ci_high": 1.0, "ci_unit": "episode", "n": 15}}
    (root / "eval" / "metrics.json").write_text(json.dumps({"stand": groups, "aggregate": {"note": "x"}}))
    _trained(root, precision)
    return root


def test_the_same_verdicts_pass_and_the_numbers_are_placed_in_the_fp32_intervals(tmp_path):
    fp32 = _results(tmp_path / "a", "inconclusive", 0.0, 450.0, "fp32")
    tf32 = _results(tmp_path / "b", "inconclusive", 2.0, 480.0, "tf32")
    result = compare(fp32, tf32)
    assert result.passed and result.verdicts == [("ds_degrades_expert", "inconclusive", "inconclusive")]
    assert result.cells == [Placed("ds_degrades_expert: stand", 2.0, -1.0, 1.0, 3)]  # walk: no interval
    assert not result.cells[0].inside and result.unplaced == 1  # ref: against the one run
    assert result.groups == [Placed("stand: student_mse_medium", 480.0, 400.0, 500.0, 3)]  # episodes: not runs
    assert result.groups[0].inside
    text = report(result)
    assert text.startswith("# TF32 against fp32: passed") and "not a TF32 check" not in text
    assert ("finding effects over training runs inside the fp32 run's 95% interval: 0 of 1 (0%; another draw of "
            "the runs: ~91%) (1 cells of other units not placed)") in text
    assert "| ds_degrades_expert: stand | 2 | [-1, 1] | 3 |" in text


def test_a_flipped_verdict_fails_the_check_and_is_listed(tmp_path, capsys):
    fp32 = _results(tmp_path / "a", "inconclusive", 0.0, 450.0, "fp32")
    tf32 = _results(tmp_path / "b", "reproduced", 0.0, 450.0, "tf32")
    result = compare(fp32, tf32)
    assert not result.passed and result.flipped == [("ds_degrades_expert", "inconclusive", "reproduced")]
    with pytest.raises(SystemExit) as exit_:
        main(["compare", str(fp32), str(tf32)])
    assert exit_.value.code == 1
    out = capsys.readouterr().out
    assert out.startswith("# TF32 against fp32: FAILED") and "| ds_degrades_expert | inconclusive | reproduced |" in out


@pytest.mark.parametrize("first,second", [("cpu", "cpu"), ("fp32", "fp32"), ("tf32", "fp32")])
def test_studies_not_trained_in_fp32_then_tf32_on_cuda_are_not_a_tf32_check(tmp_path, first, second):
    """A CPU dry run, or a pair whose second study reused fp32 work, compares nothing TF32 did: it fails."""
    result = compare(_results(tmp_path / "a", "inconclusive", 0.0, 450.0, first),
                     _results(tmp_path / "b", "inconclusive", 0.0, 450.0, second))
    assert not result.passed and result.precisions == ({first}, {second}) and not result.flipped
    assert (f"**not a TF32 check**: the first study trained in {first}, the second in {second}"
            in report(result))


def test_a_study_with_a_stage_in_the_other_precision_is_not_a_tf32_check(tmp_path):
    tf32 = _results(tmp_path / "b", "inconclusive", 0.0, 450.0, "tf32")
    (tf32 / "timings" / "collect.json").write_text(json.dumps({"device": "cuda", "cuda_matmul": "fp32"}))
    assert trained_in(tf32) == {"fp32", "tf32"}
    assert not compare(_results(tmp_path / "a", "inconclusive", 0.0, 450.0, "fp32"), tf32).passed


def test_another_draws_chance_to_land_inside_a_t_interval_falls_to_the_normal_limit():
    """P(|t_{n-1}| < t_{n-1,0.975} / sqrt(2)): closed form for 2 degrees of freedom, x / sqrt(2 + x^2), and
    the normal limit P(|Z| < 1.96 / sqrt(2)) = 0.834; checked against a simulation of two draws at n = 5."""
    x = 4.302652729911275 / 2 ** 0.5  # t_{2,0.975} / sqrt(2)
    assert redraw_inside(3) == pytest.approx(x / (2 + x * x) ** 0.5, abs=1e-9)
    assert redraw_inside(10_000) == pytest.approx(0.8342, abs=1e-3)
    assert redraw_inside(3) > redraw_inside(5) > redraw_inside(30) > redraw_inside(10_000)
    rng = np.random.default_rng(0)
    first, second = rng.normal(size=(200_000, 5)), rng.normal(size=(200_000, 5))
    half = 2.7764451051977987 * first.std(axis=1, ddof=1) / 5 ** 0.5  # t_{4,0.975}
    share = np.mean(np.abs(second.mean(axis=1) - first.mean(axis=1)) <= half)
    assert share == pytest.approx(redraw_inside(5), abs=0.005)
    with pytest.raises(ValueError, match="n: expected at least 2 runs, got 1"):
        redraw_inside(1)


def test_a_missing_or_mismatched_results_directory_is_named(tmp_path):
    fp32 = _results(tmp_path / "a", "inconclusive", 0.0, 450.0, "fp32")
    (tmp_path / "b" / "timings").mkdir(parents=True)
    with pytest.raises(SystemExit, match=r"b/timings: no timing record of a training stage"):
        compare(fp32, tmp_path / "b")
    _trained(tmp_path / "b", "tf32")
    with pytest.raises(SystemExit, match=r"b/verdicts.json: missing; expected a finished study's results"):
        compare(fp32, tmp_path / "b")
    other = _results(tmp_path / "c", "inconclusive", 0.0, 450.0, "tf32")
    (other / "verdicts.json").write_text(json.dumps({"findings": {"tau_rises": {"cells": {}, "verdict": "x"}}}))
    with pytest.raises(SystemExit, match=r"expected the findings of .*\['ds_degrades_expert', 'tau_rises'\]"):
        compare(fp32, other)


def test_a_run_refuses_an_existing_out_directory_before_running_anything(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["run", "--profile", str(ROOT / "profiles" / "tiny.yaml"), "--out", str(tmp_path)])
    assert exit_.value.code == 2 and f"--out: {tmp_path} exists" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def _record_as(root: Path, precision: str) -> Path:
    """The evidence record's verdicts and evaluation, as if a CUDA study in ``precision`` had written them."""
    (root / "eval").mkdir(parents=True)
    shutil.copy(RECORD / "verdicts.json", root / "verdicts.json")
    shutil.copy(RECORD / "eval" / "metrics.json", root / "eval" / "metrics.json")
    _trained(root, precision)
    return root


def test_on_the_evidence_records_numbers_a_flipped_verdict_and_a_moved_mean_are_found(tmp_path):
    """The record's own files (45 findings, every cell unit it writes) against a copy: equal, then with one
    verdict flipped and one group's mean moved past its interval."""
    assert trained_in(RECORD) == {"cpu"}  # the record ran on 2 CPU cores: not a TF32 study
    fp32, tf32 = _record_as(tmp_path / "a", "fp32"), _record_as(tmp_path / "b", "tf32")
    same = compare(fp32, tf32)
    assert same.passed and len(same.verdicts) == 45 and same.unplaced > 0
    assert same.cells and all(row.inside for row in same.cells)
    assert same.groups and all(row.inside for row in same.groups)
    verdicts = json.loads((tf32 / "verdicts.json").read_text())
    finding = sorted(verdicts["findings"])[0]
    verdicts["findings"][finding]["verdict"] = "moved"
    (tf32 / "verdicts.json").write_text(json.dumps(verdicts))
    metrics = json.loads((tf32 / "eval" / "metrics.json").read_text())
    group = same.groups[0].name.split(": ")[1]
    task = same.groups[0].name.split(": ")[0]
    metrics[task][group]["mean"] = same.groups[0].high + 1.0
    (tf32 / "eval" / "metrics.json").write_text(json.dumps(metrics))
    moved = compare(fp32, tf32)
    assert not moved.passed and [f[0] for f in moved.flipped] == [finding]
    assert [row.name for row in moved.groups if not row.inside] == [same.groups[0].name]
