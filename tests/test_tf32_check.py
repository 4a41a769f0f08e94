"""benchmarks/tf32_check.py: a TF32 study against its fp32 twin, from their results directories."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
from tf32_check import compare, main, report  # noqa: E402

RECORD = ROOT / "record" / "evidence" / "results"  # a finished study (the evidence record)


def _results(root: Path, verdict: str, effect: float, mean: float) -> Path:
    """A results directory with one finding (two cells) and two evaluated groups."""
    (root / "eval").mkdir(parents=True)
    cells = {"stand": {"value": effect, "ci_low": -1.0, "ci_high": 1.0, "n": 3},
             "walk": {"value": 0.5, "ci_low": None, "ci_high": None, "n": 1}}  # under 3 runs: no interval
    (root / "verdicts.json").write_text(json.dumps({"findings": {"ds_degrades_expert": {
        "cells": cells, "verdict": verdict, "reason": "r"}}, "thesis_findings": {}}))
    groups = {"student_mse_medium": {"mean": mean, "ci_low": 400.0, "ci_high": 500.0, "ci_unit": "training_seed",
                                     "n": 3},
              "behaviour_medium": {"mean": 900.0, "ci_low": 0.0, "ci_high": 1.0, "ci_unit": "episode", "n": 15}}
    (root / "eval" / "metrics.json").write_text(json.dumps({"stand": groups, "aggregate": {"note": "x"}}))
    return root


def test_the_same_verdicts_pass_and_the_numbers_are_placed_in_the_fp32_intervals(tmp_path):
    fp32 = _results(tmp_path / "a", "inconclusive", 0.0, 450.0)
    tf32 = _results(tmp_path / "b", "inconclusive", 2.0, 480.0)
    result = compare(fp32, tf32)
    assert result.passed and result.verdicts == [("ds_degrades_expert", "inconclusive", "inconclusive")]
    assert result.cells == [("ds_degrades_expert: stand", 2.0, -1.0, 1.0, False)]  # walk: no interval
    assert result.groups == [("stand: student_mse_medium", 480.0, 400.0, 500.0, True)]  # episodes: not runs
    text = report(result)
    assert text.startswith("# TF32 against fp32: passed")
    assert "finding effects inside the fp32 run's 95% interval: 0 of 1 (0%)" in text
    assert "| ds_degrades_expert: stand | 2 | [-1, 1] |" in text


def test_a_flipped_verdict_fails_the_check_and_is_listed(tmp_path, capsys):
    fp32 = _results(tmp_path / "a", "inconclusive", 0.0, 450.0)
    tf32 = _results(tmp_path / "b", "reproduced", 0.0, 450.0)
    result = compare(fp32, tf32)
    assert not result.passed and result.flipped == [("ds_degrades_expert", "inconclusive", "reproduced")]
    with pytest.raises(SystemExit) as exit_:
        main(["compare", str(fp32), str(tf32)])
    assert exit_.value.code == 1
    out = capsys.readouterr().out
    assert out.startswith("# TF32 against fp32: FAILED") and "| ds_degrades_expert | inconclusive | reproduced |" in out


def test_a_missing_or_mismatched_results_directory_is_named(tmp_path):
    fp32 = _results(tmp_path / "a", "inconclusive", 0.0, 450.0)
    with pytest.raises(SystemExit, match=r"b/verdicts.json: missing; expected a finished study's results"):
        compare(fp32, tmp_path / "b")
    other = tmp_path / "c"
    _results(other, "inconclusive", 0.0, 450.0)
    (other / "verdicts.json").write_text(json.dumps({"findings": {"tau_rises": {"cells": {}, "verdict": "x"}}}))
    with pytest.raises(SystemExit, match=r"expected the findings of .*\['ds_degrades_expert', 'tau_rises'\]"):
        compare(fp32, other)


def test_a_run_refuses_an_existing_out_directory_before_running_anything(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["run", "--profile", str(ROOT / "profiles" / "tiny.yaml"), "--out", str(tmp_path)])
    assert exit_.value.code == 2 and f"--out: {tmp_path} exists" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_the_evidence_record_against_itself_keeps_every_verdict_and_number():
    result = compare(RECORD, RECORD)
    assert result.passed and len(result.verdicts) == 45
    assert result.cells and all(row[4] for row in result.cells)
    assert result.groups and all(row[4] for row in result.groups)
