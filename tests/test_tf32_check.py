"""benchmarks/tf32_check.py: a TF32 study against its fp32 twin, from their results directories."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
from tf32_check import Placed, compare, main, redraw_inside, report  # noqa: E402

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
    assert result.cells == [Placed("ds_degrades_expert: stand", 2.0, -1.0, 1.0, 3)]  # walk: no interval
    assert not result.cells[0].inside
    assert result.groups == [Placed("stand: student_mse_medium", 480.0, 400.0, 500.0, 3)]  # episodes: not runs
    assert result.groups[0].inside
    text = report(result)
    assert text.startswith("# TF32 against fp32: passed")
    assert "finding effects inside the fp32 run's 95% interval: 0 of 1 (0%; another draw of the runs: ~91%)" in text
    assert "| ds_degrades_expert: stand | 2 | [-1, 1] | 3 |" in text


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
    assert result.cells and all(row.inside for row in result.cells)
    assert result.groups and all(row.inside for row in result.groups)
