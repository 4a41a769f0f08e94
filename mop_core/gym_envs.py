"""Gymnasium environments of the study's walker tasks, registered as ``mop/walker-<task>-v0``.

What Minari, d3rlpy and every Gymnasium-based offline-RL library evaluate through: an env id. Each
env is the study's own :class:`~mop_core.walker.envs.WalkerEnv` (dm_control's walker, the task's reward
computed as the study computes it) behind the Gymnasium API, so a policy trained on a mop dataset
sees in it exactly what the dataset holds:

- observation: the datasets' 24 floats in their order (orientations 14, torso height 1, velocity 9;
  :func:`mop_core.walker.envs.flatten_observation`), float32 as the datasets store them; shimmy's
  ``dm_control/walker-*`` orders them (height, orientations, velocity) instead;
- action: 6 torques in [-1, 1] (float32 space; passed to MuJoCo as float64, as the study does);
- reward: the task's reward of the step (``stand_still``: stand's times the stillness factor);
- the episode ends by truncation after ``episode_length`` steps (1000; walker never terminates);
- ``reset(seed=s)`` starts the episode ``WalkerEnv(task, s)`` starts (the study's evaluation
  episodes are seeds); ``reset()`` continues the env's own random stream;
- ``info``: the reward features after the step (``torso_height``, ``torso_upright``,
  ``horizontal_velocity``: the datasets' ``infos/*``, from which any task's reward is computed) and
  ``physics``, qpos+qvel after the step (the datasets' ``infos/next_physics``).

Importing this module registers every task of the registry (:data:`mop_core.walker.tasks.TASKS`, so a task
added there gets an env too) with a string entry point, so an env spec is serialisable (Minari
stores it and ``recover_environment`` rebuilds the env). Without the import, Gymnasium's
``module:id`` form imports it: ``gymnasium.make("mop_core.gym_envs:mop/walker-walk-v0")``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from mop_core.walker.envs import ACT_DIM, EPISODE_LENGTH, OBS_DIM, WalkerEnv
from mop_core.walker.tasks import REWARD_FEATURES, TASKS, get_task

NAMESPACE = "mop"
ENTRY_POINT = "mop_core.gym_envs:WalkerGymEnv"
SEED_LIMIT = 2**31 - 1  # dm_control seeds a numpy RandomState: below 2**32; Gymnasium's draws stay below this


def env_id(task: str) -> str:
    """The Gymnasium id of ``task``'s env: ``mop/walker-<task>-v0``."""
    return f"{NAMESPACE}/walker-{get_task(task).name}-v0"


class WalkerGymEnv(gym.Env):
    """The study's walker env of ``task`` behind the Gymnasium API (module docstring)."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, task: str = "walk", episode_length: int = EPISODE_LENGTH):
        if not isinstance(episode_length, int) or isinstance(episode_length, bool) or episode_length < 1:
            raise ValueError(f"episode_length: expected a positive integer, got {episode_length!r}")
        self.task = get_task(task)
        self.episode_length = episode_length
        self.observation_space = spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (ACT_DIM,), np.float32)
        self._walker: WalkerEnv | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            if not 0 <= seed < 2**32:
                raise ValueError(f"seed: expected an integer in [0, 2**32), got {seed!r}")
            if self._walker is None:
                self._walker = WalkerEnv(self.task, seed, self.episode_length)
            else:
                self._walker.reseed(seed)
        elif self._walker is None:  # no seed yet: one drawn from the env's own (entropy-seeded) generator
            self._walker = WalkerEnv(self.task, int(self.np_random.integers(SEED_LIMIT)), self.episode_length)
        return self._walker.reset().astype(np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._walker is None:
            raise gym.error.ResetNeeded(f"{env_id(self.task.name)}: call reset() before step()")
        step = self._walker.step(np.asarray(action, dtype=np.float64))
        info: dict[str, Any] = {name: float(value) for name, value in zip(REWARD_FEATURES, step.features)}
        info["physics"] = step.physics
        return step.observation.astype(np.float32), float(step.reward), False, bool(step.timeout), info


def register_envs() -> list[str]:
    """Register every task of the registry (idempotent); returns their ids."""
    ids = []
    for name in TASKS:
        ident = env_id(name)
        if ident not in gym.registry:
            gym.register(id=ident, entry_point=ENTRY_POINT, kwargs={"task": name},
                         max_episode_steps=EPISODE_LENGTH)
        ids.append(ident)
    return ids


ENV_IDS = register_envs()
