"""The schedule of an offline learner (PBRL teachers, the multi-task baseline, students): how long it
trains and how often it evaluates and checkpoints. A config type of its own so that the study grid
(mop_core.experiment.study) can hold it without importing the training loop."""

from __future__ import annotations

from dataclasses import dataclass

from mop_core.config import require


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
