"""distill stage: the multi-task students of one (loss, pairing), every seed trained together, a `matrix` entry each.

    python stages/distill.py --loss mse --pairing medium [--seeds 0 2]
    python stages/distill.py --loss mse --pairing medium --variant w16   (distill_width, distill_ranking)
    python stages/distill.py --loss mse --pairing medium --variant single_stand   (distill_single)

Trains one student per seed of ``distill.seeds`` (or of ``--seeds``, a subset: a group of one reruns a
single seed) as one vectorised group (mop_core.distill.distiller.Distiller: each run its own
initialisation, states and sampling stream; the same result as the seeds trained one by one). Reads
the teachers the catalogue names for the students (per study task: the pairing's level, the loss's
actor type, seed ``distill.teacher_seed``) and, for offline states, the datasets they were trained on,
after checking them against data/student_inputs/<loss>-<pairing>.json (the student_inputs stage's
record, this entry's only data dependency in dvc.yaml). Writes, per seed, the student
data/students/<loss>-<pairing>/<loss>-<pairing>-<seed>.pt, its metrics
results/students/metrics/<loss>-<pairing>/<name>.json, its learning curve
results/students/curves/<loss>-<pairing>/<name>.tsv and one curve per logged per-state tau in
results/students/tau/<loss>-<pairing>/<name>/; and the group's timing results/timings/students/<loss>-<pairing>.json.

``--variant`` (w<width>, rank_<ranking loss>: mop_core.distill.variants) trains a common-structure
variant of the students (thesis 6.3; the distill_width and distill_ranking entries): the same
teachers, states and seeds as the plain students, one setting changed; its files use
``<loss>-<variant>-<pairing>`` where the plain ones use ``<loss>-<pairing>``. ``--variant single_<task>``
(the distill_single entries) distils that task's teacher alone into a one-task student: the
no-sharing reference the shared_computation stage measures the multi-task students against.
``--variant on_<dataset>_w<width>`` (distill_composed, thesis 5.2.4) trains them on a composed dataset of
the teachers' rollouts (the compose stage), every hidden layer ``width`` wide; ``--variant data<percent>``
(distill_size) on that share of each task's dataset's whole episodes (the state_shift section);
``--variant <reweight|dagger>_<dataset>_w<width>`` (distill_corrected, thesis 5.3) on a composed or the
offline dataset with that state-shift correction (mop_core.distill.corrections).

``--variant ds | oqs_own | oqs_target`` with ``--pairing <level>`` (the distill_sharing entries, thesis
6.4, the data_sharing section) trains MSE students on the union of the tasks' datasets of that level:
``ds`` imitating the teachers trained on U_j D_{j->i}, ``oqs_<judge>`` the offline Q-switch over task
i's teachers on D_{j->i} (MOP's own for j = i). ``--substitute <task>`` (the distill_substitute
entries) trains them, or plain MOP's students (``--variant mop``), on the study's tasks with that
task in place of its base task (stand_still for stand), on the base task's data relabelled;
files ``mse-<variant>-<task>-<level>``.
"""

from __future__ import annotations

import argparse

from common import load_params, require_inputs, run_stage

from mop_core.artifacts import read_curve
from mop_core.catalogue import (
    LOSS_ACTORS,
    make_sharing_student,
    make_structure_student,
    make_student,
    shift_variants,
    structure_variants,
)
from mop_core.config import ConfigError, keys_under, require
from mop_core.data import read_json
from mop_core.distill.distiller import distill_config
from mop_core.distill.losses import LOSSES
from mop_core.distill.run import (
    StudentSources,
    check_student_files,
    distill_students,
    print_summary,
    write_tau_curves,
)
from mop_core.distill.variants import variant_config
from mop_core.layout import student_inputs_file
from mop_core.runtime import configure_compute, progress_enabled, resolve_device
from mop_core.study import distill_grid, pairing_levels, sharing_grid, study_config
from mop_core.teachers import teacher_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loss", required=True, choices=tuple(LOSSES))
    parser.add_argument("--pairing", required=True)
    parser.add_argument("--variant", default="", help="a common-structure variant: w<width> or rank_<loss>")
    parser.add_argument("--seeds", type=int, nargs="+", default=None,
                        help="a subset of distill.seeds to train (default: all of them)")
    parser.add_argument("--substitute", default="", help="a data_sharing substitute: its task set's students")
    args = parser.parse_args()

    params = load_params()
    study = study_config(params)
    grid, config = distill_grid(params, study, LOSS_ACTORS), distill_config(params, args.loss)
    structure_pairing, variants = structure_variants(params)
    shift_pairing, shift = shift_variants(params)
    sharing = sharing_grid(params, study)
    require(not args.substitute or args.substitute in sharing.substitutes, "--substitute",
            f"one of data_sharing.substitutes {list(sharing.substitutes)}", args.substitute)
    students = sharing.substitute_students if args.substitute else sharing.students
    sharing_variant = args.variant in students and args.pairing in sharing.levels
    require(not args.substitute or sharing_variant, "--variant", f"one of data_sharing.substitute_students "
            f"{list(students)} with a --pairing of data_sharing.levels {list(sharing.levels)}", args.variant)
    shift_variant = args.variant in shift and args.pairing == shift_pairing
    require(not args.variant or (args.variant in variants and args.pairing == structure_pairing) or sharing_variant
            or shift_variant, "--variant", f"one of the common_structure variants {list(variants)} with --pairing "
            f"{structure_pairing}, of the state_shift variants {list(shift)} with --pairing {shift_pairing}, or of "
            f"data_sharing.students {list(sharing.students)} with a --pairing of data_sharing.levels "
            f"{list(sharing.levels)}", args.variant)
    require(not sharing_variant or args.loss == "mse", "--loss", "mse for the data-sharing students", args.loss)
    config = variant_config(config, args.variant)
    seeds = list(grid.seeds) if args.seeds is None else args.seeds
    require(len(set(seeds)) == len(seeds) and set(seeds) <= set(grid.seeds), "--seeds",
            f"distinct seeds of distill.seeds {list(grid.seeds)}", seeds)
    if len(study.tasks) < 2:
        raise ConfigError(f"study.tasks: a multi-task student needs at least two tasks, got {list(study.tasks)}")
    levels = pairing_levels(args.pairing, study)
    if sharing_variant:
        runs = [make_sharing_student(args.variant, args.pairing, seed, study.tasks, grid.teacher_seed,
                                     args.substitute) for seed in seeds]
    elif shift_variant:
        require(args.loss == "mse", "--loss", "mse for the state_shift students", args.loss)
        runs = [make_student("mse", args.pairing, seed, study.tasks, levels, grid.teacher_seed, args.variant)
                for seed in seeds]
    elif args.variant:
        require(args.loss == "mse", "--loss", "mse for the common_structure students", args.loss)
        runs = [make_structure_student(args.variant, args.pairing, seed, study.tasks, levels, grid.teacher_seed)
                for seed in seeds]
    else:
        runs = [make_student(args.loss, args.pairing, seed, study.tasks, levels, grid.teacher_seed)
                for seed in seeds]
    batch = runs[0].batch
    device = resolve_device(study.device, "study.device")
    require_inputs([t.paths.checkpoint for t in runs[0].all_teachers], "train_teachers")
    require_inputs(runs[0].datasets, "compose" if runs[0].composed else "collect")
    require_inputs([*runs[0].heldout_datasets, *runs[0].reference_datasets], "compose")
    require_inputs([student_inputs_file(batch)], "student_inputs")
    check_student_files(runs, study.seed, lambda actor: teacher_config(params, study, actor),
                        student_inputs_file(batch))

    configure_compute(grid.threads)
    first = runs[0]
    sources = StudentSources(first.tasks, tuple(t.paths.checkpoint for t in first.teachers), first.datasets,
                             first.state_datasets,
                             tuple(tuple(t.paths.checkpoint for t in per_task) for per_task in first.candidates),
                             args.variant.split("_", 1)[1] if first.candidates else "own",
                             first.heldout_datasets, first.reference_datasets)
    group_paths = first.paths  # the group's resume file and timing record
    with keys_under("distill"):  # sizes checked against the states: distill.batch_size
        records = distill_students(sources, config, grid.schedule, study.episode_length, seeds, study.seed,
                                   [run.paths for run in runs], group_paths.resume, group_paths.timing, device,
                                   progress_enabled(study.progress), batch)
    timing = read_json(group_paths.timing)
    for run, metrics in zip(runs, records):
        write_tau_curves(run.tau_dir, read_curve(run.paths.curve))
        print_summary(run.name, metrics)
    print(f"{batch}: {len(runs)} students trained together in {timing['seconds']:.0f} s, "
          f"{timing['steps_per_second']:.0f} group steps/s")


if __name__ == "__main__":
    run_stage(main)
