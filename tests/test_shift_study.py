"""mop_core/shift/study.py and mop_core/report/shift.py: the state_shift stage's measures and tables,
the state-shift students' names, configs and place in the catalogue (mop_core/experiment/variants.py,
mop_core/experiment/runs.py, mop_core/experiment/catalogue.py) and the stage's table rows
(mop_core/shift/results.py)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from trajectories import ar1_episodes

from mop_core.data import LEVELS
from mop_core.distill.config import distill_config
from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.variants import VARIANTS, Composed, Corrected, Ranking, Size, Width
from mop_core.report.shift import shift_section
from mop_core.shift.results import describe, shift_stage, student_groups
from mop_core.shift.study import (
    MeasureConfig,
    correction_table,
    effective_share,
    measure_shift,
    read_states,
    student_table,
)
from mop_core.storage.layout import composed_file, dataset_file

CONFIG = MeasureConfig(states=1000, k=3, bootstrap=4, classifier_epochs=5, threads=1)


@pytest.fixture(scope="module")
def measured():
    rng = np.random.default_rng(0)
    teacher = rng.normal(size=(2000, 4))
    sets = {"same": rng.normal(size=(2000, 4)), "near": rng.normal(0.3, 1.0, size=(2000, 4)),
            "far": rng.normal(1.5, 1.0, size=(2000, 4))}
    return measure_shift(sets, teacher, CONFIG, seed=0)


def test_a_set_from_the_teachers_distribution_measures_as_its_null(measured):
    ref = measured["reference"]
    assert ref["kl_null_min"] <= ref["kl_null"] <= ref["kl_null_max"]
    same = measured["same"]
    assert abs(same["kl"] - ref["kl_null"]) < 0.1 and 0.4 < same["auc"] < 0.6 and same["ess"] > 0.8
    assert same["within_null"] and not measured["near"]["within_null"] and not measured["far"]["within_null"]
    assert ref["kl_states"] == 500 and ref["halves"] == 4 and same["states"] == 1000  # rows: their own episodes


def test_more_shift_ranks_higher_on_every_measure(measured):
    same, near, far = measured["same"], measured["near"], measured["far"]
    assert same["kl"] < near["kl"] < far["kl"] and far["kl_min"] > near["kl_max"]
    assert same["auc"] < near["auc"] < far["auc"] and far["auc"] > 0.85
    assert same["ess"] > near["ess"] > far["ess"]
    # KL of N(0, I) from N(mu, I) in 4-d is 4 mu^2 / 2: 0.18 and 4.5 nats; the estimate is in range
    assert 0.05 < near["kl"] < 0.4 and 2.5 < far["kl"] < 6


def test_episode_splits_read_one_process_within_its_null_and_a_shift_above_it():
    """The record before episode splits: the teacher's own rollouts (same process) read 30 nats against
    a row-split null of -1.25. Split by whole episodes, a second sample of the process reads within the
    null and a mean shift of 0.6 per axis above it; without episode ids (rows as episodes) the same
    sample does not."""
    teacher, teacher_ids = ar1_episodes(60, 0)
    same, same_ids = ar1_episodes(60, 1)
    shifted, shifted_ids = ar1_episodes(60, 2, shift=0.6)
    sets = {"same": same, "shifted": shifted}
    config = MeasureConfig(states=2000, k=3, bootstrap=8, classifier_epochs=5, threads=1)
    measured = measure_shift(sets, teacher, config, 0, {"reference": teacher_ids, "same": same_ids,
                                                        "shifted": shifted_ids})
    ref = measured["reference"]
    assert (ref["episodes"], ref["kl_episodes"], ref["kl_states"]) == (60, 30, 1000)
    assert measured["same"]["within_null"] and ref["kl_null_min"] <= measured["same"]["kl"] <= ref["kl_null_max"]
    assert not measured["shifted"]["within_null"] and measured["shifted"]["kl_min"] > ref["kl_null"]
    assert measured["same"]["above_null"] < 0.9 and measured["shifted"]["above_null"] == 1  # paired with each half
    assert abs(measured["same"]["kl_excess"]) < 0.5 < measured["shifted"]["kl_excess"]
    assert abs(measured["same"]["auc"] - 0.5) < 0.1 and measured["shifted"]["auc"] > 0.85
    rows = measure_shift({"same": same}, teacher, config, 0)  # the old row split: a null no other set reaches
    assert not rows["same"]["within_null"] and rows["same"]["auc"] > 0.7


def test_reweighting_weights_come_from_classifiers_that_did_not_see_their_episode():
    """mop_core.distill.corrections.density_weights, cross-fitted over whole episodes: the data's
    teacher-like episodes carry the weight, one process against itself reads AUC ~0.5, rows in dataset
    order are cut into their episodes when no ids are given, and a seed repeats its weights."""
    from mop_core.distill.corrections import ReweightConfig, block_episodes, density_weights

    teacher, teacher_ids = ar1_episodes(40, 0)
    data, data_ids = ar1_episodes(40, 1)
    data[500:] += 1.0  # 10 of 40 episodes from the teacher's process, the rest shifted
    config = ReweightConfig(clip=10.0, states=2000, epochs=10)
    weights, info = density_weights(data, teacher, config, seed=3, episode_rows=50)
    assert weights[:500].mean() > 10 * weights[500:].mean() and info["reweight_auc"] > 0.8  # 34x, 0.87
    again, _ = density_weights(data, teacher, config, seed=3, episodes=(data_ids, teacher_ids))
    assert np.array_equal(weights, again)  # blocks of 50 rows are these episodes; same seed, same weights
    assert block_episodes(2000, 50).tolist() == data_ids.tolist()
    assert block_episodes(100, 1000).max() >= 7  # MIN_BLOCKS (8) blocks at least
    same, _ = ar1_episodes(40, 2)
    assert abs(density_weights(same, teacher, config, seed=3, episode_rows=50)[1]["reweight_auc"] - 0.5) < 0.12


def test_read_states_numbers_each_datasets_episodes(monkeypatch):
    ends = np.zeros(6, dtype=bool)
    ends[[2, 5]] = True
    arrays = {"observations": np.arange(12.0).reshape(6, 2), "timeouts": ends, "terminals": np.zeros(6, dtype=bool)}
    monkeypatch.setattr("mop_core.shift.study.read_dataset", lambda path: type("D", (), {"arrays": arrays}))
    states, episodes = read_states({"reference": "r.hdf5", "online": "o.hdf5"})
    assert set(states) == {"reference", "online"} and states["online"].shape == (6, 2)
    assert episodes["reference"].tolist() == [0, 0, 0, 1, 1, 1]


def test_effective_share_of_weights():
    assert effective_share(np.ones(10)) == pytest.approx(1.0)
    assert effective_share(np.array([1.0] + [0.0] * 9)) == pytest.approx(0.1)


def _record(seed, stand, walk):
    """A distill run's record: its own final evaluation (which the table must not use) and action errors."""
    return {"seed": seed, **{task: {"return_mean": r + 1000, "student_to_teacher": 9.9, "teacher_return_mean": 1.0,
                                    "eval_episodes": 5, "action_mse": {"train": 0.1, "visited": 0.2}}
                             for task, r in (("stand", stand), ("walk", walk))}}


def test_student_table_reads_the_eval_stages_returns_and_its_teacher_run():
    norms = {"stand": {"random_return": 100.0, "expert_return": 1000.0},
             "walk": {"random_return": 0.0, "expert_return": 1000.0}}
    records = {"a": [_record(0, 400, 500), _record(1, 500, 600), _record(2, 600, 700)], "b": [_record(0, 400, 500)]}
    returns = {"a": {"stand": [400.0, 500.0, 600.0], "walk": [500.0, 600.0, 700.0]},
               "b": {"stand": [400.0], "walk": [500.0]}}
    table = student_table(records, returns, {"stand": 500.0, "walk": 400.0}, ("stand", "walk"), norms, 15)
    stand = table["a"]["stand"]
    assert stand["return"]["mean"] == pytest.approx(500) and stand["return"]["n"] == 3
    assert stand["return"]["ci_low"] < 500 < stand["return"]["ci_high"] and stand["seed_returns"] == [400, 500, 600]
    assert stand["normalised"]["mean"] == pytest.approx(100 * 400 / 900)
    assert stand["to_teacher"]["mean"] == pytest.approx(1.0) and stand["teacher_return"] == 500.0
    assert table["a"]["walk"]["to_teacher"]["mean"] == pytest.approx(1.5) and stand["episodes_per_seed"] == 15
    assert stand["action_mse"]["visited"]["mean"] == pytest.approx(0.2)  # errors: the distill runs' own
    assert table["b"]["walk"]["return"]["ci_low"] is None  # one seed: no interval over seeds
    wide = student_table({"c": records["a"]}, {"c": {"stand": [5.0, 400.0, 10.0], "walk": [1.0, 2.0, 3.0]}},
                         {"stand": 500.0, "walk": 400.0}, ("stand", "walk"), norms, 15)
    assert wide["c"]["stand"]["return"]["ci_low"] == 0.0 and wide["c"]["stand"]["return"]["cut_at_bound"]


def test_eval_returns_are_each_runs_seed_mean_and_the_teacher_runs_mean():
    from mop_core.shift.study import eval_returns

    run = type("Run", (), {})
    runs = [type("Run", (), {"group": "student_x", "seed": s})() for s in (0, 1)]
    evaluation = {"stand": {"student_x": {"seed_means": {"0": 10.0, "1": 20.0}},
                            "teacher_t": {"mean": 7.0, "runs": {"0": {"mean": 5.0}, "1": {"mean": 9.0}}}}}
    returns, teachers = eval_returns(evaluation, {"x": runs}, ["stand"], {"stand": "teacher_t"}, teacher_seed=1)
    assert returns == {"x": {"stand": [10.0, 20.0]}} and teachers == {"stand": 9.0} and run


def test_a_correction_gain_pairs_the_eval_returns_by_seed():
    from mop_core.shift.study import correction_table

    norms = {t: {"random_return": 0.0, "expert_return": 1000.0} for t in ("stand", "walk")}
    records = {"plain": [_record(s, 0, 0) for s in (0, 1, 2)], "fix": [_record(s, 0, 0) for s in (0, 1, 2)]}
    returns = {"plain": {"stand": [100.0, 200.0, 300.0], "walk": [1.0, 1.0, 1.0]},
               "fix": {"stand": [150.0, 260.0, 340.0], "walk": [1.0, 1.0, 1.0]}}
    table = student_table(records, returns, {"stand": 500.0, "walk": 500.0}, ("stand", "walk"), norms, 15)
    groups = {"plain": {"data": "random90", "width": 8, "percent": 100, "correction": "none"},
              "fix": {"data": "random90", "width": 8, "percent": 100, "correction": "reweight"}}
    gain = correction_table(table, records, groups, ("stand", "walk"))["fix"]
    assert gain["plain"] == "plain" and gain["seeds"] == [0, 1, 2]
    assert gain["stand"]["gain"]["mean"] == pytest.approx(50.0) and gain["stand"]["gain"]["n"] == 3
    assert gain["stand"]["to_teacher_gain"]["mean"] == pytest.approx(0.1)


def test_the_shift_variants_are_named_from_their_fields_and_change_one_setting(tiny_params):
    assert Composed("random99", 16).name == "on_random99_w16" and Size(10).name == "data10"
    assert Corrected("reweight", "random90", 64).name == "reweight_random90_w64"
    assert Corrected("dagger", "offline", 8).name == "dagger_offline_w8"
    assert {VARIANTS[f] for f in ("composed", "size", "corrected")} == {Composed, Size, Corrected}
    assert Composed("noise", 32) == Composed("noise", 32) != Composed("noise", 16)  # typed, hashable: group keys
    base = distill_config(tiny_params, "mse")
    wide = Composed("noise", 32).apply(base)
    assert wide.student.hidden_sizes == (32, 32) and wide.data_fraction == 1 and wide.correction == "none"
    assert Size(30).apply(base).data_fraction == pytest.approx(0.3)
    assert Size(30).apply(base).student == base.student
    corrected = Corrected("dagger", "noise", 32).apply(base)
    assert corrected.correction == "dagger" and corrected.student.hidden_sizes == (32, 32)
    assert Corrected("reweight", "offline", 16).apply(base).correction == "reweight"
    assert (Composed("noise", 8).composed, Corrected("dagger", "noise", 8).composed) == ("noise", "noise")
    assert Corrected("dagger", "offline", 8).composed == "" and Size(10).composed == ""  # the offline datasets
    assert (Corrected("reweight", "noise", 8).correction, Composed("noise", 8).correction) == ("reweight", "")


def test_each_table_row_is_described_by_its_variants_fields():
    row = {"data": "offline", "width": 256, "percent": 100, "correction": "none"}
    assert describe(None, 256) == row  # plain MOP: the offline data at its width
    assert describe(Width(16), 256) == row | {"width": 16}
    assert describe(Composed("noise", 32), 256) == row | {"data": "noise", "width": 32}
    assert describe(Size(10), 256) == row | {"percent": 10}
    assert describe(Corrected("dagger", "offline", 8), 256) == row | {"width": 8, "correction": "dagger"}
    assert describe(Corrected("reweight", "random90", 64), 256) == row | {"data": "random90", "width": 64,
                                                                       "correction": "reweight"}
    with pytest.raises(ValueError, match="ranking variant"):
        describe(Ranking("pairwise"), 256)


def test_the_table_rows_are_the_catalogues_students_references_first(tiny_params):
    catalogue = build_catalogue(tiny_params)
    groups = student_groups(catalogue, "medium", 16)
    assert list(groups) == ["offline_w16", "offline_w8", "on_online_w8", "on_random99_w8", "data50",
                            "reweight_random99_w8", "dagger_random99_w8"]
    plain, runs = groups["offline_w16"]
    assert plain is None and runs == [r for r in catalogue.mop_students() if r.loss == "mse"]
    assert groups["offline_w8"][0] == Width(8) and {r.variant for r in groups["offline_w8"][1]} == {Width(8)}
    assert [run for _, runs in list(groups.values())[2:] for run in runs] == list(catalogue.shift_students)
    assert list(student_groups(catalogue, "medium", 8)) == list(groups)[1:]  # width 8's row: the width students'
    assert student_groups(catalogue, "medium", 8)["offline_w8"][0] == Width(8)
    stage = shift_stage(tiny_params, catalogue)
    assert stage.active and stage.levels == ("medium", "medium") and stage.datasets == ("online", "random99")
    inputs = stage.inputs(Path("eval.json"))
    assert inputs["distill"] == [run.paths.metrics for _, runs in groups.values() for run in runs]
    assert composed_file("walk", "medium", "reference") in inputs["compose"] and inputs["eval"] == [Path("eval.json")]
    assert inputs["collect"] == [dataset_file(t, level) for t in ("stand", "walk") for level in LEVELS]
    params = copy.deepcopy(tiny_params)
    params["state_shift"].update(datasets=[], widths=[], data_percents=[], corrections=[], correction_datasets=[])
    idle = shift_stage(params, build_catalogue(params))
    assert not idle.active and not idle.measured_tasks and "pairing_levels" not in idle.start_metrics()


def test_the_shift_students_are_in_their_own_entries_and_eval_jobs(tiny_params):
    catalogue = build_catalogue(tiny_params)
    names = [run.name for run in catalogue.shift_students]
    assert names == ["mse-on_online_w8-medium-0", "mse-on_random99_w8-medium-0", "mse-data50-medium-0",
                     "mse-reweight_random99_w8-medium-0", "mse-dagger_random99_w8-medium-0"]
    composed = catalogue.shift_students[1]
    assert composed.composed == "random99" and composed.correction == ""
    assert composed.datasets == tuple(composed_file(task, "medium", "random99") for task in ("stand", "walk"))
    assert composed.heldout_datasets == tuple(composed_file(task, "medium", "random99_heldout")
                                              for task in ("stand", "walk"))
    assert composed.reference_datasets == ()
    assert catalogue.shift_students[2].datasets == (dataset_file("stand", "medium"), dataset_file("walk", "medium"))
    assert catalogue.shift_students[2].heldout_datasets == ()  # a dataset share's held-out: the rest of the data
    reweight, dagger = catalogue.shift_students[3:]
    assert (reweight.correction, reweight.composed, dagger.correction) == ("reweight", "random99", "dagger")
    assert reweight.reference_datasets == tuple(composed_file(task, "medium", "reference")
                                                for task in ("stand", "walk"))
    assert dagger.reference_datasets == () and dagger.heldout_datasets == composed.heldout_datasets
    assert set(reweight.input_datasets) == {*reweight.datasets, *reweight.heldout_datasets,
                                            *reweight.reference_datasets}
    assert {run.entry for run in catalogue.shift_students} <= set(catalogue.student_entries())
    jobs = {(job.group, job.train_seed, job.checkpoint, job.eval_task) for job in catalogue.eval_jobs()}
    # the eval stage rolls every shift student out on each of its tasks (every return in the report is eval's)
    assert {(run.group, run.seed, run.paths.checkpoint, task) for run in catalogue.shift_students
            for task in run.tasks} <= jobs
    assert not set(catalogue.shift_students) & set(catalogue.students)  # shared_computation: not theirs
    params = copy.deepcopy(tiny_params)
    params["state_shift"].update(datasets=[], widths=[], data_percents=[], corrections=[], correction_datasets=[])
    assert build_catalogue(params).shift_students == ()
    params["state_shift"].update(corrections=["dagger"], correction_datasets=["offline"])
    (offline,) = build_catalogue(params).shift_students
    assert offline.variant == Corrected("dagger", "offline", 8) and offline.composed == ""
    assert offline.heldout_datasets == ()
    assert offline.datasets == (dataset_file("stand", "medium"), dataset_file("walk", "medium"))


METRICS = {
    "pairing": "medium", "pairing_levels": {"stand": "medium", "walk": "medium"}, "student_width": 256,
    "measure": {"states": 10000, "k": 5, "bootstrap": 10},
    "shift": {t: {"reference": {"kl_null": 0.01, "kl_null_min": -0.1, "kl_null_max": 0.1, "halves": 10,
                                "kl_states": 5000},
                  "medium": {"kl": 2.0, "kl_min": 1.5, "kl_max": 2.5, "kl_excess": 1.99, "above_null": 1.0,
                             "within_null": False, "auc": 0.8, "ess": 0.3},
                  "online": {"kl": 0.02, "kl_min": -0.1, "kl_max": 0.1, "kl_excess": 0.01, "above_null": 0.5,
                             "within_null": True, "auc": 0.51, "ess": 0.97}}
              for t in ("stand", "walk")},
    "groups": {"offline_w256": {"data": "offline", "width": 256, "percent": 100},
               "on_online_w256": {"data": "online", "width": 256, "percent": 100},
               "data10": {"data": "offline", "width": 256, "percent": 10}},
    "hypothesis": {"256": {"stand": {"spearman": -0.5, "p_value": 0.3, "points": 5}}},
}


def _row(value):
    cell = {"mean": value, "ci_low": value - 10, "ci_high": value + 10, "n": 3}
    return {"return": cell, "to_teacher": {"mean": value / 500, "ci_low": None, "ci_high": None, "n": 3},
            "episodes_per_seed": 5}


METRICS["students"] = {label: {"seeds": [0, 1, 2], "stand": _row(v), "walk": _row(v + 1)}
                       for label, v in (("offline_w256", 400.0), ("on_online_w256", 450.0), ("data10", 300.0))}


def test_the_report_section_shows_every_measured_table():
    text = shift_section(METRICS, None, ("stand", "walk"), "state_shift/")
    assert "## 5b. State distribution shift (thesis 5.2)" in text
    assert "| stand | online | 0.02 [-0.10, 0.10] | 0.01 [-0.10, 0.10] | 0.01 (0.5 of halves above) | within | " \
        "0.510 | 0.970 |" in text
    assert "| walk | medium | 2.00 [1.50, 2.50] | 0.01 [-0.10, 0.10] | 1.99 (1.0 of halves above) | above |" in text
    assert "### Online vs offline states (thesis 5.2.3, Figure 5.7)" in text
    assert "| online | 450.0 [440.0, 460.0] (0.90) | 451.0 [441.0, 461.0] (0.90) |" in text
    assert "| 10% | 300.0 [290.0, 310.0] (0.60) |" in text and "| 100% | 400.0 [390.0, 410.0] (0.80) |" in text
    assert "width 256: stand rho = -0.50 (p = 0.30, 5 datasets)" in text
    assert "![capacity](state_shift/capacity.png)" in text
    assert "n=3 training seeds" in text


def test_the_report_says_when_the_state_shift_study_did_not_run():
    assert "Not part of this run" in shift_section(None, None, ("stand", "walk"), "state_shift/")


def _seeded(seed: int, stand: float, walk: float, errors: float) -> dict:
    record = _record(seed, stand, walk)
    for task in ("stand", "walk"):
        record[task]["action_mse"] = {"train": errors, "heldout": 2 * errors, "visited": 10 * errors}
    return record


def test_correction_gains_are_paired_by_seed_against_the_plain_students_of_the_same_data():
    records = {"on_random90_w256": [_seeded(s, 0, 0, 0.1) for s in range(3)],
               "reweight_random90_w256": [_seeded(s, 0, 0, 0.1) for s in range(3)],
               "dagger_random90_w16": [_seeded(s, 0, 0, 0.1) for s in range(3)]}  # no plain w16: no row
    returns = {"on_random90_w256": {"stand": [300.0, 310.0, 320.0], "walk": [200.0] * 3},
               "reweight_random90_w256": {"stand": [330.0, 340.0, 350.0], "walk": [190.0, 191.0, 192.0]},
               "dagger_random90_w16": {"stand": [400.0] * 3, "walk": [400.0] * 3}}
    groups = {"on_random90_w256": {"data": "random90", "width": 256, "percent": 100, "correction": "none"},
              "reweight_random90_w256": {"data": "random90", "width": 256, "percent": 100, "correction": "reweight"},
              "dagger_random90_w16": {"data": "random90", "width": 16, "percent": 100, "correction": "dagger"}}
    norms = {t: {"random_return": 0.0, "expert_return": 1000.0} for t in ("stand", "walk")}
    students = student_table(records, returns, {"stand": 500.0, "walk": 500.0}, ("stand", "walk"), norms, 15)
    table = correction_table(students, records, groups, ("stand", "walk"))
    assert list(table) == ["reweight_random90_w256"] and table["reweight_random90_w256"]["plain"] == "on_random90_w256"
    stand, walk = table["reweight_random90_w256"]["stand"]["gain"], table["reweight_random90_w256"]["walk"]["gain"]
    assert stand["mean"] == pytest.approx(30) and stand["ci_low"] == pytest.approx(30)  # the same gain every seed
    assert walk["mean"] == pytest.approx(-9) and walk["n"] == 3
    errors = students["on_random90_w256"]["stand"]["action_mse"]
    assert errors["visited"]["mean"] == pytest.approx(1.0) and errors["heldout"]["n"] == 3


def test_the_report_shows_action_errors_and_corrections():
    metrics = json.loads(json.dumps(METRICS))
    metrics["groups"]["reweight_online_w256"] = {"data": "online", "width": 256, "percent": 100,
                                                 "correction": "reweight"}
    metrics["students"]["reweight_online_w256"] = metrics["students"]["on_online_w256"]
    for row in metrics["students"].values():
        for task in ("stand", "walk"):
            row[task]["action_mse"] = {"train": {"mean": 0.1, "ci_low": 0.05, "ci_high": 0.15, "n": 3},
                                       "visited": {"mean": 0.9, "ci_low": 0.5, "ci_high": 1.3, "n": 3}}
    gain = {"mean": 12.0, "ci_low": 2.0, "ci_high": 22.0, "n": 3}
    weights = {"reweight_auc": 0.9, "reweight_ess_unclipped": 0.05, "reweight_ess": 0.3, "reweight_clipped_share": 0.02}
    metrics["corrections"] = {"reweight_online_w256": {
        "plain": "on_online_w256", "correction": "reweight", "data": "online", "width": 256, "seeds": [0, 1, 2],
        **{t: {"gain": gain, "to_teacher_gain": gain, "reweight": weights} for t in ("stand", "walk")}}}
    text = shift_section(metrics, None, ("stand", "walk"), "state_shift/")
    assert "### Where the students go wrong" in text
    assert "| online, width 256 | stand | 0.100 [0.050, 0.150] | - | 0.900 [0.500, 1.300] |" in text
    assert "### Correcting the shift: reweighting and DAgger" in text
    assert "| online, width 256, reweight | 450.0 [440.0, 460.0] (0.90) | 451.0 [441.0, 461.0] (0.90) | " \
           "12.0 [2.0, 22.0] | 12.0 [2.0, 22.0] |" in text
    assert "effective sample share 0.050 unclipped, 0.300 clipped (2.0% of states at the clip)" in text
    # the correcting students stay out of the plain tables (Figure 5.7's rows: the offline and online students)
    assert text.count("| online | 450.0") == 1
