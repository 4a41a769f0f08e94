"""train_multitask stage: the naive multi-task PBRL baseline (thesis 5.1.2), every seed of a level as one group.

    python stages/train_multitask.py --level medium [--seeds 0]

One task-conditioned actor for all study tasks, a critic ensemble per task, batches alternating
between the tasks' datasets; the PBRL settings are train_teachers' (the thesis changes only the
actor). The level's seeds train together as one vectorised group (a `matrix` entry per level; in
waves where a GPU holds fewer); --seeds retrains a subset. Writes data/multitask/<level>/<level>-<seed>.pt,
results/multitask/metrics/<level>/<level>-<seed>.json and results/multitask/curves/<level>/<level>-<seed>.tsv;
a rerun resumes from data/resume/multitask-<level>.pt.
"""

from __future__ import annotations

import argparse

from common import check_level_and_seed, load_params, require_inputs, run_stage

from mop_core.config import ConfigError, keys_under
from mop_core.experiment.study import study_config, study_device, teacher_grid
from mop_core.learning.runtime import configure_compute, progress_enabled
from mop_core.multitask import multitask_runs, train_multitask
from mop_core.storage.files import read_json
from mop_core.storage.layout import dataset_file, relabel_file
from mop_core.teachers import DataSource, teacher_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", required=True)
    parser.add_argument("--seeds", type=int, nargs="+", help="a subset of train_multitask.seeds (default: all)")
    args = parser.parse_args()

    params = load_params()
    study = study_config(params)
    for seed in args.seeds or [0]:
        check_level_and_seed(study, args.level, seed)
    if len(study.tasks) < 2:
        raise ConfigError(f"study.tasks: the multi-task baseline needs at least two tasks, got {list(study.tasks)}")
    runs = multitask_runs(params, args.level, args.seeds)
    config = teacher_config(params, study, "deterministic", args.level)
    device = study_device(study)
    sources = [DataSource(dataset_file(t, args.level), relabel_file(t, args.level), t, t, args.level)
               for t in study.tasks]
    require_inputs([p for s in sources for p in (s.dataset, s.relabel)], "relabel")

    configure_compute(teacher_grid(params).threads)
    with keys_under("train_teachers"):  # its PBRL settings are train_teachers'
        records = train_multitask(study.tasks, sources, config, [run.seed for run in runs], study.seed,
                                  [run.paths for run in runs], runs[0].paths.resume, runs[0].paths.timing, device,
                                  progress_enabled(study.progress), args.level)
    for run, metrics in zip(runs, records):
        print("\n".join(f"multitask {run.name} on {task}: return {metrics[task]['return_mean']:.1f} +- "
                        f"{metrics[task]['return_std']:.1f} (dataset {metrics[task]['dataset_return_mean']:.1f})"
                        for task in run.tasks))
    print(f"{len(runs)} trained in {read_json(runs[0].paths.timing)['seconds']:.0f} s")


if __name__ == "__main__":
    run_stage(main)
