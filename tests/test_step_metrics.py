"""StepMetrics: per-update metrics read in batches, with the first non-finite value named exactly."""

import math

import numpy as np
import pytest
import torch

from mop_core.learning import step_metrics
from mop_core.learning.runtime import TrainingDivergedError
from mop_core.learning.step_metrics import StepMetrics, as_floats


def test_as_floats_reads_tensors_and_numbers_in_order():
    assert as_floats([torch.tensor(1.5), 2, torch.tensor(-3.0, dtype=torch.float64), 0.25]) == [1.5, 2.0, -3.0, 0.25]
    assert as_floats([]) == []


def test_take_gives_each_metric_mean_over_the_steps_that_reported_it():
    metrics = StepMetrics("run")
    metrics.add(1, {"critic": torch.tensor(1.0), "beta": 3.0})
    metrics.add(2, {"critic": torch.tensor(3.0), "beta": 2.0, "actor": torch.tensor(-4.0)})
    assert metrics.take() == {"actor": -4.0, "beta": 2.5, "critic": 2.0}
    assert metrics.take() == {}  # a new window


def test_means_equal_numpy_means_of_the_same_floats():
    values = [float(v) for v in np.random.default_rng(0).normal(size=999)]
    metrics = StepMetrics("run")
    for step, value in enumerate(values, 1):
        metrics.add(step, {"loss": torch.tensor(value, dtype=torch.float64)})
    assert metrics.take()["loss"] == float(np.mean(values))


def test_values_are_read_only_every_sync_every_steps(monkeypatch):
    monkeypatch.setattr(step_metrics, "SYNC_EVERY", 3)
    metrics = StepMetrics("run")
    for step in (1, 2):
        metrics.add(step, {"loss": torch.tensor(float(step))})
    assert metrics.values == {}  # still pending
    metrics.add(3, {"loss": torch.tensor(3.0)})
    assert metrics.values == {"loss": [1.0, 2.0, 3.0]} and metrics.last == {"loss": 3.0}


def test_the_first_non_finite_value_is_named_with_its_step(monkeypatch):
    monkeypatch.setattr(step_metrics, "SYNC_EVERY", 10**9)
    metrics = StepMetrics("teacher stand-medium-0", " (resume file kept)")
    metrics.add(1199, {"critic_loss": torch.tensor(1.0), "actor_loss": torch.tensor(-2.5e9)})
    metrics.add(1200, {"critic_loss": torch.tensor(1.0), "actor_loss": torch.tensor(math.nan), "alpha": math.inf})
    metrics.add(1201, {"critic_loss": torch.tensor(math.inf)})
    with pytest.raises(TrainingDivergedError) as err:
        metrics.sync()
    assert str(err.value) == ("teacher stand-medium-0: actor_loss = nan at step 1200; stopped (resume file kept). "
                              "Lower the learning rate or check the data")


def test_take_last_gives_each_metrics_latest_value_and_a_resumed_window_continues():
    metrics = StepMetrics("run", values={"loss": [1.0, 2.0]})
    assert metrics.last == {"loss": 2.0}
    metrics.add(3, {"loss": torch.tensor(5.0), "q": torch.tensor(7.0)})
    assert metrics.take_last() == {"loss": 5.0, "q": 7.0}
    metrics.add(4, {"q": torch.tensor(8.0)})
    assert metrics.take_last() == {"q": 8.0}
