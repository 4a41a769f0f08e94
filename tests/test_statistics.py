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
