"""Batched online rollouts: evaluation returns and dataset collection with K walkers at a time.

The policy runs on one torch thread during a rollout (:func:`policy_threads`): its batches are a
few walkers, too small to split, and a second OpenMP thread that spins between calls takes the core
the walkers' MuJoCo step threads need (measured: 15 walkers x 1000 steps with three 256 x 256
students, 5.9 s on 2 torch threads, 2.7 s on 1).
"""

from __future__ import annotations

import contextlib
from typing import Callable, Iterator, Sequence

import numpy as np
import torch

from mop_core.walker.envs import VectorWalkerEnv
from mop_core.walker.tasks import WalkerTask

Policy = Callable[[np.ndarray], np.ndarray]  # observations [K, 24] -> actions [K, 6]


@contextlib.contextmanager
def policy_threads(threads: int = 1) -> Iterator[None]:
    """Run torch on ``threads`` intra-op threads inside the block, the caller's count after it."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _chunks(seeds: Sequence[int], size: int) -> list[Sequence[int]]:
    return [seeds[i:i + size] for i in range(0, len(seeds), size)]


def episode_returns(policy: Policy, task: str | WalkerTask, seeds: Sequence[int], episode_length: int,
                    num_envs: int | None = None) -> np.ndarray:
    """Undiscounted return of one episode per seed, ``num_envs`` walkers stepped together."""
    return _rollouts(policy, task, seeds, episode_length, num_envs, keep_states=False)[0]


def returns_and_states(policy: Policy, task: str | WalkerTask, seeds: Sequence[int], episode_length: int,
                       num_envs: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`episode_returns` and the observations the policy visited, ``[episodes * T, obs]``
    episode after episode (float32)."""
    return _rollouts(policy, task, seeds, episode_length, num_envs, keep_states=True)  # type: ignore[return-value]


def policies_returns_and_states(policies: Sequence[Policy], task: str | WalkerTask, seeds: Sequence[int],
                                episode_length: int, num_envs: int | None = None, keep_states: bool = True,
                                ) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Each policy on the same episode seeds, every policy's walkers stepped together (one MuJoCo
    batch of ``len(policies) x num_envs`` walkers instead of one per policy: the runs of a group
    evaluated at once). Per policy, what :func:`returns_and_states` gives it (``keep_states``
    False: states None), bit for bit: each policy still acts on batches of at most ``num_envs`` of
    its own walkers, and walkers do not interact (tested)."""
    count = len(policies)
    returns: list[list[np.ndarray]] = [[] for _ in policies]
    states: list[list[np.ndarray]] = [[] for _ in policies]
    for chunk in _chunks(list(seeds), num_envs or len(seeds)):
        size = len(chunk)

        def together(obs: np.ndarray) -> np.ndarray:
            return np.concatenate([p(obs[k * size:(k + 1) * size]) for k, p in enumerate(policies)])

        chunk_returns, chunk_states = _rollouts(together, task, list(chunk) * count, episode_length, size * count,
                                                keep_states)
        rows = size * episode_length
        for k in range(count):
            returns[k].append(chunk_returns[k * size:(k + 1) * size])
            if chunk_states is not None:
                states[k].append(chunk_states[k * rows:(k + 1) * rows])
    return [(np.concatenate(r), np.concatenate(s) if keep_states else None) for r, s in zip(returns, states)]


def _rollouts(policy: Policy, task: str | WalkerTask, seeds: Sequence[int], episode_length: int,
              num_envs: int | None, keep_states: bool) -> tuple[np.ndarray, np.ndarray | None]:
    returns, states = [], []
    for chunk in _chunks(list(seeds), num_envs or len(seeds)):
        with VectorWalkerEnv(task, chunk, episode_length) as env, policy_threads():
            obs = env.reset()
            total = np.zeros(len(chunk))
            visited = (np.empty((episode_length, len(chunk), obs.shape[-1]), dtype=np.float32) if keep_states
                       else None)
            for t in range(episode_length):
                if visited is not None:
                    visited[t] = obs
                step = env.step(policy(obs))
                total += step.reward
                obs = step.observation
        returns.append(total)
        if visited is not None:
            states.append(np.swapaxes(visited, 0, 1).reshape(-1, visited.shape[-1]))
    return np.concatenate(returns), (np.concatenate(states) if keep_states else None)


def collect_episodes(policy: Policy, task: str | WalkerTask, seeds: Sequence[int], episode_length: int,
                     num_envs: int, action_noise: float = 0.0, rng: np.random.Generator | None = None,
                     ) -> dict[str, np.ndarray]:
    """Roll out one episode per seed and return dataset arrays (episode after episode).

    Actions are ``clip(policy(s) + N(0, action_noise^2), -1, 1)``. Keys as in the dataset schema
    (in-memory names), including ``next_physics`` and ``reward_features``.
    """
    if action_noise > 0 and rng is None:
        raise ValueError("rng: a generator is required when action_noise > 0")
    per_chunk = []
    for chunk in _chunks(list(seeds), num_envs):
        with VectorWalkerEnv(task, chunk, episode_length) as env, policy_threads():
            per_chunk.append(_collect_chunk(env, policy, action_noise, rng))
    arrays = {key: np.concatenate([c[key] for c in per_chunk]) for key in per_chunk[0]}
    arrays["terminals"] = np.zeros(len(arrays["rewards"]), dtype=bool)
    return arrays


def _collect_chunk(env: VectorWalkerEnv, policy: Policy, action_noise: float, rng: np.random.Generator | None
                   ) -> dict[str, np.ndarray]:
    """One episode of each of ``env``'s walkers as dataset arrays, episode-major ``[K * T, ...]``."""
    k, t_len = env.num_envs, env.episode_length
    obs = env.reset()
    buf = {
        "observations": np.empty((t_len, k, 24)), "actions": np.empty((t_len, k, 6)),
        "rewards": np.empty((t_len, k)), "next_observations": np.empty((t_len, k, 24)),
        "timeouts": np.empty((t_len, k), dtype=bool), "next_physics": np.empty((t_len, k, 18)),
        "reward_features": np.empty((t_len, k, 3)),
    }
    for t in range(t_len):
        action = policy(obs)
        if action_noise > 0:
            assert rng is not None
            action = np.clip(action + rng.normal(0.0, action_noise, size=action.shape), -1.0, 1.0)
        step = env.step(action)
        buf["observations"][t], buf["actions"][t], buf["rewards"][t] = obs, action, step.reward
        buf["next_observations"][t], buf["timeouts"][t] = step.observation, step.timeout
        buf["next_physics"][t], buf["reward_features"][t] = step.physics, step.features
        obs = step.observation
    return {key: np.swapaxes(v, 0, 1).reshape(k * t_len, *v.shape[2:]) for key, v in buf.items()}


def trajectory_returns(rewards: np.ndarray, ends: np.ndarray, episode_length: int) -> np.ndarray:
    """Returns of the complete (``episode_length``-step) trajectories delimited by ``ends``."""
    bounds = np.flatnonzero(ends) + 1
    starts = np.concatenate([[0], bounds[:-1]])
    full = (bounds - starts) == episode_length
    sums = np.add.reduceat(rewards.astype(np.float64), starts) if len(starts) else np.zeros(0)
    return sums[full]
