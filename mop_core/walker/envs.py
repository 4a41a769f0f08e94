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

import copy
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Sequence

import mujoco
import numpy as np

from mop_core.learning.runtime import step_threads
from mop_core.walker.tasks import WalkerTask, get_task

OBS_DIM = 24
ACT_DIM = 6
PHYSICS_DIM = 18
EPISODE_LENGTH = 1000
_ORIENTATION_COLUMNS = [0, 2]  # the xx and xz entries of each body's row-major xmat: walker.orientations()


class PhysicsError(RuntimeError):
    """MuJoCo reported an invalid state during a step (dm_control raises its own PhysicsError then)."""


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
    reward: float  # dm_control's own task reward (times dm_control's tolerance of the speed: stand_still)
    timeout: bool  # the episode ended by its time limit
    physics: np.ndarray  # [18] float64 qpos+qvel after the step
    features: np.ndarray  # [3] float64 reward features after the step


_TEMPLATES: dict[str, Any] = {}  # dm_control walker task -> the suite's env of it, never stepped


def _dm_walker(dm_task: str, seed: int):
    """The dm_control env ``suite.load("walker", dm_task, task_kwargs={"random": seed, "time_limit":
    inf})`` builds, without parsing and compiling the walker's XML model again (~0.08 s, most of a
    short stage's rollout set-up): the suite builds the first env of each task, a template never
    stepped; every env after it shares the template's compiled ``MjModel`` (read-only while MuJoCo
    steps, so safe across step threads) with its own ``MjData`` (``Physics.copy(share_model=True)``)
    and a copy of its task seeded with ``seed`` (``RandomState.seed(seed)`` is ``RandomState(seed)``'s
    state), in an ``Environment`` made as the suite makes it (tested equal to a suite-built env)."""
    template = _TEMPLATES.get(dm_task)
    if template is None:
        template = _TEMPLATES[dm_task] = _suite().load("walker", dm_task,
                                                       task_kwargs={"random": 0, "time_limit": float("inf")})
    from dm_control.rl import control

    task = copy.deepcopy(template.task)
    task.random.seed(seed)
    return control.Environment(template.physics.copy(share_model=True), task, time_limit=float("inf"),
                               control_timestep=template.control_timestep())


class WalkerEnv:
    """One seeded walker environment for ``task``; ``task_kwargs={"random": seed}``."""

    def __init__(self, task: str | WalkerTask, seed: int, episode_length: int = EPISODE_LENGTH):
        if episode_length <= 0:
            raise ValueError(f"episode_length: expected a positive integer, got {episode_length!r}")
        self.task = get_task(task) if isinstance(task, str) else task
        self.episode_length = episode_length
        self._env = _dm_walker(self.task.dm_control_task, int(seed))
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

    def reseed(self, seed: int) -> None:
        """Make the next ``reset`` start the episode a fresh ``WalkerEnv(task, seed)`` starts: the
        task's generator is re-seeded (``RandomState.seed(seed)`` is ``RandomState(seed)``'s state)
        and a reset rebuilds every other piece of state (``mj_resetData``, dm_control's step count)."""
        self._env.task.random.seed(int(seed))
        self._t = 0

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
            reward=direct_reward(self.task, float(timestep.reward), self._env.physics),
            timeout=self._t >= self.episode_length,
            physics=self._env.physics.get_state().copy(),
            features=read_reward_features(self._env.physics),
        )


_FREE_ENVS: dict[tuple[WalkerTask, int], list[WalkerEnv]] = {}
MAX_FREE_ENVS = 64  # per (task, episode length): what one process keeps for reuse (~1 MB each)


def borrow_env(task: str | WalkerTask, seed: int, episode_length: int = EPISODE_LENGTH) -> WalkerEnv:
    """A walker env of ``task`` that starts as ``WalkerEnv(task, seed, episode_length)`` does: a freed
    one re-seeded (:meth:`WalkerEnv.reseed`) when there is one, else a new one. Building a walker
    parses its XML model (~0.12 s, more than 100 control steps of a rollout), which evaluating
    every few thousand updates did for each episode; :func:`release_envs` gives envs back."""
    task = get_task(task) if isinstance(task, str) else task
    free = _FREE_ENVS.get((task, episode_length))
    if free:
        env = free.pop()
        env.reseed(seed)
        return env
    return WalkerEnv(task, seed, episode_length)


def release_envs(envs: Sequence[WalkerEnv]) -> None:
    """Keep ``envs`` (no longer used by their borrower) for :func:`borrow_env`."""
    for env in envs:
        free = _FREE_ENVS.setdefault((env.task, env.episode_length), [])
        if len(free) < MAX_FREE_ENVS and all(other is not env for other in free):
            free.append(env)


@dataclass
class VectorStep:
    """:class:`Step` for a batch of environments (leading dimension K)."""

    observation: np.ndarray  # [K, 24]
    reward: np.ndarray  # [K]
    timeout: np.ndarray  # [K] bool
    physics: np.ndarray  # [K, 18]
    features: np.ndarray  # [K, 3]


_POOL: ThreadPoolExecutor | None = None  # MuJoCo releases the GIL while it steps
_POOL_THREADS = 0


def _pool() -> ThreadPoolExecutor:
    """The threads a VectorWalkerEnv steps its members with: :func:`mop_core.learning.runtime.step_threads` of them."""
    global _POOL, _POOL_THREADS
    if _POOL is not None and _POOL_THREADS != step_threads():
        _POOL.shutdown()
        _POOL = None
    if _POOL is None:
        _POOL, _POOL_THREADS = ThreadPoolExecutor(step_threads(), thread_name_prefix="walker-step"), step_threads()
    return _POOL


@dataclass
class _Member:
    """One walker's raw MuJoCo model and data, with views of the arrays a step reads."""

    model: mujoco.MjModel
    data: mujoco.MjData

    def __post_init__(self) -> None:
        d = self.data
        self.ctrl, self.xmat, self.xpos, self.qpos, self.qvel = d.ctrl, d.xmat, d.xpos, d.qpos, d.qvel
        self.sensordata, self.warnings = d.sensordata, d.warning.number


class VectorWalkerEnv:
    """K walker environments stepped together so a policy acts on all K states in one batch.

    All members share the episode length and the walker never terminates early, so they reset
    together; member k is seeded with ``seeds[k]``. Resets go through dm_control (its initial-state
    randomisation, exactly); steps go straight to MuJoCo on each member's own ``MjData``, doing what
    dm_control's legacy step does and nothing else: ``ctrl <- action``, ``mj_step2``, ``mj_step`` x
    (n_sub_steps - 1), ``mj_step1`` (so positions, orientations and sensors are in sync with the new
    state: the "legacy-step sensor timing"), and a :class:`PhysicsError` if MuJoCo raised a new
    warning (as dm_control's ``check_invalid_state``). The observation and reward features are read
    from the arrays dm_control reads (``xmat``, ``xpos``, ``qvel``, the torso subtree velocity
    sensor) and the reward is the task's vectorised formula. Observations, states and features are bit
    for bit :class:`WalkerEnv`'s dm_control step's over whole episodes, rewards equal to the last
    place (the formula vs dm_control's ``tolerance``; tested), with dm_control's per-step Python (named indexing,
    the observation dict, the reward's tolerance calls) skipped, and the members stepped in
    ``mop_core.learning.runtime.step_threads()`` threads (benchmarks/bench_collect.py measures both).
    """

    def __init__(self, task: str | WalkerTask, seeds: Sequence[int], episode_length: int = EPISODE_LENGTH):
        if len(seeds) == 0:
            raise ValueError("seeds: expected at least one seed")
        self.envs = [borrow_env(task, seed, episode_length) for seed in seeds]
        self.task, self.episode_length = self.envs[0].task, episode_length
        self._members = [_Member(env.physics.model.ptr, env.physics.data.ptr) for env in self.envs]
        model = self._members[0].model
        self._torso = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "torso")
        self._velocity = int(model.sensor_adr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR,
                                                                "torso_subtreelinvel")])
        self._sub_steps = self.envs[0].dm_env._n_sub_steps
        self._rk4 = model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
        self._t = 0

    @property
    def num_envs(self) -> int:
        return len(self.envs)

    def close(self) -> None:
        """Give the walkers back for reuse (:func:`release_envs`); the env is not used after."""
        release_envs(self.envs)
        self.envs, self._members = [], []

    def __enter__(self) -> "VectorWalkerEnv":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reset(self) -> np.ndarray:
        self._t = 0
        return np.stack([env.reset() for env in self.envs])

    def _advance(self, member: _Member) -> None:
        """dm_control's ``Physics.step(n_sub_steps)`` with ``legacy_step`` (engine.py), on raw MuJoCo."""
        model, data = member.model, member.data
        warned = int(member.warnings.sum())
        if self._rk4:
            mujoco.mj_step(model, data, self._sub_steps)
        else:  # mj_step1 already ran for this state at the end of the previous step (or the reset)
            mujoco.mj_step2(model, data)
            if self._sub_steps > 1:
                mujoco.mj_step(model, data, self._sub_steps - 1)
        mujoco.mj_step1(model, data)
        if int(member.warnings.sum()) > warned:
            raise PhysicsError(f"walker {self.task.name}: MuJoCo warnings {member.warnings.tolist()} "
                               "(an invalid physics state)")

    def _step_members(self, members: range, actions: np.ndarray, observation: np.ndarray, physics: np.ndarray,
                      features: np.ndarray) -> None:
        torso, velocity = self._torso, self._velocity
        for i in members:
            m = self._members[i]
            np.copyto(m.ctrl, actions[i])
            self._advance(m)
            observation[i, :14] = m.xmat[1:, 0:3:2].ravel()  # walker.orientations(): each body's xx, xz
            height = m.xpos[torso, 2]
            observation[i, 14] = height  # torso_height()
            observation[i, 15:] = m.qvel  # velocity()
            physics[i, :9], physics[i, 9:] = m.qpos, m.qvel  # Physics.get_state(): qpos, qvel (no act)
            features[i] = (height, m.xmat[torso, 8], m.sensordata[velocity])

    def step(self, actions: np.ndarray) -> VectorStep:
        actions = np.asarray(actions, dtype=np.float64)
        k = len(self.envs)
        observation, physics, features = np.empty((k, OBS_DIM)), np.empty((k, PHYSICS_DIM)), np.empty((k, 3))
        shares = min(step_threads(), k)
        if shares == 1:
            self._step_members(range(k), actions, observation, physics, features)
        else:
            bounds = np.linspace(0, k, shares + 1).astype(int)
            list(_pool().map(lambda lo, hi: self._step_members(range(lo, hi), actions, observation, physics,
                                                               features), bounds[:-1], bounds[1:]))
        self._t += 1
        return VectorStep(observation=observation, reward=self.task.reward(features),
                          timeout=np.full(k, self._t >= self.episode_length), physics=physics, features=features)


def direct_reward(task: WalkerTask, dm_reward: float, physics) -> float:
    """The reward of ``task`` computed directly on ``physics``: ``dm_reward`` (dm_control's
    ``get_reward`` of ``task.dm_control_task``) times, for a task with a stillness penalty,
    dm_control's own ``rewards.tolerance`` of the horizontal velocity (the reference the vectorised
    :meth:`WalkerTask.reward` is tested against)."""
    if task.stillness is None:
        return dm_reward
    from dm_control.utils import rewards

    factor = rewards.tolerance(physics.horizontal_velocity(), bounds=(0.0, 0.0), margin=task.stillness.margin,
                               sigmoid=task.stillness.form, value_at_margin=0.1)
    return dm_reward * float(factor)


def physics_replay_rewards(physics_states: np.ndarray, tasks: Sequence[str | WalkerTask]) -> dict[str, np.ndarray]:
    """Rewards by physics replay: set each state, run MuJoCo's forward pass, ask dm_control.

    This is the slow, reference path of relabelling (~10k transitions/s): for every row of
    ``physics_states [N, 18]`` it calls each task's own ``get_reward`` on the restored physics.
    """
    tasks = [get_task(t) if isinstance(t, str) else t for t in tasks]
    env = WalkerEnv(tasks[0], seed=0)
    physics = env.physics
    dm_tasks = {task.name: WalkerEnv(task, seed=0).dm_env.task for task in tasks}
    by_name = {task.name: task for task in tasks}
    out = {task.name: np.empty(len(physics_states), dtype=np.float64) for task in tasks}
    for i, state in enumerate(np.asarray(physics_states, dtype=np.float64)):
        physics.set_state(state)
        physics.forward()
        for name, dm_task in dm_tasks.items():
            out[name][i] = direct_reward(by_name[name], dm_task.get_reward(physics), physics)
    return out
