"""Online evaluation of a study's policies: jobs, episode seeds and the processes that run them.

A job is one policy rolled out on one task: ``episodes`` episodes, all of a job's walkers stepped
together (``rollout_envs`` at a time); jobs run in ``workers`` single-threaded processes. Every
policy sees the same episode seeds (common random numbers), so differences between policies are not
differences between start states. Which jobs a study has is the catalogue's business
(:meth:`mop_core.experiment.catalogue.Catalogue.eval_jobs`); their confidence intervals and aggregates are
:mod:`mop_core.statistics`'; :mod:`mop_core.eval_study` puts them together.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from mop_core.experiment.catalogue import Job
from mop_core.experiment.study import GAUSSIAN_ACTIONS, EvalConfig  # noqa: F401  (GAUSSIAN_ACTIONS: the eval stage's vocabulary)
from mop_core.learning.runtime import derive_seeds, parallel_map
from mop_core.policies import load_policy
from mop_core.walker.rollout import episode_returns


def episode_seeds(study_seed: int, config: EvalConfig) -> list[int]:
    """``episodes`` environment seeds, the same for every policy and task."""
    base = derive_seeds([study_seed, "eval"], ("episodes",))["episodes"]
    return [base + j for j in range(config.episodes)]


def run_job(job: Job, seeds: list[int], episode_length: int, rollout_envs: int) -> np.ndarray:
    """Returns ``[episodes]`` of one job."""
    policy = load_policy(job.checkpoint, job.task_id, job.sample_seed)
    return episode_returns(policy, job.eval_task, seeds, episode_length, rollout_envs)


def run_jobs(jobs: Sequence[Job], seeds: list[int], episode_length: int, config: EvalConfig,
             progress: bool = False) -> list[np.ndarray]:
    """Every job's returns, in job order; ``config.workers`` processes share the jobs."""
    args = [(job, seeds, episode_length, config.rollout_envs) for job in jobs]
    return parallel_map(run_job, args, config.workers, "eval", progress)


