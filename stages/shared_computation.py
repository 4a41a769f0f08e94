"""shared_computation stage: how much of each student's computation its tasks share (thesis 6.2).

    python stages/shared_computation.py

Every student of the catalogue acts online on each of its tasks (``shared_computation.episodes``
episodes per task; the thesis used 1000); its post-ReLU activations on the visited states are
compared across task ids: per state (Kendall's tau-a and tau-b, mean +- sd over states), on task
averages and by linear CKA, next to an untrained copy of each group's first student
(mop_core/shared_study.py). Writes
- results/shared_computation/metrics.json: Table 6.1 per (loss, pairing) group (mean over the
  group's seeds) and per student (readable with `dvc metrics show <path>`);
- results/shared_computation/students/<student>.json: everything measured, incl. the mean activations;
- results/shared_computation/figures/<student>.png: the sorted mean activations (Figure 6.3b);
- results/shared_computation/tau_during_training.png: the per-state tau logged while distilling
  (Figure 6.4b), dotted lines at each student's value at initialisation.
"""

from __future__ import annotations

from common import load_params, require_inputs, run_stage

from mop_core.config import require
from mop_core.data import write_json
from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.study import study_config
from mop_core.learning.runtime import progress_enabled
from mop_core.provenance import check_policies
from mop_core.shared_computation import shared_computation_config
from mop_core.shared_study import measure_catalogue, print_summary, tau_during_training_figure
from mop_core.storage.layout import SHARED_METRICS, stage_dir, timing_file
from mop_core.storage.timings import write_timing


def main() -> None:
    params = load_params()
    study, out = study_config(params), stage_dir("shared_computation")
    threads, config = shared_computation_config(params)
    require(len(study.tasks) >= 2, "study.tasks", "at least two tasks to compare task ids", list(study.tasks))
    catalogue = build_catalogue(params)
    require_inputs([f for run in catalogue.students for f in (run.paths.checkpoint, run.paths.curve,
                                                              run.paths.metrics)], "distill")
    check_policies(params, catalogue, students_only=True)
    metrics, seconds = measure_catalogue(catalogue, config, threads, study.episode_length, out,
                                         progress_enabled(study.progress))
    write_json(SHARED_METRICS, metrics)
    tau_during_training_figure(catalogue, out / "tau_during_training.png")
    print_summary(metrics, write_timing(timing_file("shared_computation"), **seconds))


if __name__ == "__main__":
    run_stage(main, __doc__)
