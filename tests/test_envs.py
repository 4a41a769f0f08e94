"""mop_core/walker/envs.py: seeded walker environments with flat observations, a time-out at exactly
``episode_length`` steps, and K of them stepped together as one batch."""

from __future__ import annotations

import numpy as np
import pytest

from mop_core.config import ConfigError
from mop_core.learning.runtime import set_step_threads
from mop_core.walker.envs import (
    ACT_DIM,
    OBS_DIM,
    PHYSICS_DIM,
    PhysicsError,
    VectorWalkerEnv,
    WalkerEnv,
    borrow_env,
    flatten_observation,
    physics_replay_rewards,
)
from mop_core.walker.tasks import get_task


def _actions(steps: int, k: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, size=(steps, k, ACT_DIM))


def test_reset_is_seeded_and_observations_are_24_float64s():
    first = WalkerEnv("walk", seed=3, episode_length=20).reset()
    assert first.shape == (OBS_DIM,) == (24,) and first.dtype == np.float64
    np.testing.assert_array_equal(WalkerEnv("walk", seed=3, episode_length=20).reset(), first)
    assert not np.array_equal(WalkerEnv("walk", seed=4, episode_length=20).reset(), first)
    env = WalkerEnv("walk", seed=3, episode_length=20)
    env.reset()
    second = env.reset()  # the seed fixes the sequence of episodes, not every episode's start
    assert not np.array_equal(second, first)


def test_the_observation_is_orientations_height_velocity():
    env = WalkerEnv("stand", seed=0, episode_length=20)
    env.reset()
    observation = env.dm_env.step(np.zeros(ACT_DIM)).observation
    flat = flatten_observation(observation)
    np.testing.assert_array_equal(flat[:14], observation["orientations"])
    assert flat[14] == observation["height"]
    np.testing.assert_array_equal(flat[15:], observation["velocity"])


def test_a_step_reports_the_next_state_reward_and_features():
    env = WalkerEnv("walk", seed=1, episode_length=20)
    env.reset()
    for action in _actions(3, 1)[:, 0]:
        step = env.step(action)
    assert step.observation.shape == (24,) and step.observation.dtype == np.float64
    assert step.physics.shape == (PHYSICS_DIM,) and step.physics.dtype == np.float64
    assert step.features.shape == (3,) and step.features.dtype == np.float64
    np.testing.assert_array_equal(step.physics, env.physics.get_state())
    assert isinstance(step.reward, float)
    assert step.reward == pytest.approx(float(get_task("walk").reward(step.features)), abs=1e-9)
    assert step.reward == pytest.approx(env.dm_env.task.get_reward(env.physics), abs=1e-12)


def test_an_episode_times_out_at_episode_length_and_reset_restarts_the_clock():
    env = WalkerEnv("stand", seed=0, episode_length=5)
    env.reset()
    timeouts = [env.step(np.zeros(ACT_DIM)).timeout for _ in range(5)]
    assert timeouts == [False] * 4 + [True]
    env.reset()
    assert [env.step(np.zeros(ACT_DIM)).timeout for _ in range(5)] == [False] * 4 + [True]


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match=r"^episode_length: expected a positive integer, got 0$"):
        WalkerEnv("stand", seed=0, episode_length=0)
    with pytest.raises(ConfigError, match=r"^task: unknown task 'hop'"):
        WalkerEnv("hop", seed=0)
    with pytest.raises(ValueError, match=r"^seeds: expected at least one seed$"):
        VectorWalkerEnv("stand", [], episode_length=5)


def test_a_vector_env_equals_its_members_stepped_one_by_one():
    seeds, length = [5, 6, 7], 6
    vector = VectorWalkerEnv("walk", seeds, episode_length=length)
    singles = [WalkerEnv("walk", seed, episode_length=length) for seed in seeds]
    assert vector.num_envs == 3 and vector.episode_length == length
    obs = vector.reset()
    assert obs.shape == (3, 24) and obs.dtype == np.float64
    np.testing.assert_array_equal(obs, np.stack([env.reset() for env in singles]))
    for t, actions in enumerate(_actions(length, 3, seed=1)):
        batch = vector.step(actions)
        steps = [env.step(a) for env, a in zip(singles, actions)]
        assert batch.observation.shape == (3, 24) and batch.physics.shape == (3, 18)
        assert batch.features.shape == (3, 3) and batch.reward.shape == (3,) and batch.timeout.dtype == bool
        np.testing.assert_array_equal(batch.observation, np.stack([s.observation for s in steps]))
        np.testing.assert_allclose(batch.reward, [s.reward for s in steps], rtol=1e-15, atol=1e-16)
        np.testing.assert_array_equal(batch.physics, np.stack([s.physics for s in steps]))
        np.testing.assert_array_equal(batch.features, np.stack([s.features for s in steps]))
        np.testing.assert_array_equal(batch.timeout, [t == length - 1] * 3)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("task", ["stand", "walk", "run"])
def test_the_raw_mujoco_step_equals_dm_controls_step_bit_for_bit_over_whole_episodes(task, threads):
    """The vector env steps MuJoCo directly (legacy-step order, sensors in sync after mj_step1) and
    computes the reward by the task's formula; dm_control's own step is the reference: every
    observation, physics state and feature bit for bit equal, every reward to the last place, over two
    full 1000-step episodes (the second after a reset), whatever the number of stepping threads."""
    seeds = [11, 12, 13]
    set_step_threads(threads)
    try:
        vector = VectorWalkerEnv(task, seeds, episode_length=1000)
        singles = [WalkerEnv(task, seed, episode_length=1000) for seed in seeds]
        for episode in range(2):
            np.testing.assert_array_equal(vector.reset(), np.stack([env.reset() for env in singles]))
            for actions in _actions(1000, 3, seed=episode):
                batch = vector.step(actions)
                steps = [env.step(a) for env, a in zip(singles, actions)]
                for key in ("observation", "physics", "features", "timeout"):
                    np.testing.assert_array_equal(getattr(batch, key), np.stack([getattr(s, key) for s in steps]),
                                                  err_msg=key)
                # the vectorised reward formula vs dm_control's tolerance(): equal to a unit in the last place
                np.testing.assert_allclose(batch.reward, [s.reward for s in steps], rtol=1e-15, atol=1e-16)
    finally:
        set_step_threads(1)


def test_an_invalid_physics_state_raises_as_dm_control_does():
    from dm_control.rl.control import PhysicsError as DmPhysicsError

    vector, single = VectorWalkerEnv("walk", [0]), WalkerEnv("walk", 0)
    vector.reset()
    single.reset()
    for env in (vector.envs[0], single):
        env.physics.data.qvel[:] = 1e30  # diverged: MuJoCo warns (bad qacc) and resets the data
    with pytest.raises(PhysicsError, match="invalid physics state"):
        vector.step(np.zeros((1, ACT_DIM)))
    with pytest.raises(DmPhysicsError):
        single.step(np.zeros(ACT_DIM))


def test_physics_replay_gives_each_tasks_reward_of_the_stored_states():
    env = WalkerEnv("walk", seed=2, episode_length=10)
    env.reset()
    steps = [env.step(a) for a in _actions(4, 1, seed=2)[:, 0]]
    states = np.stack([s.physics for s in steps])
    replayed = physics_replay_rewards(states, ["walk", "stand"])
    assert set(replayed) == {"walk", "stand"} and replayed["walk"].shape == (4,)
    np.testing.assert_allclose(replayed["walk"], [s.reward for s in steps], atol=1e-9)
    features = np.stack([s.features for s in steps])
    np.testing.assert_allclose(replayed["stand"], get_task("stand").reward(features), atol=1e-9)


def test_a_reused_walker_starts_the_episode_a_fresh_one_of_its_seed_starts():
    """VectorWalkerEnv borrows freed walkers (building one parses its XML: ~0.12 s) and re-seeds them:
    every episode is the one a fresh env of that seed gives, bit for bit, whatever ran before."""
    actions = _actions(40, 2)

    def episode(seeds: list[int]) -> np.ndarray:
        with VectorWalkerEnv("walk", seeds, 40) as env:
            frames = [env.reset()]
            frames += [env.step(a).observation for a in actions]
        return np.stack(frames)

    fresh = episode([3, 4])
    other = episode([5, 6])  # reuses the two walkers
    assert not np.array_equal(fresh, other)
    np.testing.assert_array_equal(episode([3, 4]), fresh)
    borrowed = borrow_env("walk", 4, 40)
    alone = WalkerEnv("walk", 4, 40)
    assert borrowed is not alone
    np.testing.assert_array_equal(borrowed.reset(), alone.reset())


@pytest.mark.parametrize("task", ["stand", "walk", "run"])
def test_a_walker_built_from_the_template_is_the_suites_own_env(task):
    """WalkerEnv builds dm_control's walker from a per-task template (the compiled model shared, data
    and task its own): episodes, rewards and physics equal an env ``suite.load`` builds, bit for bit."""
    from mop_core.walker.envs import _suite

    actions = _actions(60, 1, 11)[:, 0]
    first, second = WalkerEnv(task, 7, 60), WalkerEnv(task, 8, 60)
    assert first.physics.model.ptr is second.physics.model.ptr  # one compiled model
    assert first.physics.data.ptr is not second.physics.data.ptr
    for seed, env in ((7, first), (8, second)):
        suite_env = _suite().load("walker", task, task_kwargs={"random": seed, "time_limit": float("inf")})
        reference = suite_env.reset()
        np.testing.assert_array_equal(env.reset(), flatten_observation(reference.observation))
        for action in actions:
            step, timestep = env.step(action), suite_env.step(action)
            assert step.reward == timestep.reward
            np.testing.assert_array_equal(step.physics, suite_env.physics.get_state())
