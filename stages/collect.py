"""collect stage: per task, train TD3 online, snapshot medium/expert, write the offline datasets.

All tasks run in parallel, one single-threaded process per task (``collect.workers`` at a time):
``dvc repro`` runs stages one after another, so one stage per task would leave a core idle.

Outputs: data/behaviour/<task>/{medium,expert}.pt, data/datasets/<task>-<level>.hdf5,
results/collect/datasets/<task>-<level>.json (dvc metrics), results/collect/curves/<task>.tsv
(dvc plots) and results/collect/metrics.json (snapshot returns, the uniformly random policy's return
R_random of the normalised scores, and times per task).
"""

from __future__ import annotations

import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

from common import (
    RESULTS,
    StudyConfig,
    behaviour_checkpoint,
    dataset_file,
    load_params,
    run_stage,
    section,
    study_config,
)

from mop_core.collect import LEVELS, CollectConfig, CollectPaths, collect_task
from mop_core.config import from_mapping, require
from mop_core.data import write_json
from mop_core.runtime import die_with_parent, progress_enabled, resolve_device, set_threads


@dataclass(frozen=True)
class ParallelConfig:
    """collect.parallel: how many task processes run at once and their torch threads."""

    workers: int = 2  # task processes at a time (use the number of cores)
    threads_per_worker: int = 1  # torch threads in each process

    def __post_init__(self) -> None:
        require(self.workers >= 1, "workers", "a positive integer", self.workers)
        require(self.threads_per_worker >= 1, "threads_per_worker", "a positive integer", self.threads_per_worker)


def collect_configs(params: dict[str, Any], study: StudyConfig) -> tuple[ParallelConfig, CollectConfig]:
    raw = dict(section(params, "collect"))
    parallel = from_mapping(ParallelConfig, raw.pop("parallel", {}), "collect.parallel")
    config = from_mapping(CollectConfig, raw | {"episode_length": study.episode_length}, "collect")
    return parallel, config


def paths_for(task: str) -> CollectPaths:
    return CollectPaths(
        checkpoints={level: behaviour_checkpoint(task, level) for level in ("medium", "expert")},
        datasets={level: dataset_file(task, level) for level in LEVELS},
        dataset_metrics={level: RESULTS / "collect" / "datasets" / f"{task}-{level}.json" for level in LEVELS},
        curve=RESULTS / "collect" / "curves" / f"{task}.tsv",
    )


def _worker(task: str, config: CollectConfig, seed: int, device: str, progress: bool, position: int,
            threads: int) -> dict:
    set_threads(threads)
    return collect_task(task, config, seed, paths_for(task), device, progress, position)


def main() -> None:
    params = load_params()
    study = study_config(params)
    parallel, config = collect_configs(params, study)
    device = str(resolve_device(study.device, "study.device"))
    progress = progress_enabled(study.progress)

    started = time.perf_counter()
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(parallel.workers, len(study.tasks)), mp_context=context,
                             initializer=die_with_parent) as pool:
        futures = {task: pool.submit(_worker, task, config, study.seed, device, progress, i,
                                     parallel.threads_per_worker) for i, task in enumerate(study.tasks)}
        summaries = {task: future.result() for task, future in futures.items()}
    metrics = {task: {"medium_return": s["snapshots"]["medium"]["return_mean"],
                      "expert_return": s["snapshots"]["expert"]["return_mean"],
                      "medium_gradient_steps": s["snapshots"]["medium"]["gradient_steps"],
                      "expert_gradient_steps": s["snapshots"]["expert"]["gradient_steps"],
                      "random_return": s["random"]["return_mean"], "random_return_std": s["random"]["return_std"],
                      "random_episodes": s["random"]["episodes"],
                      "seconds": s["total_seconds"]} for task, s in summaries.items()}
    metrics["stage_seconds"] = round(time.perf_counter() - started, 1)
    write_json(RESULTS / "collect" / "metrics.json", metrics)
    for task, s in summaries.items():
        print(f"{task}: medium {s['snapshots']['medium']['return_mean']:.1f} "
              f"expert {s['snapshots']['expert']['return_mean']:.1f} random {s['random']['return_mean']:.1f} "
              f"({s['total_seconds']:.0f} s)")


if __name__ == "__main__":
    run_stage(main)
