"""Evaluation: confidence intervals on known data, the CI unit of a group, and batched rollouts of
checkpoints that match one-env-at-a-time rollouts."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from mop_core.config import ConfigError
from mop_core.evaluation import (
    EvalConfig,
    Job,
    PolicySpec,
    confidence_interval,
    episode_seeds,
    load_policy,
    run_jobs,
    summarise_group,
)
from mop_core.rollout import episode_returns
from mop_core.teachers import load_teacher


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


def test_group_ci_is_over_training_seeds_when_there_are_several():
    one = {0: np.array([[1.0, 3.0], [5.0, 7.0], [9.0, 11.0]])}  # 3 eval seeds x 2 episodes
    s = summarise_group(one)
    assert s["ci_unit"] == "eval_seed" and s["n"] == 3 and s["mean"] == 6.0 and s["episodes"] == 6
    many = {0: np.full((3, 2), 10.0), 1: np.full((3, 2), 20.0)}
    s = summarise_group(many)
    assert s["ci_unit"] == "training_seed" and s["n"] == 2 and s["mean"] == 15.0 and s["train_seeds"] == [0, 1]


def test_eval_config_needs_two_seeds_for_an_interval():
    with pytest.raises(ConfigError, match="seeds: expected an integer >= 2"):
        EvalConfig(seeds=1)


def test_batched_jobs_equal_single_env_rollouts_with_the_same_episode_seeds(tiny_teachers):
    checkpoints, _ = tiny_teachers
    config = EvalConfig(seeds=2, episodes=2, rollout_envs=4, workers=2)
    seeds = episode_seeds(0, config)
    assert seeds == episode_seeds(0, config) and seeds != episode_seeds(1, config)
    jobs = [Job("teacher", 0, PolicySpec("teacher", checkpoints[("stand", "deterministic")]), "stand"),
            Job("cross", 0, PolicySpec("teacher", checkpoints[("stand", "deterministic")]), "walk")]
    results = run_jobs(jobs, seeds, 50, config)
    assert [r.shape for r in results] == [(2, 2), (2, 2)]
    policy = load_teacher(checkpoints[("stand", "deterministic")]).act
    flat = [s for group in seeds for s in group]
    for job, result in zip(jobs, results):
        single = episode_returns(policy, job.eval_task, flat, 50, num_envs=1)
        np.testing.assert_allclose(result.ravel(), single, rtol=1e-6)


def test_unknown_policy_kind_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="kind: expected one of"):
        load_policy(PolicySpec("oracle", tmp_path / "x.pt"))
