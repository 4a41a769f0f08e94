"""Rewards: the vectorised formula equals dm_control's own reward for every task."""

from __future__ import annotations

import numpy as np
import pytest

from mop_core.config import ConfigError
from mop_core.walker.envs import PHYSICS_DIM, WalkerEnv, physics_replay_rewards
from mop_core.walker.tasks import TASKS, Stillness, WalkerTask, check_task_list, get_task, reward

TRANSITIONS_PER_POLICY = 5000  # x2 policies = 10,000 per task


def _gait(rng: np.random.Generator):
    """A structured open-loop policy (sinusoidal gait) that moves and falls in varied ways."""
    freq, phase, amp = rng.uniform(0.5, 3.0, 6), rng.uniform(0, 2 * np.pi, 6), rng.uniform(0.3, 1.0, 6)
    t = [0]

    def act(_obs):
        t[0] += 1
        return np.clip(amp * np.sin(2 * np.pi * freq * t[0] * 0.025 + phase), -1, 1)

    return act


def _rollout(task: str, policy, steps: int, seed: int):
    env = WalkerEnv(task, seed, episode_length=500)
    obs, rewards, features, physics = env.reset(), [], [], []
    for _ in range(steps):
        step = env.step(policy(obs))
        rewards.append(step.reward), features.append(step.features), physics.append(step.physics)
        obs = env.reset() if step.timeout else step.observation
    return np.array(rewards), np.array(features), np.array(physics)


@pytest.mark.parametrize("task", list(TASKS))
def test_vectorised_reward_equals_dm_control(task):
    rng = np.random.default_rng(0)
    random_policy = lambda _obs: rng.uniform(-1, 1, 6)  # noqa: E731
    r1, f1, _ = _rollout(task, random_policy, TRANSITIONS_PER_POLICY, seed=1)
    r2, f2, _ = _rollout(task, _gait(rng), TRANSITIONS_PER_POLICY, seed=2)
    rewards, features = np.concatenate([r1, r2]), np.concatenate([f1, f2])
    assert len(rewards) >= 10_000
    assert np.abs(reward(features, task) - rewards).max() <= 1e-6
    assert rewards.std() > 0  # the rollouts reach varied rewards, not one constant


def test_rewards_on_fast_and_high_states_match_dm_control():
    """States far outside random rollouts (fast, high, upside down) through physics replay."""
    rng = np.random.default_rng(3)
    _, _, physics = _rollout("stand", lambda _o: rng.uniform(-1, 1, 6), 500, seed=4)
    states = physics.copy()
    # state = qpos (rootz, rootx, rooty, 6 joints) + qvel in the same order
    states[:, 10] = rng.uniform(-2, 12, len(states))  # root x velocity: covers walk 1 and run 8 margins
    states[:, 0] += rng.uniform(-0.5, 1.0, len(states))  # root z: below and above the stand height
    replay = physics_replay_rewards(states, list(TASKS))
    env = WalkerEnv("stand", 0)
    features = []
    for state in states:
        env.physics.set_state(state)
        env.physics.forward()
        features.append([env.physics.torso_height(), env.physics.torso_upright(), env.physics.horizontal_velocity()])
    for name in TASKS:
        assert np.abs(reward(np.array(features), name) - replay[name]).max() <= 1e-12
    features = np.array(features)  # the states cover both sides of every bound of the formula
    assert features[:, 0].min() < 1.2 < features[:, 0].max()
    assert features[:, 2].min() < 1.0 and features[:, 2].max() > 8.0


def test_horizontal_velocity_is_not_qvel0():
    env = WalkerEnv("walk", 0)
    env.reset()
    diffs = []
    for _ in range(200):
        step = env.step(np.random.default_rng(len(diffs)).uniform(-1, 1, 6))
        diffs.append(np.abs(step.features[2] - step.physics[[9, 10]]))  # qvel[0] (rootz), qvel[1] (rootx)
    assert np.max(diffs, axis=0).min() > 1e-3


def test_observation_and_state_shapes():
    env = WalkerEnv("run", 7, episode_length=3)
    obs = env.reset()
    assert obs.shape == (24,)
    steps = [env.step(np.zeros(6)) for _ in range(3)]
    assert [s.timeout for s in steps] == [False, False, True]
    assert steps[0].physics.shape == (PHYSICS_DIM,) and steps[0].physics.dtype == np.float64


def test_seeded_envs_repeat():
    a, b = WalkerEnv("walk", 5), WalkerEnv("walk", 5)
    assert np.array_equal(a.reset(), b.reset())
    assert not np.array_equal(WalkerEnv("walk", 6).reset(), WalkerEnv("walk", 5).reset())  # random initial joints
    assert np.array_equal(a.step(np.ones(6)).physics, b.step(np.ones(6)).physics)


def test_unknown_task_names_the_key():
    with pytest.raises(ConfigError, match=r"study.tasks\[1\]: unknown task 'jump'"):
        check_task_list(["stand", "jump"], "study.tasks")
    with pytest.raises(ConfigError, match="must not repeat"):
        check_task_list(["walk", "walk"], "study.tasks")
    assert get_task("run").move_speed == 8.0


def test_task_order_and_subsets_are_free():
    assert check_task_list(["run", "stand", "walk"], "tasks") == ("run", "stand", "walk")


def test_stand_still_is_stand_times_a_speed_penalty():
    """stand_still = stand * tol(|x|; bounds 0, margin m, gaussian, 0.1): equal to stand at rest, 0.1 of it at
    |x| = m, and smaller the faster the walker moves either way."""
    task = get_task("stand_still")
    margin = task.stillness.margin
    speeds = np.array([0.0, margin / 5, -margin, margin, 1.0, -8.0])
    features = np.stack([np.full(6, 1.3), np.full(6, 0.9), speeds], axis=1)
    stand = reward(features, "stand")
    ratio = reward(features, "stand_still") / stand
    assert ratio[0] == 1.0 and np.allclose(ratio[2:4], 0.1, rtol=1e-12)
    assert np.allclose(ratio[1], np.exp(-(1 / 5) ** 2 * np.log(10.0)), rtol=1e-12)
    assert ratio[4] < 0.01 and ratio[5] < 1e-100
    linear = Stillness(margin=0.5, form="linear")
    assert np.allclose(linear.factor(np.array([0.0, 0.25, -0.5, 0.6])), [1.0, 0.55, 0.1, 0.0], rtol=1e-12)


def test_stillness_rejects_bad_settings():
    with pytest.raises(ValueError, match="form"):
        Stillness(margin=0.5, form="cosine")
    with pytest.raises(ValueError, match="margin"):
        Stillness(margin=0.0)
    with pytest.raises(ValueError, match="move_speed 0"):
        WalkerTask("walk_still", 1.0, "walk", 980.0, stillness=Stillness(margin=0.5))


def test_a_substitutes_set_replaces_its_base_task_and_learns_from_its_data():
    from mop_core.walker.tasks import data_tasks, substitute_base, substitute_tasks

    assert substitute_base("stand_still") == "stand"
    assert substitute_tasks(("walk", "stand"), "stand_still") == ("walk", "stand_still")
    assert data_tasks(("walk", "stand_still"), "stand_still") == ("walk", "stand")
    assert data_tasks(("stand", "walk")) == ("stand", "walk")
