"""A group of R independent PBRL runs of one configuration trained as one vectorised model.

Run r keeps everything a run alone has: its initialisation (the weights :class:`~mop_core.agents.pbrl.PBRL`
draws with its seed), its random generator (target smoothing, OOD actions, Gaussian samples, drawn in
the order a run alone draws them), its minibatches, its entropy temperature and its Adam state. What
the runs share is the tensors: layer k of the R actors is one ``[R, in, out]`` weight
(:func:`~mop_core.learning.nn.stack_networks`) and the R x E critics are one ensemble of R*E members, run r's
being members ``r*E .. (r+1)*E - 1``. One forward, one backward and one fused Adam step serve every run.

The loss is the sum over runs of each run's PBRL loss (:mod:`mop_core.agents.pbrl`'s docstring):

    L_critic = sum_r sum_e (L_in(r, e) + L_ood(r, e)),    L_actor = sum_r -mean_B [min_e Q_{r,e}(s, pi_r(s))]

so run r's gradient is its own loss's gradient, and Adam and Polyak averaging are element-wise: a
group equals its runs trained alone to float rounding, given the same minibatches (tested). Values
are laid out ``[E, R, B]`` so that the single-run formulas (``ensemble_std`` over axis 0, the in-
distribution and OOD targets) apply unchanged, per run.
"""

from __future__ import annotations

import copy
import math
from typing import Callable, Sequence

import numpy as np
import torch
from torch import nn

from mop_core.agents.pbrl import (
    PBRL,
    PBRLConfig,
    beta_ood,
    ensemble_std,
    in_distribution_target,
    make_actor,
    ood_target,
)
from mop_core.data.buffer import Batch
from mop_core.learning.graphs import (
    GraphedStep,
    graphs_enabled,
    learner_adam,
    match_loaded,
)
from mop_core.learning.nn import (
    EnsembleCritic,
    EnsembleLinear,
    GaussianActor,
    bounded_log_std,
    copy_member,
    ensemble_forward,
    member_loop_pays,
    numpy_policy,
    smoothed_target_action,
    soft_update,
    stack_networks,
)
from mop_core.learning.step_metrics import run_key


def stack_batches(batches: Sequence[Batch]) -> Batch:
    """R minibatches of one size -> one batch with a leading run dimension, ``[R, B, ...]``."""
    fields = ("observations", "actions", "rewards", "next_observations", "terminals")
    return Batch(*(torch.stack([getattr(b, name) for b in batches]) for name in fields))


def _forward(net: nn.Sequential, x: torch.Tensor, widest: int) -> torch.Tensor:
    """An ensemble network on one batch per member ``x [M, B, in]``: member by member where that pays
    on a CPU (:func:`~mop_core.learning.nn.member_loop_pays`), else one batched GEMM per layer."""
    return ensemble_forward(net, x, member_loop_pays(x.shape[1], widest, x.device))


class ActorGroup(nn.Module):
    """R PBRL actors (all deterministic or all Gaussian) as one network: ``obs [R, B, o] -> [R, B, a]``.
    Run r computes what the r-th actor computes (:class:`~mop_core.learning.nn.DeterministicActor`: ``tanh(f(s))``;
    :class:`~mop_core.learning.nn.GaussianActor`: its mean, and samples ``clip(mu + sigma eps, -1, 1)``)."""

    def __init__(self, actors: Sequence[nn.Module]):
        super().__init__()
        first = actors[0]
        if any(type(a) is not type(first) for a in actors):
            raise ValueError("actors: every actor of a group must be of one type")
        self.gaussian = isinstance(first, GaussianActor)
        self.act_dim = first.act_dim if self.gaussian else first.net[-1].out_features
        self.log_std_range = (first.log_std_min, first.log_std_max) if self.gaussian else None
        self.net = stack_networks([a.net for a in actors])
        self.widest = max(layer.out_features for layer in self.net if isinstance(layer, EnsembleLinear))

    def distribution(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Each run's (mu, sigma), ``[R, B, a]`` (Gaussian actors)."""
        mean, raw_log_std = _forward(self.net, obs, self.widest).split(self.act_dim, dim=-1)
        return torch.tanh(mean), bounded_log_std(raw_log_std, *self.log_std_range).exp()

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if self.gaussian:
            return self.distribution(obs)[0]
        return torch.tanh(_forward(self.net, obs, self.widest))

    def rsample(self, obs: torch.Tensor, noise, repeats: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
        """``repeats`` samples per state of each run, ``[R, B*repeats, a]`` in ``repeat_interleave``
        order, and each state's entropy ``[R, B]``; ``noise(shape)`` gives each run's standard normal
        draws ``[R, *shape]`` from that run's generator (:meth:`GaussianActor.rsample`, per run)."""
        mean, std = self.distribution(obs)
        entropy = (0.5 * math.log(2 * math.pi * math.e) + std.log()).sum(-1)
        if repeats > 1:
            mean, std = mean.repeat_interleave(repeats, dim=1), std.repeat_interleave(repeats, dim=1)
        return (mean + std * noise(mean.shape[1:])).clamp(-1.0, 1.0), entropy


class PBRLGroup:
    """R PBRL runs (one per seed) of one configuration; ``update(batch [R, B, ...])`` is one step of each.

    ``member_actor(r)`` and ``member_critic_state(r)`` give run r as a run alone would hold it (a plain
    actor module; the state dict of an E-member :class:`EnsembleCritic`): checkpoints and every later
    stage see ordinary teachers.
    """

    def __init__(self, config: PBRLConfig, obs_dim: int, act_dim: int, seeds: Sequence[int],
                 device: torch.device | str = "cpu", cuda_graphs: bool | None = None):
        if not seeds or len(set(seeds)) != len(seeds):
            raise ValueError(f"seeds: expected distinct seeds, one per run, got {list(seeds)}")
        self.config, self.device, self.seeds = config, torch.device(device), list(seeds)
        self.obs_dim, self.act_dim, self.members = obs_dim, act_dim, config.ensemble_size
        runs = [PBRL(config, obs_dim, act_dim, seed, self.device) for seed in seeds]  # each run's own init
        self.actor = ActorGroup([run.actor for run in runs]).to(self.device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        # on CUDA the update is captured as CUDA graphs (mop_core.learning.graphs); eager elsewhere
        captured = graphs_enabled(self.device, cuda_graphs)
        def optimizer(params) -> torch.optim.Adam:
            return learner_adam(params, config.learning_rate, self.device, captured)
        self.actor_optimizer = optimizer(self.actor.parameters())
        self.critic = EnsembleCritic(obs_dim, act_dim, config.hidden_sizes, len(seeds) * config.ensemble_size,
                                     config.layer_norm).to(self.device)
        self.critic.load_state_dict({key: torch.cat([run.critic.critic.state_dict()[key] for run in runs])
                                     for key in self.critic.state_dict()})
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.critic_optimizer = optimizer(self.critic.parameters())
        self.log_alpha = torch.stack([run.temperature.log_alpha.detach() for run in runs]).requires_grad_(
            config.target_entropy is not None)
        self.alpha_optimizer = None if config.target_entropy is None else optimizer([self.log_alpha])
        self.generators = [run.generator for run in runs]
        self.updates = 0
        self.graphed = GraphedStep(self._captured_step, self.generators) if captured else None

    @property
    def runs(self) -> int:
        return len(self.seeds)

    def optimizers(self) -> list[torch.optim.Optimizer]:
        """Every optimiser of the group (actors, critics, the entropy temperature if tuned)."""
        return [o for o in (self.actor_optimizer, self.critic_optimizer, self.alpha_optimizer) if o is not None]

    # ---- randomness and the networks, per run ----------------------------------------------------
    def _randn(self, shape: Sequence[int]) -> torch.Tensor:
        """Standard normal draws ``[R, *shape]``, run r's from run r's generator."""
        return torch.stack([torch.randn(tuple(shape), generator=g, device=self.device) for g in self.generators])

    def _noisy(self, actions: torch.Tensor, std: float) -> torch.Tensor:
        """clip(a + clip(N(0, std^2), -c, c), -1, 1) per run (:func:`mop_core.agents.pbrl.noisy`)."""
        return smoothed_target_action(actions, self._randn(actions.shape[1:]) * std, self.config.noise_clip)

    def _actor_input(self, obs: torch.Tensor) -> torch.Tensor:
        """What the actors read of states ``obs [R, B, o]``: the states (a task-conditioned group adds its task id)."""
        return obs

    def _policy(self, actor: ActorGroup, obs: torch.Tensor, repeats: int) -> torch.Tensor:
        """``repeats`` actions per state ``[R, B*repeats, a]`` (:func:`mop_core.agents.pbrl.policy_actions`)."""
        if actor.gaussian:
            return actor.rsample(self._actor_input(obs), self._randn, repeats)[0]
        actions = actor(self._actor_input(obs))
        return actions.repeat_interleave(repeats, dim=1) if repeats > 1 else actions

    def _q(self, critic: EnsembleCritic, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """Q of every run's E critics on that run's rows: ``[R, M, .] -> [E, R, M]``."""
        runs, rows = obs.shape[:2]
        x = torch.cat([obs, actions], dim=-1)
        x = x.unsqueeze(1).expand(runs, self.members, rows, x.shape[-1]).reshape(runs * self.members, rows, -1)
        return _forward(critic.net, x, critic.widest).view(runs, self.members, rows).transpose(0, 1)

    def alpha(self) -> float | torch.Tensor:
        """Each run's entropy weight: the fixed number, or the tuned values ``[R]`` (no gradient)."""
        return self.config.entropy_weight if self.alpha_optimizer is None else self.log_alpha.detach().exp()

    # ---- one step ---------------------------------------------------------------------------------
    def critic_loss(self, batch: Batch, beta: float) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """sum over runs of :meth:`PessimisticCritic.loss`; metrics per run, ``[R]``."""
        c = self.config
        obs, next_obs = batch.observations, batch.next_observations
        with torch.no_grad():
            next_action = self._noisy(self._policy(self.actor_target, next_obs, 1), c.target_noise)
            target = in_distribution_target(batch.rewards, batch.terminals, self._q(self.critic_target, next_obs,
                                                                                    next_action), c.gamma, c.beta_in)
        size = obs.shape[1]
        metrics: dict[str, torch.Tensor] = {}
        if c.ood_actions > 0:
            with torch.no_grad():
                states = torch.cat([obs, next_obs], dim=1)
                ood_actions = self._noisy(self._policy(self.actor, states, c.ood_actions), c.ood_noise)
                ood_states = states.repeat_interleave(c.ood_actions, dim=1)
            q_all = self._q(self.critic, torch.cat([obs, ood_states], 1), torch.cat([batch.actions, ood_actions], 1))
            q, q_ood = q_all[..., :size], q_all[..., size:]
            loss_ood = (q_ood - ood_target(q_ood, beta)).pow(2).mean(dim=-1).sum(dim=0)
            metrics["q_ood_std"] = ensemble_std(q_ood.detach()).mean(dim=-1)
        else:
            q = self._q(self.critic, obs, batch.actions)
            loss_ood = torch.zeros(self.runs, device=self.device)
        loss_in = (q - target).pow(2).mean(dim=-1).sum(dim=0)
        with torch.no_grad():
            metrics |= {"critic_loss_in": loss_in.detach(), "critic_loss_ood": loss_ood.detach(),
                        "q_mean": q.mean(dim=(0, 2)), "target_mean": target.mean(dim=(0, 2)),
                        "q_std": ensemble_std(q).mean(dim=-1)}
        return (loss_in + loss_ood).sum(), metrics

    def actor_loss(self, obs: torch.Tensor, randn: Callable[[Sequence[int]], torch.Tensor] | None = None
                   ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor | None]:
        """sum over runs of :func:`mop_core.agents.pbrl.actor_objective`; per-run metrics and entropies.
        ``randn``: the Gaussian actors' draws ``[R, *shape]`` (None: the runs' own generators)."""
        alpha = self.alpha()
        entropy = None
        if self.actor.gaussian:
            actions, entropy = self.actor.rsample(self._actor_input(obs), randn or self._randn)
        else:
            actions = self.actor(self._actor_input(obs))
        self.critic.requires_grad_(False)
        try:
            q = self._q(self.critic, obs, actions).min(dim=0).values  # [R, B]
        finally:
            self.critic.requires_grad_(True)
        if entropy is None:
            per_run = -q.mean(dim=-1)
            return per_run.sum(), {"actor_loss": per_run.detach(), "actor_q": q.mean(dim=-1).detach()}, None
        weight = alpha.unsqueeze(-1) if isinstance(alpha, torch.Tensor) else alpha
        per_run = -(q + weight * entropy).mean(dim=-1)
        alphas = alpha if isinstance(alpha, torch.Tensor) else torch.full((self.runs,), float(alpha),
                                                                          device=self.device)
        return per_run.sum(), {"actor_loss": per_run.detach(), "actor_q": q.mean(dim=-1).detach(),
                               "entropy": entropy.mean(dim=-1).detach(), "alpha": alphas}, entropy

    def _step(self, batch: Batch, beta: float | torch.Tensor, actor_step: bool) -> dict[str, torch.Tensor]:
        """One critic step of every run, an actor (and temperature) step if ``actor_step``, Polyak
        averaging; each metric per run, ``[R]``."""
        loss, per_run = self.critic_loss(batch, beta)
        self.critic_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.critic_optimizer.step()
        if actor_step:
            loss, actor_metrics, entropy = self.actor_loss(batch.observations)
            self.actor_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.actor_optimizer.step()
            per_run |= actor_metrics
            if entropy is not None and self.alpha_optimizer is not None:
                alpha_loss = (self.log_alpha * (entropy.detach().mean(dim=-1) - self.config.target_entropy)).sum()
                self.alpha_optimizer.zero_grad(set_to_none=True)
                alpha_loss.backward()
                self.alpha_optimizer.step()
        soft_update(self.actor_target, self.actor, self.config.actor_tau)
        soft_update(self.critic_target, self.critic, self.config.critic_tau)
        return per_run

    def _captured_step(self, actor_step: bool):
        """The step :class:`~mop_core.learning.graphs.GraphedStep` captures: inputs from its buffers."""
        def step() -> dict[str, torch.Tensor]:
            b = self.graphed.buffers
            return self._step(Batch.from_dict(b), b["beta_ood"], actor_step)
        return step

    def update(self, batch: Batch) -> dict[str, torch.Tensor | float]:
        """One critic step of every run (and every ``policy_delay``-th an actor step); metrics as 0-d
        tensors named ``key@run`` (:func:`mop_core.learning.step_metrics.run_key`). On CUDA the step is
        a replayed CUDA graph (one per variant: critic only, critic and actor)."""
        batch = batch.to(self.device)
        beta = beta_ood(self.updates, self.config)
        actor_step = (self.updates + 1) % self.config.policy_delay == 0
        if self.graphed is None:
            per_run = self._step(batch, beta, actor_step)
        else:
            per_run = self.graphed(actor_step, batch.as_dict() | {"beta_ood": torch.full((), beta,
                                                                                             device=self.device)})
        self.updates += 1
        metrics: dict[str, torch.Tensor | float] = {run_key(key, r): value for key, values in per_run.items()
                                                    for r, value in enumerate(values.to(self.device).unbind(0))}
        metrics["beta_ood"] = beta
        return metrics

    # ---- runs as a run alone holds them -----------------------------------------------------------
    def member_actor(self, run: int) -> nn.Module:
        """Run ``run``'s actor as a plain actor module (a copy, on the group's device)."""
        actor = make_actor(self.config, self.obs_dim, self.act_dim).to(self.device)
        copy_member(self.actor.net, run, actor.net)
        return actor

    def member_critic_state(self, run: int) -> dict[str, torch.Tensor]:
        """Run ``run``'s E critics as the state dict of an E-member :class:`EnsembleCritic` (copies)."""
        members = slice(run * self.members, (run + 1) * self.members)
        return {key: value[members].clone() for key, value in self.critic.state_dict().items()}

    @torch.no_grad()
    def act(self, run: int, observations: np.ndarray) -> np.ndarray:
        """Run ``run``'s deterministic action (a Gaussian actor's mean) for states ``[K, obs]``."""
        return numpy_policy(self.member_actor(run), self.device)(observations)

    def _critic_state(self) -> dict:
        """The critics' part of :meth:`state_dict` (a task-conditioned group holds one set per task)."""
        return {"critic": self.critic.state_dict(), "critic_target": self.critic_target.state_dict(),
                "critic_optimizer": self.critic_optimizer.state_dict()}

    def _load_critic_state(self, state: dict) -> None:
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])

    def state_dict(self) -> dict:
        """Everything a resumed group needs to continue bit for bit (a copy)."""
        return copy.deepcopy({
            "actor": self.actor.state_dict(), "actor_target": self.actor_target.state_dict(),
            "actor_optimizer": self.actor_optimizer.state_dict(), **self._critic_state(),
            "log_alpha": self.log_alpha.detach(),
            "alpha_optimizer": None if self.alpha_optimizer is None else self.alpha_optimizer.state_dict(),
            "generators": [g.get_state() for g in self.generators], "updates": self.updates})

    def load_state_dict(self, state: dict) -> None:
        self.actor.load_state_dict(state["actor"])
        self.actor_target.load_state_dict(state["actor_target"])
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self._load_critic_state(state)
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        if self.alpha_optimizer is not None:
            self.alpha_optimizer.load_state_dict(state["alpha_optimizer"])
        for generator, saved in zip(self.generators, state["generators"], strict=True):
            generator.set_state(saved)
        self.updates = state["updates"]
        for optimizer in self.optimizers():  # as built here, whoever wrote the state
            match_loaded(optimizer, self.graphed is not None, self.device)
        if self.graphed is not None:  # new optimiser tensors: capture again
            self.graphed.reset()


def probe_group(config: PBRLConfig, obs_dim: int, act_dim: int, batch: Callable[[int], Batch],
                device: torch.device | str) -> Callable[[int], None]:
    """``probe(R)``: a throwaway group of R runs stepped on ``batch(R)`` (``[R, B, ...]``) until every
    variant of its update has replayed (on CUDA: two eager warm-ups and a capture of each); what
    :func:`~mop_core.learning.group_memory.measure_footprint` measures a group's memory on."""
    def probe(runs: int) -> None:
        group = PBRLGroup(config, obs_dim, act_dim, list(range(runs)), device)
        for _ in range(3 * config.policy_delay):
            group.update(batch(runs))
    return probe

