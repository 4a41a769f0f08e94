"""What a distillation run is configured by (thesis 4.2, 5.1.3, 6.3.2): :class:`DistillConfig`, its
ranking regulariser (:class:`RankingConfig`) and learning-rate schedule, read from the ``distill``
params section. Kept apart from the learner (mop_core.distill.distiller), so that reading a
checkpoint's config or checking params does not import the training machinery.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from mop_core.config import ConfigError, from_mapping, require
from mop_core.distill.corrections import CORRECTIONS, DaggerConfig, ReweightConfig
from mop_core.distill.losses import LOSSES, Q_REDUCTIONS
from mop_core.distill.ranking import RANKING_LOSSES
from mop_core.distill.student import StudentConfig
from mop_core.experiment.study import DISTILL_GRID_KEYS, section
from mop_core.learning.schedule import LR_SCHEDULES, scheduled_rate

STATE_SOURCES = ("offline", "online")
RANKING_CHOICES = ("none", *RANKING_LOSSES)
PROBE_SOURCES = ("offline", "visited")


def learning_rate_at(config: "DistillConfig", step: int, total_steps: int) -> float:
    """The learning rate of gradient step ``step`` (0-based) of ``total_steps``."""
    return scheduled_rate(config.learning_rate, config.lr_schedule, step, total_steps)


@dataclass(frozen=True)
class RankingConfig:
    """The ranking regulariser of thesis 6.3.2 (mop_core.distill.ranking): the loss becomes

        L_distill + weight * sum_j layer_weights[j] * mean_{i != k} mean_s L_rank(l_j(s, i), sg[l_j(s, k)])

    over each hidden layer j, every ordered pair of task ids and ``states`` states per task per step
    (the first ``states`` of the step's draws; the thesis compares the whole batch, whose pairwise
    loss costs ``batch * width^2`` per layer; with 2 states per task a group's step at initialisation
    costs 2.74x a plain one for pairwise, 1.15x for listwise and 2.38x for ApproxNDCG on 2 CPU
    cores: benchmarks/README.md, distill)."""

    loss: str = "none"  # none | pairwise | listwise | approx_ndcg
    weight: float = 100.0  # lambda (thesis: 100)
    layer_weights: tuple[float, ...] = ()  # one per hidden layer; empty = 1 for every layer
    states: int = 2  # states per task per step the regulariser compares under every task id
    temperature: float = 0.1  # approx_ndcg's sigmoid temperature (smooth ranks)

    def __post_init__(self) -> None:
        require(self.loss in RANKING_CHOICES, "loss", f"one of {RANKING_CHOICES}", self.loss)
        require(self.weight >= 0, "weight", "a non-negative number (lambda)", self.weight)
        require(all(w >= 0 for w in self.layer_weights), "layer_weights", "non-negative numbers",
                list(self.layer_weights))
        require(self.states >= 1, "states", "a positive integer", self.states)
        require(self.temperature > 0, "temperature", "a positive number", self.temperature)

    @property
    def active(self) -> bool:
        return self.loss != "none" and self.weight > 0

    def weights_for(self, layers: int) -> tuple[float, ...]:
        return self.layer_weights or (1.0,) * layers


@dataclass(frozen=True)
class DistillConfig:
    """What a student learns from and how (the schedule is a separate TrainSchedule)."""

    loss: str = "mse"  # mse | q | kl (kl needs Gaussian teachers; its student is Gaussian too)
    student: StudentConfig = field(default_factory=StudentConfig)
    learning_rate: float = 1e-4
    lr_schedule: str = "constant"  # constant | cosine: lr * (1 + cos(pi * step / steps)) / 2, to 0 at the end
    batch_size: int = 256  # states per task per gradient step
    q_reduction: str = "min"  # Q loss: reduce the teacher's critic ensemble by min or mean
    state_source: str = "offline"  # offline: the task's dataset; online: states the teacher visits
    num_states: int = 0  # states per task; 0 = the whole offline dataset (online: must be > 0)
    data_fraction: float = 1.0  # offline: the share of each dataset's whole episodes kept (drawn per student
    #                             seed; the dataset-size experiment), before num_states draws from them
    probe_states: int = 256  # states per task for the per-state tau curve (thesis 6.3.1, Fig. 6.4b); 0 = off
    probe_source: str = "offline"  # offline: fixed dataset states, the same for every student; visited: states
    #                                the student visits in each evaluation (the reference code's choice)
    step_per_task: bool = False  # one Adam step per task per update (reference code) instead of one over all tasks
    ranking: RankingConfig = field(default_factory=RankingConfig)  # thesis 6.3.2 regulariser (loss none: off)
    correction: str = "none"  # none | reweight | dagger: a state-shift correction (mop_core.distill.corrections)
    reweight: ReweightConfig = field(default_factory=ReweightConfig)  # correction reweight's ratio and clip
    dagger: DaggerConfig = field(default_factory=DaggerConfig)  # correction dagger's rounds

    def __post_init__(self) -> None:
        require(self.loss in LOSSES, "loss", f"one of {tuple(LOSSES)}", self.loss)
        require(self.q_reduction in Q_REDUCTIONS, "q_reduction", f"one of {Q_REDUCTIONS}", self.q_reduction)
        require(self.state_source in STATE_SOURCES, "state_source", f"one of {STATE_SOURCES}", self.state_source)
        require(self.learning_rate > 0, "learning_rate", "a positive number", self.learning_rate)
        require(self.lr_schedule in LR_SCHEDULES, "lr_schedule", f"one of {LR_SCHEDULES}", self.lr_schedule)
        require(self.batch_size >= 1, "batch_size", "a positive integer", self.batch_size)
        require(self.probe_states >= 0, "probe_states", "a non-negative integer (0 = no tau curve)",
                self.probe_states)
        require(self.probe_source in PROBE_SOURCES, "probe_source", f"one of {PROBE_SOURCES}", self.probe_source)
        require(self.num_states >= 0, "num_states", "a non-negative integer (0 = the whole dataset)",
                self.num_states)
        require(self.state_source == "offline" or self.num_states > 0, "num_states",
                "a positive number of states for state_source online", self.num_states)
        require(0 < self.data_fraction <= 1, "data_fraction", "a share of the dataset's episodes in (0, 1]",
                self.data_fraction)
        require(self.data_fraction == 1 or self.state_source == "offline", "data_fraction",
                "1 unless state_source is offline", self.data_fraction)
        require(self.correction in CORRECTIONS, "correction", f"one of {CORRECTIONS}", self.correction)
        require(self.correction != "reweight" or self.state_source == "offline", "correction",
                "not reweight unless state_source is offline (it reweights dataset states)", self.correction)
        hidden = len(self.student.hidden_sizes)
        require(len(self.ranking.layer_weights) in (0, hidden), "ranking.layer_weights",
                f"one weight per hidden layer of the student ({hidden}) or [] (1 each)",
                list(self.ranking.layer_weights))
        require(not self.ranking.active or self.ranking.states <= self.batch_size, "ranking.states",
                f"at most batch_size={self.batch_size} (the regulariser compares states of the step's batch)",
                self.ranking.states)


def distill_config(params: Mapping[str, Any], loss: str) -> DistillConfig:
    raw = {k: v for k, v in section(params, "distill").items() if k not in DISTILL_GRID_KEYS}
    if "loss" in raw:
        raise ConfigError("distill.loss: set the losses in distill.losses instead")
    if "correction" in raw:  # a student variant's setting, not the study's (its correction students set it)
        raise ConfigError("distill.correction: set the state_shift corrections instead (state_shift.corrections)")
    return from_mapping(DistillConfig, raw | {"loss": loss}, "distill")
