"""compose stage: per study task, offline datasets composed from its MOP teacher's rollouts (thesis 5.2.4).

    python stages/compose.py

For each study task, the deterministic teacher of the ``state_shift.pairing`` level (seed ``distill.teacher_seed``,
checked to be the one the study trains) is rolled out in three pools of whole episodes (itself, with N(0, noise_std)
action noise, uniformly random actions); every ``state_shift.datasets`` entry is written as ``state_shift.episodes``
episodes mixed by its composition (mop_core.shift.compose), plus ``reference_episodes`` held-out teacher episodes:
the state distribution the state_shift stage measures every dataset against. Tasks run in parallel.

Outputs: data/composed/<task>-<level>-<dataset>.hdf5 and <task>-<level>-reference.hdf5 (mop_core.data's schema),
results/compose/metrics.json (each dataset's composition and returns) and results/timings/compose.json.
"""

from __future__ import annotations

import time

from common import load_params, require_inputs, run_stage

from mop_core.data import write_json
from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.study import shift_grid, study_config
from mop_core.learning.runtime import parallel_map, progress_enabled
from mop_core.provenance import check_teachers
from mop_core.shift.compose import (
    compose_config,
    compose_jobs,
    compose_metrics,
    compose_seconds,
    compose_teacher_data,
    summary_lines,
)
from mop_core.storage.layout import COMPOSE_METRICS, composed_file, timing_file
from mop_core.storage.timings import write_timing
from mop_core.teachers import teacher_config


def main() -> None:
    params = load_params()
    study = study_config(params)
    grid = shift_grid(params, study)
    config = compose_config(grid)
    started = time.perf_counter()
    teachers = build_catalogue(params).composing_teachers
    require_inputs([t.paths.checkpoint for t in teachers], "train_teachers")
    check_teachers(teachers, study.seed, lambda actor, level: teacher_config(params, study, actor, level), data=False)
    jobs = compose_jobs(teachers, config, study.seed, study.episode_length)
    summaries = parallel_map(compose_teacher_data, jobs, grid.workers, "compose", progress_enabled(study.progress))
    metrics, seconds = compose_metrics(teachers, summaries), compose_seconds(teachers, summaries)
    write_json(COMPOSE_METRICS, metrics)
    write_timing(timing_file("compose"), time.perf_counter() - started, "cpu", workers=grid.workers, tasks=seconds)
    print("\n".join(summary_lines(metrics, seconds)) if jobs
          else "compose: state_shift.datasets is empty, nothing composed")
    if not jobs:  # the stage's output folder exists even when empty
        composed_file("-", "-", "-").parent.mkdir(parents=True, exist_ok=True)


if __name__ == "__main__":
    run_stage(main, __doc__)
