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
from typing import Sequence

import torch

from mop_core.distill.config import DistillConfig, learning_rate_at
from mop_core.distill.losses import LOSSES, LossInputs, mse_per_state
from mop_core.distill.ranking import SYMMETRIC_LOSSES, cross_task_ranking, ranking_loss
from mop_core.distill.states import TaskStates
from mop_core.distill.student import Student, StudentGroup
from mop_core.learning.conflict import flat_gradient, pairwise_cosines
from mop_core.learning.graphs import GraphedStep, graphs_enabled, learner_adam, match_loaded
from mop_core.learning.nn import EnsembleCritic, with_task_id
from mop_core.learning.schedule import set_learning_rate
from mop_core.learning.step_metrics import run_key


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
                 device: torch.device | str = "cpu", total_steps: int = 1, cuda_graphs: bool | None = None):
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
        # on CUDA one update (draws and every optimiser step included) is a replayed CUDA graph
        # (mop_core.learning.graphs); eager elsewhere
        captured = graphs_enabled(self.device, cuda_graphs)
        self.optimizer = learner_adam(self.group.parameters(), config.learning_rate, self.device, captured)
        # state indices drawn on the device the states lie on (no host-to-device copy per step on a GPU)
        self.generators = [torch.Generator(self.device).manual_seed(seed) for seed in seeds]
        self.updates = 0
        self._task_ids: dict[tuple, torch.Tensor] = {}  # each row's task index, per (tasks, sizes): made once
        self.graphed = GraphedStep(lambda _variant: self._train_step, self.generators) if captured else None

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
        if self.graphed is not None:  # the captured step read the old states: capture again
            self.graphed.reset()

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
        task_ids = self._row_tasks(tasks, sizes)
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

    def _row_tasks(self, tasks: Sequence[int], sizes: Sequence[int]) -> torch.Tensor:
        """Each row's task index on the device, made once per (tasks, sizes) on the host: a repeat count
        read from the device would be a host round trip per update."""
        key = (tuple(tasks), tuple(sizes))
        if key not in self._task_ids:
            self._task_ids[key] = torch.repeat_interleave(torch.tensor(tasks), torch.tensor(sizes)).to(self.device)
        return self._task_ids[key]

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

    def _train_step(self) -> dict[str, torch.Tensor]:
        """Draws, loss and Adam step(s) of one update (one over all tasks, or one per task with
        ``step_per_task``); per-run metrics as 0-d tensors."""
        tasks = range(len(self.tasks))
        if not self.config.step_per_task:
            loss, metrics = self.loss(self._draw(tasks))
            self._step(loss)
            return metrics
        metrics = {}
        for t in tasks:
            loss, task_metrics = self.loss(self._draw([t]), [t])
            self._step(loss)
            metrics |= {k: v for k, v in task_metrics.items() if not k.startswith("loss@")}
        for r in range(self.runs):
            metrics[run_key("loss", r)] = sum(metrics[run_key(f"loss_{task}", r)]
                                              for task in self.tasks) / len(self.tasks)
        return metrics

    def update(self) -> dict[str, torch.Tensor | float]:
        """One update of every run; on CUDA a replayed CUDA graph (:class:`~mop_core.learning.graphs.GraphedStep`,
        the learning rate a tensor it reads), eager elsewhere."""
        lr = learning_rate_at(self.config, self.updates, self.total_steps)
        set_learning_rate([self.optimizer], lr)
        metrics = self._train_step() if self.graphed is None else self.graphed(0, {})
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
        match_loaded(self.optimizer, self.graphed is not None, self.device)  # as built here, whoever wrote it
        if self.graphed is not None:  # new optimiser tensors: capture again
            self.graphed.reset()
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
