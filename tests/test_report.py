"""The report renders from results alone: numbers come from the inputs, figures it links exist, and a
study without some stages says which instead of failing or showing nothing. (The tiny `dvc repro`
in test_pipeline.py renders it from a real run.)"""

from __future__ import annotations

import re

import pytest

from mop_core.evaluation import confidence_interval
from mop_core.report import Run, StudyResults, render_report, seed_band

TASKS = ["stand", "walk"]


def _curve(values: list[float], key: str = "return_mean") -> list[dict[str, str]]:
    return [{"step": str(1000 * (k + 1)), key: str(v)} for k, v in enumerate(values)]


def _entry(mean: float, n: int = 3, unit: str = "eval_seed") -> dict:
    return {"mean": mean, "ci_low": mean - 10, "ci_high": mean + 10, "n": n, "ci_unit": unit, "std": 5.0}


def _full_results() -> StudyResults:
    teachers = [Run({"task": t, "level": "medium", "actor": "deterministic"}, 0, {"return_mean": 400.0},
                    _curve([100.0, 300.0])) for t in TASKS]
    multitask = [Run({"level": "medium"}, 0, {}, [r | {"return_mean_walk": "150"} for r in
                                                  _curve([120.0, 250.0], "return_mean_stand")])]
    students = [Run({"loss": "mse", "pairing": "medium"}, seed, {"per_state_tau": {
        "probe_states_per_task": 8, "at_init": {"layer1": 0.9}, "final": {"layer1": 0.5}}},
        [r | {"return_mean_walk": "200", "action_mse_stand": "0.1", "action_mse_walk": "0.2"}
         for r in _curve([300.0 + seed, 390.0 + seed], "return_mean_stand")]) for seed in (0, 1)]
    evaluation = {task: {"behaviour_medium": _entry(250.0), "behaviour_expert": _entry(600.0),
                         "teacher_medium_deterministic": _entry(404.55), "multitask_medium": _entry(222.2),
                         "student_mse_medium": _entry(426.1, 2, "training_seed")} for task in TASKS}
    evaluation["cross_task"] = {"medium": {"stand": {"stand": 404.6, "walk": 88.6},
                                           "walk": {"stand": 286.6, "walk": 205.1}}}
    layer = {"per_state_tau_mean": 0.617, "per_state_tau_sd": 0.139, "average_tau": -0.016,
             "average_tau_seed_sd": 0.007, "linear_cka": 0.996, "linear_cka_seed_sd": 0.0}
    shared = {"note": "tau-b corrects for ties", "episodes_per_task": 10,
              "groups": {"mse_medium": {"students": 2, "pairs": {"stand-walk": {"layer1": layer}},
                                        "untrained": {"pairs": {"stand-walk": {"layer1": {
                                            "per_state_tau": {"mean": 0.811, "sd": 0.05}, "average_tau": 0.2,
                                            "linear_cka": 0.999}}}}}},
              "students": {"mse-medium-0": {"zero_fraction": {"stand": {"layer1": 0.53}, "walk": {"layer1": 0.5}}}}}
    return StudyResults(
        tasks=TASKS, levels=["medium"], settings={"summary": "tiny", "snapshot_eval_episodes": 10},
        collect={t: {"medium_gradient_steps": 35000, "medium_return": 336.4, "expert_gradient_steps": 90000,
                     "expert_return": 560.9} for t in TASKS},
        datasets={f"{t}-medium": {"transitions": 1000, "complete_episodes": 1, "return_mean": 313.8,
                                  "return_std": 59.5, "return_min": 146.1, "return_max": 476.7} for t in TASKS},
        teachers=teachers, multitask=multitask, students=students, pairing_levels={"medium": ["medium", "medium"]},
        evaluation=evaluation, shared=shared)


def test_report_shows_the_runs_numbers_in_thesis_order_and_draws_the_figures_it_links(tmp_path):
    markdown = render_report(_full_results(), tmp_path / "report", "report/")
    assert "404.6 [394.6, 414.6]" in markdown  # teacher eval with its CI, from the eval metrics
    assert "0.617 +- 0.139" in markdown and "0.996" in markdown  # Table 6.1 row
    assert "| mse_medium, untrained copy | stand-walk | 1 | 0.811 +- 0.050 | 0.200 | 0.999 | - |" in markdown
    assert "| medium | walk teacher | 286.6 | 205.1 |" in markdown  # Table 6.3 row
    assert "the walk teacher (205.1)" in markdown
    assert "1.05" in markdown  # student / teacher = 426.1 / 404.55
    order = [markdown.index(t) for t in ("Table 4.1", "Figure 5.1", "Figure 5.3", "Figure 5.4", "Appendix E",
                                         "Table 6.1", "Table 6.3")]
    assert order == sorted(order)
    assert "Not part of this run" not in markdown
    for link in re.findall(r"!\[[^\]]*\]\((report/[^)]+)\)", markdown):
        assert (tmp_path / link).read_bytes()[:4] == b"\x89PNG"
    assert {p.name for p in (tmp_path / "report").iterdir()} == {"teachers.png", "multitask.png", "losses.png"}


def test_sections_of_stages_not_run_say_so(tmp_path):
    results = StudyResults(tasks=TASKS, levels=["medium"], settings={})
    markdown = render_report(results, tmp_path / "report", "report/")
    for stage in ("collect", "train_teachers", "train_multitask", "distill", "shared_computation"):
        assert f"Not part of this run: the {stage} stage" in markdown
    assert "Not part of this run: cross-task evaluation" in markdown
    partial = _full_results()
    partial.multitask, partial.shared = [], None
    markdown = render_report(partial, tmp_path / "partial", "partial/")
    assert markdown.count("Not part of this run") == 2 and "0.617" not in markdown


def test_learning_curve_band_is_the_t_interval_over_seeds_at_common_steps():
    curves = [_curve([1.0, 2.0, 9.0]), _curve([3.0, 4.0])]
    band = seed_band(curves, "return_mean")
    assert band["step"] == [1000.0, 2000.0] and band["mean"] == [2.0, 3.0]
    assert band["ci_low"][0] == pytest.approx(confidence_interval([1.0, 3.0])["ci_low"])
    single = seed_band(curves[:1], "return_mean")
    assert single["ci_low"] is None and single["mean"] == [1.0, 2.0, 9.0]
    assert seed_band(curves, "missing") is None
