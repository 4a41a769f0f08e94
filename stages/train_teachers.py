"""train_teachers stage: the PBRL teachers of one (level, actor type), every study task and seed trained
together as one vectorised group (a `matrix` entry per level and actor type).

    python stages/train_teachers.py --level medium --actor deterministic [--tasks walk] [--seeds 0]

Teacher <task>-<level>-<actor>-<seed> reads D_{i->i} (data/datasets/<task>-<level>.hdf5 with
data/relabelled/<task>-<level>.hdf5's rewards for <task>) and writes
data/teachers/<level>-<actor>/<name>.pt (config, actor, critics), results/teachers/metrics/<level>-<actor>/<name>.json
and the learning curve results/teachers/curves/<level>-<actor>/<name>.tsv. --tasks / --seeds retrain a
subset (a group of one: one teacher alone). A rerun after an interruption resumes from
data/resume/teachers-<level>-<actor>.pt.
"""

from __future__ import annotations

import argparse

from common import check_level_and_seed, load_params, require_inputs, run_stage

from mop_core.agents.pbrl import ACTOR_TYPES
from mop_core.config import ConfigError, keys_under
from mop_core.data import read_json
from mop_core.runs import TeacherRun, teacher_batch
from mop_core.runtime import configure_compute, progress_enabled, resolve_device
from mop_core.study import study_config, teacher_grid
from mop_core.teachers import DataSource, TeacherJob, teacher_config, train_teacher_group


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", required=True)
    parser.add_argument("--actor", default="deterministic", choices=ACTOR_TYPES)
    parser.add_argument("--tasks", nargs="+", help="a subset of study.tasks (default: all)")
    parser.add_argument("--seeds", type=int, nargs="+", help="a subset of train_teachers.seeds (default: all)")
    args = parser.parse_args()

    params = load_params()
    study, grid = study_config(params), teacher_grid(params)
    tasks = list(args.tasks or study.tasks)
    seeds = list(args.seeds if args.seeds is not None else grid.seeds)
    for task in tasks:
        if task not in study.tasks:
            raise ConfigError(f"--tasks: expected a subset of study.tasks {list(study.tasks)}, got {task!r}")
    for seed in seeds:
        check_level_and_seed(study, args.level, seed)
        if seed not in grid.seeds:
            raise ConfigError(f"--seeds: expected a subset of train_teachers.seeds {list(grid.seeds)}, got {seed}")
    runs = [TeacherRun(task, args.level, args.actor, seed) for task in tasks for seed in seeds]
    config = teacher_config(params, study, args.actor)
    device = resolve_device(study.device, "study.device")
    jobs = [TeacherJob(run.task, DataSource(run.dataset, run.relabel, run.task, run.task, run.level), run.seed,
                       run.paths) for run in runs]
    require_inputs([path for job in jobs for path in (job.source.dataset, job.source.relabel)], "relabel")

    configure_compute(grid.threads)
    batch = teacher_batch(args.level, args.actor)
    with keys_under("train_teachers"):  # sizes checked against the data: train_teachers.pbrl.batch_size
        records = train_teacher_group(jobs, config, study.seed, runs[0].paths.resume, runs[0].paths.timing, device,
                                      progress_enabled(study.progress), batch)
    timing = read_json(runs[0].paths.timing)
    for run, metrics in zip(runs, records):
        print(f"{run.name}: return {metrics['return_mean']:.1f} +- {metrics['return_std']:.1f} "
              f"(dataset {metrics['dataset_return_mean']:.1f}, ratio {metrics['return_ratio']:.2f})")
    print(f"{batch}: {len(runs)} teachers in {timing['seconds']:.0f} s, {timing['steps_per_second']:.0f} group "
          "updates/s")


if __name__ == "__main__":
    run_stage(main)
