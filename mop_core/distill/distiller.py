"""The distillation learner: one update of a group of students per call (thesis 4.2, 5.1.3).

Every run of the group (its own seed) does what one student alone would: each update draws
``batch_size`` states per task (uniformly, with replacement) from that task's
:class:`~mop_core.distill.states.TaskStates`. By default it runs the student once on all
``m * batch_size`` rows (state + one-hot task id) and takes one Adam step on the loss averaged over
the rows, i.e. ``1/m sum_i E_{s~D_i}[loss_i(s)]`` as in the thesis. With ``step_per_task`` it takes
one Adam step per task instead, on that task's rows only, in task order (the thesis's reference code:
m optimiser steps per update). Teacher actions and Gaussian parameters are
read from the cache; the Q loss evaluates each task's frozen teacher critic ensemble at the
student's actions (gradients flow through the critic into the student; the critic's weights are
frozen).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import torch

from mop_core.config import ConfigError, from_mapping, require
from mop_core.conflict import flat_gradient, pairwise_cosines
from mop_core.distill.corrections import CORRECTIONS, DaggerConfig, ReweightConfig
from mop_core.distill.losses import LOSSES, Q_REDUCTIONS, LossInputs, mse_per_state
from mop_core.distill.states import STATE_SOURCES, TaskStates
from mop_core.distill.student import Student, StudentConfig, StudentGroup
from mop_core.nn import EnsembleCritic, adam, with_task_id
from mop_core.ranking import RANKING_LOSSES, SYMMETRIC_LOSSES, cross_task_ranking, ranking_loss
from mop_core.step_metrics import run_key
from mop_core.study import DISTILL_GRID_KEYS, section

LR_SCHEDULES = ("constant", "cosine")
RANKING_CHOICES = ("none", *RANKING_LOSSES)
PROBE_SOURCES = ("offline", "visited")


def learning_rate_at(config: "DistillConfig", step: int, total_steps: int) -> float:
    """The learning rate of gradient step ``step`` (0-based) of ``total_steps``."""
    if config.lr_schedule == "constant":
        return config.learning_rate
    return config.learning_rate * 0.5 * (1.0 + math.cos(math.pi * min(step, total_steps) / total_steps))


@dataclass(frozen=True)
class RankingConfig:
    """The ranking regulariser of thesis 6.3.2 (mop_core.ranking): the loss becomes

        L_distill + weight * sum_j layer_weights[j] * mean_{i != k} mean_s L_rank(l_j(s, i), sg[l_j(s, k)])

    over each hidden layer j, every ordered pair of task ids and ``states`` states per task per step
    (the first ``states`` of the step's draws; the thesis compares the whole batch, whose pairwise
    loss costs ``batch * width^2`` per layer; with 2 states per task a group's step at initialisation
    costs 2.74x a plain one for pairwise, 1.15x for listwise and 2.38x for ApproxNDCG on 2 CPU
    cores: benchmarks/README.md, distill)."""

    loss: str = "none"  # none | pairwise | listwise | approx_ndcg
    weight: float = 100.0  # lambda (thesis: 100)
    layer_weights: tuple[float, ...] = ()  # one per hidden layer; empty = 1 for every layer
    states: int = 2  # states per task per step the regulariser compares under every task id
    temperature: float = 0.1  # approx_ndcg's sigmoid temperature (smooth ranks)

    def __post_init__(self) -> None:
        require(self.loss in RANKING_CHOICES, "loss", f"one of {RANKING_CHOICES}", self.loss)
        require(self.weight >= 0, "weight", "a non-negative number (lambda)", self.weight)
        require(all(w >= 0 for w in self.layer_weights), "layer_weights", "non-negative numbers",
                list(self.layer_weights))
        require(self.states >= 1, "states", "a positive integer", self.states)
        require(self.temperature > 0, "temperature", "a positive number", self.temperature)

    @property
    def active(self) -> bool:
        return self.loss != "none" and self.weight > 0

    def weights_for(self, layers: int) -> tuple[float, ...]:
        return self.layer_weights or (1.0,) * layers


@dataclass(frozen=True)
class DistillConfig:
    """What a student learns from and how (the schedule is a separate TrainSchedule)."""

    loss: str = "mse"  # mse | q | kl (kl needs Gaussian teachers; its student is Gaussian too)
    student: StudentConfig = field(default_factory=StudentConfig)
    learning_rate: float = 1e-4
    lr_schedule: str = "constant"  # constant | cosine: lr * (1 + cos(pi * step / steps)) / 2, to 0 at the end
    batch_size: int = 256  # states per task per gradient step
    q_reduction: str = "min"  # Q loss: reduce the teacher's critic ensemble by min or mean
    state_source: str = "offline"  # offline: the task's dataset; online: states the teacher visits
    num_states: int = 0  # states per task; 0 = the whole offline dataset (online: must be > 0)
    data_fraction: float = 1.0  # offline: the share of each dataset's whole episodes kept (drawn per student
    #                             seed; the dataset-size experiment), before num_states draws from them
    probe_states: int = 256  # states per task for the per-state tau curve (thesis 6.3.1, Fig. 6.4b); 0 = off
    probe_source: str = "offline"  # offline: fixed dataset states, the same for every student; visited: states
    #                                the student visits in each evaluation (the reference code's choice)
    step_per_task: bool = False  # one Adam step per task per update (reference code) instead of one over all tasks
    ranking: RankingConfig = field(default_factory=RankingConfig)  # thesis 6.3.2 regulariser (loss none: off)
    correction: str = "none"  # none | reweight | dagger: a state-shift correction (mop_core.distill.corrections)
    reweight: ReweightConfig = field(default_factory=ReweightConfig)  # correction reweight's ratio and clip
    dagger: DaggerConfig = field(default_factory=DaggerConfig)  # correction dagger's rounds

    def __post_init__(self) -> None:
        require(self.loss in LOSSES, "loss", f"one of {tuple(LOSSES)}", self.loss)
        require(self.q_reduction in Q_REDUCTIONS, "q_reduction", f"one of {Q_REDUCTIONS}", self.q_reduction)
        require(self.state_source in STATE_SOURCES, "state_source", f"one of {STATE_SOURCES}", self.state_source)
        require(self.learning_rate > 0, "learning_rate", "a positive number", self.learning_rate)
        require(self.lr_schedule in LR_SCHEDULES, "lr_schedule", f"one of {LR_SCHEDULES}", self.lr_schedule)
        require(self.batch_size >= 1, "batch_size", "a positive integer", self.batch_size)
        require(self.probe_states >= 0, "probe_states", "a non-negative integer (0 = no tau curve)",
                self.probe_states)
        require(self.probe_source in PROBE_SOURCES, "probe_source", f"one of {PROBE_SOURCES}", self.probe_source)
        require(self.num_states >= 0, "num_states", "a non-negative integer (0 = the whole dataset)",
                self.num_states)
        require(self.state_source == "offline" or self.num_states > 0, "num_states",
                "a positive number of states for state_source online", self.num_states)
        require(0 < self.data_fraction <= 1, "data_fraction", "a share of the dataset's episodes in (0, 1]",
                self.data_fraction)
        require(self.data_fraction == 1 or self.state_source == "offline", "data_fraction",
                "1 unless state_source is offline", self.data_fraction)
        require(self.correction in CORRECTIONS, "correction", f"one of {CORRECTIONS}", self.correction)
        require(self.correction != "reweight" or self.state_source == "offline", "correction",
                "not reweight unless state_source is offline (it reweights dataset states)", self.correction)
        hidden = len(self.student.hidden_sizes)
        require(len(self.ranking.layer_weights) in (0, hidden), "ranking.layer_weights",
                f"one weight per hidden layer of the student ({hidden}) or [] (1 each)",
                list(self.ranking.layer_weights))
        require(not self.ranking.active or self.ranking.states <= self.batch_size, "ranking.states",
                f"at most batch_size={self.batch_size} (the regulariser compares states of the step's batch)",
                self.ranking.states)


def distill_config(params: Mapping[str, Any], loss: str) -> DistillConfig:
    raw = {k: v for k, v in section(params, "distill").items() if k not in DISTILL_GRID_KEYS}
    if "loss" in raw:
        raise ConfigError("distill.loss: set the losses in distill.losses instead")
    if "correction" in raw:  # a student variant's setting, not the study's (its correction students set it)
        raise ConfigError("distill.correction: set the state_shift corrections instead (state_shift.corrections)")
    return from_mapping(DistillConfig, raw | {"loss": loss}, "distill")


def cumulative_weights(weights: torch.Tensor | None) -> torch.Tensor | None:
    """The normalised cumulative sum of sampling weights (float64), None for uniform sampling."""
    if weights is None:
        return None
    if (weights < 0).any() or not weights.sum() > 0:
        raise ValueError("weights: expected non-negative sampling weights with a positive sum")
    cdf = torch.cumsum(weights.double(), 0)
    return cdf / cdf[-1]


def weighted_rows(cdf: torch.Tensor, count: int, generator: torch.Generator) -> torch.Tensor:
    """``count`` row indices drawn with replacement, row i with probability ``w_i / sum w`` (``cdf``:
    :func:`cumulative_weights`), by inverse CDF: one uniform and a binary search per draw; a zero-weight
    row is never drawn. benchmarks/bench_distill.py times it against ``torch.multinomial``."""
    u = torch.rand(count, generator=generator, device=cdf.device, dtype=torch.float64)
    return torch.searchsorted(cdf, u, right=True).clamp_max(len(cdf) - 1)


class Distiller:
    """R students (a group; R = 1 is one run), their optimiser and every task's cached targets;
    ``update()`` is one step of every run.

    Run r has its own seed (initialisation: the same weights as a lone :class:`Student` built after
    ``torch.manual_seed(seeds[r])``), its own generator of state indices and its own states
    (``targets[r][i]``: task i's). One forward, backward and fused Adam step serve all runs: the
    loss is the sum over runs of each run's mean, so run r's gradient is its own loss's gradient,
    and Adam is element-wise: a group equals its runs trained alone, to float rounding (tested).
    """

    def __init__(self, config: DistillConfig, targets: Sequence[Sequence[TaskStates]], obs_dim: int, act_dim: int,
                 seeds: Sequence[int], critics: Sequence[EnsembleCritic] | None = None,
                 device: torch.device | str = "cpu", total_steps: int = 1):
        if len(targets) != len(seeds) or not seeds:
            raise ValueError(f"targets: expected one list of task states per seed ({len(seeds)}), got {len(targets)}")
        self.config, self.device, self.targets = config, torch.device(device), [list(t) for t in targets]
        self.base = [list(t) for t in targets]  # the states before any aggregation (DAgger)
        self.added: list[list[list | None]] = [[None] * len(t) for t in targets]
        self.cdfs = [[cumulative_weights(t.weights) for t in run] for run in self.targets]  # sampling weights' CDFs
        self.total_steps = total_steps  # the length of the learning-rate schedule
        self.tasks = [t.task for t in self.targets[0]]
        if any([t.task for t in run] != self.tasks for run in self.targets):
            raise ValueError("targets: every run of a group must learn the same tasks in the same order")
        self.spec = LOSSES[config.loss]
        if self.spec.needs_critics and (critics is None or len(critics) != len(self.tasks)):
            raise ValueError(f"critics: the {config.loss} loss needs one teacher critic ensemble per task")
        if self.spec.teacher_actor == "gaussian" and any(t.teacher_std is None for run in self.targets for t in run):
            raise ValueError(f"targets: the {config.loss} loss needs Gaussian teachers (teacher_std is missing)")
        self.critics = ([c.to(self.device).requires_grad_(False) for c in critics] if self.spec.needs_critics
                        else [])
        students = []
        for seed in seeds:
            torch.manual_seed(seed)  # each run's initialisation, as a run alone would draw it
            students.append(Student(config.student, obs_dim, act_dim, len(self.tasks),
                                    gaussian=self.spec.gaussian_student))
        self.seeds = list(seeds)
        self.group = StudentGroup(students).to(self.device)
        self.optimizer = adam(self.group.parameters(), config.learning_rate)
        # state indices drawn on the device the states lie on (no host-to-device copy per step on a GPU)
        self.generators = [torch.Generator(self.device).manual_seed(seed) for seed in seeds]
        self.updates = 0

    @property
    def runs(self) -> int:
        return len(self.seeds)

    def student(self, run: int = 0) -> Student:
        """Run ``run``'s student as it is now (a copy)."""
        return self.group.member(run)

    def _rows(self, run: int, task: int, batch_size: int) -> torch.Tensor:
        cdf = self.cdfs[run][task]
        if cdf is not None:  # reweighted distillation: rows drawn in proportion to their weight
            return weighted_rows(cdf, batch_size, self.generators[run])
        return torch.randint(len(self.targets[run][task]), (batch_size,), generator=self.generators[run],
                             device=self.device)

    def aggregate(self, run: int, task: int, states: torch.Tensor, teacher_actions: torch.Tensor,
                  teacher_std: torch.Tensor | None = None) -> None:
        """Add labelled states to run ``run``'s states of task ``task`` (DAgger's aggregation: the
        states its student visited, labelled by the frozen teacher); kept in the resume state."""
        added = self.added[run][task]
        parts = [torch.as_tensor(x, dtype=torch.float32, device=self.device) if x is not None else None
                 for x in (states, teacher_actions, teacher_std)]
        self.added[run][task] = parts if added is None else [
            None if old is None else torch.cat([old, new]) for old, new in zip(added, parts)]
        self._apply_added(run, task)

    def _apply_added(self, run: int, task: int) -> None:
        base, added = self.base[run][task], self.added[run][task]
        if base.weights is not None:
            raise ValueError("aggregate: reweighted states cannot grow (their weights are the dataset's)")
        std = None if base.teacher_std is None else torch.cat([base.teacher_std, added[2]])
        self.targets[run][task] = dataclasses.replace(
            base, states=torch.cat([base.states, added[0]]), teacher_actions=torch.cat([base.teacher_actions,
                                                                                         added[1]]),
            teacher_std=std, source=base.source | {"aggregated_states": len(added[0])})

    def loss(self, rows: Sequence[Sequence[torch.Tensor]], tasks: Sequence[int] | None = None,
             regularise: bool = True) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The loss on the given state indices (``rows[r][k]``: run r's indices into task ``tasks[k]``;
        default tasks: all, in task order; every run draws the same count per task) and per-run,
        per-task metrics (0-d tensors, not read here, named ``key@run``). The loss is the sum over
        runs of each run's mean over its rows (plus the ranking regulariser when ``regularise``)."""
        cfg = self.config
        tasks = list(range(len(self.tasks))) if tasks is None else list(tasks)
        sizes = [len(r) for r in rows[0]]
        if any([len(r) for r in run_rows] != sizes for run_rows in rows):
            raise ValueError("rows: every run of a group must draw the same number of states per task")

        def gather(field: str) -> torch.Tensor:
            return torch.stack([torch.cat([getattr(self.targets[r][t], field)[i] for t, i in zip(tasks, run_rows)])
                                for r, run_rows in enumerate(rows)])

        obs, teacher_actions = gather("states"), gather("teacher_actions")
        task_ids = torch.tensor(tasks, device=self.device).repeat_interleave(torch.tensor(sizes, device=self.device))
        teacher_std = gather("teacher_std") if self.spec.teacher_actor == "gaussian" else None
        per_state, actions = self.spec.per_state(LossInputs(self.group, obs, task_ids, teacher_actions, teacher_std,
                                                            tasks, sizes, self.critics, cfg.q_reduction))
        run_losses = per_state.mean(-1)  # [R]
        metrics: dict[str, torch.Tensor] = {}
        if regularise and cfg.ranking.active and len(self.tasks) > 1:
            regulariser = self.ranking_term(obs, sizes)
            run_losses = run_losses + cfg.ranking.weight * regulariser
            for r in range(self.runs):
                metrics[run_key("ranking", r)] = regulariser[r].detach()
        with torch.no_grad():
            action_mse = mse_per_state(actions, teacher_actions)
            for r in range(self.runs):
                metrics[run_key("loss", r)] = run_losses[r].detach()
                for t, part, mse in zip(tasks, per_state[r].split(sizes), action_mse[r].split(sizes)):
                    metrics[run_key(f"loss_{self.tasks[t]}", r)] = part.mean()
                    metrics[run_key(f"action_mse_{self.tasks[t]}", r)] = mse.mean()
        return run_losses.sum(), metrics

    def ranking_term(self, obs: torch.Tensor, sizes: Sequence[int]) -> torch.Tensor:
        """The ranking regulariser per run ``[R]`` (:class:`RankingConfig`) on the first
        ``ranking.states`` states of each task's rows of ``obs [R, B, o]``, each under every task id."""
        cfg, m = self.config.ranking, len(self.tasks)
        starts = [sum(sizes[:k]) for k in range(len(sizes))]
        states = torch.cat([obs[:, start:start + min(cfg.states, size)] for start, size in zip(starts, sizes)], dim=1)
        under_ids = torch.stack([with_task_id(states, k, m) for k in range(m)], dim=1)  # [R, m, S, o + m]
        runs, _, count, width = under_ids.shape
        layers = [a.view(runs, m, count, -1) for a in self.group.hidden(under_ids.view(runs, m * count, width))]
        return cross_task_ranking(layers, ranking_loss(cfg.loss, cfg.temperature), cfg.weights_for(len(layers)),
                                  symmetric=cfg.loss in SYMMETRIC_LOSSES)

    def gradient_cosines(self, generator: torch.Generator) -> list[dict[str, float]]:
        """PCGrad's conflict measure (Yu et al. 2020) per run: for each task pair (i, k),
        ``cos(g_i, g_k)`` of the gradients of task i's and task k's distillation loss (``batch_size``
        fresh states of each task, the ranking regulariser left out) with respect to every student
        weight. All weights are shared: the task enters as a one-hot input, so only the first layer's
        task-id rows are task-specific (each task's gradient touches its own row only). A negative
        cosine is a conflict: a step for one task undoes part of the other's (thesis 5.1.2's
        explanation of naive multi-task failure). ``generator`` draws the states, so measuring leaves
        the training index streams untouched. Keys ``grad_cosine_<i>-<k>`` and ``grad_cosine`` (their
        mean)."""
        params = [p for p in self.group.parameters() if p.requires_grad]
        flat = []
        for t in range(len(self.tasks)):
            rows = [[torch.randint(len(self.targets[r][t]), (self.config.batch_size,), generator=generator,
                                   device=self.device)] for r in range(self.runs)]
            loss, _ = self.loss(rows, [t], regularise=False)  # a sum over runs: run r's rows give its gradient
            flat.append(flat_gradient(loss, params, self.runs))
        return pairwise_cosines(flat, self.tasks)

    def _step(self, loss: torch.Tensor) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()

    def _draw(self, tasks: Sequence[int]) -> list[list[torch.Tensor]]:
        return [[self._rows(r, t, self.config.batch_size) for t in tasks] for r in range(self.runs)]

    def update(self) -> dict[str, torch.Tensor | float]:
        lr = learning_rate_at(self.config, self.updates, self.total_steps)
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        tasks = range(len(self.tasks))
        if self.config.step_per_task:
            metrics = {}
            for t in tasks:
                loss, task_metrics = self.loss(self._draw([t]), [t])
                self._step(loss)
                metrics |= {k: v for k, v in task_metrics.items() if not k.startswith("loss@")}
            for r in range(self.runs):
                metrics[run_key("loss", r)] = sum(metrics[run_key(f"loss_{task}", r)]
                                                  for task in self.tasks) / len(self.tasks)
        else:
            loss, metrics = self.loss(self._draw(tasks))
            self._step(loss)
        metrics["learning_rate"] = lr
        self.updates += 1
        return metrics

    def state_dict(self) -> dict:
        return copy.deepcopy({"group": self.group.state_dict(), "optimizer": self.optimizer.state_dict(),
                              "generators": [g.get_state() for g in self.generators], "updates": self.updates,
                              "added": self.added})

    def load_state_dict(self, state: dict) -> None:
        self.group.load_state_dict(state["group"])
        self.optimizer.load_state_dict(state["optimizer"])
        for generator, saved in zip(self.generators, state["generators"], strict=True):
            generator.set_state(saved)
        self.updates = state["updates"]
        self.added = state.get("added") or [[None] * len(t) for t in self.targets]
        for run, per_task in enumerate(self.added):
            for task, added in enumerate(per_task):
                if added is None:
                    self.targets[run][task] = self.base[run][task]
                else:
                    self._apply_added(run, task)
