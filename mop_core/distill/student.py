"""The multi-task student of thesis 4.2: pi^S(s, i) from the state and a one-hot task id, and a group
of R such students trained as one vectorised model (:class:`StudentGroup`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from torch import nn

from mop_core.config import require
from mop_core.learning.nn import (
    DeterministicActor,
    GaussianActor,
    bounded_log_std,
    copy_member,
    ensemble_forward,
    member_loop_pays,
    stack_networks,
    with_task_id,
)


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


class StudentGroup(nn.Module):
    """R students of one architecture trained together as one model with a leading run dimension.

    Layer k holds the R students' weights as one ``[R, in, out]`` tensor (:class:`EnsembleLinear`),
    so one forward, one backward and one optimiser step serve every run, while each run keeps its
    own inputs ``obs [R, B, o]`` (its own data stream). Run r computes exactly what a
    :class:`Student` with run r's weights computes (tested), and :meth:`member` returns it as one:
    checkpoints, evaluation and every later stage see ordinary students.

    On a CPU a group whose rows * width^2 is large runs member by member (plain GEMMs, hand-written
    ReLU backward: :func:`~mop_core.learning.nn.per_member_forward`), a small one as one batched GEMM per layer.
    """

    def __init__(self, students: Sequence[Student]):
        super().__init__()
        if not students:
            raise ValueError("students: a group needs at least one student")
        first = students[0]
        if any((s.config, s.num_tasks, s.gaussian) != (first.config, first.num_tasks, first.gaussian)
               for s in students):
            raise ValueError("students: every student of a group must share its config, tasks and head")
        self.config, self.num_tasks, self.gaussian, self.runs = first.config, first.num_tasks, first.gaussian, len(
            students)
        self.act_dim = first.actor.act_dim if first.gaussian else first.actor.net[-1].out_features
        self.net = stack_networks([s.actor.net for s in students])

    def _raw(self, obs: torch.Tensor, task: torch.Tensor) -> torch.Tensor:
        """``obs [R, B, o]`` and task ids ``[B]`` (the same layout for every run) -> ``[R, B, out]``."""
        x = with_task_id(obs, task.expand(obs.shape[:-1]), self.num_tasks)
        return ensemble_forward(self.net, x, member_loop_pays(x.shape[1], max(self.config.hidden_sizes), x.device))

    def hidden(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Each hidden layer's ReLU activations ``[R, B, width]`` for inputs ``x [R, B, o + m]`` (state and
        one-hot task id), through autograd (the ranking regulariser's gradient flows through them)."""
        layers = []
        for module in self.net:
            x = module(x)
            if isinstance(module, nn.ReLU):
                layers.append(x)
        return layers

    def forward(self, obs: torch.Tensor, task: torch.Tensor) -> torch.Tensor:
        """Each run's action ``[R, B, k]`` (a Gaussian student's mean)."""
        if self.gaussian:
            return self.distribution(obs, task)[0]
        return torch.tanh(self._raw(obs, task))

    def distribution(self, obs: torch.Tensor, task: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Each run's (mu, sigma) ``[R, B, k]`` as :meth:`GaussianActor.distribution` computes it."""
        if not self.gaussian:
            raise TypeError("distribution: these students are deterministic (only KL students are Gaussian)")
        mean, raw_log_std = self._raw(obs, task).split(self.act_dim, dim=-1)
        return torch.tanh(mean), bounded_log_std(raw_log_std, self.config.log_std_min,
                                                 self.config.log_std_max).exp()

    def member(self, run: int) -> Student:
        """Run ``run``'s student as a plain :class:`Student` (a copy, on the group's device)."""
        student = Student(self.config, self.net[0].in_features - self.num_tasks, self.act_dim, self.num_tasks,
                          self.gaussian).to(self.net[0].weight.device)
        copy_member(self.net, run, student.actor.net)
        return student
