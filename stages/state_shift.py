"""state_shift stage: the state distribution shift of every dataset, measured, next to the students (thesis 5.2).

    python stages/state_shift.py

Per study task (mop_core.shift_study): the shift between the teacher's held-out visited states (the compose
stage's reference episodes) and each dataset, the collect stage's levels and the composed ones, every split by
whole episodes (kNN KL over random episode-halves against its null, the teacher's other half: within_null;
cross-fitted classifier AUC and the density ratio's effective sample share). Then the state_shift students'
returns (the eval stage's, as everywhere in the report; n = distill.seeds training seeds per point): per composed
dataset and width (Figure 5.8), the online dataset against the offline one at the distill student's width
(5.2.3, Figure 5.7) and per dataset share; the plain MOP students and the common_structure width students on the
offline data are the reference rows. Every group's action errors (training, held-out, visited states: each run's
metrics) and each correcting group's (reweight, dagger: thesis 5.3) return gain over the plain group of its data
and width, paired by training seed.

Outputs: results/state_shift/metrics.json, figures results/state_shift/figures/capacity.png (return
against width per dataset), shift_returns.png (student/teacher return against the measured shift)
and results/timings/state_shift.json.
"""

from __future__ import annotations

import time

from common import load_params, require_inputs, run_stage

from mop_core.catalogue import LOSS_ACTORS, build_catalogue, make_student
from mop_core.compose import REFERENCE
from mop_core.data import LEVELS, read_json, write_json
from mop_core.eval_study import normalisers
from mop_core.layout import COLLECT_METRICS, RESULTS, composed_file, dataset_file, stage_dir, timing_file
from mop_core.runs import teacher_group, width_variant
from mop_core.runtime import configure_compute, derive_seeds
from mop_core.shift_results import describe, shift_correlations, write_figures
from mop_core.shift_study import (
    correction_table,
    eval_returns,
    measure_config,
    measure_shift,
    read_states,
    student_table,
)
from mop_core.study import OFFLINE_DATA, distill_grid, pairing_levels, shift_grid, structure_grid, study_config
from mop_core.timings import write_timing

OUT = RESULTS / "state_shift"
EVAL_METRICS = stage_dir("eval") / "metrics.json"  # the students' and teachers' returns
FIGURES = OUT / "figures"  # a folder output: the figures a run's params produce (none without students)


def main() -> None:
    params = load_params()
    study = study_config(params)
    grid = shift_grid(params, study)
    measure = measure_config(grid)
    catalogue = build_catalogue(params)
    started = time.perf_counter()
    configure_compute(measure.threads)
    OUT.mkdir(parents=True, exist_ok=True)
    FIGURES.mkdir(parents=True, exist_ok=True)
    for old in FIGURES.glob("*.png"):
        old.unlink()
    metrics: dict = {"pairing": grid.pairing, "measure": vars(measure).copy(), "shift": {}, "students": {}}
    if not grid.trains_students and not grid.datasets:
        write_json(OUT / "metrics.json", metrics)
        write_timing(timing_file("state_shift"), time.perf_counter() - started, "cpu")
        print("state_shift: no composed datasets or dataset shares in the state_shift section")
        return
    levels = pairing_levels(grid.pairing, study, "state_shift.pairing")
    metrics["pairing_levels"] = dict(zip(study.tasks, levels))
    if grid.datasets:
        files = {task: {"reference": composed_file(task, level, REFERENCE),
                        **{lv: dataset_file(task, lv) for lv in LEVELS},
                        **{name: composed_file(task, level, name) for name in grid.datasets}}
                 for task, level in zip(study.tasks, levels)}
        require_inputs([p for f in files.values() for p in f.values() if "composed" in str(p)], "compose")
        require_inputs([p for f in files.values() for p in f.values() if "composed" not in str(p)], "collect")
        for task, paths in files.items():
            states, episodes = read_states(paths)  # observations and each row's episode
            reference = states.pop("reference")
            seed = derive_seeds([study.seed, "state_shift", task], ("measure",))["measure"] % (2 ** 31)
            metrics["shift"][task] = measure_shift(states, reference, measure, seed, episodes)
            print(f"state_shift {task}: " + ", ".join(f"{name} KL {m['kl']:.2f} AUC {m['auc']:.3f}"
                                                     for name, m in metrics["shift"][task].items() if "kl" in m))

    seeds = distill_grid(params, study, LOSS_ACTORS).seeds
    teacher_seed = params["distill"]["teacher_seed"]
    width = params["distill"]["student"]["hidden_sizes"][0]
    groups: dict[str, list] = {}
    for run in catalogue.shift_students:
        groups.setdefault(run.variant, []).append(run)
    plain = [make_student("mse", grid.pairing, s, study.tasks, levels, teacher_seed) for s in seeds]
    structure = structure_grid(params, study)
    references = {f"{OFFLINE_DATA}_w{width}": plain}
    if structure.pairing == grid.pairing:
        references |= {f"{OFFLINE_DATA}_w{w}": [make_student("mse", grid.pairing, s, study.tasks, levels, teacher_seed,
                                                         width_variant(w)) for s in seeds] for w in structure.widths}
    all_groups = references | groups
    require_inputs([run.paths.metrics for runs in all_groups.values() for run in runs], "distill")
    require_inputs([EVAL_METRICS], "eval")
    records = {label: [read_json(run.paths.metrics) for run in runs] for label, runs in all_groups.items()}
    norms = normalisers(study.tasks, COLLECT_METRICS)
    evaluation = read_json(EVAL_METRICS)
    returns, teachers = eval_returns(evaluation, all_groups, study.tasks,
                                     {t: teacher_group(lv, "deterministic") for t, lv in zip(study.tasks, levels)},
                                     teacher_seed)
    table = student_table(records, returns, teachers, study.tasks, norms, evaluation["eval"]["episodes_per_job"])
    metrics["students"] = table
    metrics["normalisers"] = norms
    metrics["student_width"] = width
    metrics["groups"] = {label: describe(label, width) for label in table}
    metrics["corrections"] = correction_table(table, records, metrics["groups"], study.tasks)
    metrics["hypothesis"] = shift_correlations(metrics, study.tasks)
    write_figures(metrics, study.tasks, FIGURES)
    write_json(OUT / "metrics.json", metrics)
    write_timing(timing_file("state_shift"), time.perf_counter() - started, "cpu", threads=measure.threads)
    for label, row in table.items():
        print(f"{label}: " + ", ".join(f"{task} {row[task]['return']['mean']:.1f}" for task in study.tasks))


if __name__ == "__main__":
    run_stage(main)
