"""The report renders from results alone: numbers come from the inputs, figures it links exist, and a
study without some stages says which instead of failing or showing nothing. (The tiny `dvc repro`
in test_pipeline.py renders it from a real run.)"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path
from types import SimpleNamespace

import pytest

from mop_core.experiment.runs import StudentRun
from mop_core.experiment.variants import SHARING_VARIANTS
from mop_core.report.document import render_report
from mop_core.report.format import seed_band
from mop_core.report.results import Run, StudyResults
from mop_core.statistics import confidence_interval

TASKS = ["stand", "walk"]


def _curve(values: list[float], key: str = "return_mean") -> list[dict[str, str]]:
    return [{"step": str(1000 * (k + 1)), key: str(v)} for k, v in enumerate(values)]


def _entry(mean: float, n: int = 30, unit: str = "episode", seeds: tuple[int, ...] = (0,)) -> dict:
    entry = {"mean": mean, "ci_low": mean - 10, "ci_high": mean + 10, "n": n, "ci_unit": unit, "std": 5.0,
             "seed_means": {str(s): mean + s for s in seeds},
             "normalised": {"mean": mean / 10, "ci_low": mean / 10 - 1, "ci_high": mean / 10 + 1}}
    if len(seeds) > 1:
        entry["runs"] = {str(s): {"mean": mean + s, "ci_low": mean + s - 20, "ci_high": mean + s + 20, "n": n,
                                  "ci_unit": "episode", "normalised": {"mean": (mean + s) / 10, "ci_low": 0.0,
                                                                       "ci_high": 100.0}} for s in seeds}
    return entry


def _full_results() -> StudyResults:
    teachers = [Run({"task": t, "level": "medium", "actor": "deterministic"}, 0, {"return_mean": 400.0},
                    _curve([100.0, 300.0])) for t in TASKS]
    multitask = [Run({"level": "medium"}, 0, {}, [r | {"return_mean_walk": "150", "grad_cosine": c,
                                                       "grad_cosine_stand-walk": c} for r, c in
                                                  zip(_curve([120.0, 250.0], "return_mean_stand"), ("-0.2", "0.1"))])]
    students = [Run({"loss": "mse", "pairing": "medium"}, seed, {"per_state_tau": {
        "probe_source": "offline", "probe_states_per_task": 8,
        "at_init": {"per_state_tau_a_layer1": 0.6, "per_state_tau_b_layer1": 0.9},
        "final": {"per_state_tau_a_layer1": 0.3, "per_state_tau_b_layer1": 0.5}}},
        [r | {"return_mean_walk": "200", "action_mse_stand": "0.1", "action_mse_walk": "0.2",
              "grad_cosine_stand-walk": str(0.3 + 0.1 * seed)}
         for r in _curve([300.0 + seed, 390.0 + seed], "return_mean_stand")]) for seed in (0, 1)]
    evaluation = {task: {"behaviour_medium": _entry(250.0), "behaviour_expert": _entry(600.0),
                         "teacher_medium_deterministic": _entry(404.55), "multitask_medium": _entry(222.2),
                         "student_mse_medium": _entry(426.1, 60, seeds=(0, 1)),
                         "student_mse_medium_to_teacher": 426.1 / 404.55} for task in TASKS}
    evaluation["eval"] = {"gaussian_student_action": "mean", "episodes_per_job": 30}
    evaluation["normalisation"] = {t: {"random_return": 130.0, "random_episodes": 100, "expert_return": 986.8,
                                       "expert_source": "UTDS task.json"} for t in TASKS}
    interval = {"value": 41.5, "ci_low": 38.2, "ci_high": 44.9, "reps": 2000, "tasks": "stand, walk",
                "runs_per_task": 3, "ci_unit": "runs, stratified by task"}
    evaluation["aggregate"] = {
        "iqm_normalised": {"student_mse_medium": interval,
                           "teacher_medium_deterministic": interval | {"ci_low": None, "ci_high": None,
                                                                      "runs_per_task": 1, "value": 33.3}},
        "probability_of_improvement": {
            "student_mse_medium_vs_teachers": interval | {"value": 1.0, "ci_low": None, "ci_high": None, "runs_x": 2,
                                                          "runs_y": 1},
            "student_mse_medium_vs_student_q_medium": interval | {"value": 0.61, "ci_low": 0.52, "ci_high": 0.7,
                                                                  "runs_x": 3, "runs_y": 3}},
        "paired_difference": {"student_mse_medium_vs_student_q_medium": {
            "mean": 12.5, "ci_low": 2.5, "ci_high": 22.5, "n": 3, "seeds": "0, 1, 2", "ci_unit": "paired_seed"}},
        "note": "IQM note"}
    def cross(mean):
        return {"mean": mean, "ci_low": mean - 10, "ci_high": mean + 10, "n": 20, "ci_unit": "episode"}
    evaluation["cross_task"] = {"medium": {"stand": {"stand": cross(404.6), "walk": cross(88.6),
                                                     "stand_still": cross(380.2)},
                                           "walk": {"stand": cross(286.6), "walk": cross(205.1),
                                                    "stand_still": cross(3.1)}}}
    layer = {"per_state_tau_a_mean": 0.452, "per_state_tau_a_sd": 0.101, "per_state_tau_b_mean": 0.617,
             "per_state_tau_b_sd": 0.139, "average_tau_a": -0.011, "average_tau_a_seed_sd": 0.005,
             "average_tau_b": -0.016, "average_tau_b_seed_sd": 0.007, "linear_cka": 0.996, "linear_cka_seed_sd": 0.0,
             "procrustes": 0.812, "procrustes_seed_sd": 0.011, "debiased_cka": 0.934, "debiased_cka_seed_sd": 0.02,
             "selectivity_mean": 0.081, "selectivity_mean_seed_sd": 0.01, "selective_share": 0.047,
             "selective_share_seed_sd": 0.003}
    shared = {"note": "tau-b corrects for ties", "episodes_per_task": 10,
              "groups": {"mse_medium": {"students": 2, "pairs": {"stand-walk": {"layer1": layer}},
                                        "untrained": {"pairs": {"stand-walk": {"layer1": {
                                            "per_state_tau_a": {"mean": 0.701, "sd": 0.04},
                                            "per_state_tau_b": {"mean": 0.811, "sd": 0.05}, "average_tau_a": 0.15,
                                            "average_tau_b": 0.2, "linear_cka": 0.999}}}}}},
              "students": {"mse-medium-0": {"zero_fraction": {"stand": {"layer1": 0.53}, "walk": {"layer1": 0.5}},
                                            "dormant": {"stand": {"layer1": {"0.0": 0.02, "0.1": 0.125}}}}}}
    return StudyResults(
        tasks=TASKS, levels=["medium"], settings={"summary": "tiny", "snapshot_eval_episodes": 10, "teacher_seed": 0},
        collect={t: {"medium_gradient_steps": 35000, "medium_return": 336.4, "expert_gradient_steps": 90000,
                     "expert_return": 560.9} for t in TASKS},
        datasets={f"{t}-medium": {"transitions": 1000, "complete_episodes": 1, "return_mean": 313.8,
                                  "return_std": 59.5, "return_min": 146.1, "return_max": 476.7} for t in TASKS},
        teachers=teachers, multitask=multitask, students=students, pairing_levels={"medium": ["medium", "medium"]},
        evaluation=evaluation, shared=shared,
        figures={"tau_during_training": "shared_computation/tau_during_training.png"})


def test_report_shows_the_runs_numbers_in_thesis_order_and_draws_the_figures_it_links(tmp_path):
    markdown = render_report(_full_results(), tmp_path / "report", "report/")
    assert "404.6 [394.6, 414.6] (n=30 episodes)" in markdown  # teacher eval with its CI and unit
    assert "426.1 [416.1, 436.1] (n=60 episodes of 2 seeds)" in markdown and "426.1 / 427.1" in markdown
    assert "40.5 [39.5, 41.5]" in markdown  # the teacher's normalised score
    assert "0.452 +- 0.101" in markdown and "0.617 +- 0.139" in markdown and "0.996" in markdown  # Table 6.1
    assert "-0.011 / -0.016" in markdown  # average tau-a / tau-b
    # an untrained copy measured before the measures beyond CKA existed: n/a, not an error
    assert "| mse_medium, untrained copy | stand-walk | 1 | 0.701 +- 0.040 | 0.811 +- 0.050 | 0.150 / 0.200 | " \
           "0.999 | n/a | n/a | n/a / n/a | - |" in markdown
    assert "| 0.812 (sd 0.011) | 0.934 (sd 0.020) | 0.081 / 0.047 | 2 |" in markdown  # Procrustes, debiased CKA, eta^2
    assert "mse-medium-0 stand: 0.02, 0.12" in markdown  # dead, dormant share
    assert ("| medium | walk teacher | 286.6 [276.6, 296.6] (n=20 episodes) | 205.1 [195.1, 215.1] (n=20 episodes) "
            "| 3.1 [-6.9, 13.1] (n=20 episodes) |") in markdown  # Table 6.3 row with the transfer task's column
    assert "stand_still: not a study task (`eval.transfer_tasks`): no study teacher trains on it." in markdown
    assert "margin 0.5 m/s" in markdown
    assert "medium stand_still: the stand teacher (380.2)" in markdown
    assert "the walk teacher (205.1)" in markdown
    assert "1.05" in markdown  # student / teacher = 426.1 / 404.55
    assert "41.5 [38.2, 44.9]" in markdown and "0.61 [0.52, 0.70]" in markdown  # IQM and P(X > Y) over runs
    assert "| teacher_medium_deterministic | stand, walk | 1 | 33.3 (no interval: fewer than 3 runs) |" in markdown
    assert "| student_mse_medium | teachers | 2 x 1 | 1.00 (no interval: fewer than 3 runs) |" in markdown
    assert "| student_mse_medium | student_q_medium | 0, 1, 2 | 12.5 [2.5, 22.5] (n=3 seeds) |" in markdown
    assert "R_random 130.0 (100 uniformly random episodes" in markdown
    assert "pooled over 2 training seeds" in markdown and "evaluation episodes of one trained policy" in markdown
    assert "KL students act by their mean" in markdown and "tau-a" in markdown
    assert "fixed probe set of offline dataset states" in markdown and "0.600 -> 0.300" in markdown
    order = [markdown.index(t) for t in ("Table 4.1", "Figure 5.1", "Figure 5.3", "Figure 5.4", "Appendix E",
                                         "IQM", "Table 6.1", "Table 6.3")]
    assert order == sorted(order)
    assert "Not part of this run" not in markdown
    for link in re.findall(r"!\[[^\]]*\]\((report/[^)]+)\)", markdown):
        assert (tmp_path / link).read_bytes()[:4] == b"\x89PNG"
    assert {p.name for p in (tmp_path / "report").iterdir()} == {"teachers.png", "multitask.png", "losses.png",
                                                                 "gradient_conflict.png"}
    # the gradient-conflict curves: the lowest mean cosine along training, and the final one
    assert "| multi-task actor, medium | stand-walk | -0.200 | 0.100 (1 seed, no interval) |" in markdown
    assert "| mse students, medium | stand-walk | 0.350 | 0.350 (2 seeds, no interval) |" in markdown


def test_every_interval_cell_says_its_unit():
    markdown = render_report(_full_results(), Path(tempfile.mkdtemp()) / "report", "report/")
    cells = re.findall(r"\d+\.\d \[-?\d+\.\d, -?\d+\.\d\][^|]*", markdown)
    raw = [c for c in cells if not c.strip().endswith("]")]  # normalised columns sit beside a raw cell
    assert raw and all("(n=" in c for c in raw)


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
    assert band["ci_low"] is None  # two seeds: the mean only (t(0.975, 1) = 12.7 is no interval)
    three = seed_band(curves + [_curve([5.0, 6.0])], "return_mean")
    assert three["mean"] == [3.0, 4.0]
    assert three["ci_low"][0] == pytest.approx(confidence_interval([1.0, 3.0, 5.0])["ci_low"])
    single = seed_band(curves[:1], "return_mean")
    assert single["ci_low"] is None and single["mean"] == [1.0, 2.0, 9.0]
    assert seed_band(curves, "missing") is None


def _student(variant: str, seed: int, substitute: str = "") -> StudentRun:
    """The catalogue's typed run of a data-sharing student (its teachers do not matter here)."""
    return StudentRun("mse", "medium", seed, (), SHARING_VARIANTS[variant], substitute=substitute)


def test_the_data_sharing_section_shows_figure_6_9_table_6_2_and_the_q_switch_shares(tmp_path):
    from mop_core.report.sharing import sharing_section
    results = _full_results()
    evaluation = results.evaluation
    for task, other in (("stand", "walk"), ("walk", "stand")):
        evaluation[task] |= {"teacher_ds_medium_deterministic": _entry(500.0),
                             f"teacher_from_{other}_medium_deterministic": _entry(300.0),
                             "student_mse-ds_medium": _entry(480.0, 3, "training_seed", (0, 1, 2)),
                             "student_mse-oqs_own_medium": _entry(350.0, 3, "training_seed", (0, 1, 2))}
    shares = {"stand": {"stand": 0.7, "walk": 0.3}, "walk": {"stand": 0.1, "walk": 0.9}}
    results.variants = [Run({"loss": "mse", "variant": variant, "pairing": "medium"}, seed,
                            {"q_switch": shares} if variant == "oqs_own" else {}, [], _student(variant, seed))
                        for variant in ("ds", "oqs_own") for seed in (0, 1, 2)]
    layer = results.shared["groups"]["mse_medium"]["pairs"]["stand-walk"]["layer1"]
    results.shared["groups"]["mse-ds_medium"] = {"students": 3, "pairs": {"stand-walk": {
        "layer1": layer | {"per_state_tau_a_mean": 0.61}, "layer2": layer | {"per_state_tau_a_mean": 0.72}}}}
    markdown = sharing_section(results, tmp_path / "fig", "fig/")
    assert (tmp_path / "fig" / "sharing.png").read_bytes()[:4] == b"\x89PNG"
    assert "| medium | stand | DS teacher | 500.0 [490.0, 510.0] (n=30 episodes) | 50.0 [49.0, 51.0] | 1.24 |" \
        in markdown  # / the MOP teacher's 404.55
    assert "| medium | walk | OQS teacher on D_stand->walk | 300.0" in markdown
    assert "| medium | stand | DS student | 480.0 [470.0, 490.0] (n=3 seeds)" in markdown
    # without member records the group mean alone; with them, a t-interval over the students
    # Table 6.2: the average tau (the thesis's measure, 6.2.3) beside the thesis's value, per-state tau apart
    assert "| medium | DS | stand-walk | 1 | -0.011 | 0.520 | 0.610 | 0.101 | 0.617 | 0.081 | 3 |" in markdown
    assert "| medium | DS | stand-walk | 2 | -0.011 | 0.670 | 0.720 | 0.101 | 0.617 | 0.081 | 3 |" in markdown
    assert "| medium | MOP | stand-walk | 1 | -0.011 | 0.067 | 0.452 | 0.101 | 0.617 | 0.081 | 2 |" in markdown
    assert "thesis Table 6.2 (average tau-a)" in markdown and "not Table 6.2's measure" in markdown
    students = {f"mse-ds-medium-{seed}": {"pairs": {"stand-walk": {
        layer: {"per_state_tau_a": {"mean": tau_a}, "per_state_tau_b": {"mean": tau_a + 0.1},
                "average_tau_a": tau_a - 0.4}
        for layer in ("layer1", "layer2")}}} for seed, tau_a in enumerate((0.5, 0.6, 0.7))}
    results.shared["students"] = students
    results.shared["groups"]["mse-ds_medium"]["members"] = list(students)
    results.shared["groups"]["mse-single_medium"] = {"students": 3, "members": [], "no_sharing": "...", "pairs": {
        "stand-walk": {"layer1": layer | {"per_state_tau_a_mean": 0.05}}}}
    markdown = sharing_section(results, tmp_path / "fig", "fig/")
    half = 0.1 * 4.302652729911275 / 3 ** 0.5  # t(0.975, 2) * sd / sqrt(3)
    assert (f"| medium | DS | stand-walk | 1 | 0.200 [{0.2 - half:.3f}, {0.2 + half:.3f}] | 0.520 | "
            f"0.600 [{0.6 - half:.3f}, {0.6 + half:.3f}] | 0.101 | "
            f"0.700 [{0.7 - half:.3f}, {0.7 + half:.3f}] | 0.081 | 3 |") in markdown
    assert "| medium | no sharing (single-task students) | stand-walk | 1 | -0.011 | n/a | 0.050 | 0.101 |" in markdown
    assert "| medium | OQS (own critics) | stand | D_stand->stand: 0.700, D_walk->stand: 0.300 |" in markdown
    empty = sharing_section(_full_results(), tmp_path / "fig", "fig/")
    assert "Not part of this run: the data-sharing students" in empty


def test_the_sharing_section_repeats_figure_6_9_and_table_6_2_on_a_substitutes_task_set(tmp_path):
    """{stand_still, walk}: stand_still's MOP teacher is its teacher on D_stand->stand_still (an eval group of
    teachers on stand's data), its students the set's 'mop', 'ds', 'oqs_own' groups."""
    from mop_core.report.sharing import sharing_section
    results = _full_results()
    results.evaluation["stand_still"] = {"teacher_from_stand_medium_deterministic": _entry(600.0),
                                         "teacher_from_walk_medium_deterministic": _entry(60.0),
                                         "student_mse-mop_stand_still-medium": _entry(540.0, 3, "training_seed",
                                                                                     (0, 1, 2)),
                                         "student_mse-oqs_own_stand_still-medium": _entry(300.0, 3, "training_seed",
                                                                                         (0, 1, 2))}
    results.evaluation["walk"] |= {"student_mse-mop_stand_still-medium": _entry(450.0, 3, "training_seed", (0, 1, 2))}
    shares = {"stand_still": {"stand": 0.4, "walk": 0.6}, "walk": {"stand": 0.2, "walk": 0.8}}
    results.substitutes = [Run({"loss": "mse", "variant": variant, "pairing": "medium", "substitute": "stand_still"},
                               seed, {"q_switch": shares} if variant == "oqs_own" else {}, [],
                               _student(variant, seed, "stand_still"))
                           for variant in ("mop", "oqs_own") for seed in (0, 1, 2)]
    layer = results.shared["groups"]["mse_medium"]["pairs"]["stand-walk"]["layer1"]
    results.shared["groups"]["mse-oqs_own_stand_still-medium"] = {"students": 3, "pairs": {"stand_still-walk": {
        "layer1": layer | {"per_state_tau_a_mean": 0.33}}}}
    markdown = sharing_section(results, tmp_path / "fig", "fig/")
    second = markdown[markdown.index("### Second task set: {stand_still, walk} (stand_still on stand's data)"):]
    assert (tmp_path / "fig" / "sharing_stand_still.png").read_bytes()[:4] == b"\x89PNG"
    assert "| medium | stand_still | MOP teacher | 600.0 [590.0, 610.0] (n=30 episodes)" in second
    assert "| medium | stand_still | OQS teacher on D_walk->stand_still | 60.0" in second and "| 0.10 |" in second
    assert "| medium | stand_still | MOP student | 540.0 [530.0, 550.0] (n=3 seeds)" in second
    assert "| medium | walk | MOP student | 450.0" in second
    assert "| medium | OQS (own critics) | stand_still-walk | 1 | -0.011 | n/a | 0.330 |" in markdown  # no thesis value
    assert "| medium | OQS (own critics) | stand_still | D_stand->stand_still: 0.400, D_walk->stand_still: 0.600 |" \
        in markdown
    from mop_core.report.document import cross_task_section
    results.evaluation["cross_task"] = {"medium": {task: {"stand": _entry(400.0), "stand_still": _entry(100.0)}
                                                   for task in TASKS}}
    assert "(stand_still: section 7b's second task set trains on it, from its base task's data)" in \
        cross_task_section(results)


def test_the_header_says_when_the_study_multiplies_in_tf32(tiny_params):
    from mop_core.report.load import settings

    assert "TF32" not in settings(tiny_params)["summary"]  # fp32, every profile's choice: nothing to say
    tf32 = {**tiny_params, "study": {**tiny_params["study"], "cuda_matmul": "tf32"}}
    assert settings(tf32)["summary"].endswith("; CUDA float32 matmuls in TF32 (study.cuda_matmul: faster and coarser "
                                              "than fp32, no effect on a CPU; benchmarks/tf32_check.py compares a "
                                              "study with its fp32 twin)")


def test_the_header_names_what_no_interval_covers(tiny_params):
    """The intervals vary training seeds only: the header says the behaviour data and the students' teacher
    seed are held fixed, and where the machine's float path is written."""
    from mop_core.report.document import header
    from mop_core.report.load import settings

    params = {**tiny_params, "distill": {**tiny_params["distill"], "teacher_seed": 2}}
    text = header(SimpleNamespace(settings=settings(params), tasks=["stand", "walk"], levels=["medium"]))
    assert "**What no interval covers.**" in text and "(train_teachers seed 2)" in text
    assert "one TD3 run per task" in text and "results/timings/collect.json" in text
