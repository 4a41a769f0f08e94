"""state_shift stage: the state distribution shift of every dataset, measured, next to the students (thesis 5.2).
``python stages/state_shift.py``.
Per study task, the shift between the teacher's held-out visited states (the compose stage's reference episodes)
and each dataset, the collect levels and the composed ones (mop_core.shift.study; each file checked to be what the
catalogue names first); then the state_shift students' returns from the eval stage, their action errors and each
correction's gain, next to plain MOP and the common_structure widths (the rows: mop_core.shift.results).

Outputs: results/state_shift/metrics.json, its figures/ (capacity.png: return against width per dataset;
shift_returns.png: student/teacher return against the shift), results/timings/state_shift.json.
"""

from __future__ import annotations

import time

from common import load_params, require_inputs, run_stage

from mop_core.data import write_json
from mop_core.eval_study import normalisers
from mop_core.experiment.catalogue import build_catalogue
from mop_core.learning.runtime import configure_compute
from mop_core.provenance import Provenance
from mop_core.shift.results import clear_figures, shift_stage, write_figures
from mop_core.storage.files import read_record
from mop_core.storage.layout import COLLECT_METRICS, EVAL_METRICS, SHIFT_METRICS, timing_file
from mop_core.storage.timings import write_timing

FIGURES = SHIFT_METRICS.parent / "figures"  # a folder output: the figures of a run's params (none without students)


def main() -> None:
    params = load_params()
    stage = shift_stage(params, catalogue := build_catalogue(params))
    started = time.perf_counter()
    configure_compute(stage.measure.threads)
    clear_figures(FIGURES)
    metrics = stage.start_metrics()
    if stage.active:
        for writer, paths in stage.inputs(EVAL_METRICS).items():
            require_inputs(paths, writer)
        Provenance.of_params(params, catalogue).check_datasets(
            path for task in stage.measured_tasks for path in stage.dataset_files(task).values())
        evaluation = read_record(EVAL_METRICS)
        for task in stage.measured_tasks:
            shift = stage.add_shift(metrics, task)
            print(f"state_shift {task}: " + ", ".join(f"{name} KL {m['kl']:.2f} AUC {m['auc']:.3f}"
                                                     for name, m in shift.items() if "kl" in m))
        stage.add_students(metrics, evaluation, normalisers(stage.tasks, COLLECT_METRICS))
        write_figures(metrics, stage.tasks, FIGURES)
    write_json(SHIFT_METRICS, metrics)
    write_timing(timing_file("state_shift"), time.perf_counter() - started, "cpu",
                 **({"threads": stage.measure.threads} if stage.active else {}))
    if not stage.active:
        print("state_shift: no composed datasets or dataset shares in the state_shift section")
    for label, row in metrics["students"].items():
        print(f"{label}: " + ", ".join(f"{task} {row[task]['return']['mean']:.1f}" for task in stage.tasks))


if __name__ == "__main__":
    run_stage(main, __doc__)
