"""Relabelling (thesis chapter 6.4): the reward of every transition under every task.

D_{j->i} is task j's dataset with its rewards recomputed under task i's reward function. Rewards
depend only on the next state, so they are a function of the stored reward features
(:func:`mop_core.walker.tasks.reward`, vectorised, millions of transitions per second) or, as the
reference path, of the stored physics state replayed through MuJoCo and dm_control's own
``get_reward`` (:func:`mop_core.walker.envs.physics_replay_rewards`). Both agree with dm_control to
floating-point precision; the relabel file stores float64 rewards beside, not inside, the dataset.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from mop_core.config import require
from mop_core.data.buffer import TransitionTensors
from mop_core.data.hdf5 import Dataset, DatasetError, read_dataset, read_relabel, write_dataset, write_relabel
from mop_core.walker.envs import physics_replay_rewards
from mop_core.walker.tasks import check_task_list, reward

METHODS = ("vectorised", "physics")


@dataclass(frozen=True)
class RelabelConfig:
    """How the relabel stage computes and checks rewards."""

    method: str = "vectorised"  # "vectorised" (reward features) or "physics" (replay through MuJoCo)
    physics_check_transitions: int = 1000  # rows per dataset also replayed through physics as a check
    tolerance: float = 1e-6  # max |reward difference| allowed between the two paths and the stored rewards

    def __post_init__(self) -> None:
        require(self.method in METHODS, "method", f"one of {', '.join(METHODS)}", self.method)
        require(self.physics_check_transitions >= 0, "physics_check_transitions", "a non-negative integer",
                self.physics_check_transitions)
        require(self.tolerance > 0, "tolerance", "a positive number", self.tolerance)


def relabel_rewards(dataset: Dataset, tasks: Sequence[str], method: str = "vectorised") -> dict[str, np.ndarray]:
    """Rewards [N] float64 of every transition of ``dataset`` under each of ``tasks``."""
    if method == "vectorised":
        return {task: reward(dataset.arrays["reward_features"], task) for task in tasks}
    if method == "physics":
        return physics_replay_rewards(dataset.arrays["next_physics"], tasks)
    raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")


def relabel_dataset(dataset_path: str | os.PathLike, out_path: str | os.PathLike, tasks: Sequence[str],
                    config: RelabelConfig, source_task: str | None = None, level: str | None = None) -> dict:
    """Write the relabel file of one dataset and return its check metrics.

    The dataset's stored content_sha256 is verified first (a file edited after collect is refused,
    as is one whose attributes name another ``source_task`` or ``level`` than expected). Checks,
    failing loudly beyond ``config.tolerance``: the recomputed reward of the dataset's own task
    against the stored (dm_control) rewards, and the other method on a sample of rows.
    """
    tasks = check_task_list(tasks, "tasks")
    dataset = read_dataset(dataset_path, verify_checksum=True, task=source_task, level=level)
    rewards = relabel_rewards(dataset, tasks, config.method)
    own_task = dataset.attrs["task"]
    metrics: dict = {"transitions": len(dataset), "method": config.method}
    if own_task in rewards:
        stored = dataset.arrays["rewards"].astype(np.float64)
        # stored rewards are float32, so this difference includes float32 rounding (~3e-8)
        diff = float(np.abs(rewards[own_task] - stored).max())
        metrics["max_abs_diff_vs_stored"] = diff
        if diff > config.tolerance:
            raise DatasetError(f"{dataset_path}: relabelled {own_task} rewards differ from the stored dm_control "
                               f"rewards by {diff:.3g} > tolerance {config.tolerance}")
    n_check = min(config.physics_check_transitions, len(dataset))
    if n_check:
        rows = np.linspace(0, len(dataset) - 1, n_check).astype(int)
        other = "physics" if config.method == "vectorised" else "vectorised"
        subset = Dataset(dataset.path, {k: v[rows] for k, v in dataset.arrays.items()}, dataset.attrs)
        check = relabel_rewards(subset, tasks, other)
        diff = max(float(np.abs(check[t] - rewards[t][rows]).max()) for t in tasks)
        metrics["max_abs_diff_vectorised_vs_physics"] = diff
        if diff > config.tolerance:
            raise DatasetError(f"{dataset_path}: vectorised and physics-replay rewards differ by {diff:.3g}")
    for task in tasks:
        metrics[f"reward_mean_{task}"] = float(rewards[task].mean())
    attrs = {"dataset_content_sha256": dataset.attrs["content_sha256"], "source_task": own_task,
             "level": dataset.attrs["level"], "method": config.method, "tasks": ",".join(tasks)}
    write_relabel(out_path, rewards, attrs)
    return metrics


def load_transitions(dataset_path: str | os.PathLike, relabel_path: str | os.PathLike | None = None,
                     reward_task: str | None = None, device: torch.device | str = "cpu") -> TransitionTensors:
    """D_{j->i} in memory: dataset j's transitions with task i's rewards, as tensors on ``device``.

    Without ``relabel_path``/``reward_task`` the stored (behaviour-task) rewards are used.
    """
    dataset = read_dataset(dataset_path)
    rewards = None
    if reward_task is not None:
        if relabel_path is None:
            raise ValueError("relabel_path: required when reward_task is given")
        rewards = read_relabel(relabel_path, dataset, reward_task)[reward_task]
    return TransitionTensors.from_arrays(dataset.arrays, rewards, device)


def export_d4rl(dataset_path: str | os.PathLike, relabel_path: str | os.PathLike, reward_task: str,
                out_path: str | os.PathLike) -> Path:
    """Write D_{j->i} as a standalone dataset file: task j's transitions with task i's rewards
    (``reward_task``, float32 under ``rewards``, D4RL's keys), in the study's own schema, so
    :func:`~mop_core.data.read_dataset` reads it back (as a dataset of task i: attribute ``task`` is
    the reward task, ``source_task`` the task whose behaviour policy acted) and any D4RL reader too.
    Its content_sha256 is its own; ``dataset_content_sha256`` names the dataset it came from."""
    dataset = read_dataset(dataset_path)
    rewards = read_relabel(relabel_path, dataset, reward_task)[reward_task]
    arrays = dict(dataset.arrays) | {"rewards": rewards.astype(np.float32)}
    attrs = {key: value for key, value in dataset.attrs.items() if key != "content_sha256"} | {
        "task": reward_task, "source_task": dataset.attrs["task"], "reward_task": reward_task,
        "dataset_content_sha256": dataset.attrs["content_sha256"]}
    write_dataset(out_path, arrays, attrs)
    return Path(out_path)
