"""The schedules of the study's learners: how long they train and how often they evaluate and
checkpoint. :class:`TrainSchedule`: an offline learner (PBRL teachers, the multi-task baseline,
students; mop_core.learning.training.train_loop). :class:`OnlineSchedule`: an online one (collect's
TD3 behaviour policies; mop_core.learning.online.fit_online). Config types of their own so that the
study grid (mop_core.experiment.study) can hold them without importing the loops. Both loops ask
:func:`due` when to evaluate and when to check their weights: every ``every`` steps and at the last."""

from __future__ import annotations

import math
from dataclasses import dataclass

from mop_core.config import require

LR_SCHEDULES = ("constant", "cosine")  # a learner's learning rate over its run


def scheduled_rate(base: float, schedule: str, step: int, total_steps: int) -> float:
    """The learning rate of gradient step ``step`` (0-based) of ``total_steps``: ``base`` (constant) or
    ``base * (1 + cos(pi * step / total_steps)) / 2`` (cosine, to 0 at the last step)."""
    if schedule == "constant":
        return base
    return base * 0.5 * (1.0 + math.cos(math.pi * min(step, total_steps) / total_steps))


def set_learning_rate(optimizers, lr: float) -> None:
    """Every parameter group of ``optimizers`` at learning rate ``lr``; a tensor rate (a captured
    step's, :func:`mop_core.learning.graphs.capturable_adam`) is filled in place, so the replayed
    graph reads it."""
    for optimizer in optimizers:
        for group in optimizer.param_groups:
            if hasattr(group["lr"], "fill_"):  # a torch.Tensor
                group["lr"].fill_(lr)
            else:
                group["lr"] = lr


def due(step: int, every: int, last: int) -> bool:
    """A periodic event (an evaluation, a weight check) at ``step``: every ``every`` steps, and at ``last``."""
    return step % every == 0 or step == last


@dataclass(frozen=True)
class TrainSchedule:
    """How long a PBRL run trains and how often it evaluates and checkpoints (gradient steps)."""

    steps: int  # gradient steps (the multi-task baseline: per task)
    eval_every: int = 10000  # steps between learning-curve evaluations
    eval_episodes: int = 5  # episodes per learning-curve evaluation (same seeds every time)
    final_eval_episodes: int = 10  # episodes of the final evaluation (seeds not used for the curve)
    checkpoint_every: int = 10000  # steps between resume checkpoints
    rollout_envs: int = 10  # walkers stepped together in evaluations

    def __post_init__(self) -> None:
        for name in ("steps", "eval_every", "eval_episodes", "final_eval_episodes", "checkpoint_every",
                     "rollout_envs"):
            require(getattr(self, name) > 0, name, "a positive integer", getattr(self, name))

    def evaluates_at(self, step: int) -> bool:
        """A learning-curve point after update ``step``."""
        return due(step, self.eval_every, self.steps)


@dataclass(frozen=True)
class OnlineSchedule:
    """How an online learner interleaves environment steps and updates: ``warmup_steps`` random
    actions, then one update per environment step for ``updates`` updates (TD3, thesis 4.4.3)."""

    warmup_steps: int  # uniformly random actions before the first update
    updates: int  # gradient steps, one per environment step after the warm-up
    eval_every: int  # updates between learning-curve evaluations
    checkpoint_every: int  # updates between resume files (each written at the next episode end)
    extra_evals: tuple[int, ...] = ()  # updates that also evaluate (collect: the medium snapshot's step)

    @property
    def env_steps(self) -> int:
        return self.warmup_steps + self.updates

    def evaluates_at(self, update: int) -> bool:
        """A learning-curve point after update ``update``."""
        return due(update, self.eval_every, self.updates) or update in self.extra_evals
