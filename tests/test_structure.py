"""Shared-computation measures: tau-b against scipy (random and tied data), its extremes, CKA's
invariances, and activation capture from a student."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import stats

from mop_core.distill.student import Student, StudentConfig
from mop_core.representations.measures import (
    average_comparison,
    hidden_activations,
    kendall_tau,
    kendall_tau_a,
    kendall_tau_b,
    linear_cka,
    per_state_comparison,
    per_state_tau_by_layer,
)


@pytest.mark.parametrize("tied", [False, True])
def test_tau_b_equals_scipy_on_random_and_tied_data(tied):
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(20, 64)), rng.normal(size=(20, 64))
    if tied:  # ReLU-like: many exact zeros
        x, y = np.maximum(x, 0.3), np.maximum(0.5 * x + y, 0.0)
    ours = kendall_tau_b(torch.tensor(x), torch.tensor(y), chunk=7).numpy()
    ref = [stats.kendalltau(a, b, variant="b").statistic for a, b in zip(x, y)]
    np.testing.assert_allclose(ours, ref, rtol=1e-12)  # the same counts: equal to rounding


def test_tau_b_is_one_for_identical_and_minus_one_for_reversed_and_nan_for_constant():
    v = torch.rand(50)
    assert kendall_tau_b(v, v).item() == pytest.approx(1.0)
    assert kendall_tau_b(v, -v).item() == pytest.approx(-1.0)
    assert torch.isnan(kendall_tau_b(v, torch.zeros(50)))
    with pytest.raises(ValueError, match="same shape"):
        kendall_tau_b(torch.rand(3, 5), torch.rand(3, 6))


def test_cka_is_invariant_to_orthogonal_transforms_and_isotropic_scaling():
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(200, 32, generator=gen, dtype=torch.float64)
    y = x @ torch.randn(32, 16, generator=gen, dtype=torch.float64) + 0.5 * torch.randn(200, 16, generator=gen,
                                                                                          dtype=torch.float64)
    q, _ = torch.linalg.qr(torch.randn(32, 32, generator=gen, dtype=torch.float64))
    base = linear_cka(x, y)
    assert 0 < base < 1
    assert linear_cka(x @ q, y) == pytest.approx(base, rel=1e-10)
    assert linear_cka(3.7 * x, y) == pytest.approx(base, rel=1e-10)
    assert linear_cka(x, x) == pytest.approx(1.0)
    assert linear_cka(x, torch.randn(200, 32, generator=gen, dtype=torch.float64)) < 0.3


def test_tau_b_of_float32_activations_equals_float64_and_cka_chunks_equal_one_pass():
    gen = torch.Generator().manual_seed(1)
    x = torch.relu(torch.randn(40, 30, generator=gen))
    y = torch.relu(x + 0.3 * torch.randn(40, 30, generator=gen))
    torch.testing.assert_close(kendall_tau_b(x, y), kendall_tau_b(x.double(), y.double()), rtol=1e-12, atol=0)
    xc, yc = x.double() - x.double().mean(0), y.double() - y.double().mean(0)  # the textbook formula
    direct = float((yc.T @ xc).pow(2).sum() / ((xc.T @ xc).norm() * (yc.T @ yc).norm()))
    assert linear_cka(x, y, chunk=7) == pytest.approx(direct, rel=1e-9)
    assert linear_cka(x, y) == pytest.approx(direct, rel=1e-9)


def test_hidden_activations_are_the_post_relu_outputs_of_every_hidden_layer():
    student = Student(StudentConfig(hidden_sizes=(8, 5)), 24, 6, num_tasks=2)
    obs = torch.randn(4, 24)
    acts = hidden_activations(student, obs, 1)
    assert [a.shape for a in acts] == [(4, 8), (4, 5)] and all((a >= 0).all() for a in acts)
    net = student.actor.net
    x = torch.cat([obs, torch.tensor([[0.0, 1.0]]).expand(4, 2)], 1)
    torch.testing.assert_close(acts[0], torch.relu(net[0](x)))
    assert not student.actor.net[1]._forward_hooks  # hooks removed


def _two_task_student(task_weight: torch.Tensor) -> Student:
    """One hidden layer of 6 neurons whose task-id input weights are ``task_weight [6, 2]``."""
    student = Student(StudentConfig(hidden_sizes=(6,)), 3, 1, num_tasks=2)
    first = student.actor.net[0]
    with torch.no_grad():
        first.weight.zero_()
        first.weight[:, :3] = torch.arange(1.0, 19.0).view(6, 3) / 10  # state part
        first.weight[:, 3:] = task_weight
        first.bias.zero_()
    return student


def test_per_state_and_average_paths_on_a_network_with_known_overlap():
    obs = torch.rand(10, 3) + 0.1
    shared = _two_task_student(torch.zeros(6, 2))  # the task id changes nothing: full overlap
    (layer,) = per_state_comparison(shared, obs, own_task=0)
    torch.testing.assert_close(layer[1]["b"], torch.ones(10, dtype=torch.float64))
    # a task id that dominates the state: activations follow relu(b_t), a known ranking per task
    b0 = torch.tensor([50.0, 40.0, 30.0, 20.0, -5.0, -10.0])
    b1 = torch.tensor([-10.0, 10.0, 20.0, 30.0, 40.0, 50.0])
    split = _two_task_student(torch.stack([b0, b1], 1))
    (layer,) = per_state_comparison(split, obs, own_task=0)
    expected = {"a": kendall_tau_a(torch.relu(b0), torch.relu(b1)).item(),
                "b": kendall_tau_b(torch.relu(b0), torch.relu(b1)).item()}
    assert expected["b"] < -0.5 and abs(expected["a"]) < abs(expected["b"])  # two zeros of b0 tie
    for variant in ("a", "b"):
        torch.testing.assert_close(layer[1][variant], torch.full((10,), expected[variant], dtype=torch.float64))
    assert per_state_tau_by_layer(shared, [obs, obs])["b"] == pytest.approx([1.0])
    assert per_state_tau_by_layer(split, [obs, obs[:4]]) == {"a": pytest.approx([expected["a"]]),
                                                             "b": pytest.approx([expected["b"]])}
    means = [[hidden_activations(split, obs, t)[0].mean(0)] for t in (0, 1)]
    (tau,) = average_comparison(means)
    for variant in ("a", "b"):
        assert tau[variant][0, 0] == 1 and tau[variant][0, 1] == tau[variant][1, 0] == pytest.approx(expected[variant])


def _brute_force_tau_a(x: list[float], y: list[float]) -> float:
    """The thesis's formula 2 (C - D) / (N (N - 1)), pair by pair (ties count as neither)."""
    n, score = len(x), 0
    for i in range(n):
        for j in range(i + 1, n):
            score += np.sign(x[i] - x[j]) * np.sign(y[i] - y[j])
    return 2 * score / (n * (n - 1))


@pytest.mark.parametrize("tied", [False, True])
def test_tau_a_equals_the_thesis_formula_pair_by_pair(tied):
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=(6, 30)), rng.normal(size=(6, 30))
    if tied:  # ReLU-like: many exact zeros
        x, y = np.maximum(x, 0), np.maximum(x + 0.5 * y, 0)
    ours = kendall_tau_a(torch.tensor(x), torch.tensor(y), chunk=4).numpy()
    expected = [_brute_force_tau_a(list(a), list(b)) for a, b in zip(x, y)]
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-12)
    both = kendall_tau(torch.tensor(x), torch.tensor(y))
    assert torch.all(both["a"].abs() <= both["b"].abs() + 1e-12)
    if not tied:  # without ties the two variants agree
        torch.testing.assert_close(both["a"], both["b"])
    assert kendall_tau_a(torch.ones(5), torch.arange(5.0)).item() == 0.0  # defined for a constant vector
