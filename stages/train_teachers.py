"""train_teachers stage: the PBRL teachers of one (level, actor type), every study task and seed trained
together as one vectorised group (a `matrix` entry per level and actor type).

    python stages/train_teachers.py --level medium --actor deterministic [--tasks walk] [--seeds 0]
    python stages/train_teachers.py --level medium --sharing ds|oqs   (train_relabelled_teachers, thesis 6.4)

Teacher <task>-<level>-<actor>-<seed> reads D_{i->i} (data/datasets/<task>-<level>.hdf5 with
data/relabelled/<task>-<level>.hdf5's rewards for <task>) and writes data/teachers/<level>-<actor>/<name>.pt
(config, actor, critics), results/teachers/metrics/<level>-<actor>/<name>.json and the learning curve
results/teachers/curves/<level>-<actor>/<name>.tsv. --tasks / --seeds retrain a subset. A rerun resumes from
data/resume/teachers-<level>-<actor>.pt (-wave<k>.pt where a GPU holds fewer runs: learning.group_memory).

``--sharing`` trains the data_sharing section's teachers on relabelled data (deterministic, seed
distill.teacher_seed): ``ds``, per task i one on the union over every task j of D_{j->i}; ``oqs``, per
pair j != i one on D_{j->i}, and per data_sharing substitute its own on D_{base->substitute} and its set's
DS / OQS teachers not trained already. Files as above under <kind>-<level>-deterministic/, named
<task>-from-<tasks>-<level>-deterministic-<seed>. The runs of an entry: the catalogue's teacher_entries.
"""

from __future__ import annotations

import argparse

from common import check_level_and_seed, load_params, require_inputs, run_stage

from mop_core.agents.pbrl import ACTOR_TYPES
from mop_core.config import keys_under
from mop_core.experiment.runs import SHARING_KINDS
from mop_core.experiment.study import study_config, study_device, teacher_grid
from mop_core.learning.runtime import configure_compute, progress_enabled
from mop_core.teachers import TeacherJob, entry_runs, group_lines, teacher_config, train_teacher_group


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", required=True)
    parser.add_argument("--actor", default="deterministic", choices=ACTOR_TYPES)
    parser.add_argument("--tasks", nargs="+", help="a subset of the entry's tasks (default: all)")
    parser.add_argument("--seeds", type=int, nargs="+", help="a subset of the entry's seeds (default: all)")
    parser.add_argument("--sharing", choices=SHARING_KINDS, help="teachers on relabelled data (data_sharing)")
    args = parser.parse_args()

    params = load_params()
    study = study_config(params)
    for seed in args.seeds or [0]:  # the level, and each seed asked for
        check_level_and_seed(study, args.level, seed)
    runs = entry_runs(params, args.level, args.actor, args.sharing, args.tasks, args.seeds)
    config = teacher_config(params, study, args.actor, args.level)
    device = study_device(study)
    jobs = [TeacherJob.of(run) for run in runs]
    require_inputs([path for job in jobs for s in job.sources for path in (s.dataset, s.relabel)], "relabel")
    configure_compute(teacher_grid(params).threads)
    with keys_under("train_teachers"):  # sizes checked against the data: train_teachers.pbrl.batch_size
        records = train_teacher_group(jobs, config, study.seed, runs[0].paths.resume, runs[0].paths.timing, device,
                                      progress_enabled(study.progress), runs[0].entry)
    print("\n".join(group_lines(runs, records)))


if __name__ == "__main__":
    run_stage(main)
