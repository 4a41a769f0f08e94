"""TD3 (Fujimoto et al., 2018), the behaviour-policy learner of thesis chapter 4.4.3 / Appendix A.

Critic targets use the *target* actor and the *target* twin critics with clipped target-policy
smoothing::

    a' = clip(pi_targ(s') + clip(eps, -c, c), -1, 1),   eps ~ N(0, sigma_target^2)
    y  = r + gamma * (1 - terminal) * min_{k=1,2} Q_targ_k(s', a')

both critics regress to ``y`` (sum of the two mean squared errors); every ``policy_delay`` critic
updates the actor ascends ``Q_1(s, pi(s))`` and the targets move by Polyak averaging with rate
``tau``. Exploration adds N(0, sigma_explore^2) to the actor's action. Walker episodes end by
time-out only, so ``terminal`` is always 0 there and time-outs are bootstrapped through.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch

from mop_core.config import require
from mop_core.data.buffer import Batch
from mop_core.learning.graphs import (
    GraphedStep,
    graphs_enabled,
    learner_adam,
    match_loaded,
)
from mop_core.learning.nn import DeterministicActor, EnsembleCritic, smoothed_target_action, soft_update


@dataclass(frozen=True)
class TD3Config:
    """TD3 hyper-parameters (Appendix A holds the thesis's values; see profiles/thesis.yaml)."""

    hidden_sizes: tuple[int, ...] = (256, 256)  # widths of the actor's and each critic's hidden layers
    layer_norm: bool = False  # first hidden layer Linear -> LayerNorm -> tanh (reference code)
    learning_rate: float = 3e-4  # Adam, actor and critics
    batch_size: int = 256
    gamma: float = 0.99  # discount
    tau: float = 0.005  # Polyak rate of the target networks
    exploration_noise: float = 0.2  # std of the Gaussian added to actions while collecting
    target_noise: float = 0.2  # std of the target-policy smoothing noise
    target_noise_clip: float = 0.5  # the smoothing noise is clipped to [-clip, clip]
    policy_delay: int = 2  # critic updates per actor (and target) update

    def __post_init__(self) -> None:
        require(len(self.hidden_sizes) > 0 and all(h > 0 for h in self.hidden_sizes), "hidden_sizes",
                "a non-empty list of positive widths", list(self.hidden_sizes))
        require(self.learning_rate > 0, "learning_rate", "a positive number", self.learning_rate)
        require(self.batch_size > 0, "batch_size", "a positive integer", self.batch_size)
        require(0 <= self.gamma < 1, "gamma", "a discount in [0, 1)", self.gamma)
        require(0 < self.tau <= 1, "tau", "a rate in (0, 1]", self.tau)
        require(self.exploration_noise >= 0, "exploration_noise", "a non-negative std", self.exploration_noise)
        require(self.target_noise >= 0, "target_noise", "a non-negative std", self.target_noise)
        require(self.target_noise_clip >= 0, "target_noise_clip", "a non-negative clip", self.target_noise_clip)
        require(self.policy_delay >= 1, "policy_delay", "an integer >= 1", self.policy_delay)


def td3_target(rewards: torch.Tensor, terminals: torch.Tensor, next_q: torch.Tensor, gamma: float) -> torch.Tensor:
    """y = r + gamma * (1 - terminal) * min over the critics' axis 0 of ``next_q [2, B]``."""
    return rewards + gamma * (1.0 - terminals) * next_q.min(dim=0).values


class TD3:
    """A TD3 learner: ``act`` for collection, ``update(batch)`` for one gradient step."""

    def __init__(self, config: TD3Config, obs_dim: int, act_dim: int, seed: int,
                 device: torch.device | str = "cpu", cuda_graphs: bool | None = None):
        self.config = config
        self.device = torch.device(device)
        torch.manual_seed(seed)  # network initialisation
        self.actor = DeterministicActor(obs_dim, act_dim, config.hidden_sizes, config.layer_norm).to(self.device)
        self.critic = EnsembleCritic(obs_dim, act_dim, config.hidden_sizes, 2, config.layer_norm).to(self.device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        captured = graphs_enabled(self.device, cuda_graphs)  # on CUDA: updates replayed as CUDA graphs
        self.actor_optimizer = learner_adam(self.actor.parameters(), config.learning_rate, self.device, captured)
        self.critic_optimizer = learner_adam(self.critic.parameters(), config.learning_rate, self.device, captured)
        self.generator = torch.Generator(self.device).manual_seed(seed)
        self.updates = 0
        self.graphed = GraphedStep(self._captured_step, [self.generator]) if captured else None

    @torch.no_grad()
    def act(self, observations: np.ndarray, noise_std: float = 0.0) -> np.ndarray:
        """pi(s) (+ N(0, noise_std^2), clipped to [-1, 1]) for a batch ``[K, obs]`` or one state."""
        obs = torch.as_tensor(np.asarray(observations, dtype=np.float32), device=self.device)
        action = self.actor(obs)
        if noise_std > 0:
            noise = torch.randn(action.shape, generator=self.generator, device=self.device) * noise_std
            action = (action + noise).clamp(-1.0, 1.0)
        return action.cpu().numpy()

    @torch.no_grad()
    def compute_target(self, batch: Batch) -> torch.Tensor:
        """The critic regression target y of the module docstring (target networks only)."""
        next_action = self.actor_target(batch.next_observations)
        noise = torch.randn(next_action.shape, generator=self.generator, device=self.device) * self.config.target_noise
        next_action = smoothed_target_action(next_action, noise, self.config.target_noise_clip)
        next_q = self.critic_target(batch.next_observations, next_action)
        return td3_target(batch.rewards, batch.terminals, next_q, self.config.gamma)

    def _step(self, batch: Batch, actor_now: bool) -> dict[str, torch.Tensor]:
        """One critic step; if ``actor_now`` an actor step and the target networks' update."""
        target = self.compute_target(batch)
        q = self.critic(batch.observations, batch.actions)  # [2, B]
        critic_loss = (q - target).pow(2).mean(dim=1).sum()
        self.critic_optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_optimizer.step()
        metrics = {"critic_loss": critic_loss.detach(), "q_mean": q.mean().detach()}
        if actor_now:
            self.critic.requires_grad_(False)  # the actor step needs dQ/da only
            actor_loss = -self.critic.first(batch.observations, self.actor(batch.observations)).mean()
            self.actor_optimizer.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_optimizer.step()
            self.critic.requires_grad_(True)
            soft_update(self.actor_target, self.actor, self.config.tau)
            soft_update(self.critic_target, self.critic, self.config.tau)
            metrics["actor_loss"] = actor_loss.detach()
        return metrics

    def _captured_step(self, actor_now: bool):
        def step() -> dict[str, torch.Tensor]:
            return self._step(Batch.from_dict(self.graphed.buffers), actor_now)
        return step

    def update(self, batch: Batch) -> dict[str, torch.Tensor]:
        """One critic step; every ``policy_delay``-th call also an actor step and target update (on CUDA a
        replayed CUDA graph per variant). Metrics are 0-d tensors, read in batches by the caller
        (:mod:`mop_core.learning.step_metrics`)."""
        batch = batch.to(self.device)
        actor_now = (self.updates + 1) % self.config.policy_delay == 0
        if self.graphed is None:
            metrics = self._step(batch, actor_now)
        else:
            metrics = self.graphed(actor_now, batch.as_dict())
        self.updates += 1
        return metrics

    def state_dict(self) -> dict:
        """Everything a resumed run needs to continue bit for bit (a copy, not views of live tensors)."""
        return copy.deepcopy({"actor": self.actor.state_dict(), "critic": self.critic.state_dict(),
                              "actor_target": self.actor_target.state_dict(),
                              "critic_target": self.critic_target.state_dict(),
                              "actor_optimizer": self.actor_optimizer.state_dict(),
                              "critic_optimizer": self.critic_optimizer.state_dict(),
                              "generator": self.generator.get_state(), "updates": self.updates})

    def load_state_dict(self, state: dict) -> None:
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.actor_target.load_state_dict(state["actor_target"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])
        self.generator.set_state(state["generator"])
        for optimizer in (self.actor_optimizer, self.critic_optimizer):  # as built here, whoever wrote the state
            match_loaded(optimizer, self.graphed is not None, self.device)
        if self.graphed is not None:  # new optimiser tensors: capture again
            self.graphed.reset()
        self.updates = state["updates"]

    def actor_state(self) -> dict[str, torch.Tensor]:
        """The actor's weights on the CPU (a behaviour-policy snapshot)."""
        return {k: v.detach().cpu().clone() for k, v in self.actor.state_dict().items()}


def actor_from_checkpoint(checkpoint: dict) -> DeterministicActor:
    """The actor of a behaviour snapshot (config + weights), in eval mode and frozen."""
    config = checkpoint["td3_config"]
    actor = DeterministicActor(checkpoint["obs_dim"], checkpoint["act_dim"], config["hidden_sizes"],
                               config["layer_norm"])
    actor.load_state_dict(checkpoint["actor"])
    return actor.eval().requires_grad_(False)
