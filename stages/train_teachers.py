"""train_teachers stage: one PBRL teacher per (task, level, actor type, seed), a `matrix` entry each.

    python stages/train_teachers.py --task walk --level medium --actor deterministic --seed 0

Reads D_{i->i} (data/datasets/<task>-<level>.hdf5 with data/relabelled/<task>-<level>.hdf5's
rewards for <task>) and writes data/teachers/<name>.pt (config, actor, critics),
results/teachers/metrics/<name>.json and the learning curve results/teachers/curves/<name>.tsv.
A rerun after an interruption resumes from data/resume/teachers-<name>.pt.
"""

from __future__ import annotations

import argparse

from common import check_level_and_seed, load_params, require_inputs, run_stage

from mop_core.agents.pbrl import ACTOR_TYPES
from mop_core.config import ConfigError, keys_under
from mop_core.data import read_json
from mop_core.runs import TeacherRun
from mop_core.runtime import configure_compute, progress_enabled, resolve_device
from mop_core.study import study_config, teacher_grid
from mop_core.teachers import DataSource, teacher_config, train_teacher


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--level", required=True)
    parser.add_argument("--actor", default="deterministic", choices=ACTOR_TYPES)
    parser.add_argument("--seed", type=int, required=True)
    args = parser.parse_args()

    params = load_params()
    study = study_config(params)
    if args.task not in study.tasks:
        raise ConfigError(f"--task: expected one of study.tasks {list(study.tasks)}, got {args.task!r}")
    check_level_and_seed(study, args.level, args.seed)
    run = TeacherRun(args.task, args.level, args.actor, args.seed)
    config, threads = teacher_config(params, study, run.actor), teacher_grid(params).threads
    device = resolve_device(study.device, "study.device")
    source = DataSource(run.dataset, run.relabel, run.task, run.task, run.level)
    require_inputs([source.dataset, source.relabel], "relabel")

    configure_compute(threads)
    with keys_under("train_teachers"):  # sizes checked against the data: train_teachers.pbrl.batch_size
        metrics = train_teacher(run.task, source, config, run.seed, study.seed, run.paths,
                                device, progress_enabled(study.progress))
    timing = read_json(run.paths.timing)
    print(f"{run.name}: return {metrics['return_mean']:.1f} +- {metrics['return_std']:.1f} "
          f"(dataset {metrics['dataset_return_mean']:.1f}, ratio {metrics['return_ratio']:.2f}) "
          f"in {timing['seconds']:.0f} s, {timing['steps_per_second']:.0f} updates/s")


if __name__ == "__main__":
    run_stage(main)
