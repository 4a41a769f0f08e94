"""train_multitask stage: the naive multi-task PBRL baseline (thesis 5.1.2), one per (level, seed).

    python stages/train_multitask.py --level medium --seed 0

One task-conditioned actor for all study tasks, a critic ensemble per task, batches alternating
between the tasks' datasets; the PBRL settings are train_teachers' (the thesis changes only the
actor). Writes data/multitask/<level>-<seed>.pt, results/multitask/metrics/<level>-<seed>.json and
results/multitask/curves/<level>-<seed>.tsv.
"""

from __future__ import annotations

import argparse

from common import check_level_and_seed, load_params, require_inputs, run_stage

from mop_core.config import ConfigError, keys_under
from mop_core.data import read_json
from mop_core.experiment.runs import MultitaskRun
from mop_core.experiment.study import multitask_grid, study_config, teacher_grid
from mop_core.learning.runtime import configure_compute, progress_enabled, resolve_device
from mop_core.storage.layout import dataset_file, relabel_file
from mop_core.teachers import DataSource, teacher_config, train_multitask


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", required=True)
    parser.add_argument("--seed", type=int, required=True)
    args = parser.parse_args()

    params = load_params()
    study = study_config(params)
    check_level_and_seed(study, args.level, args.seed)
    multitask_grid(params, study)  # the section's keys, checked even when the stage is run by hand
    if len(study.tasks) < 2:
        raise ConfigError(f"study.tasks: the multi-task baseline needs at least two tasks, got {list(study.tasks)}")
    run = MultitaskRun(args.level, args.seed, study.tasks)
    config, threads = teacher_config(params, study, "deterministic", args.level), teacher_grid(params).threads
    device = resolve_device(study.device, "study.device")
    sources = [DataSource(dataset_file(t, run.level), relabel_file(t, run.level), t, t, run.level) for t in run.tasks]
    require_inputs([p for s in sources for p in (s.dataset, s.relabel)], "relabel")

    configure_compute(threads)
    with keys_under("train_teachers"):  # its PBRL settings are train_teachers'
        metrics = train_multitask(run.tasks, sources, config, run.seed, study.seed, run.paths,
                                  device, progress_enabled(study.progress))
    for task in run.tasks:
        m = metrics[task]
        print(f"multitask {run.name} on {task}: return {m['return_mean']:.1f} +- {m['return_std']:.1f} "
              f"(dataset {m['dataset_return_mean']:.1f})")
    print(f"trained in {read_json(run.paths.timing)['seconds']:.0f} s")


if __name__ == "__main__":
    run_stage(main)
