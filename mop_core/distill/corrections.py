"""Distillation that corrects for the state distribution shift (thesis 5.3; issue 18 parts 5-6).

The student learns on dataset states s ~ D_i but acts on the states it visits itself, close to the
teacher's own T_i when it imitates well. Two corrections, each a ``distill.correction``:

- ``reweight`` (the thesis's proposal, 5.3 / 8.3): task i's training states are drawn with
  probability proportional to a clipped density ratio instead of uniformly::

      w(s) = min(r(s) / mean_{s' in D_i} r(s'), clip),   r(s) = p_T(s) / p_D(s) = c(s) / (1 - c(s))

  with c the probability of a classifier telling the teacher's held-out visited states (the compose
  stage's reference episodes) from D_i's states (mop_core.shift.classifier_test). Uniform weights
  are w = 1; the clip bounds a single state's weight at ``clip`` times the mean (without it, a few
  states carry the whole distribution: the measured effective sample share of r is 0.19 on the
  medium dataset and 0.01 on random99).
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
from mop_core.shift import ClassifierConfig, classifier_test, draw, effective_share
from mop_core.study import SHIFT_CORRECTIONS

CORRECTIONS = ("none", *SHIFT_CORRECTIONS)  # distill.correction: none, or a state_shift.corrections entry


@dataclass(frozen=True)
class ReweightConfig:
    """The ``reweight`` correction's density ratio and its clip (module docstring)."""

    clip: float = 10.0  # the largest weight, in units of the mean weight
    states: int = 20000  # states of each set (teacher, dataset) the classifier learns on
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


def density_weights(states: np.ndarray, reference: np.ndarray, config: ReweightConfig, seed: int
                    ) -> tuple[np.ndarray, dict]:
    """The clipped, mean-normalised density-ratio weight of every row of ``states`` (dataset D) against
    the teacher's ``reference`` states T (module docstring), and what it did: the classifier's
    held-out AUC, the effective sample share of the weights before and after clipping and the share
    of states clipped."""
    rng = np.random.default_rng(seed)
    classifier = classifier_test(draw(reference, config.states, rng), draw(states, config.states, rng),
                                 ClassifierConfig(epochs=config.epochs, seed=seed % (2 ** 31)))
    ratio = classifier.density_ratio(np.asarray(states, dtype=np.float32))
    ratio = ratio / ratio.mean()
    weights = np.minimum(ratio, config.clip)
    return weights, {"reweight_auc": classifier.auc, "reweight_ess_unclipped": effective_share(ratio),
                     "reweight_ess": effective_share(weights),
                     "reweight_clipped_share": float((ratio > config.clip).mean())}
