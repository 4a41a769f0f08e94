"""Measures of how alike a student's hidden layer is under two task ids, beyond Kendall's tau and
linear CKA (which is saturated here: 0.94-0.998 for every trained student, 1.000 for an untrained
copy, so it cannot tell students apart). Each takes activation matrices ``x [N, p]``, ``y [N, q]``
of the same N inputs (rows: a state; x under task id i, y under id j) and works in float64.

- :func:`procrustes_similarity`: ``||X_c^T Y_c||_* / (||X_c||_F ||Y_c||_F)``, the orthogonal
  Procrustes similarity (1 - d/2 of the Procrustes distance of Ding, Denain and Steinhardt 2021 on
  Frobenius-normalised, centred representations): 1 when one is a rotation of the other, lower
  than CKA's when the two differ in a few directions of large variance.
- :func:`debiased_cka`: CKA from the unbiased HSIC estimator (Song et al. 2012; Nguyen, Raghu and
  Kornblith 2021) with linear kernels, computed in O(N p q) without the N x N Gram matrices.
  Plain (biased) CKA is pulled towards 1 when the width is large against N.
- :func:`task_selectivity`: per neuron, the share of its activation variance over (state, task id)
  explained by the task id (eta^2 of a one-way decomposition, the same states under every id);
  neurons that never vary are left out (NaN).
- :func:`dormant_shares`: per layer, the share of tau-dormant neurons of Sokar et al. 2023: neuron
  k is dormant when ``E|h_k| / mean_l E|h_l| <= tau`` (tau = 0: dead).
"""

from __future__ import annotations

from typing import Sequence

import torch

DORMANT_THRESHOLDS = (0.0, 0.1)  # dead, and Sokar et al.'s tau = 0.1


def _pair(x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    if x.dim() != 2 or y.dim() != 2 or x.shape[0] != y.shape[0]:
        raise ValueError(f"x, y: expected [N, p] and [N, q] of the same N rows, got {tuple(x.shape)} and "
                         f"{tuple(y.shape)}")
    return x.double(), y.double()


@torch.no_grad()
def procrustes_similarity(x: torch.Tensor, y: torch.Tensor) -> float:
    """``||X_c^T Y_c||_* / (||X_c||_F ||Y_c||_F)`` in [0, 1] (NaN when either is constant)."""
    x, y = _pair(x, y)
    x, y = x - x.mean(0), y - y.mean(0)
    denominator = x.norm() * y.norm()
    if denominator == 0:
        return float("nan")
    return float(torch.linalg.matrix_norm(x.T @ y, ord="nuc") / denominator)


def _unbiased_hsic(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """HSIC_u(K, L) with K = X X^T, L = Y Y^T (Song et al. 2012, Eq. 5), without forming K or L:
    with K~ = K - diag(K),
        HSIC_u = [tr(K~ L~) + 1^T K~ 1 * 1^T L~ 1 / ((n-1)(n-2)) - 2/(n-2) 1^T K~ L~ 1] / (n (n-3))."""
    n = x.shape[0]
    x_sq, y_sq = x.pow(2).sum(1), y.pow(2).sum(1)  # diag(K), diag(L)
    trace = (x.T @ y).pow(2).sum() - (x_sq * y_sq).sum()
    x_rows, y_rows = x @ x.sum(0) - x_sq, y @ y.sum(0) - y_sq  # K~ 1, L~ 1
    return (trace + x_rows.sum() * y_rows.sum() / ((n - 1) * (n - 2)) - 2.0 / (n - 2) * (x_rows * y_rows).sum()) / (
        n * (n - 3))


@torch.no_grad()
def debiased_cka(x: torch.Tensor, y: torch.Tensor) -> float:
    """``HSIC_u(K, L) / sqrt(HSIC_u(K, K) HSIC_u(L, L))`` with linear kernels (needs N >= 4 rows;
    NaN when either self-similarity is not positive)."""
    x, y = _pair(x, y)
    if x.shape[0] < 4:
        raise ValueError(f"x, y: the unbiased HSIC needs at least 4 rows, got {x.shape[0]}")
    xx, yy = _unbiased_hsic(x, x), _unbiased_hsic(y, y)
    if xx <= 0 or yy <= 0:
        return float("nan")
    return float(_unbiased_hsic(x, y) / torch.sqrt(xx * yy))


@torch.no_grad()
def task_selectivity(acts: Sequence[torch.Tensor]) -> torch.Tensor:
    """``acts[t] [N, p]``: a layer's activations on the same N states under task id t. Per neuron
    ``[p]``: SS_between / SS_total over the ``len(acts) * N`` (state, id) activations, where
    SS_between = N sum_t (mean_t - mean)^2; NaN for a neuron constant over every state and id."""
    if len(acts) < 2 or any(a.shape != acts[0].shape for a in acts):
        raise ValueError("acts: expected >= 2 activation matrices of one shape [N, p] (the same states per id)")
    stacked = torch.stack([a.double() for a in acts])  # [m, N, p]
    grand = stacked.mean((0, 1))
    total = (stacked - grand).pow(2).sum((0, 1))
    between = stacked.shape[1] * (stacked.mean(1) - grand).pow(2).sum(0)
    return torch.where(total > 0, between / total.clamp_min(torch.finfo(torch.float64).tiny),
                       torch.full_like(total, float("nan")))


@torch.no_grad()
def dormant_shares(acts: torch.Tensor, thresholds: Sequence[float] = DORMANT_THRESHOLDS) -> dict[str, float]:
    """``acts [N, p]``: the share of neurons with ``E|h_k| / mean_l E|h_l| <= tau`` per threshold tau
    (``{"0.0": dead share, "0.1": ...}``); every neuron counts as dormant in a layer that is all zero."""
    score = acts.double().abs().mean(0)
    mean = score.mean()
    normalised = score / mean if mean > 0 else torch.zeros_like(score)
    return {str(tau): float((normalised <= tau).double().mean()) for tau in thresholds}
