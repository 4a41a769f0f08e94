"""R independent runs of the naive multi-task PBRL baseline (thesis 5.1.2) trained as one vectorised model.

Run r is what :class:`~mop_core.agents.pbrl_multitask.MultiTaskPBRL` with seed ``seeds[r]`` is alone: its
initialisation, its generator (target smoothing, OOD actions, Gaussian samples, in a run's order), its
entropy temperature and Adam state. The R shared actors are one :class:`~mop_core.agents.pbrl_group.ActorGroup`
reading ``[s, onehot(i)]``; task i's critics of the R runs are one ensemble of R*E members (run r's
being ``r*E .. (r+1)*E - 1``), with its own target and optimiser. Update t is task ``t mod m``'s for
every run (the runs alternate in step): each run's critic step on its own batch of task i's data,
every ``policy_delay``-th step *of that task* the actors', Polyak averaging of the actors and of task
i's critics. The loss is the sum over runs of each run's (:mod:`mop_core.agents.pbrl_group`), so a
group equals its runs trained alone to float rounding, given the same minibatches (tested).

Why: a run alone takes one small step of one task's critic at a time, which leaves a GPU waiting on
kernel launches; R runs per step cost little more than one (benchmarks/bench_rates.py measures it).
"""

from __future__ import annotations

import copy
from typing import Callable, Sequence

import numpy as np
import torch
from torch import nn

from mop_core.agents.pbrl import PBRLConfig, make_actor
from mop_core.agents.pbrl_group import ActorGroup, PBRLGroup
from mop_core.agents.pbrl_multitask import MultiTaskPBRL, task_turn
from mop_core.data.buffer import Batch
from mop_core.learning.conflict import flat_gradient, pairwise_cosines
from mop_core.learning.graphs import GraphedStep, graphs_enabled, learner_adam
from mop_core.learning.nn import EnsembleCritic, copy_member, numpy_policy, with_task_id
from mop_core.learning.step_metrics import run_key


class MultiTaskPBRLGroup(PBRLGroup):
    """R multi-task baselines over ``tasks``; ``update(batch [R, B, ...], task)`` is one step of each.

    The :class:`PBRLGroup` step runs unchanged on the selected task's critics (``critic``,
    ``critic_target``, ``critic_optimizer`` are task i's while its step runs) with the actors reading the
    task id. ``member_actor(r)`` and ``member_critic_state(r, i)`` give run r as a run alone holds it.
    """

    def __init__(self, config: PBRLConfig, tasks: Sequence[str], obs_dim: int, act_dim: int, seeds: Sequence[int],
                 device: torch.device | str = "cpu", cuda_graphs: bool | None = None):
        if not seeds or len(set(seeds)) != len(seeds):
            raise ValueError(f"seeds: expected distinct seeds, one per run, got {list(seeds)}")
        self.config, self.device, self.seeds, self.tasks = config, torch.device(device), list(seeds), tuple(tasks)
        self.obs_dim, self.act_dim, self.members = obs_dim, act_dim, config.ensemble_size
        runs = [MultiTaskPBRL(config, self.tasks, obs_dim, act_dim, seed, self.device, cuda_graphs=False)
                for seed in seeds]  # each run's own initialisation and generator
        captured = graphs_enabled(self.device, cuda_graphs)
        def optimizer(params) -> torch.optim.Adam:
            return learner_adam(params, config.learning_rate, self.device, captured)
        self.actor = ActorGroup([run.actor for run in runs]).to(self.device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.actor_optimizer = optimizer(self.actor.parameters())
        self.critics: list[EnsembleCritic] = []
        for i in range(len(self.tasks)):
            critic = EnsembleCritic(obs_dim, act_dim, config.hidden_sizes, len(seeds) * self.members,
                                    config.layer_norm).to(self.device)
            critic.load_state_dict({key: torch.cat([run.critics[i].critic.state_dict()[key] for run in runs])
                                    for key in critic.state_dict()})
            self.critics.append(critic)
        self.critic_targets = [copy.deepcopy(c).requires_grad_(False) for c in self.critics]
        self.critic_optimizers = [optimizer(c.parameters()) for c in self.critics]
        self.critic_updates = [0] * len(self.tasks)
        self.log_alpha = torch.stack([run.temperature.log_alpha.detach() for run in runs]).requires_grad_(
            config.target_entropy is not None)
        self.alpha_optimizer = None if config.target_entropy is None else optimizer([self.log_alpha])
        self.generators = [run.generator for run in runs]
        self.updates = 0
        self._select(0)
        self.graphed = GraphedStep(self._captured_step, self.generators) if captured else None

    def _select(self, task: int) -> None:
        """Task ``task``'s critics become the ones the :class:`PBRLGroup` step trains and reads."""
        self.task = task
        self.critic, self.critic_target = self.critics[task], self.critic_targets[task]
        self.critic_optimizer = self.critic_optimizers[task]

    def _actor_input(self, obs: torch.Tensor) -> torch.Tensor:
        return with_task_id(obs, self.task, len(self.tasks))

    def optimizers(self) -> list[torch.optim.Optimizer]:
        """Every optimiser: the actors', each task's critics', the entropy temperature's if tuned."""
        found = [self.actor_optimizer, *self.critic_optimizers, self.alpha_optimizer]
        return [o for o in found if o is not None]

    @property
    def next_task(self) -> int:
        """The task index the next :meth:`update` expects (tasks alternate)."""
        return self.updates % len(self.tasks)

    def _captured_step(self, variant: tuple[int, bool]):
        def step() -> dict[str, torch.Tensor]:
            self._select(variant[0])
            b = self.graphed.buffers
            return self._step(Batch.from_dict(b), b["beta_ood"], variant[1])
        return step

    def update(self, batch: Batch, task: int) -> dict[str, torch.Tensor | float]:  # type: ignore[override]
        """One PBRL step of task ``task`` for every run on ``batch`` (run r's rows: a batch of task
        ``task``'s data); metrics as 0-d tensors named ``key@run``. On CUDA a replayed CUDA graph per
        (task, actor step or not)."""
        beta, actor_now = task_turn(self.next_task, task, self.critic_updates[task], self.config)
        batch = batch.to(self.device)
        if self.graphed is None:
            self._select(task)
            per_run = self._step(batch, beta, actor_now)
        else:
            per_run = self.graphed((task, actor_now), batch.as_dict() | {
                "beta_ood": torch.full((), beta, device=self.device)})
        self.critic_updates[task] += 1
        self.updates += 1
        metrics: dict[str, torch.Tensor | float] = {run_key(key, r): value for key, values in per_run.items()
                                                    for r, value in enumerate(values.to(self.device).unbind(0))}
        metrics["beta_ood"] = beta
        return metrics

    def gradient_cosines(self, batches: Sequence[Batch], generators: Sequence[torch.Generator]
                         ) -> list[dict[str, float]]:
        """Per run, :meth:`MultiTaskPBRL.gradient_cosines`: the cosines between task i's and task k's
        actor-objective gradients on the shared actor (``batches[i]``: ``[R, B, ...]`` of task i's data;
        run r's Gaussian samples from ``generators[r]``)."""
        def draws(shape: Sequence[int]) -> torch.Tensor:
            return torch.stack([torch.randn(tuple(shape), generator=g, device=self.device) for g in generators])
        params, flat = list(self.actor.parameters()), []
        selected = self.task
        try:
            for task, batch in enumerate(batches):
                self._select(task)
                loss, _, _ = self.actor_loss(batch.to(self.device).observations, draws)
                flat.append(flat_gradient(loss, params, self.runs))
        finally:
            self._select(selected)
        return pairwise_cosines(flat, self.tasks)

    # ---- runs as a run alone holds them -----------------------------------------------------------
    def member_actor(self, run: int) -> nn.Module:
        """Run ``run``'s shared actor (state and one-hot task id in) as a plain actor module (a copy)."""
        actor = make_actor(self.config, self.obs_dim + len(self.tasks), self.act_dim).to(self.device)
        copy_member(self.actor.net, run, actor.net)
        return actor

    def member_critic_state(self, run: int, task: int = 0) -> dict[str, torch.Tensor]:  # type: ignore[override]
        """Run ``run``'s E critics of task ``task`` as an E-member :class:`EnsembleCritic`'s state dict (copies)."""
        members = slice(run * self.members, (run + 1) * self.members)
        return {key: value[members].clone() for key, value in self.critics[task].state_dict().items()}

    @torch.no_grad()
    def act(self, run: int, observations: np.ndarray, task: int = 0) -> np.ndarray:  # type: ignore[override]
        """Run ``run``'s deterministic action on task ``task`` for states ``[K, obs]``."""
        return numpy_policy(self.member_actor(run), self.device, task, len(self.tasks))(observations)

    def _critic_state(self) -> dict:
        return {"critics": [c.state_dict() for c in self.critics],
                "critic_targets": [c.state_dict() for c in self.critic_targets],
                "critic_optimizers": [o.state_dict() for o in self.critic_optimizers],
                "critic_updates": list(self.critic_updates)}

    def _load_critic_state(self, state: dict) -> None:
        for modules, saved in ((self.critics, state["critics"]), (self.critic_targets, state["critic_targets"]),
                               (self.critic_optimizers, state["critic_optimizers"])):
            for module, module_state in zip(modules, saved, strict=True):
                module.load_state_dict(module_state)
        self.critic_updates = list(state["critic_updates"])

def probe_multitask_group(config: PBRLConfig, tasks: Sequence[str], obs_dim: int, act_dim: int,
                          batch: Callable[[int], Batch], device: torch.device | str) -> Callable[[int], None]:
    """``probe(R)``: a throwaway group of R baselines stepped on ``batch(R)`` until every (task, actor step
    or not) variant has replayed; :func:`~mop_core.agents.pbrl_group.probe_group`'s twin for the
    footprint (:func:`~mop_core.learning.group_memory.measure_footprint`)."""
    def probe(runs: int) -> None:
        group = MultiTaskPBRLGroup(config, tasks, obs_dim, act_dim, list(range(runs)), device)
        for _ in range(3 * config.policy_delay * len(tasks)):
            group.update(batch(runs), group.next_task)
    return probe
