"""The states a student learns on, per task, with the frozen teacher's outputs cached once.

- offline (thesis 4.2): states of the task's offline dataset D_i, all of them or ``num_states``
  drawn without replacement;
- online (thesis 5.2.3): states the teacher visits when it is rolled out on its task,
  ``ceil(num_states / episode_length)`` episodes, batched.

The teachers do not change during distillation, so their action (a Gaussian teacher: mean and
standard deviation) at every state is computed here, once, not at every gradient step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from mop_core.data.hdf5 import read_dataset
from mop_core.distill.losses import reduce_ensemble
from mop_core.learning.nn import GaussianActor
from mop_core.walker.rollout import collect_episodes


@dataclass
class TaskStates:
    """One task's distillation states ``[N, obs]`` with the teacher's cached outputs."""

    task: str
    states: torch.Tensor
    teacher_actions: torch.Tensor  # [N, act]: pi_i^T(s) (a Gaussian teacher: its mean mu_i^T(s))
    teacher_std: torch.Tensor | None  # [N, act]: sigma_i^T(s) of a Gaussian teacher, else None
    source: dict  # where the states came from (for the checkpoint)
    weights: torch.Tensor | None = None  # [N]: sampling weights (reweighted distillation); None = uniform
    heldout: torch.Tensor | None = None  # [M, obs]: held-out states of the same data (never trained on)

    def __len__(self) -> int:
        return len(self.states)


def episode_rows(ends: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """The rows of ``round(fraction * episodes)`` (at least one) whole episodes, drawn without
    replacement and kept in dataset order; ``ends[t]`` marks an episode's last row."""
    bounds = np.flatnonzero(ends) + 1
    starts = np.concatenate([[0], bounds[:-1]])
    count = min(len(starts), max(1, int(round(fraction * len(starts)))))
    chosen = np.sort(rng.choice(len(starts), size=count, replace=False))
    return np.concatenate([np.arange(starts[e], bounds[e]) for e in chosen])


def offline_states(dataset: str | Path, num_states: int, rng: np.random.Generator, fraction: float = 1.0
                   ) -> np.ndarray:
    """``num_states`` observations of the dataset drawn without replacement (0 or more than N: all);
    ``fraction`` < 1: drawn from that share of its whole episodes (:func:`episode_rows`) only."""
    return offline_split(dataset, num_states, rng, fraction)[0]


def offline_split(dataset: str | Path, num_states: int, rng: np.random.Generator, fraction: float = 1.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`offline_states` and the observations of the whole episodes it left out (``fraction`` < 1:
    the rest of the dataset, the students' held-out states; else none)."""
    arrays = read_dataset(dataset).arrays
    observations = arrays["observations"]
    heldout = observations[:0]
    if fraction < 1:
        rows = episode_rows(arrays["timeouts"] | arrays["terminals"], fraction, rng)
        kept = np.zeros(len(observations), dtype=bool)
        kept[rows] = True
        observations, heldout = observations[kept], observations[~kept]
    if 0 < num_states < len(observations):
        index = np.sort(rng.choice(len(observations), size=num_states, replace=False))
        observations = observations[index]
    return np.asarray(observations, dtype=np.float32), np.asarray(heldout, dtype=np.float32)


def online_states(policy, task: str, num_states: int, episode_length: int, seeds: Sequence[int],
                  num_envs: int) -> np.ndarray:
    """The first ``num_states`` states the policy visits on ``task``, one episode per seed, in order.

    ``seeds`` must hold at least ``ceil(num_states / episode_length)`` seeds.
    """
    episodes = math.ceil(num_states / episode_length)
    if len(seeds) < episodes:
        raise ValueError(f"seeds: {num_states} states need {episodes} episodes, got {len(seeds)} seeds")
    arrays = collect_episodes(policy, task, list(seeds)[:episodes], episode_length, num_envs)
    return np.asarray(arrays["observations"][:num_states], dtype=np.float32)


@torch.no_grad()
def teacher_outputs(actor: torch.nn.Module, states: torch.Tensor, chunk: int = 65536
                    ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The teacher's action (Gaussian: mean) and, for a Gaussian teacher, its std at every state."""
    means, stds = [], []
    for part in states.split(chunk):
        if isinstance(actor, GaussianActor):
            mu, std = actor.distribution(part)
            means.append(mu)
            stds.append(std)
        else:
            means.append(actor(part))
    return torch.cat(means), (torch.cat(stds) if stds else None)


def task_states(task: str, states: np.ndarray, teacher_actor: torch.nn.Module, source: dict,
                device: torch.device | str = "cpu") -> TaskStates:
    """Wrap a task's states as tensors on ``device`` and cache the teacher's outputs at them."""
    tensor = torch.as_tensor(states, dtype=torch.float32)
    actions, std = teacher_outputs(teacher_actor, tensor)
    device = torch.device(device)
    return TaskStates(task, tensor.to(device), actions.to(device), None if std is None else std.to(device), source)


@torch.no_grad()
def q_switch_states(task: str, states: np.ndarray, candidates: Sequence, judges: Sequence, reduction: str,
                    source: dict, device: torch.device | str = "cpu", chunk: int = 65536) -> TaskStates:
    """Offline Q-switch targets (thesis 6.4.3) for one task: at every state s the action of
    ``argmax_j Q_j(s, pi_j(s))`` over the candidate teachers (``candidates[j]``: actor ``pi_j``,
    trained on D_{j->i}), each action judged by ``judges[j]``'s critic ensemble reduced over its
    members by ``reduction`` (min: what PBRL's actor maximises). ``judges = candidates`` is the
    thesis's rule (each candidate by its own critics, whose scales were never coordinated);
    every judge the target task's own teacher is QMP's. ``source`` gains ``q_switch``: per candidate
    (by the task whose data it learned from) the share of states whose label it gave."""
    if len(candidates) != len(judges) or not candidates:
        raise ValueError(f"candidates, judges: expected one judge per candidate, got {len(candidates)} and "
                         f"{len(judges)}")
    tensor = torch.as_tensor(states, dtype=torch.float32)
    actions, winners = [], []
    for part in tensor.split(chunk):
        proposed = torch.stack([teacher_outputs(c.actor, part)[0] for c in candidates])  # [J, B, act]
        values = torch.stack([reduce_ensemble(judge.critic(part, a), reduction) for judge, a in zip(judges, proposed)])
        best = values.argmax(0)  # [B]; ties: the first candidate (task order)
        actions.append(proposed[best, torch.arange(len(part))])
        winners.append(best)
    best = torch.cat(winners)
    names = [_data_name(c, j) for j, c in enumerate(candidates)]
    shares = {name: float((best == j).float().mean()) for j, name in enumerate(names)}
    device = torch.device(device)
    return TaskStates(task, tensor.to(device), torch.cat(actions).to(device), None,
                      source | {"q_switch": shares})


def _data_name(teacher, index: int) -> str:
    """A candidate's label in the win shares: the task(s) whose data it learned from, else its position."""
    return str(getattr(teacher, "source_task", "") or f"candidate{index}")
