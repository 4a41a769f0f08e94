"""A distillation group evaluated during training: rollouts of every run on every task, per-state tau on the
probe states, and the action errors on the training, held-out and visited states (thesis 5.2, 6.3.1)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from mop_core.distill.checkpoint import student_policy
from mop_core.distill.config import DistillConfig
from mop_core.distill.distiller import Distiller
from mop_core.distill.losses import mse_per_state
from mop_core.distill.states import (
    TaskStates,
    teacher_outputs,
)
from mop_core.distill.student import Student
from mop_core.learning.training import returns_summary
from mop_core.representations.measures import per_state_tau_by_layer
from mop_core.teacher_policies import Teacher
from mop_core.walker.rollout import policies_returns_and_states


def visited_probes(visited: Sequence[np.ndarray], per_task: int, seed: int) -> list[torch.Tensor]:
    """``per_task`` of the states the student visited on each task in one evaluation (``probe_source:
    visited``, as the thesis's reference code measured), drawn without replacement with ``seed``."""
    rng = np.random.default_rng(seed)
    return [torch.as_tensor(states[np.sort(rng.choice(len(states), size=min(per_task, len(states)),
                                                      replace=False))]) for states in visited]


def tau_columns(taus: dict[str, list[float]]) -> dict[str, float]:
    """``{"a": [..], "b": [..]}`` per layer -> curve columns ``per_state_tau_<a|b>_layer<k>``."""
    return {f"per_state_tau_{variant}_layer{k + 1}": tau for variant, layers in taus.items()
            for k, tau in enumerate(layers)}


Rollouts = list[tuple[np.ndarray, np.ndarray | None]]  # per run: returns [episodes], visited states or None


def group_rollouts(students: Sequence[Student], tasks: Sequence[str], task_index: int, seeds: list[int],
                   episode_length: int, rollout_envs: int, device: torch.device, keep_states: bool
                   ) -> Rollouts:
    """Every run's student on task ``tasks[task_index]`` (returns and, with ``keep_states``, visited
    states per run), the runs' walkers stepped together: what each run's own rollout gives, bit
    for bit (:func:`mop_core.walker.rollout.policies_returns_and_states`), in one MuJoCo batch."""
    return policies_returns_and_states([student_policy(s, task_index, device) for s in students], tasks[task_index],
                                       seeds, episode_length, rollout_envs, keep_states)


@dataclass
class GroupEvaluation:
    """How a group's students are evaluated online: every run on every task (its returns and
    visited states), and each run's per-state tau on the probes (``fixed_probes``, or with none, on
    states it visited: ``probe_source: visited``). The last curve point is the final evaluation
    (:func:`~mop_core.learning.training.train_loop`'s ``final_seeds``): its rollouts are kept in ``final``
    and the run's final metrics reuse them rather than rolling them out again."""

    tasks: Sequence[str]
    episode_length: int
    rollout_envs: int
    device: torch.device
    track_tau: bool
    probe_states: int
    probe_seed: int
    fixed_probes: Sequence[torch.Tensor]
    final_seeds: list[int]
    final: list[Rollouts] | None = None  # [task] of the final evaluation, once the last curve point ran

    def rollouts(self, students: Sequence[Student], task_index: int, seeds: list[int], keep_states: bool
                 ) -> Rollouts:
        return group_rollouts(students, self.tasks, task_index, seeds, self.episode_length, self.rollout_envs,
                              self.device, keep_states)

    def per_task(self, students: Sequence[Student], seeds: list[int]) -> list[Rollouts]:
        """Every task's rollouts on episodes ``seeds`` (kept as ``final`` when they are the final ones)."""
        out = [self.rollouts(students, i, seeds, keep_states=True) for i in range(len(self.tasks))]
        if seeds == self.final_seeds:
            self.final = out
        return out

    def final_rollouts(self, students: Sequence[Student]) -> list[Rollouts]:
        return self.final if self.final is not None else self.per_task(students, self.final_seeds)

    def probe_tau(self, student: Student, visited: Sequence[np.ndarray]) -> dict[str, float]:
        probes = self.fixed_probes or visited_probes(visited, self.probe_states, self.probe_seed)
        return tau_columns(per_state_tau_by_layer(student, [p.to(self.device) for p in probes]))

    def rows(self, students: Sequence[Student], per_task: list[Rollouts]) -> list[dict[str, float]]:
        """Per run: each task's return mean and std, their mean over tasks and (tracked) the tau columns."""
        rows: list[dict[str, float]] = [{} for _ in students]
        visited: list[list[np.ndarray]] = [[] for _ in students]
        for task, task_runs in zip(self.tasks, per_task):
            for r, (returns, states) in enumerate(task_runs):
                rows[r] |= {f"{key}_{task}": value for key, value in returns_summary(returns).items()}
                visited[r].append(states)
        for row in rows:
            row["return_mean"] = float(np.mean([row[f"return_mean_{task}"] for task in self.tasks]))
        if not self.track_tau:
            return rows
        return [row | self.probe_tau(s, v) for row, s, v in zip(rows, students, visited)]


def tau_record(config: DistillConfig, fixed_probes: Sequence[torch.Tensor], at_init: dict[str, float],
               last_row: dict) -> dict:
    """The metrics record's per-state tau: how it was probed, at initialisation and at the end."""
    return {"probe_source": config.probe_source,
            "probe_states_per_task": min(len(p) for p in fixed_probes) if fixed_probes else config.probe_states,
            "probe_sha256": (hashlib.sha256(torch.cat(list(fixed_probes)).numpy().tobytes()).hexdigest()
                             if fixed_probes else None),
            "at_init": at_init, "final": {key: float(last_row[key]) for key in at_init}}


def final_returns_record(tasks: Sequence[str], teachers: Sequence[Teacher], finals: Sequence[np.ndarray]) -> dict:
    """Per task: the final evaluation's returns next to the teacher's (the metrics record)."""
    record = {}
    for task, teacher, final in zip(tasks, teachers, finals):
        teacher_return = float(teacher.metrics.get("return_mean", float("nan")))
        record[task] = {"return_mean": float(final.mean()), "return_std": float(final.std()),
                        "eval_episodes": len(final), "teacher_return_mean": teacher_return,
                        "student_to_teacher": float(final.mean() / teacher_return)}
    return record


@torch.no_grad()
def action_error(student: Student, task_index: int, states: torch.Tensor, teacher_actions: torch.Tensor,
                 chunk: int = 65536) -> float:
    """Mean over ``states`` of ``||pi^T(s) - pi^S(s, i)||^2`` (the MSE loss's per-state term; a
    Gaussian student's action is its mean, as it acts in evaluation)."""
    total = 0.0
    for part, target in zip(states.split(chunk), teacher_actions.split(chunk)):
        total += float(mse_per_state(student(part, task_index), target).sum())
    return total / len(states)


def action_errors(student: Student, teachers: Sequence[Teacher], targets: Sequence[TaskStates],
                  visited: Sequence[np.ndarray], device: torch.device) -> list[dict[str, float]]:
    """Where the student goes wrong, per task: its action error to its targets on
    its training states (``train``: the dataset's, before any aggregation), on held-out states of
    the same data (``heldout``, when it has them) and to its teacher on the states it visited itself in
    the final evaluation (``visited``: what it meets when it acts)."""
    def to_teacher(states: torch.Tensor | np.ndarray, i: int) -> float:
        cpu = torch.as_tensor(states, dtype=torch.float32).cpu()  # the frozen teachers act on the CPU
        return action_error(student, i, cpu.to(device), teacher_outputs(teachers[i].actor, cpu)[0].to(device))

    out = []
    for i, states in enumerate(targets):
        errors = {"train": action_error(student, i, states.states, states.teacher_actions)}
        if states.heldout is not None:
            errors["heldout"] = to_teacher(states.heldout, i)
        errors["visited"] = to_teacher(visited[i], i)
        out.append(errors)
    return out


def shift_record(metrics: dict, distiller: Distiller, run: int, student: Student, teachers: Sequence[Teacher],
                 visited: Sequence[np.ndarray], device: torch.device) -> None:
    """Add run ``run``'s state-shift record to its metrics: per task its action errors
    (:func:`action_errors`) and what its density-ratio weights did (reweighted), and its DAgger
    aggregation (the states each task gained)."""
    for i, (task, errors) in enumerate(zip(distiller.tasks, action_errors(student, teachers, distiller.base[run],
                                                                            visited, device))):
        metrics[task]["action_mse"] = errors
        reweight = {k: v for k, v in distiller.base[run][i].source.items() if k.startswith("reweight_")}
        if reweight:  # mop_core.distill.corrections.density_weights
            metrics[task]["reweight"] = reweight
    if distiller.config.correction == "dagger":
        dagger = distiller.config.dagger
        metrics["dagger"] = {"rounds": dagger.rounds, "episodes_per_round": dagger.episodes,
                             "aggregated_states": {task: 0 if added is None else len(added[0])
                                                   for task, added in zip(distiller.tasks, distiller.added[run])}}
