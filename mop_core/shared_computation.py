"""Shared computation of a trained student across its task ids (thesis 6.2, Table 6.1, Figure 6.3).

1. :func:`visited_states`: the student acts online on each task (``episodes`` episodes, the thesis
   used 1000); its visited observations form ``D_i^S``.
2. :func:`measure_student`: with the post-ReLU activations of every hidden layer,
   - *per state*: for each pair of tasks (i, j) and each state ``s ~ D_i^S u D_j^S``, Kendall's
     tau-b between the layer's activations of ``pi^S(s, i)`` and ``pi^S(s, j)``; mean and
     standard deviation over the states;
   - *average*: per task, the mean activation of each neuron over its own states under its own
     id, ``a_i = E_{s~D_i^S}[h(s, i)]``; tau-b between ``a_i`` and ``a_j``;
   - *linear CKA* (the thesis's suggested future work, 6.2.4) between the activation matrices
     ``H_i = h(S, i)`` and ``H_j = h(S, j)`` over the same states ``S = D_i^S u D_j^S``.
   Both Kendall variants are recorded: tau-a (the thesis's formula and the reference code's, so
   Table 6.1/6.2 stay comparable) and tau-b (corrects for ties: ReLU zeros tie many neurons).
   ``zero_fraction`` records how many activations are exactly zero, i.e. how much the two differ.
   - *beyond CKA* (linear CKA is 0.94-1.0 for every student and its untrained copy here):
     orthogonal Procrustes similarity, debiased CKA, per-neuron task selectivity (mean, and the
     share of neurons the id explains >= half of), and per task the dead / dormant share of each
     layer (mop_core.representations.similarity).
3. :func:`summarise_students`: a group of students trained with different seeds -> mean and
   standard deviation over seeds of every figure (Table 6.1 rows).
4. Two references a number is read against, measured the same way on the same kind of states:
   - :func:`untrained_like`: an untrained network of the student's shape: with a one-hot task id
     as 2 of 26 inputs, a random network's per-state tau is already high (~0.8 here);
   - :func:`separate_hidden`: two students distilled each on one task alone, "task id i" being
     network i (the null for "no sharing": neurons of separate networks correspond by index only,
     so per-state and average tau measure chance agreement, while CKA and Procrustes, invariant to
     a rotation of the neurons, measure how alike the two representations are anyway).
"""

from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch

from mop_core.config import from_mapping, require
from mop_core.experiment.study import positive_threads, section
from mop_core.learning.runtime import derive_seeds, parallel_map, resolve_workers
from mop_core.representations.measures import (
    TAU_VARIANTS,
    average_comparison,
    hidden_activations,
    kendall_tau,
    linear_cka,
)
from mop_core.representations.similarity import debiased_cka, dormant_shares, procrustes_similarity, task_selectivity
from mop_core.walker.rollout import collect_episodes

TIES_NOTE = ("Kendall's tau in two variants: tau-a = (C - D) / n0, the thesis's formula (6.2.2) and the "
             "reference code's, where tied neuron pairs stay in the denominator; tau-b = (C - D) / "
             "sqrt((n0 - n1)(n0 - n2)), scipy's default, which removes tied pairs. ReLU outputs are often "
             "exactly 0 and tie neurons, so tau-a < tau-b; zero_fraction gives the share of zero activations "
             "per layer.")


@dataclass(frozen=True)
class SharedComputationConfig:
    """How many states the measurement sees: ``episodes`` online episodes per task and student."""

    episodes: int = 10  # per task (thesis 6.2.1: 1000)
    rollout_envs: int = 10  # walkers stepped together in one process
    workers: int | str = 2  # rollout processes (one torch thread each); auto: the cores this process may use

    def __post_init__(self) -> None:
        for name in ("episodes", "rollout_envs"):
            require(getattr(self, name) >= 1, name, "a positive integer", getattr(self, name))
        object.__setattr__(self, "workers", resolve_workers(self.workers, "workers"))


def shared_computation_config(params: Mapping[str, Any]) -> tuple[int, SharedComputationConfig]:
    """The measurement's torch threads and the rollouts' settings."""
    raw = dict(section(params, "shared_computation"))
    threads = positive_threads(raw.pop("threads", 1), "shared_computation.threads")
    return threads, from_mapping(SharedComputationConfig, raw, "shared_computation")


def episode_seeds(study_seed: int, task: str, episodes: int) -> list[int]:
    """Environment seeds of the measurement rollouts: the same for every student of a task."""
    base = derive_seeds([study_seed, "shared_computation", task], ("episodes",))["episodes"]
    return [base + k for k in range(episodes)]


def visited_states(student_path: Path, task: str, seeds: Sequence[int], episode_length: int,
                   rollout_envs: int) -> tuple[np.ndarray, np.ndarray]:
    """``D_task^S``: the observations ``[episodes * T, obs]`` (float32) a student visits acting on
    ``task`` under its id, and the episodes' returns."""
    from mop_core.distill.checkpoint import load_student

    policy = load_student(student_path).policy(task)
    arrays = collect_episodes(policy, task, seeds, episode_length, rollout_envs)
    returns = arrays["rewards"].reshape(len(seeds), episode_length).sum(1)
    return arrays["observations"].astype(np.float32), returns


def rollout_jobs(students: Mapping[str, tuple[Path, Sequence[str]]], study_tasks: Sequence[str]
                 ) -> list[tuple[Path, str]]:
    """The (checkpoint, task) rollouts of every student, in the order of the tasks *its checkpoint*
    was trained with: ``measure_student`` pairs ``states[i]`` with task id i, so the study's own
    order (``study.tasks``) must not be used. ``students`` maps a name to (checkpoint, its tasks).
    A student trained on another set of tasks than the study's is refused (ConfigError) before any
    rollout."""
    for name, (path, tasks) in students.items():
        require(sorted(tasks) == sorted(study_tasks), "study.tasks",
                f"the tasks student {name} ({path}) was distilled on, {list(tasks)} (rerun distill)",
                list(study_tasks))
    return [(path, task) for path, tasks in students.values() for task in tasks]


def collect_visited(jobs: Sequence[tuple[Path, str]], study_seed: int, episode_length: int,
                    config: SharedComputationConfig, progress: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`visited_states` of every (student checkpoint, task) job, ``config.workers`` processes."""
    args = [(path, task, episode_seeds(study_seed, task, config.episodes), episode_length, config.rollout_envs)
            for path, task in jobs]
    return parallel_map(visited_states, args, config.workers, "shared_computation rollouts", progress)


def layer_key(index: int) -> str:
    """``layer1``, ``layer2``, ...: hidden layers as JSON keys (dvc metrics shows dicts, not lists)."""
    return f"layer{index + 1}"


def _stats(values: torch.Tensor) -> dict:
    finite = values[~torch.isnan(values)]
    return {"mean": float(finite.mean()) if len(finite) else float("nan"),
            "sd": float(finite.std(unbiased=False)) if len(finite) else float("nan"),
            "states": int(len(values)), "undefined": int(len(values) - len(finite))}


Hidden = Callable[[torch.Tensor, int], list]  # (states, task id) -> post-ReLU activations per hidden layer


def student_hidden(student) -> Hidden:
    """One multi-task student's activations under each task id."""
    return lambda obs, task: hidden_activations(student, obs, task)


def separate_hidden(students: Sequence) -> Hidden:
    """The no-sharing reference: "task id i" is the activation of ``students[i]``, a network distilled
    on task i alone (its only id, 0); the same measures then compare two networks that share no
    weight, the value a multi-task student's numbers mean nothing below."""
    return lambda obs, task: hidden_activations(students[task], obs, 0)


@torch.no_grad()
def measure_student(student, tasks: Sequence[str], states: Sequence[torch.Tensor]) -> dict:
    """Per-state, average and CKA comparisons of one student (module docstring); ``states[i]`` were
    visited acting as ``tasks[i]``. Per pair ``"<task_i>-<task_j>"`` and layer (1-based order)."""
    return measure_networks(student_hidden(student), tasks, states)


@torch.no_grad()
def measure_networks(hidden: Hidden, tasks: Sequence[str], states: Sequence[torch.Tensor]) -> dict:
    """:func:`measure_student` for any ``hidden(states, task id)``: one student's task ids
    (:func:`student_hidden`) or separately trained single-task networks (:func:`separate_hidden`)."""
    if len(tasks) != len(states) or len(tasks) < 2:
        raise ValueError(f"states: expected one state batch per task for >= 2 tasks, got {len(states)} for {tasks}")
    m = len(tasks)
    own = [hidden(obs, i) for i, obs in enumerate(states)]  # own[i][layer]
    under = [[own[i] if j == i else hidden(obs, j) for j in range(m)] for i, obs in enumerate(states)]
    averages = average_comparison([[acts.mean(0) for acts in layers] for layers in own])
    layers = len(own[0])
    pairs = {}
    for i, j in itertools.combinations(range(m), 2):
        rows = {}
        for layer in range(layers):
            row = {}
            # s ~ D_i u D_j: per state, the layer under the state's own id against it under the other id
            per_state = [kendall_tau(own[i][layer], under[i][j][layer]), kendall_tau(own[j][layer], under[j][i][layer])]
            for variant in TAU_VARIANTS:
                row[f"per_state_tau_{variant}"] = _stats(torch.cat([taus[variant] for taus in per_state]))
            for variant in TAU_VARIANTS:
                row[f"average_tau_{variant}"] = float(averages[layer][variant][i, j])
            under_i = torch.cat([own[i][layer], under[j][i][layer]])
            under_j = torch.cat([under[i][j][layer], own[j][layer]])
            row["linear_cka"] = linear_cka(under_i, under_j)
            row |= beyond_cka(under_i, under_j)
            rows[layer_key(layer)] = row
        pairs[f"{tasks[i]}-{tasks[j]}"] = rows
    return {
        "tasks": list(tasks),
        "states_per_task": {task: int(len(obs)) for task, obs in zip(tasks, states)},
        "pairs": pairs,
        "zero_fraction": {task: {layer_key(k): float((acts == 0).double().mean()) for k, acts in enumerate(own[i])}
                          for i, task in enumerate(tasks)},
        "dormant": {task: {layer_key(k): dormant_shares(acts) for k, acts in enumerate(own[i])}
                    for i, task in enumerate(tasks)},
        "mean_activations": {task: [acts.mean(0).tolist() for acts in own[i]] for i, task in enumerate(tasks)},
    }


BEYOND_CKA = ("procrustes", "debiased_cka", "selectivity_mean", "selective_share")
SELECTIVE = 0.5  # a neuron is task-selective when the task id explains at least half its variance


def beyond_cka(under_i: torch.Tensor, under_j: torch.Tensor) -> dict[str, float]:
    """The measures that can tell students apart where linear CKA saturates (mop_core.representations.similarity),
    on a layer's activations over the same states under ids i and j: orthogonal Procrustes
    similarity, debiased CKA, the mean task selectivity of the neurons that vary and the share of
    all neurons the task id explains at least half of (``SELECTIVE``)."""
    eta = task_selectivity([under_i, under_j])
    varying = eta[~torch.isnan(eta)]
    return {"procrustes": procrustes_similarity(under_i, under_j), "debiased_cka": debiased_cka(under_i, under_j),
            "selectivity_mean": float(varying.mean()) if len(varying) else float("nan"),
            "selective_share": float((varying >= SELECTIVE).double().sum() / len(eta))}


def untrained_like(student, seed: int):
    """A copy of the student with every layer re-initialised (``torch.manual_seed(seed)`` first), i.e.
    an untrained network of the same architecture and the same default initialisation."""
    fresh = copy.deepcopy(student)
    torch.manual_seed(seed)
    for module in fresh.modules():
        if isinstance(module, torch.nn.Linear):
            module.reset_parameters()
    return fresh.eval().requires_grad_(False)


def summarise_students(records: Sequence[dict]) -> dict:
    """Table 6.1 row(s) of a group of students (different training seeds): per pair and layer, the
    seed-mean of the per-state mean tau (a and b), its states' sd, the average tau (a and b) and CKA,
    with the sd over seeds (0 for one seed)."""
    summary: dict = {"students": len(records), "pairs": {}}
    for pair, layers in records[0]["pairs"].items():
        out = {}
        for layer in layers:
            entries = [record["pairs"][pair][layer] for record in records]
            values = {}
            for variant in TAU_VARIANTS:
                key = f"per_state_tau_{variant}"
                values[f"{key}_mean"] = [e[key]["mean"] for e in entries]
                values[f"{key}_sd"] = [e[key]["sd"] for e in entries]
            for key in ("average_tau_a", "average_tau_b", "linear_cka", *BEYOND_CKA):
                values[key] = [e[key] for e in entries if key in e]
            row: dict = {}
            for key, vals in values.items():
                if vals:
                    row[key] = float(np.mean(vals))
                    row[f"{key}_seed_sd"] = float(np.std(vals, ddof=1)) if len(vals) > 1 else 0.0  # sample sd
            out[layer] = row
        summary["pairs"][pair] = out
    return summary
