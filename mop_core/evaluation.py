"""Online evaluation of every policy of a study: returns, 95% confidence intervals, cross-task tables.

A job is one policy rolled out on one task: ``seeds x episodes`` episodes, all of a job's walkers
stepped together (``rollout_envs`` at a time); jobs run in ``workers`` single-threaded processes.
Every policy sees the same episode seeds (common random numbers), so differences between policies
are not differences between start states.

Confidence intervals (:func:`confidence_interval`) are Student-t intervals over independent units:
a group of models trained with several seeds uses one unit per training seed (its mean over all
its evaluation episodes), as the thesis's figures do; a model trained once uses one unit per
evaluation seed.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
from scipy import stats
from tqdm import tqdm

from mop_core.config import require
from mop_core.rollout import episode_returns
from mop_core.runtime import derive_seeds, set_threads

Policy = Callable[[np.ndarray], np.ndarray]
POLICY_KINDS = ("behaviour", "teacher", "multitask", "student")


@dataclass(frozen=True)
class EvalConfig:
    """How much evaluation: ``seeds`` groups of ``episodes`` episodes per (policy, task)."""

    seeds: int = 3  # evaluation seeds (the CI unit of a model trained once)
    episodes: int = 10  # episodes per evaluation seed
    rollout_envs: int = 30  # walkers stepped together in one process
    workers: int = 2  # processes (one torch thread each)

    def __post_init__(self) -> None:
        require(self.seeds >= 2, "seeds", "an integer >= 2 (a confidence interval needs two units)", self.seeds)
        for name in ("episodes", "rollout_envs", "workers"):
            require(getattr(self, name) >= 1, name, "a positive integer", getattr(self, name))


@dataclass(frozen=True)
class PolicySpec:
    """Which checkpoint to act with and, for a task-conditioned policy, under which task id."""

    kind: str  # behaviour | teacher | multitask | student
    path: Path
    task: str | None = None  # task id to condition on (multitask baseline and students)


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
        from mop_core.collect import load_actor

        payload = torch.load(spec.path, map_location="cpu", weights_only=False)
        if not isinstance(payload, dict) or "td3_config" not in payload:
            raise ValueError(f"{spec.path}: expected a behaviour snapshot of the collect stage")
        return load_actor(payload)
    if spec.kind == "teacher":
        from mop_core.teachers import load_teacher

        return load_teacher(spec.path).act
    if spec.kind == "multitask":
        from mop_core.teachers import load_multitask

        return load_multitask(spec.path).policy(spec.task)
    if spec.kind == "student":
        from mop_core.distill.run import load_student

        return load_student(spec.path).policy(spec.task)
    raise ValueError(f"kind: expected one of {POLICY_KINDS}, got {spec.kind!r}")


def episode_seeds(study_seed: int, config: EvalConfig) -> list[list[int]]:
    """``[seeds][episodes]`` environment seeds, the same for every policy and task."""
    bases = [derive_seeds([study_seed, "eval", k], ("episodes",))["episodes"] for k in range(config.seeds)]
    return [[base + j for j in range(config.episodes)] for base in bases]


def run_job(job: Job, seeds: list[list[int]], episode_length: int, rollout_envs: int) -> np.ndarray:
    """Returns ``[len(seeds), episodes]`` of one job."""
    policy = load_policy(job.policy)
    flat = [s for group in seeds for s in group]
    return episode_returns(policy, job.eval_task, flat, episode_length, rollout_envs).reshape(len(seeds), -1)


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
        with ProcessPoolExecutor(max_workers=min(workers, len(args), os.cpu_count() or 1)) as pool:
            for result in pool.map(_in_worker, [(fn, a) for a in args]):
                results.append(result)
                bar.update(1)
    bar.close()
    return results


def run_jobs(jobs: Sequence[Job], seeds: list[list[int]], episode_length: int, config: EvalConfig,
             progress: bool = False) -> list[np.ndarray]:
    """Every job's returns, in job order; ``config.workers`` processes share the jobs."""
    args = [(job, seeds, episode_length, config.rollout_envs) for job in jobs]
    return parallel_map(run_job, args, config.workers, "eval", progress)


def confidence_interval(values: Sequence[float], confidence: float = 0.95) -> dict[str, float | int | None]:
    """Mean, sample standard deviation and the Student-t confidence interval of the mean.

    ``mean +- t_{(1+confidence)/2, n-1} * sd / sqrt(n)``; with one value the interval is undefined
    (None).
    """
    x = np.asarray(values, dtype=np.float64)
    n = len(x)
    if n == 0:
        raise ValueError("values: expected at least one value")
    mean = float(x.mean())
    if n == 1:
        return {"mean": mean, "std": None, "ci_low": None, "ci_high": None, "n": 1}
    sd = float(x.std(ddof=1))
    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1) * sd / math.sqrt(n))
    return {"mean": mean, "std": sd, "ci_low": mean - half, "ci_high": mean + half, "n": n}


def summarise_group(returns_by_seed: dict[int, np.ndarray]) -> dict:
    """CI of one group (one policy family on one task) from ``{train_seed: returns [seeds, episodes]}``.

    Several training seeds: one unit per training seed; one training seed: one unit per evaluation seed.
    """
    if len(returns_by_seed) > 1:
        units = [float(r.mean()) for r in returns_by_seed.values()]
        unit = "training_seed"
    else:
        (only,) = returns_by_seed.values()
        units = [float(row.mean()) for row in only]
        unit = "eval_seed"
    episodes = int(sum(r.size for r in returns_by_seed.values()))
    return confidence_interval(units) | {"ci_unit": unit, "episodes": episodes,
                                        "train_seeds": sorted(returns_by_seed)}
