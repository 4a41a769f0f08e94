"""Online evaluation of every policy of a study: returns, 95% confidence intervals, cross-task tables.

A job is one policy rolled out on one task: ``episodes`` episodes, all of a job's walkers stepped
together (``rollout_envs`` at a time); jobs run in ``workers`` single-threaded processes. Every
policy sees the same episode seeds (common random numbers), so differences between policies are not
differences between start states.

Confidence intervals (:func:`summarise_group`), always with their unit and n:

- one trained policy: Student-t over its evaluation episodes (n = episodes);
- a group of >= 3 training seeds: Student-t over the seeds' mean returns (n = seeds), the interval
  the thesis's figures draw;
- a group of 2 seeds: a t-interval over 2 units has t(0.975, 1) = 12.7 and says nothing, so the
  group gets the per-episode interval over its pooled episodes (n = episodes; it ignores the
  between-seed variance) and lists each seed's mean.

Aggregates across tasks and runs (IQM, probability of improvement) are in :mod:`mop_core.statistics`.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from tqdm import tqdm

from mop_core.config import InputFileError, require
from mop_core.rollout import episode_returns
from mop_core.runtime import derive_seeds, die_with_parent, set_threads
from mop_core.statistics import (
    MIN_SEEDS_FOR_SEED_CI,
    confidence_interval,
    iqm,
    normalised_score,
    probability_of_improvement,
    stratified_bootstrap,
)

Policy = Callable[[np.ndarray], np.ndarray]
POLICY_KINDS = ("behaviour", "teacher", "multitask", "student")
GAUSSIAN_ACTIONS = ("mean", "sample")


@dataclass(frozen=True)
class EvalConfig:
    """How much evaluation: ``episodes`` episodes per (policy, task), the same seeds for every policy."""

    episodes: int = 30  # per policy and task: the CI unit of a policy trained once
    rollout_envs: int = 30  # walkers stepped together in one process
    workers: int = 2  # processes (one torch thread each)
    bootstrap_reps: int = 2000  # replicates of the stratified bootstrap (IQM, probability of improvement)
    gaussian_student_action: str = "mean"  # KL students act by their mean, or by a sample (the reference code)

    def __post_init__(self) -> None:
        require(self.episodes >= 2, "episodes", "an integer >= 2 (a confidence interval needs two units)",
                self.episodes)
        for name in ("rollout_envs", "workers", "bootstrap_reps"):
            require(getattr(self, name) >= 1, name, "a positive integer", getattr(self, name))
        require(self.gaussian_student_action in GAUSSIAN_ACTIONS, "gaussian_student_action",
                f"one of {GAUSSIAN_ACTIONS}", self.gaussian_student_action)


@dataclass(frozen=True)
class PolicySpec:
    """Which checkpoint to act with and, for a task-conditioned policy, under which task id.

    ``sample_seed``: a Gaussian student acts by sampling ``clip(mu + sigma eps, -1, 1)`` from a
    generator with this seed instead of by its mean (None: the mean)."""

    kind: str  # behaviour | teacher | multitask | student
    path: Path
    task: str | None = None  # task id to condition on (multitask baseline and students)
    sample_seed: int | None = None


@dataclass(frozen=True)
class Job:
    """Roll ``policy`` out on ``eval_task``; ``group``/``train_seed`` say whose CI it joins."""

    group: str
    train_seed: int
    policy: PolicySpec
    eval_task: str


def load_policy(spec: PolicySpec) -> Policy:
    """A numpy policy from any checkpoint of the study (Gaussian actors act with their mean)."""
    if spec.kind == "behaviour":
        from mop_core.artifacts import read_torch_file
        from mop_core.collect import load_actor

        payload = read_torch_file(spec.path)
        if not isinstance(payload, dict) or "td3_config" not in payload:
            raise InputFileError(f"{spec.path}: expected a behaviour snapshot of the collect stage")
        return load_actor(payload)
    if spec.kind == "teacher":
        from mop_core.teachers import load_teacher

        return load_teacher(spec.path).act
    if spec.kind == "multitask":
        from mop_core.teachers import load_multitask

        return load_multitask(spec.path).policy(spec.task)
    if spec.kind == "student":
        from mop_core.distill.run import load_student

        return load_student(spec.path).policy(spec.task, spec.sample_seed)
    raise ValueError(f"kind: expected one of {POLICY_KINDS}, got {spec.kind!r}")


def episode_seeds(study_seed: int, config: EvalConfig) -> list[int]:
    """``episodes`` environment seeds, the same for every policy and task."""
    base = derive_seeds([study_seed, "eval"], ("episodes",))["episodes"]
    return [base + j for j in range(config.episodes)]


def run_job(job: Job, seeds: list[int], episode_length: int, rollout_envs: int) -> np.ndarray:
    """Returns ``[episodes]`` of one job."""
    return episode_returns(load_policy(job.policy), job.eval_task, seeds, episode_length, rollout_envs)


def _in_worker(call: tuple) -> Any:
    fn, args = call
    set_threads(1)
    return fn(*args)


def parallel_map(fn: Callable, args: Sequence[tuple], workers: int, desc: str, progress: bool = False) -> list:
    """``[fn(*a) for a in args]`` in order, over ``workers`` single-threaded processes (in this
    process when ``workers`` or the number of calls is 1); a tqdm bar counts finished calls.
    ``fn`` must be a module-level function (it is pickled)."""
    bar = tqdm(total=len(args), desc=desc, unit="job", disable=not progress)
    results = []
    if workers == 1 or len(args) == 1:
        for a in args:
            results.append(fn(*a))
            bar.update(1)
    else:
        with ProcessPoolExecutor(max_workers=min(workers, len(args), os.cpu_count() or 1),
                                 initializer=die_with_parent) as pool:
            for result in pool.map(_in_worker, [(fn, a) for a in args]):
                results.append(result)
                bar.update(1)
    bar.close()
    return results


def run_jobs(jobs: Sequence[Job], seeds: list[int], episode_length: int, config: EvalConfig,
             progress: bool = False) -> list[np.ndarray]:
    """Every job's returns, in job order; ``config.workers`` processes share the jobs."""
    args = [(job, seeds, episode_length, config.rollout_envs) for job in jobs]
    return parallel_map(run_job, args, config.workers, "eval", progress)


def summarise_group(returns_by_seed: dict[int, np.ndarray], random_return: float | None = None,
                    expert_return: float | None = None) -> dict:
    """Mean and 95% CI of one group (one policy family on one task) from ``{train_seed: returns [episodes]}``.

    >= MIN_SEEDS_FOR_SEED_CI training seeds: over the seeds' means (``ci_unit`` training_seed);
    fewer: over all episodes pooled (``ci_unit`` episode). ``seed_means`` lists every seed's mean;
    with several seeds ``runs`` holds each seed's own per-episode interval. With the task's random and
    expert returns, ``normalised`` holds the same mean and interval as normalised scores (an affine
    map, so the interval maps exactly).
    """
    if not returns_by_seed:
        raise ValueError("returns_by_seed: expected at least one training seed")
    seeds = sorted(returns_by_seed)
    runs = {seed: np.asarray(returns_by_seed[seed], dtype=np.float64).ravel() for seed in seeds}
    if len(seeds) >= MIN_SEEDS_FOR_SEED_CI:
        summary = confidence_interval([runs[s].mean() for s in seeds]) | {"ci_unit": "training_seed"}
    else:
        summary = confidence_interval(np.concatenate([runs[s] for s in seeds])) | {"ci_unit": "episode"}
    summary |= {"episodes": int(sum(len(r) for r in runs.values())), "train_seeds": seeds,
                "seed_means": {str(s): float(runs[s].mean()) for s in seeds}}
    if len(seeds) > 1:
        summary["runs"] = {str(s): confidence_interval(runs[s]) | {"ci_unit": "episode"} for s in seeds}
    if random_return is not None and expert_return is not None:
        for entry in [summary, *summary.get("runs", {}).values()]:
            entry["normalised"] = {key: None if entry[key] is None else
                                   float(normalised_score(entry[key], random_return, expert_return))
                                   for key in ("mean", "ci_low", "ci_high")}
    return summary


def ratio_to_teacher(group: dict, teacher: dict, teacher_seed: int | None = None) -> float:
    """``group`` mean / the teacher's mean: of the teacher run ``teacher_seed`` (the one a student was
    distilled from), or of the teacher group's mean over its seeds (None)."""
    if teacher_seed is None:
        return group["mean"] / teacher["mean"]
    if str(teacher_seed) not in teacher["seed_means"]:
        raise ValueError(f"teacher_seed: {teacher_seed} is not among the teacher's evaluated seeds "
                         f"{list(teacher['seed_means'])}")
    return group["mean"] / teacher["seed_means"][str(teacher_seed)]


AGGREGATE_UNIT = "runs x episodes, stratified by task"


def score_matrix(samples_by_task: dict[str, np.ndarray]) -> np.ndarray:
    """``{task: scores [n]}`` -> ``[n, tasks]`` (every task must have the same number of samples)."""
    lengths = {task: len(v) for task, v in samples_by_task.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"samples_by_task: expected the same number of samples per task, got {lengths}")
    return np.stack([np.asarray(v, dtype=np.float64) for v in samples_by_task.values()], axis=1)


def iqm_summary(samples_by_task: dict[str, np.ndarray], reps: int, seed: int) -> dict:
    """IQM of normalised scores pooled over tasks, with its stratified-bootstrap 95% interval
    (rliable's recommended aggregate). ``samples_by_task[task]``: one score per (run, episode).
    No lists in the record: ``dvc metrics show`` drops them."""
    matrix = score_matrix(samples_by_task)
    return stratified_bootstrap(iqm, [matrix], reps, seed=seed) | {
        "tasks": ", ".join(samples_by_task), "samples_per_task": int(matrix.shape[0]), "ci_unit": AGGREGATE_UNIT}


def improvement_summary(x_by_task: dict[str, np.ndarray], y_by_task: dict[str, np.ndarray], reps: int,
                        seed: int) -> dict:
    """P(X > Y) averaged over tasks (ties 1/2) with its stratified-bootstrap 95% interval, X and Y
    resampled independently within each task."""
    if list(x_by_task) != list(y_by_task):
        raise ValueError(f"x_by_task, y_by_task: expected the same tasks, got {list(x_by_task)} and {list(y_by_task)}")
    x, y = score_matrix(x_by_task), score_matrix(y_by_task)
    return stratified_bootstrap(probability_of_improvement, [x, y], reps, seed=seed) | {
        "tasks": ", ".join(x_by_task), "samples_x": int(x.shape[0]), "samples_y": int(y.shape[0]),
        "ci_unit": AGGREGATE_UNIT}
