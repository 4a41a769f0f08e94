"""PBRL, Pessimistic Bootstrapping for offline RL (Bai et al., 2022): the teachers of thesis 5.1.1.

An actor and an ensemble of E critics ``Q_1..Q_E`` with target copies. With
``u(s, a) = std_e Q_e(s, a)`` the ensemble's (unbiased) standard deviation, one critic step
minimises, summed over the members e (one loss, one backward, one optimiser)::

    in-distribution, (s, a, r, s') from the dataset:
        a'    = clip(pi_targ(s') + clip(N(0, sigma_t^2), -c, c), -1, 1)     target-policy smoothing
        y_e   = r + gamma * (1 - terminal) * (Qtarg_e(s', a') - beta_in * utarg(s', a'))
        L_in  = mean_B (Q_e(s, a) - y_e)^2
    out-of-distribution, N noisy current-policy actions at s and at s':
        a~    = clip(pi(x) + clip(N(0, sigma_ood^2), -c, c), -1, 1),   x in {s, s'}
        y~_e  = max(Q_e(x, a~) - beta_ood(t) * u(x, a~), 0)                 (no gradient)
        L_ood = mean_{2NB} (Q_e(x, a~) - y~_e)^2
    beta_ood(t) = max(beta_ood_init * beta_ood_decay^t, beta_ood_min)

Every ``policy_delay`` critic steps the actor maximises the ensemble minimum
``min_e Q_e(s, pi(s))`` (a Gaussian actor: of a reparameterised sample, plus ``alpha * H(pi(.|s))``
with alpha fixed at ``entropy_weight`` or, with ``target_entropy`` set, tuned as in SAC by
minimising ``log alpha * (H - target_entropy)``). Both target networks move by Polyak averaging after every critic
step, as in the reference code.

Where this differs from the thesis's reference code (the design card's section 5, the reference
implementation's defects): the bootstrap reads the
*target* critics (the reference read the online ones); the ensemble is one vectorised module with
one optimiser (the reference looped over E critics with E optimisers); the OOD regression target is
taken from the same forward pass that is trained (the reference recomputed nothing else either, but
ran E backward passes through a retained graph).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from torch import nn

from mop_core.config import require
from mop_core.data.buffer import Batch
from mop_core.learning.nn import (
    ACTOR_TYPES,
    DeterministicActor,
    EnsembleCritic,
    GaussianActor,
    adam,
    numpy_policy,
    smoothed_target_action,
    soft_update,
)
from mop_core.learning.schedule import LR_SCHEDULES

# (obs [B, o], repeats N) -> actions [N*B, a], N per state in repeat_interleave order; for a Gaussian
# actor N independent samples, for a deterministic one its action N times
PolicyFn = Callable[[torch.Tensor, int], torch.Tensor]


@dataclass(frozen=True)
class PBRLConfig:
    """PBRL hyper-parameters. Appendix B + the reference code's values are in profiles/thesis.yaml."""

    actor: str = "deterministic"  # "deterministic" (MSE/Q-value distillation) or "gaussian" (KL, 5.1.3)
    hidden_sizes: tuple[int, ...] = (256, 256)  # actor and each critic (Appendix B: 256 x 2)
    layer_norm: bool = False  # first hidden layer Linear -> LayerNorm -> tanh
    ensemble_size: int = 5  # E critics
    learning_rate: float = 1e-4  # Adam, actor and critics (Appendix B)
    lr_schedule: str = "constant"  # constant (Appendix B) | cosine: annealed to 0 over the run's steps, so that
    #   the last policy is not wherever an oscillating actor happens to stop (train_teachers' loops apply it)
    batch_size: int = 1024
    gamma: float = 0.99
    critic_tau: float = 5e-3  # Polyak rate of the target critics (Appendix B)
    actor_tau: float = 5e-3  # Polyak rate of the target actor (Appendix B)
    policy_delay: int = 2  # critic steps per actor step (Appendix B: ratio 1/2)
    target_noise: float = 0.2  # sigma_t, target-policy smoothing (Appendix B)
    noise_clip: float = 0.5  # c, clip of the smoothing and the OOD noise
    beta_in: float = 1e-3  # in-distribution uncertainty penalty
    ood_actions: int = 3  # N noisy policy actions per state, at s and at s' (0 disables the OOD term)
    ood_noise: float = 0.01  # sigma_ood
    beta_ood_init: float = 3.0
    beta_ood_min: float = 0.1
    beta_ood_decay: float = 0.99995  # per critic step
    entropy_weight: float = 0.1  # Gaussian actor only: alpha, the weight of H(pi(.|s)) (initial value if tuned)
    target_entropy: float | None = None  # Gaussian actor only: tune alpha towards this entropy (SAC: -act_dim)
    log_std_min: float = -5.0  # Gaussian actor only: log sigma bounded smoothly to (min, max)
    log_std_max: float = 0.0

    def __post_init__(self) -> None:
        require(self.actor in ACTOR_TYPES, "actor", f"one of {', '.join(ACTOR_TYPES)}", self.actor)
        require(len(self.hidden_sizes) > 0 and all(h > 0 for h in self.hidden_sizes), "hidden_sizes",
                "a non-empty list of positive widths", list(self.hidden_sizes))
        require(self.ensemble_size >= 2, "ensemble_size", "an integer >= 2 (the penalty is a standard deviation)",
                self.ensemble_size)
        require(self.learning_rate > 0, "learning_rate", "a positive number", self.learning_rate)
        require(self.lr_schedule in LR_SCHEDULES, "lr_schedule", f"one of {LR_SCHEDULES}", self.lr_schedule)
        require(self.batch_size > 0, "batch_size", "a positive integer", self.batch_size)
        require(0 <= self.gamma < 1, "gamma", "a discount in [0, 1)", self.gamma)
        require(0 < self.critic_tau <= 1, "critic_tau", "a rate in (0, 1]", self.critic_tau)
        require(0 < self.actor_tau <= 1, "actor_tau", "a rate in (0, 1]", self.actor_tau)
        require(self.policy_delay >= 1, "policy_delay", "an integer >= 1", self.policy_delay)
        for name in ("target_noise", "noise_clip", "beta_in", "ood_noise", "beta_ood_min", "entropy_weight"):
            require(getattr(self, name) >= 0, name, "a non-negative number", getattr(self, name))
        require(self.target_entropy is None or self.entropy_weight > 0, "entropy_weight",
                "a positive initial alpha when target_entropy is set", self.entropy_weight)
        require(self.ood_actions >= 0, "ood_actions", "a non-negative integer", self.ood_actions)
        require(self.beta_ood_init >= self.beta_ood_min, "beta_ood_init",
                f"a value >= beta_ood_min={self.beta_ood_min}", self.beta_ood_init)
        require(0 < self.beta_ood_decay <= 1, "beta_ood_decay", "a factor in (0, 1]", self.beta_ood_decay)
        require(self.log_std_min < self.log_std_max, "log_std_min", f"a value < log_std_max={self.log_std_max}",
                self.log_std_min)


def beta_ood(step: int, config: PBRLConfig) -> float:
    """beta_ood(t) = max(beta_ood_init * beta_ood_decay^t, beta_ood_min), t = critic steps taken."""
    return max(config.beta_ood_init * config.beta_ood_decay ** step, config.beta_ood_min)


def ensemble_std(q: torch.Tensor) -> torch.Tensor:
    """u = unbiased standard deviation over the ensemble axis 0 of ``q [E, ...]``:
    ``sqrt(sum_e (q_e - mean_e q)^2 / (E - 1))``, two passes (``torch.std(dim=0)`` gives the same
    to float tolerance, tested, but runs ~8x slower on a CPU at ``[5, 2048]``)."""
    deviation = q - q.mean(dim=0)
    return (deviation.pow(2).sum(dim=0) / (q.shape[0] - 1)).sqrt()


def in_distribution_target(rewards: torch.Tensor, terminals: torch.Tensor, next_q: torch.Tensor, gamma: float,
                           beta_in: float) -> torch.Tensor:
    """y_e = r + gamma (1 - terminal) (Qtarg_e(s', a') - beta_in * std_e Qtarg(s', a')), ``[E, B]``."""
    return rewards + gamma * (1.0 - terminals) * (next_q - beta_in * ensemble_std(next_q))


def ood_target(q_ood: torch.Tensor, beta: float) -> torch.Tensor:
    """y~_e = max(Q_e - beta * std_e Q, 0) for OOD values ``q_ood [E, M]`` (no gradient)."""
    q_ood = q_ood.detach()
    return (q_ood - beta * ensemble_std(q_ood)).clamp(min=0.0)


def make_actor(config: PBRLConfig, obs_dim: int, act_dim: int) -> nn.Module:
    if config.actor == "gaussian":
        return GaussianActor(obs_dim, act_dim, config.hidden_sizes, config.layer_norm, config.log_std_min,
                             config.log_std_max)
    return DeterministicActor(obs_dim, act_dim, config.hidden_sizes, config.layer_norm)


def policy_actions(actor: nn.Module, obs: torch.Tensor, generator: torch.Generator, repeats: int = 1
                   ) -> torch.Tensor:
    """The actions the algorithm perturbs, ``repeats`` per state: pi(s) for a deterministic actor,
    independent samples for a Gaussian one. The network runs once per state, not once per repeat."""
    if isinstance(actor, GaussianActor):
        return actor.rsample(obs, generator, repeats)[0]
    actions = actor(obs)
    return actions.repeat_interleave(repeats, dim=0) if repeats > 1 else actions


def noisy(actions: torch.Tensor, std: float, clip: float, generator: torch.Generator) -> torch.Tensor:
    """clip(a + clip(N(0, std^2), -clip, clip), -1, 1)."""
    noise = torch.randn(actions.shape, generator=generator, device=actions.device) * std
    return smoothed_target_action(actions, noise, clip)


class PessimisticCritic:
    """The critic half of PBRL for one reward function: ensemble, target ensemble, optimiser.

    ``policy``/``target_policy`` map states to actions, so the same critic serves a single-task
    actor and a task-conditioned one (the naive multi-task baseline).
    """

    def __init__(self, config: PBRLConfig, obs_dim: int, act_dim: int, device: torch.device):
        self.config = config
        self.critic = EnsembleCritic(obs_dim, act_dim, config.hidden_sizes, config.ensemble_size,
                                     config.layer_norm).to(device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.optimizer = adam(self.critic.parameters(), config.learning_rate)

    @torch.no_grad()
    def compute_target(self, batch: Batch, target_policy: PolicyFn, generator: torch.Generator) -> torch.Tensor:
        """The in-distribution targets y ``[E, B]`` from the TARGET actor and the TARGET critics."""
        c = self.config
        next_action = noisy(target_policy(batch.next_observations, 1), c.target_noise, c.noise_clip, generator)
        next_q = self.critic_target(batch.next_observations, next_action)
        return in_distribution_target(batch.rewards, batch.terminals, next_q, c.gamma, c.beta_in)

    @torch.no_grad()
    def ood_inputs(self, batch: Batch, policy: PolicyFn, generator: torch.Generator
                   ) -> tuple[torch.Tensor, torch.Tensor]:
        """N noisy current-policy actions at every s and every s': (states, actions), ``[2NB, .]``,
        the N rows of a state adjacent. The policy runs on the 2B states, not on 2NB repeats."""
        c = self.config
        states = torch.cat([batch.observations, batch.next_observations])
        actions = noisy(policy(states, c.ood_actions), c.ood_noise, c.noise_clip, generator)
        return states.repeat_interleave(c.ood_actions, dim=0), actions

    def loss(self, batch: Batch, policy: PolicyFn, target_policy: PolicyFn, beta: float,
             generator: torch.Generator) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """sum_e (L_in + L_ood) of the module docstring; one forward through the ensemble. Metrics
        are 0-d tensors, not read here (:mod:`mop_core.learning.step_metrics`)."""
        target = self.compute_target(batch, target_policy, generator)
        batch_size = batch.observations.shape[0]
        if self.config.ood_actions > 0:
            ood_states, ood_actions = self.ood_inputs(batch, policy, generator)
            q_all = self.critic(torch.cat([batch.observations, ood_states]), torch.cat([batch.actions, ood_actions]))
            q, q_ood = q_all[:, :batch_size], q_all[:, batch_size:]
            loss_ood = (q_ood - ood_target(q_ood, beta)).pow(2).mean(dim=1).sum()
        else:
            q = self.critic(batch.observations, batch.actions)
            q_ood, loss_ood = None, torch.zeros((), device=q.device)
        loss_in = (q - target).pow(2).mean(dim=1).sum()
        with torch.no_grad():
            metrics = {"critic_loss_in": loss_in.detach(), "critic_loss_ood": loss_ood.detach(), "q_mean": q.mean(),
                       "target_mean": target.mean(), "q_std": ensemble_std(q).mean()}
            if q_ood is not None:
                metrics["q_ood_std"] = ensemble_std(q_ood).mean()
        return loss_in + loss_ood, metrics

    def step(self, batch: Batch, policy: PolicyFn, target_policy: PolicyFn, beta: float,
             generator: torch.Generator) -> dict[str, torch.Tensor]:
        loss, metrics = self.loss(batch, policy, target_policy, beta, generator)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return metrics

    def min_q(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """min_e Q_e(s, a), ``[B]``; differentiable in ``actions`` only (critic weights frozen)."""
        self.critic.requires_grad_(False)
        try:
            return self.critic(obs, actions).min(dim=0).values
        finally:
            self.critic.requires_grad_(True)

    def soft_update(self) -> None:
        soft_update(self.critic_target, self.critic, self.config.critic_tau)

    def state_dict(self) -> dict:
        return {"critic": self.critic.state_dict(), "critic_target": self.critic_target.state_dict(),
                "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.optimizer.load_state_dict(state["optimizer"])


class EntropyTemperature:
    """alpha of the Gaussian actor's objective: fixed, or tuned towards ``target_entropy`` (SAC)."""

    def __init__(self, config: PBRLConfig, device: torch.device):
        self.target = config.target_entropy
        self.log_alpha = torch.tensor(math.log(max(config.entropy_weight, 1e-30)), device=device,
                                      requires_grad=self.target is not None)
        self.fixed = config.entropy_weight if self.target is None else None
        self.optimizer = None if self.target is None else adam([self.log_alpha], config.learning_rate)

    @property
    def value(self) -> float | torch.Tensor:
        """alpha: the fixed number, or the tuned value as a 0-d tensor (read without a device sync)."""
        return self.fixed if self.fixed is not None else self.log_alpha.detach().exp()

    def update(self, entropy: torch.Tensor) -> None:
        """One step on ``log alpha * (H - target)``: alpha falls while the entropy is above target."""
        if self.optimizer is None:
            return
        loss = self.log_alpha * (entropy.detach().mean() - self.target)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()

    def state_dict(self) -> dict:
        return {"log_alpha": self.log_alpha.detach().clone(),
                "optimizer": None if self.optimizer is None else self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        if self.optimizer is not None:
            self.optimizer.load_state_dict(state["optimizer"])


def actor_objective(actor: nn.Module, obs: torch.Tensor, actor_input: torch.Tensor, critic: PessimisticCritic,
                    alpha: float | torch.Tensor, generator: torch.Generator
                    ) -> tuple[torch.Tensor, dict[str, torch.Tensor | float], torch.Tensor | None]:
    """-mean_B [min_e Q_e(s, pi(s))] (Gaussian: of a reparameterised sample, minus alpha * H).

    ``actor_input`` is what the actor reads (the state, or the state with a task id); ``obs`` what
    the critic reads. Returns the loss, its metrics (0-d tensors, not read here) and the entropies
    ``[B]`` (None if deterministic).
    """
    if isinstance(actor, GaussianActor):
        actions, entropy = actor.rsample(actor_input, generator)
        q = critic.min_q(obs, actions)
        loss = -(q + alpha * entropy).mean()
        return loss, {"actor_loss": loss.detach(), "actor_q": q.mean().detach(),
                      "entropy": entropy.mean().detach(), "alpha": alpha}, entropy
    q = critic.min_q(obs, actor(actor_input))
    loss = -q.mean()
    return loss, {"actor_loss": loss.detach(), "actor_q": q.mean().detach()}, None


def actor_step(actor: nn.Module, optimizer: torch.optim.Optimizer, temperature: EntropyTemperature,
               obs: torch.Tensor, actor_input: torch.Tensor, critic: PessimisticCritic,
               generator: torch.Generator) -> dict[str, torch.Tensor | float]:
    """One optimiser step on :func:`actor_objective` (and, for a Gaussian actor, on alpha)."""
    loss, metrics, entropy = actor_objective(actor, obs, actor_input, critic, temperature.value, generator)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    if entropy is not None:
        temperature.update(entropy)
    return metrics


class PBRL:
    """A single-task PBRL learner: ``update(batch)`` is one gradient step of the module docstring."""

    def __init__(self, config: PBRLConfig, obs_dim: int, act_dim: int, seed: int,
                 device: torch.device | str = "cpu"):
        self.config = config
        self.device = torch.device(device)
        torch.manual_seed(seed)  # network initialisation
        self.actor = make_actor(config, obs_dim, act_dim).to(self.device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.actor_optimizer = adam(self.actor.parameters(), config.learning_rate)
        self.critic = PessimisticCritic(config, obs_dim, act_dim, self.device)
        self.temperature = EntropyTemperature(config, self.device)
        self.generator = torch.Generator(self.device).manual_seed(seed)
        self.updates = 0

    def policy(self, obs: torch.Tensor, repeats: int = 1) -> torch.Tensor:
        return policy_actions(self.actor, obs, self.generator, repeats)

    def target_policy(self, obs: torch.Tensor, repeats: int = 1) -> torch.Tensor:
        return policy_actions(self.actor_target, obs, self.generator, repeats)

    def update(self, batch: Batch) -> dict[str, torch.Tensor | float]:
        """One critic step (and every ``policy_delay``-th an actor step); metrics as 0-d tensors."""
        batch = batch.to(self.device)
        beta = beta_ood(self.updates, self.config)
        metrics = self.critic.step(batch, self.policy, self.target_policy, beta, self.generator)
        metrics["beta_ood"] = beta
        self.updates += 1
        if self.updates % self.config.policy_delay == 0:
            metrics |= actor_step(self.actor, self.actor_optimizer, self.temperature, batch.observations,
                                  batch.observations, self.critic, self.generator)
        soft_update(self.actor_target, self.actor, self.config.actor_tau)
        self.critic.soft_update()
        return metrics

    @torch.no_grad()
    def act(self, observations: np.ndarray) -> np.ndarray:
        """The deterministic action (a Gaussian actor's mean) for states ``[K, obs]``."""
        return numpy_policy(self.actor, self.device)(observations)

    def state_dict(self) -> dict:
        """Everything a resumed run needs to continue bit for bit (a copy, not views of live tensors)."""
        return copy.deepcopy({"actor": self.actor.state_dict(), "actor_target": self.actor_target.state_dict(),
                "actor_optimizer": self.actor_optimizer.state_dict(), "critic": self.critic.state_dict(),
                "temperature": self.temperature.state_dict(), "generator": self.generator.get_state(),
                "updates": self.updates})

    def load_state_dict(self, state: dict) -> None:
        self.actor.load_state_dict(state["actor"])
        self.actor_target.load_state_dict(state["actor_target"])
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.critic.load_state_dict(state["critic"])
        self.temperature.load_state_dict(state["temperature"])
        self.generator.set_state(state["generator"])
        self.updates = state["updates"]
