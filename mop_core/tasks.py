"""The walker task registry and the vectorised task rewards.

All walker tasks share one body and one dynamics; they differ only in the reward. dm_control's
``suite/walker.py`` defines, for a target speed ``v`` (stand 0, walk 1, run 8)::

    standing = tol(h; bounds=(1.2, inf), margin=0.6, gaussian, value_at_margin=0.1)
    upright  = (1 + u) / 2
    stand    = (3 * standing + upright) / 4
    r        = stand                                        if v == 0
    r        = stand * (5 * tol(x; bounds=(v, inf), margin=v/2, linear, 0.5) + 1) / 6   otherwise

with ``h`` the torso height, ``u`` the torso's zz orientation entry (torso upright) and ``x`` the
horizontal centre-of-mass velocity of the torso subtree (sensor ``torso_subtreelinvel[0]``, not
``qvel[0]``). These three *reward features* are stored with every transition, so the reward of
any transition under any task (D_{j->i} of thesis chapter 6.4) is this formula evaluated on arrays.
A new task is a new :class:`WalkerTask` entry in :data:`TASKS`; nothing else branches on names.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from mop_core.config import ConfigError

#: Column order of the reward-feature arrays ``[..., 3]``.
REWARD_FEATURES: tuple[str, ...] = ("torso_height", "torso_upright", "horizontal_velocity")

_STAND_HEIGHT = 1.2
_GAUSSIAN_SCALE = np.sqrt(-2.0 * np.log(0.1))  # dm_control's default value_at_margin=0.1
_LINEAR_SCALE = 1.0 - 0.5  # value_at_margin=0.5 for the move reward


def _lower_bound_gaussian(x: np.ndarray, lower: float, margin: float) -> np.ndarray:
    """dm_control ``tolerance(x, bounds=(lower, inf), margin, 'gaussian', 0.1)``."""
    d = (lower - x) / margin
    return np.where(x >= lower, 1.0, np.exp(-0.5 * (d * _GAUSSIAN_SCALE) ** 2))


def _lower_bound_linear(x: np.ndarray, lower: float, margin: float) -> np.ndarray:
    """dm_control ``tolerance(x, bounds=(lower, inf), margin, 'linear', 0.5)``."""
    scaled = (lower - x) / margin * _LINEAR_SCALE
    return np.where(x >= lower, 1.0, np.where(np.abs(scaled) < 1.0, 1.0 - scaled, 0.0))


@dataclass(frozen=True)
class WalkerTask:
    """A walker reward function.

    Attributes:
        name: the task's name in the study (``stand``, ``walk``, ``run``).
        move_speed: target horizontal speed ``v`` in m/s; 0 means the pure stand reward.
        dm_control_task: the dm_control suite task with this reward (used to build envs and to
            check rewards against dm_control's own ``get_reward``).
        expert_return: the published expert return of this task (UTDS's ``task.json``, the
            reference of D4RL-style normalised scores ``100 (R - R_random) / (R_expert - R_random)``;
            R_random is measured by the collect stage).
    """

    name: str
    move_speed: float
    dm_control_task: str
    expert_return: float

    def reward(self, features: np.ndarray) -> np.ndarray:
        """Reward of each row of ``features [..., 3]`` (columns :data:`REWARD_FEATURES`), float64."""
        features = np.asarray(features, dtype=np.float64)
        if features.shape[-1] != len(REWARD_FEATURES):
            raise ValueError(f"features: expected last dimension {len(REWARD_FEATURES)} "
                             f"({', '.join(REWARD_FEATURES)}), got shape {features.shape}")
        height, upright, velocity = features[..., 0], features[..., 1], features[..., 2]
        standing = _lower_bound_gaussian(height, _STAND_HEIGHT, _STAND_HEIGHT / 2)
        stand_reward = (3 * standing + (1 + upright) / 2) / 4
        if self.move_speed == 0:
            return stand_reward
        move_reward = _lower_bound_linear(velocity, self.move_speed, self.move_speed / 2)
        return stand_reward * (5 * move_reward + 1) / 6


TASKS: dict[str, WalkerTask] = {
    task.name: task
    for task in (
        WalkerTask("stand", 0.0, "stand", expert_return=986.8),
        WalkerTask("walk", 1.0, "walk", expert_return=980.0),
        WalkerTask("run", 8.0, "run", expert_return=842.6),
    )
}


def get_task(name: str, key: str = "task") -> WalkerTask:
    """The registered task ``name``; a ``ConfigError`` naming ``key`` and the known tasks otherwise."""
    if name not in TASKS:
        raise ConfigError(f"{key}: unknown task {name!r}; known tasks: {', '.join(TASKS)}")
    return TASKS[name]


def reward(features: np.ndarray, task: str | WalkerTask) -> np.ndarray:
    """Vectorised reward of ``features [..., 3]`` under ``task`` (a name or a :class:`WalkerTask`)."""
    task = get_task(task) if isinstance(task, str) else task
    return task.reward(features)


def check_task_list(names: Iterable[str], key: str) -> tuple[str, ...]:
    """Validate a study's task list: known names, no repeats, at least one."""
    names = tuple(names)
    if not names:
        raise ConfigError(f"{key}: expected at least one task, got an empty list")
    for i, name in enumerate(names):
        get_task(name, f"{key}[{i}]")
    if len(set(names)) != len(names):
        raise ConfigError(f"{key}: tasks must not repeat, got {list(names)}")
    return names
