"""Similarity measures beyond tau and linear CKA (mop_core/representations/similarity.py) against direct
computations and the properties they must have."""

from __future__ import annotations

import math

import pytest
import torch

from mop_core.representations.measures import linear_cka
from mop_core.representations.similarity import debiased_cka, dormant_shares, procrustes_similarity, task_selectivity


def _data(n: int = 60, p: int = 8, seed: int = 0) -> torch.Tensor:
    return torch.randn(n, p, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def test_procrustes_is_one_for_a_rotated_copy_and_matches_the_svd_definition():
    x = _data()
    rotation, _ = torch.linalg.qr(_data(8, 8, seed=1))
    assert procrustes_similarity(x, x @ rotation * 3.0 + 1.0) == pytest.approx(1.0, abs=1e-12)
    y = _data(seed=2)
    xc, yc = x - x.mean(0), y - y.mean(0)
    expected = torch.linalg.svdvals(xc.T @ yc).sum() / (xc.norm() * yc.norm())
    assert procrustes_similarity(x, y) == pytest.approx(float(expected))
    assert 0 <= procrustes_similarity(x, y) < 0.9
    assert math.isnan(procrustes_similarity(x, torch.ones(60, 3)))


def _hsic_u_direct(k: torch.Tensor, l_: torch.Tensor) -> float:
    n = k.shape[0]
    k, l_ = k - torch.diag(torch.diag(k)), l_ - torch.diag(torch.diag(l_))
    one = torch.ones(n, dtype=k.dtype)
    value = (torch.trace(k @ l_) + (one @ k @ one) * (one @ l_ @ one) / ((n - 1) * (n - 2))
             - 2.0 / (n - 2) * (one @ k @ l_ @ one))
    return float(value / (n * (n - 3)))


def test_debiased_cka_equals_the_unbiased_hsic_on_explicit_gram_matrices():
    x, y = _data(30, 5), _data(30, 7, seed=3)
    k, l_ = x @ x.T, y @ y.T
    expected = _hsic_u_direct(k, l_) / math.sqrt(_hsic_u_direct(k, k) * _hsic_u_direct(l_, l_))
    assert debiased_cka(x, y) == pytest.approx(expected, rel=1e-9)
    assert debiased_cka(x, 2 * x + 5) == pytest.approx(1.0)


def test_debiased_cka_removes_the_bias_that_inflates_linear_cka_for_wide_layers():
    """Independent random features: linear CKA is far above 0 when width ~ N, debiased CKA is near 0."""
    x, y = _data(100, 200, seed=4), _data(100, 200, seed=5)
    assert linear_cka(x, y) > 0.5
    assert abs(debiased_cka(x, y)) < 0.05
    with pytest.raises(ValueError, match="at least 4 rows"):
        debiased_cka(x[:3], y[:3])


def test_task_selectivity_is_the_share_of_variance_the_task_id_explains():
    states = _data(50, 3)
    shifted = states.clone()
    shifted[:, 0] += 10.0  # neuron 0 is mostly the task id; neuron 1 is the same under both ids
    shifted[:, 2] = states[:, 2] * -1  # neuron 2: same variance, no mean shift: nothing explained by the id
    constant = torch.zeros(50, 1, dtype=torch.float64)
    eta = task_selectivity([torch.cat([states, constant], 1), torch.cat([shifted, constant], 1)])
    assert eta[0] > 0.9 and eta[1] == 0.0 and eta[2] < 0.05 and math.isnan(eta[3])
    grand = torch.cat([states[:, 0], shifted[:, 0]])
    between = 50 * ((states[:, 0].mean() - grand.mean()) ** 2 + (shifted[:, 0].mean() - grand.mean()) ** 2)
    assert float(eta[0]) == pytest.approx(float(between / ((grand - grand.mean()) ** 2).sum()))


def test_dormant_shares_count_neurons_by_their_normalised_mean_activation():
    acts = torch.tensor([[0.0, 1.0, 2.0, 0.05], [0.0, 3.0, 2.0, 0.05]])  # scores 0, 2, 2, 0.05; mean 1.0125
    assert dormant_shares(acts) == {"0.0": 0.25, "0.1": 0.5}
    assert dormant_shares(torch.zeros(3, 4)) == {"0.0": 1.0, "0.1": 1.0}
