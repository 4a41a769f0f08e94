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

dm_control's stand does not forbid moving: a walker that walks upright earns the full stand reward,
and the walk teacher beats the stand teacher at standing (thesis Table 6.3, 6.4.5), so stand and
walk cannot show negative transfer. The thesis recommends a movement penalty (7.3); ``stand_still``
is that task (not in dm_control)::

    stand_still = stand * tol(x; bounds=(0, 0), margin=m, form, value_at_margin=0.1)

a factor 1 at rest that decays with the horizontal speed |x| to 0.1 at |x| = m (``form`` gaussian:
``exp(-(|x|/m)^2 ln 10)``; linear: ``max(0, 1 - 0.9 |x|/m)``). Its registry entry sets m = 0.5 m/s
and the gaussian form: a walker at walk's target speed 1 m/s keeps 1e-4 of its stand reward, one
swaying at 0.1 m/s 0.91. Form and margin are fields of the task's :class:`Stillness`, not
params.yaml keys: they define the reward, so a different value is a different task (a new registry
entry with its own name), never the same name silently relabelled differently.
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


STILLNESS_FORMS = ("gaussian", "linear")
_STILL_VALUE_AT_MARGIN = 0.1


@dataclass(frozen=True)
class Stillness:
    """The movement penalty of a stand-still task: ``tol(x; bounds=(0, 0), margin, form, 0.1)``,
    dm_control's ``rewards.tolerance`` of the horizontal velocity ``x`` (1 at rest, 0.1 at
    ``|x| = margin``)."""

    margin: float  # m/s: the horizontal speed at which the factor has decayed to 0.1
    form: str = "gaussian"  # gaussian | linear (dm_control's sigmoid names)

    def __post_init__(self) -> None:
        if self.form not in STILLNESS_FORMS:
            raise ValueError(f"stillness form: expected one of {STILLNESS_FORMS}, got {self.form!r}")
        if not self.margin > 0:
            raise ValueError(f"stillness margin: expected a positive speed (m/s), got {self.margin!r}")

    def factor(self, velocity: np.ndarray) -> np.ndarray:
        """The factor of each horizontal velocity (float64)."""
        d = np.abs(np.asarray(velocity, dtype=np.float64)) / self.margin
        if self.form == "gaussian":
            return np.exp(-0.5 * (d * np.sqrt(-2.0 * np.log(_STILL_VALUE_AT_MARGIN))) ** 2)
        scaled = d * (1.0 - _STILL_VALUE_AT_MARGIN)
        return np.where(scaled < 1.0, 1.0 - scaled, 0.0)


@dataclass(frozen=True)
class WalkerTask:
    """A walker reward function.

    Attributes:
        name: the task's name in the study (``stand``, ``walk``, ``run``).
        move_speed: target horizontal speed ``v`` in m/s; 0 means the pure stand reward.
        dm_control_task: the dm_control suite task with this reward (used to build envs and to
            check rewards against dm_control's own ``get_reward``); for a task with a ``stillness``
            penalty, the task whose reward the penalty multiplies.
        expert_return: the published expert return of this task (UTDS's ``task.json``, the
            reference of D4RL-style normalised scores ``100 (R - R_random) / (R_expert - R_random)``;
            R_random is measured by the collect stage). stand_still has none published: it takes
            stand's (the factor is at most 1; a walker standing perfectly still scores its stand return).
        stillness: the movement penalty multiplying the reward (None: dm_control's reward as is).
    """

    name: str
    move_speed: float
    dm_control_task: str
    expert_return: float
    stillness: Stillness | None = None

    def __post_init__(self) -> None:
        if self.stillness is not None and self.move_speed != 0:
            raise ValueError(f"task {self.name!r}: a stillness penalty needs move_speed 0, got {self.move_speed}")

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
            return stand_reward if self.stillness is None else stand_reward * self.stillness.factor(velocity)
        move_reward = _lower_bound_linear(velocity, self.move_speed, self.move_speed / 2)
        return stand_reward * (5 * move_reward + 1) / 6


TASKS: dict[str, WalkerTask] = {
    task.name: task
    for task in (
        WalkerTask("stand", 0.0, "stand", expert_return=986.8),
        WalkerTask("walk", 1.0, "walk", expert_return=980.0),
        WalkerTask("run", 8.0, "run", expert_return=842.6),
        WalkerTask("stand_still", 0.0, "stand", expert_return=986.8, stillness=Stillness(margin=0.5)),
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


def substitute_base(task: str) -> str:
    """The study task whose datasets a substitute task learns from: the task its reward derives from
    (its registry entry's dm_control task: stand_still -> stand)."""
    return get_task(task, "substitute").dm_control_task


def substitute_tasks(tasks: tuple[str, ...], substitute: str) -> tuple[str, ...]:
    """The task set of a substitute: ``tasks`` with its base task replaced by it, in the same order."""
    base = substitute_base(substitute)
    return tuple(substitute if task == base else task for task in tasks)


def data_tasks(tasks: tuple[str, ...], substitute: str = "") -> tuple[str, ...]:
    """Per task of a set, the task whose datasets are its own: itself, but a substitute's base task."""
    return tuple(substitute_base(task) if substitute and task == substitute else task for task in tasks)
