"""Distillation that corrects for the state distribution shift (thesis 5.3).

The student learns on dataset states s ~ D_i but acts on the states it visits itself, close to the
teacher's own T_i when it imitates well. Two corrections, each a ``distill.correction``:

- ``reweight`` (the thesis's proposal, 5.3 / 8.3): task i's training states are drawn with
  probability proportional to a clipped density ratio instead of uniformly::

      w(s) = min(r(s) / mean_{s' in D_i} r(s'), clip),   r(s) = p_T(s) / p_D(s) = c(s) / (1 - c(s))

  with c the probability of a classifier telling the teacher's held-out visited states (the compose
  stage's reference episodes) from D_i's states, cross-fitted over whole episodes
  (mop_core.shift.measures.crossfit_test): each set's episodes are dealt into two folds, and a
  state's ratio comes from the classifier trained on the other fold's episodes of both sets, never
  on its own episode (an episode's states are near-duplicates: a classifier scoring states of the
  episodes it learned on reads them as D and underweights them); its AUC is the folds' held-out
  mean. Uniform weights are w = 1; the clip bounds a single state's weight at ``clip`` times the
  mean (without it, a few states carry the whole distribution: the measured effective sample share
  of r is 0.19 on the medium dataset and 0.01 on random99, with the earlier row-split classifier).
- ``dagger``: the student-sampled reference (DAgger, Ross et al. 2011; in distillation, Czarnecki
  et al. 2019): the training steps are cut into ``rounds + 1`` equal phases; before each phase but the
  first, every student rolls out ``episodes`` episodes per task, the frozen teacher labels the visited
  states and they join the student's states for the rest of training (aggregated, not replaced).
  Same gradient steps as plain MOP, plus ``rounds * episodes`` online episodes per task: an upper
  bound on what correcting the shift can give, at a cost offline distillation cannot pay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mop_core.config import require
from mop_core.experiment.variants import SHIFT_CORRECTIONS
from mop_core.shift.measures import ClassifierConfig, crossfit_test, effective_share, row_episodes

CORRECTIONS = ("none", *SHIFT_CORRECTIONS)  # distill.correction: none, or a state_shift.corrections entry
REWEIGHT_FOLDS = 2  # folds of whole episodes the density ratio is cross-fitted over
MIN_BLOCKS = 8  # pseudo-episodes per set at least, when no episode ids are given (density_weights)


@dataclass(frozen=True)
class ReweightConfig:
    """The ``reweight`` correction's density ratio and its clip (module docstring)."""

    clip: float = 10.0  # the largest weight, in units of the mean weight
    states: int = 20000  # states of each set (teacher, dataset) each fold's classifier learns on
    epochs: int = 10  # classifier epochs

    def __post_init__(self) -> None:
        require(self.clip >= 1, "clip", "a number >= 1 (the largest weight over the mean one)", self.clip)
        require(self.states >= 100, "states", "at least 100", self.states)
        require(self.epochs >= 1, "epochs", "a positive integer", self.epochs)


@dataclass(frozen=True)
class DaggerConfig:
    """The ``dagger`` reference's aggregation rounds (module docstring)."""

    rounds: int = 3  # aggregation rounds (the steps are cut into rounds + 1 phases)
    episodes: int = 2  # episodes per task, student and round

    def __post_init__(self) -> None:
        require(self.rounds >= 1, "rounds", "a positive integer", self.rounds)
        require(self.episodes >= 1, "episodes", "a positive integer", self.episodes)

    def round_starts(self, steps: int) -> dict[int, int]:
        """{update index: round} at which each round aggregates (``k * steps // (rounds + 1)``, k >= 1)."""
        return {k * steps // (self.rounds + 1): k for k in range(1, self.rounds + 1)}


def block_episodes(rows: int, episode_rows: int) -> np.ndarray:
    """Pseudo-episode ids of ``rows`` states in dataset order: contiguous blocks of ``episode_rows``
    (fewer when that leaves under MIN_BLOCKS blocks). Whole dataset episodes of that length in order
    (all rows, or whole episodes of them) make each block one episode."""
    size = max(1, min(episode_rows, rows // MIN_BLOCKS))
    return np.arange(rows) // size


def density_weights(states: np.ndarray, reference: np.ndarray, config: ReweightConfig, seed: int,
                    episode_rows: int | None = None, episodes: tuple[np.ndarray, np.ndarray] | None = None
                    ) -> tuple[np.ndarray, dict]:
    """The clipped, mean-normalised density-ratio weight of every row of ``states`` (dataset D) against
    the teacher's ``reference`` states T (module docstring), and what it did: the classifier's
    held-out AUC, the effective sample share of the weights before and after clipping and the share
    of states clipped. ``episodes``: the episode id of every row of (states, reference); without
    them the rows are taken in dataset order as episodes of ``episode_rows`` (:func:`block_episodes`:
    exact for whole episodes of that length). Deterministic under ``seed``."""
    if episodes is None:
        if episode_rows is None:
            raise ValueError("density_weights: expected episode_rows (the episode length) or episodes (row ids)")
        episodes = (block_episodes(len(states), episode_rows), block_episodes(len(reference), episode_rows))
    state_ids, reference_ids = row_episodes(episodes[0], len(states)), row_episodes(episodes[1], len(reference))
    classifier = crossfit_test(reference, states, ClassifierConfig(epochs=config.epochs, seed=seed % (2 ** 31)),
                               x_episodes=reference_ids, y_episodes=state_ids, folds=REWEIGHT_FOLDS,
                               train_states=config.states)
    ratio = classifier.ratio / classifier.ratio.mean()
    weights = np.minimum(ratio, config.clip)
    return weights, {"reweight_auc": classifier.auc, "reweight_ess_unclipped": effective_share(ratio),
                     "reweight_ess": effective_share(weights),
                     "reweight_clipped_share": float((ratio > config.clip).mean())}
