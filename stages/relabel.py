"""relabel stage: the reward of every transition of every dataset under every study task (and every
data_sharing substitute task).

    python stages/relabel.py

Reads data/datasets/<task>-<level>.hdf5 and writes data/relabelled/<task>-<level>.hdf5 holding
``rewards/<reward task>`` (float64) for each task, plus results/relabel/metrics.json with the
exactness checks (recomputed vs stored dm_control rewards; vectorised vs physics replay).
"""

from __future__ import annotations

import time

from common import load_params, run_stage

from mop_core.config import ConfigError
from mop_core.data import write_json
from mop_core.experiment.study import sharing_grid, study_config, typed_section
from mop_core.learning.runtime import configure_compute
from mop_core.relabel import RelabelConfig, relabel_dataset
from mop_core.storage.layout import RELABEL_METRICS, dataset_file, relabel_file, timing_file
from mop_core.storage.timings import per_second, write_timing


def main() -> None:
    params = load_params()
    study = study_config(params)
    config = typed_section(params, "relabel", RelabelConfig)
    # the study's tasks and the substitutes, which learn from their base task's data (data_sharing)
    reward_tasks = study.tasks + sharing_grid(params, study).substitutes
    sources = [(task, level) for task in study.tasks for level in study.levels]
    missing = [str(dataset_file(t, lv)) for t, lv in sources if not dataset_file(t, lv).is_file()]
    if missing:
        raise ConfigError(f"study.tasks: no dataset for {', '.join(missing)}; run the collect stage first")
    configure_compute(1)
    started = time.perf_counter()
    metrics = {}
    for task, level in sources:
        metrics[f"{task}-{level}"] = relabel_dataset(dataset_file(task, level), relabel_file(task, level),
                                                     reward_tasks, config, source_task=task, level=level)
    write_json(RELABEL_METRICS, metrics)
    seconds = time.perf_counter() - started
    relabelled = sum(m["transitions"] for m in metrics.values()) * len(reward_tasks)
    timing = write_timing(timing_file("relabel"), seconds, datasets=len(sources),
                          rewards_per_second=per_second(relabelled, seconds))
    print(f"relabelled {len(sources)} datasets under {len(reward_tasks)} tasks in {timing['seconds']} s")


if __name__ == "__main__":
    run_stage(main, __doc__)
