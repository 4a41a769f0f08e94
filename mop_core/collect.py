"""The collect step for one task (thesis 4.4.3): train TD3 online, snapshot, write three datasets.

Proficiency levels as the thesis defines them: the *medium* behaviour policy is an early stop of
TD3 (by default at ``medium_step`` gradient steps; optionally the first periodic evaluation whose
mean return reaches ``medium_target_return``) and the *expert* one the end of training
(``total_steps`` gradient steps). Datasets:

- ``expert``: ``expert_episodes`` rollouts of the expert snapshot;
- ``medium``: ``medium_episodes`` rollouts of the medium snapshot;
- ``medium_replay``: every transition the learner saw up to the medium snapshot (warm-up
  included), in order; its last trajectory is cut at the snapshot and marked as a time-out.

TD3 does one gradient step per environment step after ``warmup_steps`` uniformly random actions.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from mop_core.agents.td3 import TD3, TD3Config
from mop_core.artifacts import package_versions, save_checkpoint, state_sha256, write_curve
from mop_core.config import require, to_dict
from mop_core.data import LEVELS, ReplayBuffer, write_dataset, write_json
from mop_core.envs import ACT_DIM, OBS_DIM, PHYSICS_DIM, WalkerEnv
from mop_core.rollout import collect_episodes, episode_returns, trajectory_returns
from mop_core.runtime import derive_seeds, require_finite
from mop_core.tasks import REWARD_FEATURES, get_task


@dataclass(frozen=True)
class ScheduleConfig:
    """When TD3 trains, evaluates and snapshots (all counts are gradient steps unless named env)."""

    total_steps: int  # gradient steps of the whole run: the expert snapshot
    medium_step: int  # gradient steps at the medium snapshot (early stop)
    medium_target_return: float | None = None  # if set: medium = first evaluation reaching this return
    warmup_steps: int = 5000  # env steps with uniformly random actions before learning starts
    eval_every: int = 10000  # gradient steps between learning-curve evaluations
    eval_episodes: int = 5  # episodes per learning-curve evaluation
    snapshot_eval_episodes: int = 10  # episodes to measure each snapshot's return (Table 4.1)
    random_episodes: int = 100  # uniformly random-action episodes: R_random of the normalised score

    def __post_init__(self) -> None:
        for name in ("total_steps", "medium_step", "eval_every", "eval_episodes", "snapshot_eval_episodes",
                     "random_episodes"):
            require(getattr(self, name) > 0, name, "a positive integer", getattr(self, name))
        require(self.warmup_steps >= 0, "warmup_steps", "a non-negative integer", self.warmup_steps)
        require(self.medium_step < self.total_steps, "medium_step",
                f"fewer gradient steps than total_steps={self.total_steps} (medium is an early stop "
                "of the expert run)", self.medium_step)


@dataclass(frozen=True)
class DatasetSizes:
    """How much each dataset holds and how it is rolled out."""

    expert_episodes: int  # episodes of the expert dataset
    medium_episodes: int  # episodes of the medium dataset
    rollout_envs: int = 10  # walkers stepped together while rolling out
    action_noise: float = 0.0  # std of Gaussian noise on the snapshot's actions during rollouts

    def __post_init__(self) -> None:
        for name in ("expert_episodes", "medium_episodes", "rollout_envs"):
            require(getattr(self, name) > 0, name, "a positive integer", getattr(self, name))
        require(self.action_noise >= 0, "action_noise", "a non-negative std", self.action_noise)


@dataclass(frozen=True)
class CollectConfig:
    """Everything the collect step of one task needs besides the task, seed and paths."""

    td3: TD3Config
    schedule: ScheduleConfig
    datasets: DatasetSizes
    episode_length: int = 1000  # control steps per episode (1000 = dm_control's 25 s)

    def __post_init__(self) -> None:
        require(self.episode_length > 0, "episode_length", "a positive integer", self.episode_length)
        capacity = self.schedule.warmup_steps + self.schedule.total_steps
        require(self.td3.batch_size <= capacity, "td3.batch_size",
                f"at most the {capacity} transitions the replay buffer ever holds (warmup_steps + total_steps)",
                self.td3.batch_size)


@dataclass(frozen=True)
class CollectPaths:
    """Where the collect step of one task writes (chosen by the stage, never by the library)."""

    checkpoints: dict[str, Path]  # "medium"/"expert" -> .pt
    datasets: dict[str, Path]  # level -> .hdf5
    dataset_metrics: dict[str, Path]  # level -> .json
    curve: Path  # learning curve .tsv


def task_seeds(seed: int, task: str) -> dict[str, int]:
    """Independent seeds per purpose, derived from (study seed, task name) only.

    Adding or reordering tasks in a study leaves every other task's seeds unchanged. ``agent`` seeds
    TD3's initialisation and its noise generator (exploration and target smoothing); the replay
    sampler and the warm-up actions have seeds of their own, so no two streams are the same.
    """
    return derive_seeds([seed, task], ("train_env", "agent", "eval", "expert_rollout", "medium_rollout", "sampler",
                                       "warmup", "random_policy", "random_episodes"))


def random_returns(task: str, episodes: int, seed: int, episode_length: int, rollout_envs: int,
                   policy_seed: int) -> np.ndarray:
    """Returns of ``episodes`` episodes of uniformly random actions in [-1, 1]^6 (R_random of the
    normalised score), episode seeds ``seed, seed + 1, ...``."""
    rng = np.random.default_rng(policy_seed)
    return episode_returns(lambda obs: rng.uniform(-1.0, 1.0, size=(len(obs), ACT_DIM)), task,
                           _eval_seeds(seed, episodes), episode_length, rollout_envs)


def load_actor(checkpoint: dict) -> Callable[[np.ndarray], np.ndarray]:
    """A numpy policy from a behaviour checkpoint (config + actor weights)."""
    from mop_core.nn import DeterministicActor

    config = checkpoint["td3_config"]
    actor = DeterministicActor(checkpoint["obs_dim"], checkpoint["act_dim"], config["hidden_sizes"],
                               config["layer_norm"])
    actor.load_state_dict(checkpoint["actor"])
    actor.eval()

    @torch.no_grad()
    def policy(obs: np.ndarray) -> np.ndarray:
        return actor(torch.as_tensor(obs, dtype=torch.float32)).numpy().astype(np.float64)

    return policy


def _eval_seeds(base: int, count: int) -> list[int]:
    return [base + i for i in range(count)]


@dataclass
class _Snapshot:
    actor: dict[str, torch.Tensor]
    gradient_steps: int
    env_steps: int
    curve_return: float


def train_behaviour(task: str, config: CollectConfig, seed: int, device: torch.device, progress: bool,
                    position: int = 0) -> tuple[_Snapshot, _Snapshot, ReplayBuffer, list[dict]]:
    """Train TD3 on ``task``; return the medium and expert snapshots, the replay and the curve."""
    sched, seeds = config.schedule, task_seeds(seed, task)
    env = WalkerEnv(task, seeds["train_env"], config.episode_length)
    agent = TD3(config.td3, OBS_DIM, ACT_DIM, seeds["agent"], device)
    rng = np.random.default_rng(seeds["warmup"])  # warm-up actions
    sampler = torch.Generator().manual_seed(seeds["sampler"])  # replay minibatches (CPU, whatever the device)
    buffer = ReplayBuffer(sched.warmup_steps + sched.total_steps, OBS_DIM, ACT_DIM, PHYSICS_DIM, len(REWARD_FEATURES))
    eval_seeds = _eval_seeds(seeds["eval"], sched.eval_episodes)
    policy = lambda o: agent.act(o).astype(np.float64)  # noqa: E731

    curve: list[dict] = []
    medium: _Snapshot | None = None
    fallback: _Snapshot | None = None  # closest evaluation below the target return so far
    obs = env.reset()
    started, last_losses = time.perf_counter(), {}
    total_env_steps = sched.warmup_steps + sched.total_steps
    bar = tqdm(total=sched.total_steps, desc=f"collect {task}", position=position, disable=not progress,
               mininterval=2.0, unit="upd")
    for t in range(total_env_steps):
        if t < sched.warmup_steps:
            action = rng.uniform(-1.0, 1.0, ACT_DIM)
        else:
            action = agent.act(obs, config.td3.exploration_noise)
        step = env.step(action)
        buffer.add(obs, action, step.reward, step.observation, False, step.timeout, step.physics, step.features)
        obs = env.reset() if step.timeout else step.observation
        if t < sched.warmup_steps:
            continue
        losses = agent.update(buffer.sample(config.td3.batch_size, sampler))
        require_finite(losses, f"collect {task} (TD3)", agent.updates)
        last_losses = last_losses | losses
        g = agent.updates
        bar.update(1)
        if g % sched.eval_every == 0 or g == sched.total_steps or g == sched.medium_step:
            returns = episode_returns(policy, task, eval_seeds, config.episode_length)
            elapsed = time.perf_counter() - started
            row = {"step": g, "env_step": t + 1, "return_mean": float(returns.mean()),
                   "return_std": float(returns.std()), "critic_loss": last_losses.get("critic_loss", math.nan),
                   "actor_loss": last_losses.get("actor_loss", math.nan), "seconds": round(elapsed, 1)}
            curve.append(row)
            last_losses = {}
            bar.set_postfix(ret=f"{row['return_mean']:.0f}")
            snap = _Snapshot(agent.actor_state(), g, t + 1, row["return_mean"])
            if medium is None and g < sched.total_steps:
                if sched.medium_target_return is None:
                    if g == sched.medium_step:
                        medium = snap
                elif row["return_mean"] >= sched.medium_target_return:
                    medium = snap
                elif fallback is None or row["return_mean"] > fallback.curve_return:
                    fallback = snap
    bar.close()
    expert = _Snapshot(agent.actor_state(), agent.updates, total_env_steps, curve[-1]["return_mean"])
    if medium is None:  # target return never reached: the best evaluation below it
        medium = fallback if fallback is not None else expert
    return medium, expert, buffer, curve


def _dataset_summary(arrays: dict[str, np.ndarray], episode_length: int, behaviour_return: float | None) -> dict:
    returns = trajectory_returns(arrays["rewards"], arrays["timeouts"] | arrays["terminals"], episode_length)
    stats = {"return_mean": float(returns.mean()), "return_std": float(returns.std()),
             "return_min": float(returns.min()), "return_max": float(returns.max())} if len(returns) else {}
    summary = {"transitions": int(len(arrays["rewards"])),
               "episodes": int((arrays["timeouts"] | arrays["terminals"]).sum()),
               "complete_episodes": int(len(returns)), **stats}
    if behaviour_return is not None:
        summary["behaviour_return"] = behaviour_return
    return summary


def collect_task(task: str, config: CollectConfig, seed: int, paths: CollectPaths,
                 device: torch.device | str = "cpu", progress: bool = False, position: int = 0) -> dict:
    """Run the whole collect step of one task and write its checkpoints, datasets and metrics.

    Returns a summary: the snapshots' returns and each dataset's metrics.
    """
    get_task(task)
    device = torch.device(device)
    started = time.perf_counter()
    medium, expert, buffer, curve = train_behaviour(task, config, seed, device, progress, position)
    train_seconds = time.perf_counter() - started
    seeds = task_seeds(seed, task)
    versions = json.dumps(package_versions(), sort_keys=True)
    snapshot_seeds = _eval_seeds(seeds["eval"] + 10_000, config.schedule.snapshot_eval_episodes)

    summary: dict = {"task": task, "train_seconds": round(train_seconds, 1), "snapshots": {}, "datasets": {}}
    policies = {}
    for level, snap in (("medium", medium), ("expert", expert)):
        checkpoint = {"task": task, "level": level, "td3_config": to_dict(config.td3), "obs_dim": OBS_DIM,
                      "act_dim": ACT_DIM, "actor": snap.actor, "gradient_steps": snap.gradient_steps,
                      "env_steps": snap.env_steps, "seed": seed}
        policy = load_actor(checkpoint)
        returns = episode_returns(policy, task, snapshot_seeds, config.episode_length,
                                  config.datasets.rollout_envs)
        checkpoint |= {"sha256": state_sha256(snap.actor), "return_mean": float(returns.mean()),
                       "return_std": float(returns.std()), "eval_episodes": len(returns)}
        save_checkpoint(paths.checkpoints[level], checkpoint)
        policies[level] = policy
        summary["snapshots"][level] = {k: checkpoint[k] for k in
                                       ("gradient_steps", "env_steps", "return_mean", "return_std", "sha256")}

    random = random_returns(task, config.schedule.random_episodes, seeds["random_episodes"], config.episode_length,
                            config.datasets.rollout_envs, seeds["random_policy"])
    summary["random"] = {"return_mean": float(random.mean()), "return_std": float(random.std()),
                         "episodes": len(random)}

    size = config.datasets

    def rollouts(level: str, episodes: int) -> dict[str, np.ndarray]:
        base = seeds[f"{level}_rollout"]
        return collect_episodes(policies[level], task, _eval_seeds(base, episodes), config.episode_length,
                                size.rollout_envs, size.action_noise, np.random.default_rng(base))

    level_arrays = {
        "expert": lambda: rollouts("expert", size.expert_episodes),
        "medium": lambda: rollouts("medium", size.medium_episodes),
        "medium_replay": lambda: buffer.arrays(end=medium.env_steps),
    }
    for level in LEVELS:
        arrays = level_arrays[level]()
        arrays["timeouts"][-1] = True  # medium_replay: the trajectory cut at the snapshot ends here
        behaviour = "expert" if level == "expert" else "medium"
        attrs = {"task": task, "level": level, "seed": seed, "episode_length": config.episode_length,
                 "behaviour_sha256": summary["snapshots"][behaviour]["sha256"], "versions": versions}
        write_dataset(paths.datasets[level], arrays, attrs)
        metrics = _dataset_summary(arrays, config.episode_length, summary["snapshots"][behaviour]["return_mean"])
        write_json(paths.dataset_metrics[level], metrics)
        summary["datasets"][level] = metrics
    write_curve(paths.curve, curve)
    summary["total_seconds"] = round(time.perf_counter() - started, 1)
    return summary
