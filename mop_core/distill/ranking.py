"""Ranking losses between two activation vectors, and the ranking regulariser of thesis 6.3.2.

Each loss compares *scores* ``x`` with *labels* ``y`` (tensors ``[..., n]``: one list of n neurons per
leading index) and returns one value per list (``[...]``); it is smallest when ``x`` ranks the n
items the way ``y`` does. In the regulariser both are a hidden layer's activations on the same state
under two task ids: ``x`` under id i, ``y`` under id k with its gradient stopped (labels are targets
in learning to rank), summed over every ordered pair (i, k), i != k, so the regulariser is
symmetric in the tasks and defined for any number of them (the thesis writes it for two tasks with
``i xor 1``); each task's activations receive gradient as the scores of their pairs.

- :func:`pairwise_logistic` (thesis Eq. in 6.3.2, RankNet-style):
  ``1/(n(n-1)) sum_{i != j} log(1 + exp(-(x_i - x_j)(y_i - y_j)))``. The diagonal terms (``i = j``)
  are the constant log 2 with zero gradient: they are left out. The n(n-1) ordered pairs are averaged,
  not summed, so the value (and lambda's meaning) does not grow with the layer's width squared; the
  n^2 compute is one vectorised ``[..., n, n]`` pass.
- :func:`listwise_softmax_ce` (ListNet): ``-sum_i P_y(i) log P_x(i)`` with ``P_z = softmax(z)``: the
  labels' distribution against the scores' log-probabilities (the thesis's reference code swapped
  the two arguments). For fixed labels it is smallest at ``x = y + c``.
- :func:`approx_ndcg` (ApproxNDCG, Qin, Liu and Li 2010): ``1 - DCG~/IDCG``. The thesis's NDCG ranks
  by ``argsort(x)``, whose gradient is zero almost everywhere; ApproxNDCG replaces item i's rank by
  the smooth ``1 + sum_{j != i} sigmoid((x_j - x_i) / T)``, so DCG~ = ``sum_i g_i / log2(1 + rank_i)``
  has a gradient everywhere. Gains ``g = y - min(y)`` (non-negative; ReLU activations already are);
  IDCG is the DCG of the gains sorted descending. A list whose labels are all equal has nothing to
  rank: loss 0.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import torch
import torch.nn.functional as F

RankingLoss = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def _check(x: torch.Tensor, y: torch.Tensor) -> int:
    if x.shape != y.shape or x.dim() < 1:
        raise ValueError(f"x, y: expected two tensors of one shape [..., n], got {tuple(x.shape)} and {tuple(y.shape)}")
    n = x.shape[-1]
    if n < 2:
        raise ValueError(f"x, y: a ranking needs at least 2 items, got n = {n}")
    return n


class _PairwiseLogistic(torch.autograd.Function):
    """The pairwise logistic loss with a hand-written backward: autograd's version makes ~15 passes
    over the ``[..., n, n]`` pair tensors (every subtraction's and softplus's backward), this one 6.
    With ``w_ij = -sigmoid(-p_ij)``, ``p_ij = (x_i - x_j)(y_i - y_j)`` (w symmetric, the differences
    antisymmetric): ``dL/dx_i = 2 c sum_j w_ij (y_i - y_j)`` and likewise for y, ``c = 1/(n(n-1))``."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        n = x.shape[-1]
        products = (x.unsqueeze(-1) - x.unsqueeze(-2)).mul_(y.unsqueeze(-1) - y.unsqueeze(-2))
        log_sigmoid = F.logsigmoid(products)  # softplus(-p) = -log sigmoid(p)
        ctx.save_for_backward(x, y, log_sigmoid)
        # the n diagonal terms are softplus(0) = log 2 exactly, with zero gradient: subtracted, not masked
        return (log_sigmoid.sum((-2, -1)).neg_() - n * math.log(2.0)) / (n * (n - 1))

    @staticmethod
    def backward(ctx, grad: torch.Tensor):  # type: ignore[override]
        x, y, log_sigmoid = ctx.saved_tensors
        n = x.shape[-1]
        weights = torch.expm1(log_sigmoid)  # sigmoid(p) - 1 = -sigmoid(-p) = dL/dp / c
        scale = (2.0 / (n * (n - 1))) * grad.unsqueeze(-1)
        grad_x = grad_y = None
        if ctx.needs_input_grad[0]:
            grad_x = (weights * (y.unsqueeze(-1) - y.unsqueeze(-2))).sum(-1) * scale
        if ctx.needs_input_grad[1]:
            grad_y = (weights * (x.unsqueeze(-1) - x.unsqueeze(-2))).sum(-1) * scale
        return grad_x, grad_y


def pairwise_logistic(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``1/(n(n-1)) sum_{i != j} log(1 + exp(-(x_i - x_j)(y_i - y_j)))`` per list ``[...]``."""
    _check(x, y)
    return _PairwiseLogistic.apply(x, y)


def _pairwise_logistic_autograd(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """The same loss through autograd (the reference the hand-written backward is tested against)."""
    n = _check(x, y)
    products = (x.unsqueeze(-1) - x.unsqueeze(-2)) * (y.unsqueeze(-1) - y.unsqueeze(-2))
    return (F.softplus(-products).sum((-2, -1)) - n * math.log(2.0)) / (n * (n - 1))


def listwise_softmax_ce(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``-sum_i softmax(y)_i log softmax(x)_i`` per list: labels ``y`` against scores ``x``."""
    _check(x, y)
    return -(torch.softmax(y, dim=-1) * torch.log_softmax(x, dim=-1)).sum(-1)


def approx_ndcg(x: torch.Tensor, y: torch.Tensor, temperature: float = 0.1) -> torch.Tensor:
    """``1 - DCG~(x; y) / IDCG(y)`` per list, with ApproxNDCG's smooth ranks at ``temperature``."""
    n = _check(x, y)
    if temperature <= 0:
        raise ValueError(f"temperature: expected a positive number, got {temperature}")
    gains = y - y.min(dim=-1, keepdim=True).values
    # rank_i = 1 + sum_{j != i} sigmoid((x_j - x_i) / T); the j = i term is sigmoid(0) = 1/2
    ranks = 0.5 + torch.sigmoid((x.unsqueeze(-2) - x.unsqueeze(-1)) / temperature).sum(-1)
    dcg = (gains / torch.log2(1.0 + ranks)).sum(-1)
    discounts = torch.log2(torch.arange(2, n + 2, dtype=x.dtype, device=x.device))
    ideal = (gains.sort(dim=-1, descending=True).values / discounts).sum(-1)
    return torch.where(ideal > 0, 1.0 - dcg / ideal.clamp_min(torch.finfo(x.dtype).tiny), torch.zeros_like(dcg))


RANKING_LOSSES: dict[str, RankingLoss] = {
    "pairwise": pairwise_logistic,
    "listwise": listwise_softmax_ce,
    "approx_ndcg": approx_ndcg,
}
SYMMETRIC_LOSSES = ("pairwise",)  # L(x, y) = L(y, x): the regulariser evaluates each unordered pair once


def ranking_loss(name: str, temperature: float = 0.1) -> RankingLoss:
    """The ranking loss called ``name`` (approx_ndcg at ``temperature``)."""
    if name not in RANKING_LOSSES:
        raise ValueError(f"ranking loss: expected one of {tuple(RANKING_LOSSES)}, got {name!r}")
    if name == "approx_ndcg":
        return lambda x, y: approx_ndcg(x, y, temperature)
    return RANKING_LOSSES[name]


def cross_task_ranking(layers: Sequence[torch.Tensor], loss: RankingLoss, layer_weights: Sequence[float],
                       symmetric: bool = False) -> torch.Tensor:
    """The ranking regulariser of thesis 6.3.2, for any number of tasks m:

        sum_j w_j * mean_{i != k} mean_s L_rank(l_j(pi(s, i)), sg[l_j(pi(s, k))])

    ``layers[j]``: layer j's activations ``[..., m, S, n]`` (the same S states under each of the m
    task ids; leading dims, e.g. runs of a group, are kept); ``sg`` stops the label side's gradient.
    Returns ``[...]``.

    ``symmetric``: ``loss`` is symmetric in its arguments (pairwise logistic), so the ordered pairs
    (i, k) and (k, i) have one value, and the gradients they give a_i and a_k (each as scores) are
    the two partial derivatives of ``L(a_i, a_k)``: each unordered pair is evaluated once, without
    the stop-gradient and with its gradient halved (the mean over unordered pairs weighs each pair
    twice as much), for the same value and gradient at half the cost (tested)."""
    if len(layer_weights) != len(layers):
        raise ValueError(f"layer_weights: expected one weight per hidden layer ({len(layers)}), got "
                         f"{len(layer_weights)}")
    total = None
    for weight, acts in zip(layer_weights, layers):
        m = acts.shape[-3]
        if m < 2:
            raise ValueError(f"layers: the ranking regulariser needs activations under >= 2 task ids, got {m}")
        pairs = [(i, k) for i in range(m) for k in range(m) if (i < k if symmetric else i != k)]
        scores = torch.stack([acts[..., i, :, :] for i, _ in pairs], dim=-3)
        labels = torch.stack([acts[..., k, :, :] for _, k in pairs], dim=-3)
        values = loss(scores, labels if symmetric else labels.detach()).mean((-2, -1))
        if symmetric:  # one unordered pair carries both ordered pairs' gradients: halve it to match them
            values = values.detach() + 0.5 * (values - values.detach())
        term = weight * values
        total = term if total is None else total + term
    assert total is not None
    return total
