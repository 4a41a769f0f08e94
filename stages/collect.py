"""collect stage: per task, train TD3 online, snapshot medium/expert, write the offline datasets.

    python stages/collect.py

All tasks run in parallel, one single-threaded process per task (``collect.parallel``).
Outputs: data/behaviour/<task>/{medium,expert}.pt, data/datasets/<task>-<level>.hdf5,
results/collect/datasets/<task>-<level>.json (readable with `dvc metrics show <path>`),
results/collect/curves/<task>.tsv
(dvc plots), results/collect/metrics.json (snapshot returns, the uniformly random policy's return
R_random of the normalised scores) and results/timings/collect.json (seconds per task, the machine and
its float path: mop_core/float_path.py).
"""

from __future__ import annotations

import time

from common import load_params, run_stage

from mop_core.collect import collect_configs, collect_metrics, collect_tasks, collect_timing
from mop_core.data import write_json
from mop_core.experiment.study import study_config, study_device
from mop_core.float_path import float_path
from mop_core.learning.runtime import progress_enabled
from mop_core.storage.layout import COLLECT_METRICS, collect_paths, timing_file
from mop_core.storage.timings import write_timing


def main() -> None:
    params = load_params()
    study = study_config(params)
    parallel, config = collect_configs(params, study)
    device = str(study_device(study))
    started = time.perf_counter()
    summaries = collect_tasks([(task, collect_paths(task)) for task in study.tasks], config, study.seed,
                              device, progress_enabled(study.progress), parallel.workers, parallel.threads_per_worker,
                              study.cuda_matmul)
    seconds = time.perf_counter() - started
    write_json(COLLECT_METRICS, collect_metrics(summaries))
    write_timing(timing_file("collect"), seconds, device, tasks=collect_timing(summaries), workers=parallel.workers,
                 threads_per_worker=parallel.threads_per_worker,
                 float_path=float_path())  # this machine's rounding: other machines may train other data
    for task, s in summaries.items():
        print(f"{task}: medium {s['snapshots']['medium']['return_mean']:.1f} "
              f"expert {s['snapshots']['expert']['return_mean']:.1f} random {s['random']['return_mean']:.1f} "
              f"({s['total_seconds']:.0f} s)")


if __name__ == "__main__":
    run_stage(main, __doc__)
