"""Frozen policies rebuilt from the teacher stages' checkpoints: a PBRL teacher (actor and critics) and
the naive multi-task baseline's shared actor. What the distillation, evaluation and state-shift code reads,
without importing the training code of :mod:`mop_core.teachers` (which writes these checkpoints).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from mop_core.agents.pbrl import PBRLConfig, make_actor
from mop_core.config import from_mapping
from mop_core.learning.nn import EnsembleCritic, numpy_policy
from mop_core.storage.artifacts import load_checkpoint

TEACHER_KIND = "pbrl_teacher"
MULTITASK_KIND = "pbrl_multitask"


@dataclass
class Teacher:
    """A frozen teacher rebuilt from its checkpoint: actor (deterministic or Gaussian) and critics."""

    task: str
    level: str
    seed: int
    config: PBRLConfig
    actor: torch.nn.Module
    critic: EnsembleCritic
    actor_sha256: str = ""
    metrics: dict = field(default_factory=dict)  # the training run's metrics (final return, dataset return)
    source_task: str = ""  # the task(s) whose data it learned from ('+'-joined for a union), D_{j->task}

    def act(self, observations: np.ndarray) -> np.ndarray:
        return numpy_policy(self.actor)(observations)


def load_teacher(path: str | Path) -> Teacher:
    """Rebuild a teacher from a ``train_teacher`` checkpoint (no params.yaml needed)."""
    return teacher_from_checkpoint(load_checkpoint(path, TEACHER_KIND))


def teacher_from_checkpoint(payload: dict) -> Teacher:
    config = from_mapping(PBRLConfig, payload["pbrl_config"], "pbrl_config")
    actor = make_actor(config, payload["obs_dim"], payload["act_dim"])
    actor.load_state_dict(payload["actor"])
    critic = EnsembleCritic(payload["obs_dim"], payload["act_dim"], config.hidden_sizes, config.ensemble_size,
                            config.layer_norm)
    critic.load_state_dict(payload["critic"])
    return Teacher(payload["task"], payload["level"], payload["seed"], config, actor.eval().requires_grad_(False),
                   critic.eval().requires_grad_(False), payload["actor_sha256"], dict(payload["metrics"]),
                   str(payload.get("dataset", {}).get("source_task", "")))


@dataclass
class MultiTaskPolicy:
    """The naive multi-task baseline's shared actor rebuilt from its checkpoint."""

    tasks: list[str]
    level: str
    seed: int
    actor: torch.nn.Module

    def policy(self, task: str) -> Callable[[np.ndarray], np.ndarray]:
        if task not in self.tasks:
            raise ValueError(f"task: expected one of the baseline's tasks {self.tasks}, got {task!r}")
        return numpy_policy(self.actor, torch.device("cpu"), self.tasks.index(task), len(self.tasks))


def multitask_from_checkpoint(payload: dict) -> MultiTaskPolicy:
    config = from_mapping(PBRLConfig, payload["pbrl_config"], "pbrl_config")
    actor = make_actor(config, payload["obs_dim"] + len(payload["tasks"]), payload["act_dim"])
    actor.load_state_dict(payload["actor"])
    return MultiTaskPolicy(list(payload["tasks"]), payload["level"], payload["seed"],
                           actor.eval().requires_grad_(False))
