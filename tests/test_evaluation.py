"""Evaluation: confidence intervals on known data, the CI unit of a group (episodes, or >= 3 training
seeds), normalised scores, and batched rollouts of checkpoints that match one-env-at-a-time rollouts."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from mop_core.config import ConfigError, InputFileError
from mop_core.evaluation import episode_seeds, run_jobs
from mop_core.experiment.catalogue import Job
from mop_core.experiment.study import EvalConfig
from mop_core.policies import load_policy
from mop_core.statistics import (
    confidence_interval,
    improvement_summary,
    iqm_summary,
    paired_difference,
    ratio_to_teacher,
    summarise_group,
)
from mop_core.teacher_policies import load_teacher
from mop_core.walker.rollout import episode_returns


def test_confidence_interval_on_known_data():
    ci = confidence_interval([1.0, 2.0, 3.0, 4.0, 5.0])
    # mean 3, sd sqrt(2.5), t_{0.975, 4} = 2.776445
    half = 2.7764451051977987 * np.sqrt(2.5) / np.sqrt(5)
    assert ci["mean"] == 3.0 and ci["std"] == pytest.approx(np.sqrt(2.5)) and ci["n"] == 5
    assert ci["ci_low"] == pytest.approx(3 - half) and ci["ci_high"] == pytest.approx(3 + half)
    x = np.random.default_rng(0).normal(100, 20, size=7)
    low, high = stats.t.interval(0.95, 6, loc=x.mean(), scale=stats.sem(x))
    ci = confidence_interval(x)
    assert (ci["ci_low"], ci["ci_high"]) == pytest.approx((low, high))
    assert confidence_interval([4.0])["ci_low"] is None
    assert confidence_interval([2.0, 2.0])["ci_low"] == confidence_interval([2.0, 2.0])["ci_high"] == 2.0


def test_a_policy_trained_once_gets_an_interval_over_its_episodes():
    returns = np.array([100.0, 300.0, 200.0, 400.0, 250.0, 150.0])
    s = summarise_group({0: returns})
    expected = confidence_interval(returns)
    assert s["ci_unit"] == "episode" and s["n"] == 6 and s["episodes"] == 6
    assert (s["mean"], s["ci_low"], s["ci_high"]) == pytest.approx((expected["mean"], expected["ci_low"],
                                                                      expected["ci_high"]))
    assert s["seed_means"] == {"0": pytest.approx(233.333333)} and "runs" not in s


def test_two_training_seeds_pool_their_episodes_and_list_the_seed_means():
    """Two seeds whose means agree by chance must not get a narrow 'interval over seeds' (t(0.975, 1) = 12.7
    makes it meaningless either way): the interval is over the pooled episodes, with n saying so."""
    a, b = np.array([100.0, 400.0, 150.0, 450.0]), np.array([120.0, 380.0, 140.0, 460.0])
    s = summarise_group({0: a, 1: b})
    pooled = confidence_interval(np.concatenate([a, b]))
    assert s["ci_unit"] == "episode" and s["n"] == 8 and s["train_seeds"] == [0, 1]
    assert (s["ci_low"], s["ci_high"]) == pytest.approx((pooled["ci_low"], pooled["ci_high"]))
    assert s["seed_means"] == {"0": 275.0, "1": 275.0}
    assert s["runs"]["1"]["n"] == 4 and s["runs"]["1"]["ci_unit"] == "episode"
    assert s["ci_high"] - s["ci_low"] > 100  # the episodes' spread, not the seeds' agreement


def test_three_or_more_training_seeds_get_an_interval_over_the_seeds():
    runs = {seed: np.full(4, 100.0 * (seed + 1)) + np.arange(4) for seed in range(3)}
    s = summarise_group(runs)
    expected = confidence_interval([r.mean() for r in runs.values()])
    assert s["ci_unit"] == "training_seed" and s["n"] == 3 and s["episodes"] == 12
    # a return is >= 0: the t-interval over 3 seeds reaches below 0 here, so it is cut there and flagged
    assert expected["ci_low"] < 0 and s["ci_low"] == 0.0 and s["cut_at_bound"]
    assert s["ci_high"] == pytest.approx(expected["ci_high"])
    wide = summarise_group({seed: np.full(4, 500.0 + seed) for seed in range(3)})
    assert not wide["cut_at_bound"] and wide["ci_low"] == pytest.approx(confidence_interval([500, 501, 502])["ci_low"])


def test_normalised_scores_map_the_mean_and_interval():
    s = summarise_group({0: np.array([110.0, 530.0, 320.0])}, random_return=110.0, expert_return=530.0)
    z = s["normalised"]
    assert z["mean"] == pytest.approx(50.0)
    assert z["ci_low"] == pytest.approx(100 * (s["ci_low"] - 110) / 420)
    assert z["ci_high"] == pytest.approx(100 * (s["ci_high"] - 110) / 420)


def test_a_student_is_compared_with_the_teacher_run_it_learned_from():
    teacher = summarise_group({0: np.array([100.0, 120.0]), 1: np.array([300.0, 320.0])})
    student = summarise_group({0: np.array([150.0, 180.0])})
    assert ratio_to_teacher(student, teacher, teacher_seed=0) == pytest.approx(165.0 / 110.0)
    assert ratio_to_teacher(student, teacher, teacher_seed=1) == pytest.approx(165.0 / 310.0)
    assert ratio_to_teacher(student, teacher) == pytest.approx(165.0 / 210.0)  # a baseline: the teachers' mean
    with pytest.raises(ValueError, match="teacher_seed: 2 is not among"):
        ratio_to_teacher(student, teacher, teacher_seed=2)


def test_iqm_and_improvement_summaries_name_their_unit_and_sizes():
    rng = np.random.default_rng(0)
    good = {"stand": rng.normal(60, 10, 30), "walk": rng.normal(40, 10, 30)}
    bad = {"stand": rng.normal(30, 10, 15), "walk": rng.normal(10, 10, 15)}
    summary = iqm_summary(good, reps=200, seed=0)
    assert summary["tasks"] == "stand, walk" and summary["runs_per_task"] == 30
    assert summary["ci_low"] < summary["value"] < summary["ci_high"]
    assert summary["ci_unit"] == "runs, stratified by task"
    better = improvement_summary(good, bad, reps=200, seed=0)
    assert (better["runs_x"], better["runs_y"]) == (30, 15) and better["ci_low"] > 0.5
    with pytest.raises(ValueError, match="same number of runs per task"):
        iqm_summary({"stand": np.zeros(3), "walk": np.zeros(4)}, reps=10, seed=0)


def test_fewer_than_three_runs_get_no_interval():
    one_run = {"stand": np.array([40.0]), "walk": np.array([60.0])}
    summary = iqm_summary(one_run, reps=200, seed=0)
    assert summary["value"] == pytest.approx(50.0) and summary["ci_low"] is None and summary["ci_high"] is None
    three = {"stand": np.array([70.0, 75.0, 80.0]), "walk": np.array([65.0, 70.0, 90.0])}
    versus_one = improvement_summary(three, one_run, reps=200, seed=0)
    assert versus_one["value"] == 1.0 and versus_one["ci_low"] is None  # one teacher run: no interval
    assert improvement_summary(three, three, reps=200, seed=0)["ci_low"] is not None


def test_the_eval_aggregates_score_each_run_by_its_mean_over_episodes():
    """rliable's unit: 3 runs x 15 episodes are 3 scores per task, not 45 (the bootstrap resamples runs)."""
    from mop_core.eval_study import run_scores

    rng = np.random.default_rng(1)
    scores = {"g": {"stand": {s: rng.normal(50 + 10 * s, 30, 15) for s in range(3)}}}
    assert run_scores(scores, "g", "stand") == {s: pytest.approx(scores["g"]["stand"][s].mean()) for s in range(3)}
    assert list(run_scores(scores, "g", "stand", seed=1)) == [1]


def test_groups_sharing_seeds_are_compared_paired_by_seed():
    x = {"stand": {0: 10.0, 1: 20.0, 2: 30.0}, "walk": {0: 12.0, 1: 22.0, 2: 32.0}}
    y = {"stand": {0: 9.0, 1: 18.0, 2: 29.0, 3: 0.0}, "walk": {0: 11.0, 1: 20.0, 2: 30.0}}
    d = paired_difference(x, y)  # per seed: mean over tasks of x - y = 1, 2, 1.5 (seed 3 is not paired)
    expected = confidence_interval([1.0, 2.0, 1.5])
    assert d["n"] == 3 and d["seeds"] == "0, 1, 2" and d["ci_unit"] == "paired_seed"
    assert (d["mean"], d["ci_low"], d["ci_high"]) == pytest.approx((1.5, expected["ci_low"], expected["ci_high"]))
    two = paired_difference({"stand": {0: 1.0, 1: 2.0}}, {"stand": {0: 0.0, 1: 0.0}})
    assert two["n"] == 2 and two["ci_low"] is None  # under 3 seeds: no interval


def test_eval_config_needs_two_episodes_for_an_interval_and_a_known_action_rule():
    with pytest.raises(ConfigError, match="episodes: expected an integer >= 2"):
        EvalConfig(episodes=1)
    with pytest.raises(ConfigError, match="gaussian_student_action: expected one of"):
        EvalConfig(gaussian_student_action="mode")


def test_batched_jobs_equal_single_env_rollouts_with_the_same_episode_seeds(tiny_teachers):
    checkpoints, _ = tiny_teachers
    config = EvalConfig(episodes=4, rollout_envs=3, workers=2)
    seeds = episode_seeds(0, config)
    assert seeds == episode_seeds(0, config) and seeds != episode_seeds(1, config) and len(seeds) == 4
    jobs = [Job("teacher", 0, checkpoints[("stand", "deterministic")], "stand"),
            Job("cross", 0, checkpoints[("stand", "deterministic")], "walk")]
    results = run_jobs(jobs, seeds, 50, config)
    assert [r.shape for r in results] == [(4,), (4,)]
    policy = load_teacher(checkpoints[("stand", "deterministic")]).act
    for job, result in zip(jobs, results):
        single = episode_returns(policy, job.eval_task, seeds, 50, num_envs=1)
        np.testing.assert_allclose(result, single, rtol=1e-6)


def test_a_checkpoint_of_unknown_kind_is_rejected(tmp_path):
    import torch

    torch.save({"kind": "oracle"}, tmp_path / "x.pt")
    with pytest.raises(InputFileError, match="x.pt: not a policy checkpoint of this study .kind 'oracle'"):
        load_policy(tmp_path / "x.pt")


def test_a_teacher_groups_iqm_pools_the_studys_tasks_and_a_student_groups_all_of_its_tasks(tiny_params):
    """A substitute's teachers share their kind's group name (stand_still's own teacher, on stand's data, is
    in teacher_from_stand_..., with walk's OQS teacher): their IQM keeps to the study's tasks; the substitute
    set's students pool theirs."""
    from mop_core.eval_study import iqm_tasks
    from mop_core.experiment.catalogue import build_catalogue

    catalogue = build_catalogue(tiny_params)
    tasks = ["walk", "stand_still"]
    assert iqm_tasks("teacher_from_stand_medium_deterministic", tasks, catalogue) == ["walk"]
    assert iqm_tasks("student_mse-mop_stand_still-medium", ["stand_still", "walk"], catalogue) == [
        "stand_still", "walk"]
    assert iqm_tasks("multitask_medium", ["stand", "walk"], catalogue) == ["stand", "walk"]
