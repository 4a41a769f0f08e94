"""Naive multi-task PBRL, the baseline of thesis 5.1.2 (Figures 5.2, 5.3; Appendix D).

One task-conditioned actor ``pi(s, i)`` (the state with a one-hot task id) is shared by all m
tasks; each task i keeps its own PBRL critic ensemble ``Q^i`` trained on its own dataset's rewards.
Training alternates tasks: update t draws a batch from task ``t mod m``'s dataset and takes one
PBRL step for that task (its critic; every ``policy_delay``-th step *of that task* also the shared
actor, maximising ``min_e Q^i_e(s, pi(s, i))``). The actor's optimiser holds the live shared actor
(the reference code's pointed at a stale copy, so its shared actor never trained).
"""

from __future__ import annotations

import copy
from typing import Sequence

import numpy as np
import torch

from mop_core.agents.pbrl import (
    EntropyTemperature,
    PBRLConfig,
    PessimisticCritic,
    actor_objective,
    actor_step,
    beta_ood,
    make_actor,
    policy_actions,
)
from mop_core.data.buffer import Batch
from mop_core.learning.conflict import flat_gradient, pairwise_cosines
from mop_core.learning.graphs import (
    GraphedStep,
    capturable_adam,
    graphs_enabled,
    match_loaded,
)
from mop_core.learning.nn import adam, numpy_policy, soft_update, with_task_id


def task_turn(expected: int, task: int, critic_updates: int, config: PBRLConfig) -> tuple[float, bool]:
    """Task ``task``'s next step, its ``critic_updates``-th: its beta_ood and whether it also trains the
    shared actor (every ``policy_delay``-th step of that task). A task out of turn (``expected``) is refused."""
    if task != expected:
        raise ValueError(f"task: expected {expected} (tasks alternate), got {task}")
    return beta_ood(critic_updates, config), (critic_updates + 1) % config.policy_delay == 0


class MultiTaskPBRL:
    """A shared actor over ``tasks`` and one :class:`PessimisticCritic` per task."""

    def __init__(self, config: PBRLConfig, tasks: Sequence[str], obs_dim: int, act_dim: int, seed: int,
                 device: torch.device | str = "cpu", cuda_graphs: bool | None = None):
        self.config, self.tasks = config, tuple(tasks)
        self.device = torch.device(device)
        torch.manual_seed(seed)
        self.actor = make_actor(config, obs_dim + len(self.tasks), act_dim).to(self.device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.actor_optimizer = adam(self.actor.parameters(), config.learning_rate)
        self.critics = [PessimisticCritic(config, obs_dim, act_dim, self.device) for _ in self.tasks]
        self.critic_updates = [0] * len(self.tasks)
        self.temperature = EntropyTemperature(config, self.device)
        self.generator = torch.Generator(self.device).manual_seed(seed)
        self.updates = 0
        self.graphed = None  # on CUDA: each (task, actor step or not) a replayed CUDA graph
        if graphs_enabled(self.device, cuda_graphs):
            self.actor_optimizer = capturable_adam(self.actor.parameters(), config.learning_rate, self.device)
            for critic in self.critics:
                critic.optimizer = capturable_adam(critic.critic.parameters(), config.learning_rate, self.device)
            if self.temperature.optimizer is not None:
                self.temperature.optimizer = capturable_adam([self.temperature.log_alpha], config.learning_rate,
                                                             self.device)
            self.graphed = GraphedStep(self._captured_step, [self.generator])

    def optimizers(self) -> list[torch.optim.Optimizer]:
        """Every optimiser: the shared actor's, each task critic's, the entropy temperature's if tuned."""
        found = [self.actor_optimizer, *(c.optimizer for c in self.critics), self.temperature.optimizer]
        return [o for o in found if o is not None]

    @property
    def next_task(self) -> int:
        """The task index the next :meth:`update` expects (tasks alternate)."""
        return self.updates % len(self.tasks)

    def _conditioned(self, actor: torch.nn.Module, task: int):
        return lambda obs, repeats=1: policy_actions(actor, with_task_id(obs, task, len(self.tasks)), self.generator,
                                                     repeats)

    def _step(self, batch: Batch, task: int, beta: float | torch.Tensor, actor_now: bool
              ) -> dict[str, torch.Tensor | float]:
        """Task ``task``'s critic step, the shared actor's step if ``actor_now``, Polyak averaging."""
        critic = self.critics[task]
        metrics = critic.step(batch, self._conditioned(self.actor, task), self._conditioned(self.actor_target, task),
                              beta, self.generator)
        if actor_now:
            actor_input = with_task_id(batch.observations, task, len(self.tasks))
            metrics |= actor_step(self.actor, self.actor_optimizer, self.temperature, batch.observations,
                                  actor_input, critic, self.generator)
        soft_update(self.actor_target, self.actor, self.config.actor_tau)
        critic.soft_update()
        return metrics

    def _captured_step(self, variant: tuple[int, bool]):
        def step() -> dict[str, torch.Tensor | float]:
            b = self.graphed.buffers
            return self._step(Batch.from_dict(b), variant[0], b["beta_ood"], variant[1])
        return step

    def update(self, batch: Batch, task: int) -> dict[str, torch.Tensor | float]:
        """One PBRL step for ``task`` on ``batch`` (a batch of that task's dataset and rewards)."""
        beta, actor_now = task_turn(self.next_task, task, self.critic_updates[task], self.config)
        batch = batch.to(self.device)
        if self.graphed is None:
            metrics = self._step(batch, task, beta, actor_now)
        else:
            metrics = self.graphed((task, actor_now), batch.as_dict() | {
                "beta_ood": torch.full((), beta, device=self.device)})
        metrics["beta_ood"] = beta
        self.critic_updates[task] += 1
        self.updates += 1
        return metrics

    def gradient_cosines(self, batches: Sequence[Batch], generator: torch.Generator) -> dict[str, float]:
        """The gradient conflict on the shared actor (:mod:`mop_core.learning.conflict`): per task pair, the
        cosine between task i's and task k's actor-objective gradients (each task's own critic on a
        batch of its own data, ``batches[i]``). ``generator`` draws the Gaussian actor's samples."""
        params = list(self.actor.parameters())
        flat = []
        for task, batch in enumerate(batches):
            obs = batch.to(self.device).observations
            loss, _, _ = actor_objective(self.actor, obs, with_task_id(obs, task, len(self.tasks)),
                                         self.critics[task], self.temperature.value, generator)
            flat.append(flat_gradient(loss, params))
        return pairwise_cosines(flat, self.tasks)[0]

    @torch.no_grad()
    def act(self, observations: np.ndarray, task: int) -> np.ndarray:
        return numpy_policy(self.actor, self.device, task, len(self.tasks))(observations)

    def state_dict(self) -> dict:
        """Everything a resumed run needs to continue bit for bit (a copy, not views of live tensors)."""
        return copy.deepcopy({"actor": self.actor.state_dict(), "actor_target": self.actor_target.state_dict(),
                              "actor_optimizer": self.actor_optimizer.state_dict(),
                              "critics": [c.state_dict() for c in self.critics],
                              "critic_updates": list(self.critic_updates), "generator": self.generator.get_state(),
                              "temperature": self.temperature.state_dict(),
                              "updates": self.updates})

    def load_state_dict(self, state: dict) -> None:
        self.actor.load_state_dict(state["actor"])
        self.actor_target.load_state_dict(state["actor_target"])
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        for critic, critic_state in zip(self.critics, state["critics"], strict=True):
            critic.load_state_dict(critic_state)
        self.critic_updates = list(state["critic_updates"])
        self.temperature.load_state_dict(state["temperature"])
        self.generator.set_state(state["generator"])
        self.updates = state["updates"]
        for optimizer in self.optimizers():  # as built here, whoever wrote the state
            match_loaded(optimizer, self.graphed is not None, self.device)
        if self.graphed is not None:  # new optimiser tensors: capture again
            self.graphed.reset()
