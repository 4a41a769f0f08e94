"""distill stage: one multi-task student per (loss, pairing, seed), a `matrix` entry each.

    python stages/distill.py --loss mse --pairing medium --seed 0

Reads the teachers the catalogue names for the student (per study task: the pairing's level, the
loss's actor type, seed ``distill.teacher_seed``) and, for offline states, the datasets they were
trained on, after checking them against data/student_inputs/<name>.json (the student_inputs stage's
record, this entry's only data dependency in dvc.yaml). Writes data/students/<loss>-<pairing>-<seed>.pt, the metrics
results/students/metrics/<name>.json, the learning curve results/students/curves/<name>.tsv, one curve
per logged per-state tau in results/students/tau/<name>/ and the timing results/timings/students/<name>.json.
"""

from __future__ import annotations

import argparse

from common import load_params, require_inputs, run_stage

from mop_core.catalogue import LOSS_ACTORS, make_student
from mop_core.config import ConfigError, keys_under, require
from mop_core.data import read_json
from mop_core.distill.distiller import distill_config
from mop_core.distill.losses import LOSSES
from mop_core.distill.run import StudentSources, check_student_files, distill_student, print_summary, write_tau_curves
from mop_core.layout import student_inputs_file
from mop_core.plots import read_curve
from mop_core.runtime import configure_compute, progress_enabled, resolve_device
from mop_core.study import distill_grid, pairing_levels, study_config
from mop_core.teachers import teacher_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loss", required=True, choices=tuple(LOSSES))
    parser.add_argument("--pairing", required=True)
    parser.add_argument("--seed", type=int, required=True)
    args = parser.parse_args()

    params = load_params()
    study = study_config(params)
    grid, config = distill_grid(params, study, LOSS_ACTORS), distill_config(params, args.loss)
    require(args.seed >= 0, "--seed", "a non-negative integer", args.seed)
    if len(study.tasks) < 2:
        raise ConfigError(f"study.tasks: a multi-task student needs at least two tasks, got {list(study.tasks)}")
    run = make_student(args.loss, args.pairing, args.seed, study.tasks, pairing_levels(args.pairing, study),
                       grid.teacher_seed)
    device = resolve_device(study.device, "study.device")
    require_inputs([t.paths.checkpoint for t in run.teachers], "train_teachers")
    require_inputs(run.datasets, "collect")
    require_inputs([student_inputs_file(run.name)], "student_inputs")
    check_student_files(run, study.seed, lambda actor: teacher_config(params, study, actor),
                        student_inputs_file(run.name))

    configure_compute(grid.threads)
    sources = StudentSources(run.tasks, tuple(t.paths.checkpoint for t in run.teachers), run.datasets)
    with keys_under("distill"):  # sizes checked against the states: distill.batch_size
        metrics = distill_student(sources, config, grid.schedule, study.episode_length,
                                  args.seed, study.seed, run.paths, device, progress_enabled(study.progress),
                                  run.name)
    write_tau_curves(run.tau_dir, read_curve(run.paths.curve))
    print_summary(run.name, metrics, read_json(run.paths.timing))


if __name__ == "__main__":
    run_stage(main)
