"""mop_core/walker/rollout.py: K walkers stepped together give what one walker at a time gives, and
trajectory_returns sums complete episodes only."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mop_core.walker.envs import WalkerEnv
from mop_core.walker.rollout import (
    collect_episodes,
    episode_returns,
    policies_returns_and_states,
    policy_threads,
    returns_and_states,
    trajectory_returns,
)

SEEDS = [11, 12, 13]
LENGTH = 15


def policy(obs: np.ndarray) -> np.ndarray:
    """Row by row (no matrix product), so the batch size cannot change the rounding."""
    return np.tanh(obs[:, :6] - 0.5 * obs[:, 6:12])


def _single_episode(seed: int) -> tuple[float, np.ndarray]:
    env = WalkerEnv("walk", seed, LENGTH)
    obs, total, visited = env.reset(), 0.0, []
    for _ in range(LENGTH):
        visited.append(obs)
        step = env.step(policy(obs[None])[0])
        total += step.reward
        obs = step.observation
    return total, np.stack(visited)


def test_batched_rollouts_equal_one_env_at_a_time():
    one = episode_returns(policy, "walk", SEEDS, LENGTH, num_envs=1)
    assert one.shape == (3,) and one.dtype == np.float64
    np.testing.assert_allclose(one, [_single_episode(seed)[0] for seed in SEEDS], rtol=1e-12)
    for num_envs in (None, 2, 3):  # None: all at once; 2: a full chunk and a short one
        np.testing.assert_array_equal(episode_returns(policy, "walk", SEEDS, LENGTH, num_envs=num_envs), one)


def test_returns_and_states_lists_each_episodes_states_in_seed_order():
    returns, states = returns_and_states(policy, "walk", SEEDS, LENGTH, num_envs=2)
    np.testing.assert_array_equal(returns, episode_returns(policy, "walk", SEEDS, LENGTH, num_envs=1))
    assert states.shape == (3 * LENGTH, 24) and states.dtype == np.float32
    for k, seed in enumerate(SEEDS):
        np.testing.assert_array_equal(states[k * LENGTH:(k + 1) * LENGTH],
                                      _single_episode(seed)[1].astype(np.float32))


def test_collected_episodes_are_dataset_rows_episode_after_episode():
    batched = collect_episodes(policy, "walk", SEEDS, LENGTH, num_envs=2)
    single = collect_episodes(policy, "walk", SEEDS, LENGTH, num_envs=1)
    shapes = {"observations": (45, 24), "actions": (45, 6), "rewards": (45,), "next_observations": (45, 24),
              "timeouts": (45,), "terminals": (45,), "next_physics": (45, 18), "reward_features": (45, 3)}
    assert {k: v.shape for k, v in batched.items()} == shapes
    for key in shapes:
        np.testing.assert_array_equal(batched[key], single[key], err_msg=key)
    assert not batched["terminals"].any()
    np.testing.assert_array_equal(np.flatnonzero(batched["timeouts"]), [14, 29, 44])
    within = np.arange(44) % LENGTH != LENGTH - 1  # within an episode, the next state is the next row's state
    np.testing.assert_array_equal(batched["next_observations"][:-1][within], batched["observations"][1:][within])
    np.testing.assert_allclose(batched["rewards"].reshape(3, LENGTH).sum(1),
                               episode_returns(policy, "walk", SEEDS, LENGTH), rtol=1e-12)
    np.testing.assert_allclose(trajectory_returns(batched["rewards"], batched["timeouts"], LENGTH),
                               episode_returns(policy, "walk", SEEDS, LENGTH), rtol=1e-12)


def test_action_noise_is_clipped_and_needs_a_generator():
    with pytest.raises(ValueError, match="^rng: a generator is required when action_noise > 0$"):
        collect_episodes(policy, "walk", SEEDS[:1], 5, 1, action_noise=0.5)
    noisy = collect_episodes(policy, "walk", SEEDS[:1], 5, 1, action_noise=5.0, rng=np.random.default_rng(0))
    again = collect_episodes(policy, "walk", SEEDS[:1], 5, 1, action_noise=5.0, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(noisy["actions"], again["actions"])
    assert np.abs(noisy["actions"]).max() == 1.0  # noise of sd 5 saturates some actions at the bounds
    assert not np.array_equal(noisy["actions"], policy(noisy["observations"]))


def test_trajectory_returns_sums_the_complete_trajectories_only():
    rewards = np.arange(10, dtype=np.float32)
    ends = np.zeros(10, dtype=bool)
    ends[[2, 5, 6, 9]] = True  # [0..2] [3..5] [6] [7..9]: the third is cut short
    returns = trajectory_returns(rewards, ends, 3)
    assert returns.dtype == np.float64
    np.testing.assert_array_equal(returns, [0 + 1 + 2, 3 + 4 + 5, 7 + 8 + 9])
    ends[9] = False  # rows after the last end belong to no complete trajectory
    np.testing.assert_array_equal(trajectory_returns(rewards, ends, 3), [3.0, 12.0])
    np.testing.assert_array_equal(trajectory_returns(rewards, ends, 4), [])
    assert trajectory_returns(rewards, np.zeros(10, dtype=bool), 3).shape == (0,)


def test_policies_stepped_together_get_what_each_gets_alone_bit_for_bit():
    """A group's runs evaluated in one MuJoCo batch: each policy's returns and visited states are
    those of its own rollout (same seeds, same per-policy batches of at most num_envs walkers)."""
    policies = [policy, lambda obs: -policy(obs), lambda obs: np.tanh(obs[:, 6:12])]
    together = policies_returns_and_states(policies, "walk", SEEDS, LENGTH, num_envs=2)
    for p, (returns, states) in zip(policies, together):
        alone_returns, alone_states = returns_and_states(p, "walk", SEEDS, LENGTH, num_envs=2)
        np.testing.assert_array_equal(returns, alone_returns)
        np.testing.assert_array_equal(states, alone_states)
    no_states = policies_returns_and_states(policies, "walk", SEEDS, LENGTH, 2, keep_states=False)
    assert all(states is None for _, states in no_states)
    np.testing.assert_array_equal(no_states[1][0], together[1][0])


def test_policies_run_on_one_torch_thread_during_a_rollout_and_the_count_is_restored():
    before = torch.get_num_threads()
    seen = []

    def counting(obs: np.ndarray) -> np.ndarray:
        seen.append(torch.get_num_threads())
        return policy(obs)

    torch.set_num_threads(2)
    try:
        episode_returns(counting, "walk", SEEDS[:1], 3)
        assert set(seen) == {1} and torch.get_num_threads() == 2
        with pytest.raises(RuntimeError):
            with policy_threads():
                raise RuntimeError("a failing rollout")
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
