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

import math
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from mop_core.agents.td3 import TD3, TD3Config, actor_from_checkpoint
from mop_core.config import from_mapping, require, to_dict
from mop_core.data.buffer import ReplayBuffer
from mop_core.data.hdf5 import write_dataset
from mop_core.experiment.study import StudyConfig, section
from mop_core.learning.nn import numpy_policy
from mop_core.learning.online import fit_online
from mop_core.learning.resume import run_fingerprint
from mop_core.learning.runtime import (
    CriterionNotMetError,
    configure_compute,
    derive_seeds,
    die_with_parent,
    resolve_workers,
    set_cuda_matmul,
)
from mop_core.learning.schedule import OnlineSchedule
from mop_core.storage.artifacts import save_checkpoint, state_sha256, write_curve
from mop_core.storage.files import write_json
from mop_core.storage.layout import LEVELS, CollectPaths
from mop_core.walker.envs import ACT_DIM, OBS_DIM, PHYSICS_DIM, WalkerEnv
from mop_core.walker.rollout import collect_episodes, episode_returns, trajectory_returns
from mop_core.walker.tasks import REWARD_FEATURES, get_task

BEHAVIOUR_KIND = "td3_behaviour"  # the checkpoint kind of a medium/expert snapshot


@dataclass(frozen=True)
class ScheduleConfig:
    """When TD3 trains, evaluates and snapshots (all counts are gradient steps unless named env)."""

    total_steps: int  # gradient steps of the whole run: the expert snapshot (with expert_return: the cap)
    medium_step: int  # gradient steps at the medium snapshot (early stop)
    medium_target_return: float | dict[str, float] | None = None  # if set: medium = the first evaluation
    #   reaching this return (one number, or one per task: {stand: 458.85, walk: 681.4})
    expert_return: dict[str, float] | None = None  # the expert criterion per task (thesis 4.4.3: 979 / 907);
    #   if set, training stops at the first evaluation whose return over expert_eval_episodes fresh episodes
    #   reaches it (that snapshot is the expert; total_steps is the cap: an error names the task and its best
    #   return), and medium is the earlier snapshot whose return over snapshot_eval_episodes episodes is
    #   nearest medium_target_return
    expert_eval_episodes: int = 20  # episodes of the expert criterion's check
    attempts: int = 1  # with expert_return: TD3 runs from fresh initialisations (seeds derived from the attempt)
    #   until one meets every criterion within total_steps; only after the last one does collect stop with an error
    warmup_steps: int = 5000  # env steps with uniformly random actions before learning starts
    eval_every: int = 10000  # gradient steps between learning-curve evaluations
    eval_episodes: int = 5  # episodes per learning-curve evaluation
    snapshot_eval_episodes: int = 10  # episodes to measure each snapshot's return (Table 4.1)
    random_episodes: int = 100  # uniformly random-action episodes: R_random of the normalised score
    checkpoint_every: int = 10000  # gradient steps between resume files (written at the next episode end)

    def __post_init__(self) -> None:
        for name in ("total_steps", "medium_step", "eval_every", "eval_episodes", "snapshot_eval_episodes",
                     "random_episodes", "checkpoint_every", "expert_eval_episodes", "attempts"):
            require(getattr(self, name) > 0, name, "a positive integer", getattr(self, name))
        if self.expert_return is not None:
            require(isinstance(self.medium_target_return, dict), "medium_target_return",
                    "a target return per task when expert_return is set (medium is the snapshot nearest it)",
                    self.medium_target_return)
            for task, value in self.expert_return.items():
                medium = self.medium_target_return.get(task)
                require(medium is None or value > medium, f"expert_return.{task}",
                        f"a return above medium_target_return.{task}={medium}", value)
        require(self.attempts == 1 or self.expert_return is not None, "attempts",
                "1 without an expert criterion (expert_return: null: no run can fail)", self.attempts)
        require(self.warmup_steps >= 0, "warmup_steps", "a non-negative integer", self.warmup_steps)
        require(self.medium_step < self.total_steps, "medium_step",
                f"fewer gradient steps than total_steps={self.total_steps} (medium is an early stop "
                "of the expert run)", self.medium_step)

    def medium_target(self, task: str) -> float | None:
        """Task ``task``'s medium target return (None: the medium snapshot is taken at ``medium_step``)."""
        target = self.medium_target_return
        if isinstance(target, dict):
            require(task in target, "medium_target_return", f"a target return for every study task ({task!r} "
                    "is missing)", target)
            return target[task]
        return target

    def expert_criterion(self, task: str) -> float | None:
        """Task ``task``'s expert criterion (None: the expert is the snapshot at ``total_steps``)."""
        if self.expert_return is None:
            return None
        require(task in self.expert_return, "expert_return", f"a criterion for every study task ({task!r} is "
                "missing)", self.expert_return)
        return self.expert_return[task]


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
class ParallelConfig:
    """collect.parallel: how many task processes run at once and their torch threads."""

    workers: int | str = 2  # task processes at a time; auto: the cores this process may use
    threads_per_worker: int = 1  # torch threads in each process

    def __post_init__(self) -> None:
        object.__setattr__(self, "workers", resolve_workers(self.workers, "workers"))
        require(self.threads_per_worker >= 1, "threads_per_worker", "a positive integer", self.threads_per_worker)


def collect_configs(params: Mapping[str, Any], study: StudyConfig) -> tuple[ParallelConfig, CollectConfig]:
    """The params' collect section: the task processes' settings and one task's collect config."""
    raw = dict(section(params, "collect"))
    parallel = from_mapping(ParallelConfig, raw.pop("parallel", {}), "collect.parallel")
    config = from_mapping(CollectConfig, raw | {"episode_length": study.episode_length}, "collect")
    return parallel, config


def task_seeds(seed: int, task: str, attempt: int = 0) -> dict[str, int]:
    """Independent seeds per purpose, derived from (study seed, task name) only (and, for a behaviour
    run's later attempts, the attempt number: attempt 0 is the first run's seeds).

    Adding or reordering tasks in a study leaves every other task's seeds unchanged. ``agent`` seeds
    TD3's initialisation and its noise generator (exploration and target smoothing); the replay
    sampler and the warm-up actions have seeds of their own, so no two streams are the same.
    """
    name = [seed, task] if attempt == 0 else [seed, task, f"attempt-{attempt}"]
    return derive_seeds(name, ("train_env", "agent", "eval", "expert_rollout", "medium_rollout", "sampler", "warmup",
                               "random_policy", "random_episodes"))


def random_returns(task: str, episodes: int, seed: int, episode_length: int, rollout_envs: int,
                   policy_seed: int) -> np.ndarray:
    """Returns of ``episodes`` episodes of uniformly random actions in [-1, 1]^6 (R_random of the
    normalised score), episode seeds ``seed, seed + 1, ...``."""
    rng = np.random.default_rng(policy_seed)
    return episode_returns(lambda obs: rng.uniform(-1.0, 1.0, size=(len(obs), ACT_DIM)), task,
                           _eval_seeds(seed, episodes), episode_length, rollout_envs)


def _eval_seeds(base: int, count: int) -> list[int]:
    return [base + i for i in range(count)]


@dataclass
class _Snapshot:
    actor: dict[str, torch.Tensor]
    gradient_steps: int
    env_steps: int
    curve_return: float


@dataclass
class _Progress:
    """What a behaviour run has produced besides the learner: the curve and the snapshots so far."""

    curve: list[dict] = field(default_factory=list)
    medium: _Snapshot | None = None
    fallback: _Snapshot | None = None  # closest evaluation below the target return so far
    snapshots: list[_Snapshot] = field(default_factory=list)  # with an expert criterion: every evaluation's
    expert: _Snapshot | None = None  # the first snapshot meeting the expert criterion (curve_return: its check's)
    best_check: tuple[float, int] | None = None  # the best criterion check so far: (return, gradient steps)

    def record(self, row: dict, snap: _Snapshot, sched: ScheduleConfig, target: float | None) -> None:
        """Add an evaluation row and choose the medium snapshot (fixed step or first target return; with
        an expert criterion, every snapshot is kept and medium is chosen at the end)."""
        self.curve.append(row)
        if sched.expert_return is not None:
            self.snapshots.append(snap)
        elif self.medium is None and snap.gradient_steps < sched.total_steps:
            if target is None:
                if snap.gradient_steps == sched.medium_step:
                    self.medium = snap
            elif row["return_mean"] >= target:
                self.medium = snap
            elif self.fallback is None or row["return_mean"] > self.fallback.curve_return:
                self.fallback = snap


def train_behaviour(task: str, config: CollectConfig, seed: int, device: torch.device, progress: bool,
                    position: int = 0, resume: Path | None = None, attempt: int = 0
                    ) -> tuple[_Snapshot, _Snapshot, ReplayBuffer, list[dict]]:
    """Train TD3 on ``task`` online (mop_core.learning.online.fit_online); return the medium and expert
    snapshots, the replay and the curve.

    With ``resume``, the run writes a resume file at the first episode end after every
    ``checkpoint_every`` gradient steps (learner, optimisers, every generator, the replay, the curve,
    the snapshots so far and the environment's random state before its next reset) and, started
    again, continues from it: the same snapshots, datasets and curve as an uninterrupted run.
    """
    sched, seeds = config.schedule, task_seeds(seed, task, attempt)
    env = WalkerEnv(task, seeds["train_env"], config.episode_length)
    agent = TD3(config.td3, OBS_DIM, ACT_DIM, seeds["agent"], device)
    rng = np.random.default_rng(seeds["warmup"])  # warm-up actions
    sampler = torch.Generator().manual_seed(seeds["sampler"])  # replay minibatches (CPU, whatever the device)
    buffer = ReplayBuffer(sched.warmup_steps + sched.total_steps, OBS_DIM, ACT_DIM, PHYSICS_DIM, len(REWARD_FEATURES))
    eval_seeds = _eval_seeds(seeds["eval"], sched.eval_episodes)
    policy = lambda o: agent.act(o).astype(np.float64)  # noqa: E731
    target, criterion = sched.medium_target(task), sched.expert_criterion(task)
    check_seeds = _eval_seeds(seeds["eval"] + 20_000, sched.expert_eval_episodes)

    def evaluate(run: _Progress, update: int, env_steps: int, losses: dict) -> tuple[float, bool]:
        returns = episode_returns(policy, task, eval_seeds, config.episode_length)
        row = {"step": update, "env_step": env_steps, "return_mean": float(returns.mean()),
               "return_std": float(returns.std()), "critic_loss": losses.get("critic_loss", math.nan),
               "actor_loss": losses.get("actor_loss", math.nan)}
        snap = _Snapshot(agent.actor_state(), update, env_steps, row["return_mean"])
        run.record(row, snap, sched, target)
        if criterion is None or row["return_mean"] < criterion:
            return row["return_mean"], False
        check = float(episode_returns(policy, task, check_seeds, config.episode_length,
                                      config.datasets.rollout_envs).mean())
        if run.best_check is None or check > run.best_check[0]:
            run.best_check = (check, update)
        if check >= criterion:
            run.expert = replace(snap, curve_return=check)
        return row["return_mean"], run.expert is not None

    schedule = OnlineSchedule(sched.warmup_steps, sched.total_steps, sched.eval_every, sched.checkpoint_every,
                              extra_evals=(sched.medium_step,))
    run, _ = fit_online(agent, env, buffer, schedule, act_dim=ACT_DIM, batch_size=config.td3.batch_size,
                        exploration_noise=config.td3.exploration_noise, warmup_rng=rng, sampler=sampler,
                        record=_Progress(), evaluate=evaluate, resume=resume,
                        fingerprint=run_fingerprint({"task": task, "config": to_dict(config), "seed": seed}
                                                    | ({"attempt": attempt} if attempt else {})),
                        desc=f"collect {task}" + (f" (attempt {attempt + 1})" if attempt else ""), progress=progress,
                        position=position)
    if criterion is not None:
        return _criterion_snapshots(task, run, criterion, target, seeds, config) + (buffer, run.curve)
    expert = _Snapshot(agent.actor_state(), agent.updates, schedule.env_steps, run.curve[-1]["return_mean"])
    medium = run.medium
    if medium is None:  # target return never reached: the best evaluation below it
        medium = run.fallback if run.fallback is not None else expert
    return medium, expert, buffer, run.curve


def snapshot_policy(actor: dict[str, torch.Tensor], td3: TD3Config):
    """The deterministic numpy policy of a snapshot's actor weights."""
    return numpy_policy(actor_from_checkpoint({"td3_config": to_dict(td3), "obs_dim": OBS_DIM, "act_dim": ACT_DIM,
                                               "actor": actor}))


def _criterion_snapshots(task: str, run: _Progress, criterion: float, target: float, seeds: dict,
                         config: CollectConfig) -> tuple[_Snapshot, _Snapshot]:
    """(medium, expert) of a run with an expert criterion: the expert is the snapshot that met it; medium,
    among the earlier snapshots the three whose curve return is nearest ``target``, the one whose return
    over ``snapshot_eval_episodes`` fresh episodes is nearest it. A run that never met the criterion
    raises :class:`CriterionNotMetError` naming the task and its best return."""
    sched = config.schedule
    if run.expert is None:
        best = (f"its best check {run.best_check[0]:.1f} over {sched.expert_eval_episodes} episodes at step "
                f"{run.best_check[1]}" if run.best_check else
                f"its best evaluation {max(r['return_mean'] for r in run.curve):.1f} (never at the criterion)")
        raise CriterionNotMetError(f"collect {task}: the behaviour policy did not reach the expert criterion "
                                   f"{criterion} (collect.schedule.expert_return.{task}) within total_steps="
                                   f"{sched.total_steps} updates; {best}. No dataset was written.", run.curve)
    earlier = [s for s in run.snapshots if s.gradient_steps < run.expert.gradient_steps]
    if not earlier:
        raise CriterionNotMetError(f"collect {task}: the expert criterion held at the first evaluation (step "
                                   f"{run.expert.gradient_steps}): no earlier snapshot can be the medium one; "
                                   "lower collect.schedule.eval_every")
    candidates = sorted(earlier, key=lambda s: abs(s.curve_return - target))[:3]
    episodes = _eval_seeds(seeds["eval"] + 30_000, sched.snapshot_eval_episodes)
    measured = [(abs(float(episode_returns(snapshot_policy(s.actor, config.td3), task, episodes, config.episode_length,
                                           config.datasets.rollout_envs).mean()) - target), s) for s in candidates]
    medium = min(measured, key=lambda m: (m[0], m[1].gradient_steps))[1]
    return medium, run.expert


def _attempt_resume(resume: Path | None, attempt: int) -> Path | None:
    """The resume file of a behaviour run's attempt (the first attempt's is the task's resume file)."""
    if resume is None or attempt == 0:
        return resume
    return resume.with_name(f"{resume.stem}.attempt{attempt + 1}{resume.suffix}")


def _behaviour_attempt(task: str, config: CollectConfig, seed: int, device: torch.device, progress: bool,
                       position: int, resume: Path | None, attempt: int, snapshot_seeds: list[int]):
    """One behaviour run (:func:`train_behaviour`) and its snapshots measured over ``snapshot_seeds``:
    (medium, expert, replay, curve, checkpoints, policies). With an expert criterion, an expert that does
    not return more than its medium raises :class:`CriterionNotMetError` like a missed criterion."""
    medium, expert, buffer, curve = train_behaviour(task, config, seed, device, progress, position, resume, attempt)
    policies, checkpoints = {}, {}
    for level, snap in (("medium", medium), ("expert", expert)):
        checkpoint = {"kind": BEHAVIOUR_KIND, "task": task, "level": level, "td3_config": to_dict(config.td3),
                      "obs_dim": OBS_DIM, "act_dim": ACT_DIM, "actor": snap.actor,
                      "gradient_steps": snap.gradient_steps, "env_steps": snap.env_steps, "seed": seed}
        if attempt:
            checkpoint["attempt"] = attempt + 1
        policy = snapshot_policy(snap.actor, config.td3)
        returns = episode_returns(policy, task, snapshot_seeds, config.episode_length,
                                  config.datasets.rollout_envs)
        checkpoints[level] = checkpoint | {"sha256": state_sha256(snap.actor), "return_mean": float(returns.mean()),
                                           "return_std": float(returns.std()), "eval_episodes": len(returns)}
        policies[level] = policy
    if config.schedule.expert_return is not None and \
            checkpoints["expert"]["return_mean"] <= checkpoints["medium"]["return_mean"]:
        raise CriterionNotMetError(
            f"collect {task}: the expert snapshot (step {expert.gradient_steps}) returns "
            f"{checkpoints['expert']['return_mean']:.1f} over {len(snapshot_seeds)} episodes, not above the medium "
            f"one's {checkpoints['medium']['return_mean']:.1f} (step {medium.gradient_steps}). No dataset was written.",
            curve)
    return medium, expert, buffer, curve, checkpoints, policies


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
    seeds = task_seeds(seed, task)
    snapshot_seeds = _eval_seeds(seeds["eval"] + 10_000, config.schedule.snapshot_eval_episodes)
    failures: list[str] = []
    for attempt in range(config.schedule.attempts):
        try:
            medium, expert, buffer, curve, checkpoints, policies = _behaviour_attempt(
                task, config, seed, device, progress, position, _attempt_resume(paths.resume, attempt), attempt,
                snapshot_seeds)
            break
        except CriterionNotMetError as err:
            failures.append(f"attempt {attempt + 1}: {err}" if config.schedule.attempts > 1 else str(err))
            if attempt + 1 < config.schedule.attempts:
                continue
            if err.curve:  # no dataset, but the last attempt's curve that shows why (not a DVC output then)
                write_curve(paths.curve, err.curve)
            where = f" Its learning curve: {paths.curve}" if err.curve else ""
            raise CriterionNotMetError(" ".join(failures) + where, err.curve) from None
    train_seconds = time.perf_counter() - started
    summary: dict = {"task": task, "train_seconds": round(train_seconds, 1), "snapshots": {}, "datasets": {}}
    if config.schedule.expert_return is not None:  # the check that made the expert, over its own episodes
        summary["criterion"] = {"expert_criterion": config.schedule.expert_criterion(task),
                                "expert_criterion_return": expert.curve_return,
                                "expert_criterion_episodes": config.schedule.expert_eval_episodes,
                                "attempts": len(failures) + 1}
    for level, checkpoint in checkpoints.items():
        save_checkpoint(paths.checkpoints[level], checkpoint)
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
                 "behaviour_sha256": summary["snapshots"][behaviour]["sha256"]}
        write_dataset(paths.datasets[level], arrays, attrs)
        metrics = _dataset_summary(arrays, config.episode_length, summary["snapshots"][behaviour]["return_mean"])
        write_json(paths.dataset_metrics[level], metrics)
        summary["datasets"][level] = metrics
    write_curve(paths.curve, curve)
    for attempt in range(config.schedule.attempts):  # every output is written: the run is over
        resume = _attempt_resume(paths.resume, attempt)
        if resume is not None:
            resume.unlink(missing_ok=True)
    summary["total_seconds"] = round(time.perf_counter() - started, 1)
    return summary


def _collect_worker(task: str, config: CollectConfig, seed: int, paths: CollectPaths, device: str, progress: bool,
                    position: int, threads: int, cuda_matmul: str) -> dict:
    configure_compute(threads)
    set_cuda_matmul(cuda_matmul)
    return collect_task(task, config, seed, paths, device, progress, position)


def collect_tasks(tasks: Sequence[tuple[str, CollectPaths]], config: CollectConfig, seed: int, device: str,
                  progress: bool, workers: int, threads: int, cuda_matmul: str) -> dict[str, dict]:
    """Every task's collect step, each in a spawned process with ``threads`` torch threads and CUDA float32
    matmuls in ``cuda_matmul`` (study.cuda_matmul), ``workers`` at a time (``dvc repro`` runs stages one
    after another, so one stage per task would leave a core idle). Returns each task's summary
    (:func:`collect_task`)."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=context,
                             initializer=die_with_parent) as pool:
        futures = {task: pool.submit(_collect_worker, task, config, seed, paths, device, progress, i, threads,
                               cuda_matmul)
                   for i, (task, paths) in enumerate(tasks)}
        return {task: future.result() for task, future in futures.items()}


def collect_metrics(summaries: dict[str, dict]) -> dict:
    """The collect stage's metrics: snapshot returns and R_random of the normalised score, per task
    (the times are in the stage's timing record: :func:`collect_timing`)."""
    metrics = {task: {"medium_return": s["snapshots"]["medium"]["return_mean"],
                      "expert_return": s["snapshots"]["expert"]["return_mean"],
                      "medium_gradient_steps": s["snapshots"]["medium"]["gradient_steps"],
                      "expert_gradient_steps": s["snapshots"]["expert"]["gradient_steps"],
                      "random_return": s["random"]["return_mean"], "random_return_std": s["random"]["return_std"],
                      "random_episodes": s["random"]["episodes"]} | s.get("criterion", {})
               for task, s in summaries.items()}
    return metrics


def collect_timing(summaries: dict[str, dict]) -> dict:
    """Per task: seconds of TD3 training and of the whole task (snapshots, datasets included)."""
    return {task: {"train_seconds": s["train_seconds"], "seconds": s["total_seconds"]}
            for task, s in summaries.items()}
