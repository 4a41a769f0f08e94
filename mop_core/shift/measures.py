"""State distribution shift between two sets of states (thesis 5.2.2 could not measure it): a
nearest-neighbour KL estimator with its split-half null and a bootstrap interval, and a
classifier two-sample test with the density ratio it implies.

Every split is by whole episodes. The states of one episode are near-duplicates of each
other, so two halves that share episodes look alike whatever the process (a row-split null near 0
that no other set reaches; a classifier that scores rows of the episodes it trained on). Each
function takes the episode id of every row (:func:`episode_ids`: from the datasets' ``timeouts``,
an episode's last row); without them each row is its own episode, right for independent rows only.

- :func:`knn_kl`: Wang, Kulkarni and Verdu (2009), for ``x ~ p`` (n states) and ``y ~ q`` (m states)
  in d dimensions::

      D(p || q) ~= d / n * sum_i log(nu_k(i) / rho_k(i)) + log(m / (n - 1))

  with ``rho_k(i)`` the distance from x_i to its k-th nearest neighbour among the other x and
  ``nu_k(i)`` to its k-th nearest neighbour among y. Consistent, but biased at finite n in many
  dimensions (low here: tests/test_shift.py measures it against Gaussians of known KL), so a value
  is read against :func:`split_half_null`, the estimate between two halves of the same set's
  episodes, which is what "no shift" gives at that sample size.
- :func:`bootstrap_interval`: a percentile interval of any two-sample statistic over resampled
  whole episodes.
- :func:`classifier_test`: a small MLP separating x (label 1) from y (label 0), trained on some
  episodes of each and scored on the others: held-out ROC AUC (0.5: indistinguishable) and, per
  state s, the density ratio ``p(s) / q(s) = c(s) / (1 - c(s))`` its probability ``c(s)`` implies
  (Sugiyama et al. 2012; the two classes carry equal total weight in the loss, so no n/m prior
  correction): the weight that turns an expectation under q into one under p.
  :func:`crossfit_test`: the same over episode folds, each fold scored by the classifier trained on
  the others: an AUC from every episode and the ratio at every y state from a classifier that never
  saw its episode.

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


def draw_rows(rows: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` of ``rows`` drawn without replacement, in order (all of them when there are fewer)."""
    rows = np.asarray(rows)
    if len(rows) <= count:
        return rows
    return np.sort(rng.choice(rows, size=count, replace=False))


def episode_ids(ends: np.ndarray) -> np.ndarray:
    """The episode of every row, numbered from 0 in order, from ``ends`` (a D4RL-style dataset's
    ``timeouts``, or ``timeouts | terminals``: True at an episode's last row)."""
    ends = np.asarray(ends, dtype=bool)
    ids = np.zeros(len(ends), dtype=np.int64)
    ids[1:] = np.cumsum(ends[:-1])
    return ids


def row_episodes(episodes: np.ndarray | None, rows: int) -> np.ndarray:
    """``episodes`` checked against the ``rows`` states they label; None: each row its own episode."""
    if episodes is None:
        return np.arange(rows)
    ids = np.asarray(episodes)
    if ids.shape != (rows,):
        raise ValueError(f"episodes: expected one episode id per state ({rows}), got shape {ids.shape}")
    return ids


def episode_folds(episodes: np.ndarray, folds: int, rng: np.random.Generator) -> np.ndarray:
    """The fold (0 .. folds - 1) of every row: whole episodes dealt at random to the folds, whose
    episode counts differ by at most one."""
    unique, inverse = np.unique(episodes, return_inverse=True)
    if len(unique) < folds:
        raise ValueError(f"episodes: expected at least {folds} episodes to split by whole episodes, got {len(unique)}")
    fold_of = np.empty(len(unique), dtype=np.int64)
    fold_of[rng.permutation(len(unique))] = np.arange(len(unique)) % folds
    return fold_of[inverse.reshape(-1)]


def episode_sample(episodes: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """The rows of ``count`` whole episodes drawn without replacement (all when there are fewer), in order."""
    unique, inverse = np.unique(episodes, return_inverse=True)
    if count >= len(unique):
        return np.arange(len(episodes))
    chosen = np.zeros(len(unique), dtype=bool)
    chosen[rng.choice(len(unique), size=count, replace=False)] = True
    return np.flatnonzero(chosen[inverse.reshape(-1)])


def effective_share(weights: np.ndarray) -> float:
    """``(sum w)^2 / (n sum w^2)``: the share of n equally weighted samples that the weights are worth."""
    w = np.asarray(weights, dtype=np.float64)
    return float(w.sum() ** 2 / (len(w) * (w ** 2).sum()))


def split_half_null(x: np.ndarray, statistic: Statistic, seed: int = 0, episodes: np.ndarray | None = None) -> float:
    """The statistic between two disjoint random halves of the same states' whole ``episodes`` (the
    same number of rows each): its value under no shift at half the sample size (the reference a
    measured shift is read against)."""
    x = np.asarray(x)
    rng = np.random.default_rng(seed)
    half = episode_folds(row_episodes(episodes, len(x)), 2, rng)
    first, second = np.flatnonzero(half == 0), np.flatnonzero(half == 1)
    size = min(len(first), len(second))
    return statistic(x[draw_rows(first, size, rng)], x[draw_rows(second, size, rng)])


def _resample_episodes(episodes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Rows of as many whole episodes as there are, drawn with replacement (a cluster bootstrap)."""
    unique, inverse = np.unique(episodes, return_inverse=True)
    order = np.argsort(inverse.reshape(-1), kind="stable")
    rows = np.split(order, np.cumsum(np.bincount(inverse.reshape(-1)))[:-1])
    return np.concatenate([rows[e] for e in rng.integers(len(unique), size=len(unique))])


def bootstrap_interval(x: np.ndarray, y: np.ndarray, statistic: Statistic, reps: int = 20, seed: int = 0,
                       confidence: float = 0.95, x_episodes: np.ndarray | None = None,
                       y_episodes: np.ndarray | None = None) -> tuple[float, float]:
    """Percentile interval of ``statistic(x*, y*)`` over ``reps`` bootstrap resamples of the whole
    episodes of each set (the kNN estimator counts a repeated state once, so its resamples are ~63%
    subsamples). Read it as the estimator's spread, next to its split-half null."""
    if reps < 2:
        raise ValueError(f"reps: expected at least 2 bootstrap resamples, got {reps}")
    rng = np.random.default_rng(seed)
    x, y = np.asarray(x), np.asarray(y)
    x_ids, y_ids = row_episodes(x_episodes, len(x)), row_episodes(y_episodes, len(y))
    values = [statistic(x[_resample_episodes(x_ids, rng)], y[_resample_episodes(y_ids, rng)]) for _ in range(reps)]
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
    cross-entropy, scored on a held-out share of each set's whole episodes."""

    hidden: int = 64
    epochs: int = 20
    batch_size: int = 512
    learning_rate: float = 1e-3
    held_out: float = 0.3  # share of each set's episodes held out (classifier_test; crossfit_test: its folds)
    seed: int = 0


@dataclass(frozen=True)
class ClassifierResult:
    auc: float  # held-out ROC AUC: 0.5 = the sets cannot be told apart
    held_out: tuple[int, int]  # held-out states of x and of y (whole episodes)
    model: torch.nn.Module  # logit of "drawn from x", on standardised states
    mean: torch.Tensor
    std: torch.Tensor

    @torch.no_grad()
    def density_ratio(self, states: np.ndarray | torch.Tensor) -> np.ndarray:
        """``p(s) / q(s) = c(s) / (1 - c(s)) = exp(logit)`` per state (float64), c the classifier's
        probability of "drawn from x" (classes weighted equally in training)."""
        z = (_as_tensor(states, self.mean.device) - self.mean) / self.std
        return torch.exp(self.model(z).squeeze(-1).double()).cpu().numpy()


@dataclass(frozen=True)
class CrossFitResult:
    auc: float  # mean over the folds of each fold's held-out ROC AUC
    fold_aucs: tuple[float, ...]
    ratio: np.ndarray  # p/q at every row of y, from the classifier that did not train on its episode


def held_out_episodes(episodes: np.ndarray, share: float, rng: np.random.Generator) -> np.ndarray:
    """Rows of ``round(share * episodes)`` random whole episodes (at least one, all but one at most)."""
    unique, inverse = np.unique(episodes, return_inverse=True)
    if len(unique) < 2:
        raise ValueError(f"x, y: too few episodes ({len(unique)}) to hold out whole episodes; expected at least 2")
    count = min(len(unique) - 1, max(1, int(round(share * len(unique)))))
    chosen = np.zeros(len(unique), dtype=bool)
    chosen[rng.choice(len(unique), size=count, replace=False)] = True
    return chosen[inverse.reshape(-1)]


def _fit(x_train: torch.Tensor, y_train: torch.Tensor, config: ClassifierConfig, generator: torch.Generator,
         seed: int) -> tuple[torch.nn.Module, torch.Tensor, torch.Tensor]:
    """The classifier trained to tell x_train (1) from y_train (0), and its standardisation."""
    device = x_train.device
    train = torch.cat([x_train, y_train])
    mean, std = train.mean(0), train.std(0).clamp_min(1e-6)
    labels = torch.cat([torch.ones(len(x_train)), torch.zeros(len(y_train))]).to(device)
    weights = torch.where(labels > 0, len(train) / (2.0 * len(x_train)), len(train) / (2.0 * len(y_train)))
    torch.manual_seed(seed)
    dim = train.shape[1]
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
    return model.eval().requires_grad_(False), mean, std


@torch.no_grad()
def _logits(model: torch.nn.Module, mean: torch.Tensor, std: torch.Tensor, states: torch.Tensor) -> torch.Tensor:
    return model((states - mean) / std).squeeze(-1)


def _mask(rows: np.ndarray, device: torch.device | str) -> torch.Tensor:
    return torch.as_tensor(rows, device=device)


def classifier_test(x: np.ndarray, y: np.ndarray, config: ClassifierConfig = ClassifierConfig(),
                    device: torch.device | str = "cpu", x_episodes: np.ndarray | None = None,
                    y_episodes: np.ndarray | None = None) -> ClassifierResult:
    """Train a classifier to tell ``x`` (label 1) from ``y`` (label 0) on ``1 - held_out`` of the whole
    episodes of each (``x_episodes``, ``y_episodes``: every row's episode; None: independent rows)
    and return its AUC on the other episodes and the density ratio p/q it implies (module docstring)."""
    if not 0 < config.held_out < 1:
        raise ValueError(f"held_out: expected a share in (0, 1), got {config.held_out}")
    rng = np.random.default_rng(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    xs, ys = _as_tensor(x, device), _as_tensor(y, device)
    x_test = _mask(held_out_episodes(row_episodes(x_episodes, len(xs)), config.held_out, rng), device)
    y_test = _mask(held_out_episodes(row_episodes(y_episodes, len(ys)), config.held_out, rng), device)
    model, mean, std = _fit(xs[~x_test], ys[~y_test], config, generator, config.seed)
    auc = roc_auc(_logits(model, mean, std, xs[x_test]), _logits(model, mean, std, ys[y_test]))
    return ClassifierResult(auc, (int(x_test.sum()), int(y_test.sum())), model, mean, std)


def crossfit_test(x: np.ndarray, y: np.ndarray, config: ClassifierConfig = ClassifierConfig(),
                  device: torch.device | str = "cpu", x_episodes: np.ndarray | None = None,
                  y_episodes: np.ndarray | None = None, folds: int = 2, train_states: int | None = None
                  ) -> CrossFitResult:
    """:func:`classifier_test` over ``folds`` folds of whole episodes of each set (``held_out`` unused):
    fold j is scored by a classifier trained on the other folds (at most ``train_states`` rows of
    each set, drawn from them); the AUC is the folds' mean and the density ratio at every y row comes
    from the classifier that never saw its episode (cross-fitting)."""
    if folds < 2:
        raise ValueError(f"folds: expected at least 2, got {folds}")
    rng = np.random.default_rng(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    xs, ys = _as_tensor(x, device), _as_tensor(y, device)
    x_fold = episode_folds(row_episodes(x_episodes, len(xs)), folds, rng)
    y_fold = episode_folds(row_episodes(y_episodes, len(ys)), folds, rng)
    cap = train_states or max(len(xs), len(ys))
    ratio = np.empty(len(ys), dtype=np.float64)
    aucs = []
    for fold in range(folds):
        x_train = _mask(draw_rows(np.flatnonzero(x_fold != fold), cap, rng), device)
        y_train = _mask(draw_rows(np.flatnonzero(y_fold != fold), cap, rng), device)
        model, mean, std = _fit(xs[x_train], ys[y_train], config, generator, config.seed + fold)
        y_rows = np.flatnonzero(y_fold == fold)
        y_logits = _logits(model, mean, std, ys[_mask(y_rows, device)])
        aucs.append(roc_auc(_logits(model, mean, std, xs[_mask(np.flatnonzero(x_fold == fold), device)]), y_logits))
        ratio[y_rows] = torch.exp(y_logits.double()).cpu().numpy()
    return CrossFitResult(float(np.mean(aucs)), tuple(aucs), ratio)
