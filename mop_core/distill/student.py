"""The multi-task student of thesis 4.2: pi^S(s, i) from the state and a one-hot task id."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from torch import nn

from mop_core.config import require
from mop_core.nn import DeterministicActor, GaussianActor, with_task_id


@dataclass(frozen=True)
class StudentConfig:
    """Architecture of the student: ReLU hidden layers, tanh output (thesis: 256 x 256)."""

    hidden_sizes: tuple[int, ...] = (256, 256)
    log_std_min: float = -5.0  # Gaussian students (the KL loss) only: log sigma bounded smoothly to (min, max)
    log_std_max: float = 0.0

    def __post_init__(self) -> None:
        require(len(self.hidden_sizes) >= 1 and all(isinstance(h, int) and h >= 1 for h in self.hidden_sizes),
                "hidden_sizes", "a non-empty list of positive integers (the thesis varies 16 to 512)",
                self.hidden_sizes)
        require(self.log_std_min < self.log_std_max, "log_std_min", f"a value < log_std_max={self.log_std_max}",
                self.log_std_min)


class Student(nn.Module):
    """``(obs [B, o], task ids [B] or int) -> action [B, k]``; a Gaussian student's action is its mean.

    ``gaussian``: a diagonal Gaussian head (mean, log std) as the KL loss needs (thesis 5.1.3).
    """

    def __init__(self, config: StudentConfig, obs_dim: int, act_dim: int, num_tasks: int, gaussian: bool = False):
        super().__init__()
        self.config, self.num_tasks, self.gaussian = config, num_tasks, gaussian
        in_dim = obs_dim + num_tasks
        if gaussian:
            self.actor: nn.Module = GaussianActor(in_dim, act_dim, config.hidden_sizes, False, config.log_std_min,
                                                  config.log_std_max)
        else:
            self.actor = DeterministicActor(in_dim, act_dim, config.hidden_sizes)

    def forward(self, obs: torch.Tensor, task: int | torch.Tensor) -> torch.Tensor:
        return self.actor(with_task_id(obs, task, self.num_tasks))

    def distribution(self, obs: torch.Tensor, task: int | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mu, sigma) of a Gaussian student."""
        if not isinstance(self.actor, GaussianActor):
            raise TypeError("distribution: this student is deterministic (only KL students are Gaussian)")
        return self.actor.distribution(with_task_id(obs, task, self.num_tasks))

    def hidden_layers(self) -> Sequence[nn.Module]:
        """The ReLU modules whose outputs are the hidden activations (thesis 6.2.1)."""
        return [m for m in self.actor.net if isinstance(m, nn.ReLU)]
