"""State distribution shift between two sets of states (thesis 5.2.2 could not measure it; issue 18
part 4): a nearest-neighbour KL estimator with its split-half null and a bootstrap interval, and a
classifier two-sample test with the density ratio it implies.

- :func:`knn_kl`: Wang, Kulkarni and Verdu (2009), for ``x ~ p`` (n states) and ``y ~ q`` (m states)
  in d dimensions::

      D(p || q) ~= d / n * sum_i log(nu_k(i) / rho_k(i)) + log(m / (n - 1))

  with ``rho_k(i)`` the distance from x_i to its k-th nearest neighbour among the other x and
  ``nu_k(i)`` to its k-th nearest neighbour among y. Consistent, but biased at finite n in many
  dimensions (low here: tests/test_shift.py measures it against Gaussians of known KL), so a value
  is read against :func:`split_half_null`, the estimate between two halves of the same set, which
  is what "no shift" gives at that sample size.
- :func:`bootstrap_interval`: a percentile interval of any two-sample statistic over resampled rows.
- :func:`classifier_test`: a small MLP separating x (label 1) from y (label 0), trained on part of
  each and scored on the rest: held-out ROC AUC (0.5: indistinguishable) and, per state s, the
  density ratio ``p(s) / q(s) = c(s) / (1 - c(s))`` its probability ``c(s)`` implies (Sugiyama et
  al. 2012; the two classes carry equal total weight in the loss, so no n/m prior correction): the
  weight that turns an expectation under q into one under p.

Distances and the classifier run in float32 torch on the given device, chunked so 20k x 20k states
need O(chunk x m) memory.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

Statistic = Callable[[np.ndarray, np.ndarray], float]


def _as_tensor(states: np.ndarray | torch.Tensor, device: torch.device | str) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(states, dtype=np.float32), device=device)


@torch.no_grad()
def kth_neighbour_distance(queries: torch.Tensor, points: torch.Tensor, k: int, exclude_self: bool = False,
                           chunk: int = 2048) -> torch.Tensor:
    """Distance from each query row to its k-th nearest row of ``points`` (``exclude_self``: the
    queries are the points, and each row's distance to itself is skipped)."""
    out = []
    for start in range(0, len(queries), chunk):
        block = queries[start:start + chunk]
        distances = torch.cdist(block, points)
        if exclude_self:
            rows = torch.arange(len(block), device=block.device)
            distances[rows, rows + start] = float("inf")
        out.append(distances.topk(k, dim=1, largest=False).values[:, k - 1])
    return torch.cat(out)


def knn_kl(x: np.ndarray | torch.Tensor, y: np.ndarray | torch.Tensor, k: int = 1,
           device: torch.device | str = "cpu") -> float:
    """The k-nearest-neighbour estimate of KL(p || q) in nats from ``x [n, d] ~ p`` and ``y [m, d] ~ q``
    (module docstring). Exact duplicate states count once (a bootstrap resample repeats states: it
    becomes a smaller sample, which n and m account for); a zero distance to y is nudged to the
    smallest positive float so the logarithm stays finite."""
    xs, ys = _as_tensor(x, device), _as_tensor(y, device)
    if xs.dim() != 2 or ys.dim() != 2 or xs.shape[1] != ys.shape[1]:
        raise ValueError(f"x, y: expected [n, d] and [m, d] arrays, got {tuple(xs.shape)} and {tuple(ys.shape)}")
    xs, ys = torch.unique(xs, dim=0), torch.unique(ys, dim=0)  # a state drawn twice counts once
    n, d = xs.shape
    m = len(ys)
    if not 1 <= k < min(n, m + 1):
        raise ValueError(f"k: expected 1 <= k < {min(n, m + 1)} (fewer neighbours than states), got {k}")
    tiny = torch.finfo(torch.float32).tiny
    rho = kth_neighbour_distance(xs, xs, k, exclude_self=True).clamp_min(tiny).double()
    nu = kth_neighbour_distance(xs, ys, k).clamp_min(tiny).double()
    return float(d * torch.log(nu / rho).mean() + np.log(m / (n - 1)))


def draw(states: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` rows drawn without replacement (all of them when there are fewer)."""
    if len(states) <= count:
        return np.asarray(states, dtype=np.float32)
    return np.asarray(states[np.sort(rng.choice(len(states), size=count, replace=False))], dtype=np.float32)


def effective_share(weights: np.ndarray) -> float:
    """``(sum w)^2 / (n sum w^2)``: the share of n equally weighted samples that the weights are worth."""
    w = np.asarray(weights, dtype=np.float64)
    return float(w.sum() ** 2 / (len(w) * (w ** 2).sum()))


def split_half_null(x: np.ndarray, statistic: Statistic, seed: int = 0) -> float:
    """The statistic between two random halves of the same states: its value under no shift at half
    the sample size (the reference a measured shift is read against)."""
    order = np.random.default_rng(seed).permutation(len(x))
    half = len(x) // 2
    return statistic(np.asarray(x)[order[:half]], np.asarray(x)[order[half:2 * half]])


def bootstrap_interval(x: np.ndarray, y: np.ndarray, statistic: Statistic, reps: int = 20, seed: int = 0,
                       confidence: float = 0.95) -> tuple[float, float]:
    """Percentile interval of ``statistic(x*, y*)`` over ``reps`` bootstrap resamples of the rows of each
    set (the kNN estimator counts a repeated state once, so its resamples are ~63% subsamples). Read
    it as the estimator's spread, next to its split-half null."""
    if reps < 2:
        raise ValueError(f"reps: expected at least 2 bootstrap resamples, got {reps}")
    rng = np.random.default_rng(seed)
    x, y = np.asarray(x), np.asarray(y)
    values = [statistic(x[rng.integers(len(x), size=len(x))], y[rng.integers(len(y), size=len(y))])
              for _ in range(reps)]
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(values, [tail, 100 - tail])
    return float(low), float(high)


def roc_auc(scores_positive: torch.Tensor, scores_negative: torch.Tensor) -> float:
    """P(score of a positive > score of a negative), ties 1/2 (the Mann-Whitney form of ROC AUC)."""
    scores = torch.cat([scores_positive, scores_negative]).double()
    ranks = torch.empty_like(scores)
    order = scores.argsort()
    ranks[order] = torch.arange(1, len(scores) + 1, dtype=torch.float64)
    unique, inverse = torch.unique(scores, return_inverse=True)  # ties share their mean rank
    mean_rank = torch.zeros(len(unique), dtype=torch.float64).index_add_(0, inverse, ranks)
    mean_rank /= torch.bincount(inverse, minlength=len(unique)).double()
    ranks = mean_rank[inverse]
    n_pos, n_neg = len(scores_positive), len(scores_negative)
    return float((ranks[:n_pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


@dataclass(frozen=True)
class ClassifierConfig:
    """The two-sample classifier: an MLP on standardised states, trained with Adam on a class-balanced
    cross-entropy, scored on a held-out share of each set."""

    hidden: int = 64
    epochs: int = 20
    batch_size: int = 512
    learning_rate: float = 1e-3
    held_out: float = 0.3
    seed: int = 0


@dataclass(frozen=True)
class ClassifierResult:
    auc: float  # held-out ROC AUC: 0.5 = the sets cannot be told apart
    held_out: tuple[int, int]  # held-out states of x and of y
    model: torch.nn.Module  # logit of "drawn from x", on standardised states
    mean: torch.Tensor
    std: torch.Tensor

    @torch.no_grad()
    def density_ratio(self, states: np.ndarray | torch.Tensor) -> np.ndarray:
        """``p(s) / q(s) = c(s) / (1 - c(s)) = exp(logit)`` per state (float64), c the classifier's
        probability of "drawn from x" (classes weighted equally in training)."""
        z = (_as_tensor(states, self.mean.device) - self.mean) / self.std
        return torch.exp(self.model(z).squeeze(-1).double()).cpu().numpy()


def classifier_test(x: np.ndarray, y: np.ndarray, config: ClassifierConfig = ClassifierConfig(),
                    device: torch.device | str = "cpu") -> ClassifierResult:
    """Train a classifier to tell ``x`` (label 1) from ``y`` (label 0) on ``1 - held_out`` of each and
    return its held-out AUC and the density ratio p/q it implies (module docstring)."""
    if not 0 < config.held_out < 1:
        raise ValueError(f"held_out: expected a share in (0, 1), got {config.held_out}")
    generator = torch.Generator().manual_seed(config.seed)
    xs, ys = _as_tensor(x, device), _as_tensor(y, device)
    split = []
    for states in (xs, ys):
        order = torch.randperm(len(states), generator=generator).to(device)
        cut = int(round(len(states) * (1 - config.held_out)))
        if cut < 1 or cut >= len(states):
            raise ValueError(f"x, y: too few states ({len(states)}) for a held-out share of {config.held_out}")
        split.append((states[order[:cut]], states[order[cut:]]))
    (x_train, x_test), (y_train, y_test) = split
    train = torch.cat([x_train, y_train])
    mean, std = train.mean(0), train.std(0).clamp_min(1e-6)
    labels = torch.cat([torch.ones(len(x_train)), torch.zeros(len(y_train))]).to(device)
    weights = torch.where(labels > 0, len(train) / (2.0 * len(x_train)), len(train) / (2.0 * len(y_train)))
    torch.manual_seed(config.seed)
    dim = xs.shape[1]
    model = torch.nn.Sequential(torch.nn.Linear(dim, config.hidden), torch.nn.ReLU(),
                                torch.nn.Linear(config.hidden, config.hidden), torch.nn.ReLU(),
                                torch.nn.Linear(config.hidden, 1)).to(device)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    z = (train - mean) / std
    for _ in range(config.epochs):
        order = torch.randperm(len(z), generator=generator).to(device)
        for start in range(0, len(z), config.batch_size):
            rows = order[start:start + config.batch_size]
            logits = model(z[rows]).squeeze(-1)
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, labels[rows], weight=weights[rows])
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
    model.eval().requires_grad_(False)
    with torch.no_grad():
        auc = roc_auc(model((x_test - mean) / std).squeeze(-1), model((y_test - mean) / std).squeeze(-1))
    return ClassifierResult(auc, (len(x_test), len(y_test)), model, mean, std)
