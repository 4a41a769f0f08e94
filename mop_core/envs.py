"""Seeded DeepMind Control walker environments with flat observations and reward features.

Facts (dm_control 1.0.50, ``suite/walker.py``): the observation is orientations (14) + height (1)
+ velocity (9) = 24 floats; the action is 6 torques in [-1, 1]; the physics state qpos+qvel has
18 float64 entries; one control step is 0.025 s (10 physics steps). dm_control's legacy step runs
``mj_step1`` after stepping, so positions, orientations and sensors are in sync with the state the
reward is computed on; :func:`read_reward_features` reads the three quantities that reward needs.

The wrappers own the episode length (dm_control's time limit is switched off) so episodes have
exactly ``episode_length`` steps; walker never terminates, an episode end is a time-out.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mop_core.tasks import WalkerTask, get_task

OBS_DIM = 24
ACT_DIM = 6
PHYSICS_DIM = 18
EPISODE_LENGTH = 1000


def _suite():
    with warnings.catch_warnings():  # glfw warns about a missing DISPLAY; we never render
        warnings.simplefilter("ignore")
        from dm_control import suite
    return suite


def flatten_observation(observation: dict) -> np.ndarray:
    """dm_control's observation dict as 24 float64s: orientations, height, velocity."""
    return np.concatenate([
        np.asarray(observation["orientations"], dtype=np.float64).ravel(),
        np.asarray(observation["height"], dtype=np.float64).ravel(),
        np.asarray(observation["velocity"], dtype=np.float64).ravel(),
    ])


def read_reward_features(physics) -> np.ndarray:
    """(torso height, torso upright, torso-subtree horizontal velocity) of a walker physics."""
    return np.array([physics.torso_height(), physics.torso_upright(), physics.horizontal_velocity()],
                    dtype=np.float64)


@dataclass
class Step:
    """The result of one control step: everything a dataset row needs about the next state."""

    observation: np.ndarray  # [24] float64
    reward: float  # dm_control's own task reward
    timeout: bool  # the episode ended by its time limit
    physics: np.ndarray  # [18] float64 qpos+qvel after the step
    features: np.ndarray  # [3] float64 reward features after the step


class WalkerEnv:
    """One seeded walker environment for ``task``; ``task_kwargs={"random": seed}``."""

    def __init__(self, task: str | WalkerTask, seed: int, episode_length: int = EPISODE_LENGTH):
        if episode_length <= 0:
            raise ValueError(f"episode_length: expected a positive integer, got {episode_length!r}")
        self.task = get_task(task) if isinstance(task, str) else task
        self.episode_length = episode_length
        self._env = _suite().load("walker", self.task.dm_control_task,
                                  task_kwargs={"random": int(seed), "time_limit": float("inf")})
        self._t = 0

    @property
    def physics(self):
        return self._env.physics

    @property
    def dm_env(self):
        """The wrapped dm_control environment (its ``task.get_reward`` is the reference reward)."""
        return self._env

    def reset(self) -> np.ndarray:
        self._t = 0
        return flatten_observation(self._env.reset().observation)

    def random_state(self) -> tuple:
        """The state of the task's random generator (what the next ``reset`` draws the start state from)."""
        return self._env.task.random.get_state()

    def set_random_state(self, state: tuple) -> None:
        """Continue the task's random stream from ``state``: a reset after it starts the episode an
        uninterrupted run would have started (a resumed run restarts at an episode boundary)."""
        self._env.task.random.set_state(state)

    def step(self, action: np.ndarray) -> Step:
        timestep = self._env.step(np.asarray(action, dtype=np.float64))
        self._t += 1
        return Step(
            observation=flatten_observation(timestep.observation),
            reward=float(timestep.reward),
            timeout=self._t >= self.episode_length,
            physics=self._env.physics.get_state().copy(),
            features=read_reward_features(self._env.physics),
        )


@dataclass
class VectorStep:
    """:class:`Step` for a batch of environments (leading dimension K)."""

    observation: np.ndarray  # [K, 24]
    reward: np.ndarray  # [K]
    timeout: np.ndarray  # [K] bool
    physics: np.ndarray  # [K, 18]
    features: np.ndarray  # [K, 3]


class VectorWalkerEnv:
    """K walker environments stepped together so a policy acts on all K states in one batch.

    All members share the episode length and the walker never terminates early, so they reset
    together; member k is seeded with ``seeds[k]``.
    """

    def __init__(self, task: str | WalkerTask, seeds: Sequence[int], episode_length: int = EPISODE_LENGTH):
        if len(seeds) == 0:
            raise ValueError("seeds: expected at least one seed")
        self.envs = [WalkerEnv(task, seed, episode_length) for seed in seeds]
        self.episode_length = episode_length

    @property
    def num_envs(self) -> int:
        return len(self.envs)

    def reset(self) -> np.ndarray:
        return np.stack([env.reset() for env in self.envs])

    def step(self, actions: np.ndarray) -> VectorStep:
        steps = [env.step(a) for env, a in zip(self.envs, actions)]
        return VectorStep(
            observation=np.stack([s.observation for s in steps]),
            reward=np.array([s.reward for s in steps]),
            timeout=np.array([s.timeout for s in steps]),
            physics=np.stack([s.physics for s in steps]),
            features=np.stack([s.features for s in steps]),
        )


def physics_replay_rewards(physics_states: np.ndarray, tasks: Sequence[str | WalkerTask]) -> dict[str, np.ndarray]:
    """Rewards by physics replay: set each state, run MuJoCo's forward pass, ask dm_control.

    This is the slow, reference path of relabelling (~10k transitions/s): for every row of
    ``physics_states [N, 18]`` it calls each task's own ``get_reward`` on the restored physics.
    """
    tasks = [get_task(t) if isinstance(t, str) else t for t in tasks]
    env = WalkerEnv(tasks[0], seed=0)
    physics = env.physics
    dm_tasks = {task.name: WalkerEnv(task, seed=0).dm_env.task for task in tasks}
    out = {task.name: np.empty(len(physics_states), dtype=np.float64) for task in tasks}
    for i, state in enumerate(np.asarray(physics_states, dtype=np.float64)):
        physics.set_state(state)
        physics.forward()
        for name, dm_task in dm_tasks.items():
            out[name][i] = dm_task.get_reward(physics)
    return out
