"""train_teachers stage: the PBRL teachers of one (level, actor type), every study task and seed trained
together as one vectorised group (a `matrix` entry per level and actor type).

    python stages/train_teachers.py --level medium --actor deterministic [--tasks walk] [--seeds 0]
    python stages/train_teachers.py --level medium --sharing ds|oqs   (train_shared_teachers, thesis 6.4)

Teacher <task>-<level>-<actor>-<seed> reads D_{i->i} (data/datasets/<task>-<level>.hdf5 with
data/relabelled/<task>-<level>.hdf5's rewards for <task>) and writes
data/teachers/<level>-<actor>/<name>.pt (config, actor, critics), results/teachers/metrics/<level>-<actor>/<name>.json
and the learning curve results/teachers/curves/<level>-<actor>/<name>.tsv. --tasks / --seeds retrain a
subset (a group of one: one teacher alone). A rerun after an interruption resumes from
data/resume/teachers-<level>-<actor>.pt.

``--sharing`` trains the teachers on relabelled data of the data_sharing section (the
train_shared_teachers entries; deterministic, seed distill.teacher_seed): ``ds``, per task i one
teacher on the union over every task j of D_{j->i}; ``oqs``, per pair j != i one on D_{j->i}, and for
each data_sharing substitute its own teacher on D_{base->substitute} and its set's DS / OQS teachers
(those not already trained). Files as above under <kind>-<level>-deterministic/, named
<task>-from-<tasks>-<level>-deterministic-<seed>.
"""

from __future__ import annotations

import argparse

from common import check_level_and_seed, load_params, require_inputs, run_stage

from mop_core.agents.pbrl import ACTOR_TYPES
from mop_core.config import ConfigError, keys_under, require
from mop_core.data import read_json
from mop_core.runs import SHARING_KINDS, TeacherRun, shared_teacher_runs, sharing_teacher_batch
from mop_core.runtime import configure_compute, progress_enabled, resolve_device
from mop_core.study import section, sharing_grid, study_config, teacher_grid
from mop_core.teachers import DataSource, TeacherJob, teacher_config, train_teacher_group


def sharing_runs(params, study, level: str, actor: str, kind: str, tasks: list[str], seeds: list[int] | None
                 ) -> list[TeacherRun]:
    """The data_sharing teachers of ``kind`` at ``level`` among ``tasks`` (their target task) and ``seeds``:
    the catalogue's train_shared_teachers entry (with a substitute task set's teachers of that kind)."""
    grid = sharing_grid(params, study)
    require(level in grid.levels and kind in grid.teachers, "--level/--sharing",
            f"a level of data_sharing.levels {list(grid.levels)} and a kind of data_sharing.teachers "
            f"{list(grid.teachers)}", f"{level} {kind}")
    require(actor == "deterministic", "--actor", "deterministic (data-sharing teachers serve MSE students and "
            "OQS's critics)", actor)
    teacher_seed = section(params, "distill")["teacher_seed"]
    require(seeds is None or list(seeds) == [teacher_seed], "--seeds",
            f"[distill.teacher_seed] ([{teacher_seed}]): data-sharing teachers train that seed only", seeds)
    return [run for run in shared_teacher_runs(study.tasks, level, grid.teachers, teacher_seed, grid.substitutes)
            if run.batch == sharing_teacher_batch(kind, level, actor) and run.task in tasks]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", required=True)
    parser.add_argument("--actor", default="deterministic", choices=ACTOR_TYPES)
    parser.add_argument("--tasks", nargs="+", help="a subset of study.tasks (default: all)")
    parser.add_argument("--seeds", type=int, nargs="+", help="a subset of train_teachers.seeds (default: all)")
    parser.add_argument("--sharing", choices=SHARING_KINDS, help="teachers on relabelled data (data_sharing)")
    args = parser.parse_args()

    params = load_params()
    study, grid = study_config(params), teacher_grid(params)
    known = study.tasks + (sharing_grid(params, study).substitutes if args.sharing else ())
    tasks = list(args.tasks or known)
    seeds = list(args.seeds if args.seeds is not None else grid.seeds)
    for task in tasks:
        if task not in known:
            raise ConfigError(f"--tasks: expected a subset of study.tasks {list(known)}, got {task!r}")
    for seed in seeds:
        check_level_and_seed(study, args.level, seed)
        if seed not in grid.seeds:
            raise ConfigError(f"--seeds: expected a subset of train_teachers.seeds {list(grid.seeds)}, got {seed}")
    if args.sharing:
        runs = sharing_runs(params, study, args.level, args.actor, args.sharing, tasks, args.seeds)
    else:
        runs = [TeacherRun(task, args.level, args.actor, seed) for task in tasks for seed in seeds]
    config = teacher_config(params, study, args.actor)
    device = resolve_device(study.device, "study.device")
    jobs = []
    for run in runs:
        sources = [DataSource(dataset, relabel, run.task, source, run.level)
                   for dataset, relabel, source in zip(run.datasets, run.relabels, run.data_tasks)]
        jobs.append(TeacherJob(run.task, sources[0], run.seed, run.paths, tuple(sources[1:])))
    require_inputs([path for job in jobs for s in job.sources for path in (s.dataset, s.relabel)], "relabel")

    configure_compute(grid.threads)
    batch = runs[0].batch
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
