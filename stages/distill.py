"""distill stage: one multi-task student per (loss, pairing, seed), a `matrix` entry each.

    python stages/distill.py --loss mse --pairing medium --seed 0

Reads the teachers data/teachers/<task>-<level>-<actor>-<teacher_seed>.pt of every study task (the
levels of the pairing; Gaussian teachers for the KL loss) and, for offline states, the datasets
they were trained on. Writes data/students/<loss>-<pairing>-<seed>.pt, the metrics
results/students/metrics/<name>.json and the learning curve results/students/curves/<name>.tsv.
"""

from __future__ import annotations

import argparse

from common import dataset_file, load_params, require_inputs, run_paths, run_stage, study_config, teacher_name
from distill_config import distill_config, distill_grid, pairing_levels, student_name, teacher_actor
from teacher_config import teacher_config

from mop_core.config import ConfigError, keys_under, require
from mop_core.data import read_dataset_attrs
from mop_core.distill.losses import LOSSES
from mop_core.distill.run import StudentSources, distill_student
from mop_core.runtime import progress_enabled, resolve_device, set_threads
from mop_core.teachers import check_teacher_checkpoint


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loss", required=True, choices=LOSSES)
    parser.add_argument("--pairing", required=True)
    parser.add_argument("--seed", type=int, required=True)
    args = parser.parse_args()

    params = load_params()
    study = study_config(params)
    grid = distill_grid(params, study)
    config = distill_config(params, args.loss)
    levels = pairing_levels(args.pairing, study)
    require(args.seed >= 0, "--seed", "a non-negative integer", args.seed)
    if len(study.tasks) < 2:
        raise ConfigError(f"study.tasks: a multi-task student needs at least two tasks, got {list(study.tasks)}")
    device = resolve_device(study.device, "study.device")
    actor = teacher_actor(args.loss)
    teachers = tuple(run_paths(teacher_name(t, lv, actor, grid.teacher_seed)).checkpoint
                     for t, lv in zip(study.tasks, levels))
    datasets = tuple(dataset_file(t, lv) for t, lv in zip(study.tasks, levels))
    require_inputs(teachers, "train_teachers")
    require_inputs(datasets, "collect")
    for task, level, teacher, dataset in zip(study.tasks, levels, teachers, datasets):
        check_teacher_checkpoint(teacher, task, level, grid.teacher_seed, study.seed,
                                 teacher_config(params, study, actor), read_dataset_attrs(dataset)["content_sha256"])

    set_threads(grid.threads)
    name = student_name(args.loss, args.pairing, args.seed)
    with keys_under("distill"):  # sizes checked against the states: distill.batch_size
        metrics = distill_student(StudentSources(study.tasks, teachers, datasets), config, grid.schedule,
                                  study.episode_length, args.seed, study.seed, run_paths(name, "students"), device,
                                  progress_enabled(study.progress), name)
    for task in study.tasks:
        m = metrics[task]
        print(f"student {name} on {task}: return {m['return_mean']:.1f} +- {m['return_std']:.1f} "
              f"(teacher {m['teacher_return_mean']:.1f}, ratio {m['student_to_teacher']:.2f})")
    print(f"trained in {metrics['train_seconds']:.0f} s, {metrics['steps_per_second']:.0f} steps/s")


if __name__ == "__main__":
    run_stage(main)
