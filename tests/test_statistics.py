"""Aggregate statistics against rliable's own functions (point estimates) and against what a
bootstrap interval must do (coverage, stratification)."""

from __future__ import annotations

import numpy as np
import pytest
from rliable import metrics as rliable_metrics

from mop_core.statistics import (
    confidence_interval,
    iqm,
    normalised_score,
    probability_of_improvement,
    stratified_bootstrap,
)


def _scores(seed: int, runs: int, tasks: int, loc: float = 50.0) -> np.ndarray:
    return np.random.default_rng(seed).normal(loc, 20.0, size=(runs, tasks))


@pytest.mark.parametrize("shape", [(30, 2), (7, 3), (1, 4)])
def test_iqm_equals_rliable(shape):
    scores = _scores(0, *shape)
    assert iqm(scores) == pytest.approx(rliable_metrics.aggregate_iqm(scores), rel=1e-12)
    batched = np.stack([scores, scores + 1.0])  # a leading replicate axis
    np.testing.assert_allclose(iqm(batched), [iqm(scores), iqm(scores) + 1.0])


def test_probability_of_improvement_equals_rliable_with_ties_and_unequal_runs():
    x, y = np.round(_scores(1, 30, 2, 55.0)), np.round(_scores(2, 15, 2))  # rounding makes ties
    y[0, 0] = x[0, 0]
    assert probability_of_improvement(x, y) == pytest.approx(rliable_metrics.probability_of_improvement(x, y))
    assert probability_of_improvement(x, x) == pytest.approx(0.5)
    assert probability_of_improvement(x + 1000, y) == 1.0 and probability_of_improvement(y, x + 1000) == 0.0
    with pytest.raises(ValueError, match="same number of tasks"):
        probability_of_improvement(x, y[:, :1])


def test_bootstrap_interval_covers_the_true_center_about_95_percent_of_the_time():
    hits = 0
    for trial in range(100):
        scores = _scores(100 + trial, 40, 2)
        ci = stratified_bootstrap(iqm, [scores], reps=500, seed=trial)
        assert ci["ci_low"] <= ci["value"] <= ci["ci_high"]
        hits += ci["ci_low"] <= 50.0 <= ci["ci_high"]
    assert 85 <= hits <= 100


def test_bootstrap_resamples_within_each_task_and_is_repeatable():
    scores = np.stack([np.zeros(20), np.arange(20.0)], axis=1)  # task 0 constant, task 1 spread out
    only_first = stratified_bootstrap(lambda s: s[..., 0].mean(-1), [scores], reps=300, seed=0)
    assert only_first["ci_low"] == only_first["ci_high"] == 0.0  # rows of task 1 never enter task 0
    second = stratified_bootstrap(lambda s: s[..., 1].mean(-1), [scores], reps=4000, seed=0)
    t = confidence_interval(scores[:, 1])
    assert second["ci_high"] - second["ci_low"] == pytest.approx(t["ci_high"] - t["ci_low"], rel=0.15)
    assert stratified_bootstrap(iqm, [scores], reps=50, seed=3) == stratified_bootstrap(iqm, [scores], reps=50, seed=3)


def test_probability_of_improvement_interval_excludes_half_for_a_clear_difference():
    x, y = _scores(3, 30, 2, 80.0), _scores(4, 30, 2, 20.0)
    ci = stratified_bootstrap(probability_of_improvement, [x, y], reps=500, seed=0)
    assert ci["ci_low"] > 0.5 and ci["value"] == pytest.approx(rliable_metrics.probability_of_improvement(x, y))


def test_normalised_score_maps_random_to_zero_and_expert_to_hundred():
    assert normalised_score(150.0, 150.0, 986.8) == 0.0
    assert normalised_score(986.8, 150.0, 986.8) == pytest.approx(100.0)
    np.testing.assert_allclose(normalised_score(np.array([568.4]), 150.0, 986.8), [50.0])
    with pytest.raises(ValueError, match="expert_return"):
        normalised_score(1.0, 100.0, 50.0)


def _rliable_intervals(score_dict, func, reps, seed):
    """rliable.library's own stratified bootstrap (percentile), seeded through numpy's global state."""
    library = pytest.importorskip("rliable.library", reason="rliable.library needs arch<8 with pandas<3")
    np.random.seed(seed)
    return library.get_interval_estimates(score_dict, func, reps=reps)


@pytest.mark.parametrize("runs", [3, 5, 10])
def test_run_level_iqm_and_its_interval_equal_rliables(runs):
    """Run-level score matrices ([runs, tasks], each run its mean over episodes): the point estimate is
    rliable's exactly, the interval within Monte Carlo error of rliable's own StratifiedBootstrap."""
    scores = _scores(runs, runs, 2)
    ours = stratified_bootstrap(iqm, [scores], reps=20000, seed=0)
    points, intervals = _rliable_intervals({"g": scores}, rliable_metrics.aggregate_iqm, 20000, 0)
    assert ours["value"] == pytest.approx(points["g"], rel=1e-12)
    spread = scores.max() - scores.min()
    assert [ours["ci_low"], ours["ci_high"]] == pytest.approx(np.ravel(intervals["g"]).tolist(), abs=0.03 * spread)


def test_run_level_probability_of_improvement_and_its_interval_equal_rliables():
    x, y = _scores(11, 5, 2, 60.0), _scores(12, 4, 2)
    # 2000 resamples: rliable's loop over them takes ~1 s per 600 (20000: 23 s); the intervals agree to 1e-3
    ours = stratified_bootstrap(probability_of_improvement, [x, y], reps=2000, seed=0)
    points, intervals = _rliable_intervals({"x,y": [x, y]}, rliable_metrics.probability_of_improvement, 2000, 0)
    assert ours["value"] == pytest.approx(points["x,y"], rel=1e-12)
    assert [ours["ci_low"], ours["ci_high"]] == pytest.approx(np.ravel(intervals["x,y"]).tolist(), abs=0.03)


def test_pooling_episodes_as_runs_shrinks_the_interval():
    """Why the unit matters: 3 runs x 15 episodes whose runs differ; resampling the 45 episodes as if
    they were runs gives an interval several times narrower than resampling the 3 runs."""
    rng = np.random.default_rng(5)
    run_means = np.array([[20.0, 30.0], [45.0, 55.0], [70.0, 60.0]])
    episodes = run_means[:, None, :] + rng.normal(0, 5, size=(3, 15, 2))
    by_run = stratified_bootstrap(iqm, [episodes.mean(1)], reps=4000, seed=0)
    by_episode = stratified_bootstrap(iqm, [episodes.reshape(45, 2)], reps=4000, seed=0)
    assert by_run["ci_high"] - by_run["ci_low"] > 2 * (by_episode["ci_high"] - by_episode["ci_low"])


def test_seed_intervals_stop_at_the_quantitys_bounds():
    from mop_core.statistics import TAU_BOUNDS, seed_interval

    low = seed_interval([5.0, 90.0, 10.0], (0.0, np.inf))
    assert low["ci_low"] == 0.0 and low["cut_at_bound"] and low["ci_high"] > 90
    tau = seed_interval([0.95, 0.99, 0.5], TAU_BOUNDS)
    assert tau["ci_high"] == 1.0 and tau["cut_at_bound"]
    assert seed_interval([1.0, 2.0])["ci_low"] is None  # under 3 seeds: no interval
