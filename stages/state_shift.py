"""state_shift stage: the state distribution shift of every dataset, measured, next to the students (thesis 5.2).

    python stages/state_shift.py

Per study task (mop_core.shift_study): the shift between the teacher's held-out visited states (the
compose stage's reference episodes) and each dataset, the collect stage's levels and the composed
ones (kNN KL with an interval over random halves and split-half null; classifier AUC and the density ratio's
effective sample share). Then the state_shift students' returns (their distill runs' final
evaluations; n = distill.seeds training seeds per point): per composed dataset and width (Figure
5.8), the online dataset against the offline one at the distill student's width (5.2.3, Figure 5.7)
and per dataset share; the plain MOP students and the common_structure width students on the
offline data are the reference rows. Every group's action errors (training, held-out, visited states:
each run's metrics) and each correcting group's (reweight, dagger: thesis 5.3) return gain over the
plain group of its data and width, paired by training seed.

Outputs: results/state_shift/metrics.json, figures results/state_shift/figures/capacity.png (return
against width per dataset), shift_returns.png (student/teacher return against the measured shift)
and results/timings/state_shift.json.
"""

from __future__ import annotations

import time

from common import load_params, require_inputs, run_stage
from scipy.stats import spearmanr

from mop_core.catalogue import LOSS_ACTORS, build_catalogue, make_student
from mop_core.compose import REFERENCE
from mop_core.data import LEVELS, read_dataset, read_json, write_json
from mop_core.eval_study import normalisers
from mop_core.layout import COLLECT_METRICS, RESULTS, composed_file, dataset_file, timing_file
from mop_core.plots import interval_panels
from mop_core.runs import correction_parts, shift_data, size_percent, width_variant
from mop_core.runtime import configure_compute, derive_seeds
from mop_core.shift_study import correction_table, measure_config, measure_shift, student_table
from mop_core.study import OFFLINE_DATA, distill_grid, pairing_levels, shift_grid, structure_grid, study_config
from mop_core.timings import write_timing

OUT = RESULTS / "state_shift"
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
            states = {name: read_dataset(path).arrays["observations"] for name, path in paths.items()}
            reference = states.pop("reference")
            seed = derive_seeds([study.seed, "state_shift", task], ("measure",))["measure"] % (2 ** 31)
            metrics["shift"][task] = measure_shift(states, reference, measure, seed)
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
    records = {label: [read_json(run.paths.metrics) for run in runs] for label, runs in all_groups.items()}
    norms = normalisers(study.tasks, COLLECT_METRICS)
    table = student_table(records, study.tasks, norms)
    metrics["students"] = table
    metrics["normalisers"] = norms
    metrics["student_width"] = width
    metrics["groups"] = {label: describe(label, width) for label in table}
    metrics["corrections"] = correction_table(records, metrics["groups"], study.tasks)
    metrics["hypothesis"] = shift_correlations(metrics, study.tasks)
    write_figures(metrics, study.tasks)
    write_json(OUT / "metrics.json", metrics)
    write_timing(timing_file("state_shift"), time.perf_counter() - started, "cpu", threads=measure.threads)
    for label, row in table.items():
        print(f"{label}: " + ", ".join(f"{task} {row[task]['return']['mean']:.1f}" for task in study.tasks))


def describe(label: str, width: int) -> dict:
    """What a table row is: its data (offline, a composed dataset), width, dataset share and state-shift
    correction (none, reweight, dagger)."""
    correction = (correction_parts(label) or ("none",))[0]
    if label.startswith(f"{OFFLINE_DATA}_w"):
        return {"data": OFFLINE_DATA, "width": int(label[len(OFFLINE_DATA) + 2:]), "percent": 100,
                "correction": correction}
    parts = shift_data(label)
    if parts:
        return {"data": parts[0], "width": parts[1], "percent": 100, "correction": correction}
    return {"data": OFFLINE_DATA, "width": width, "percent": size_percent(label), "correction": correction}


def plain(info: dict) -> bool:
    """A row of students without a state-shift correction at the whole dataset (the figures' points)."""
    return info["percent"] == 100 and info["correction"] == "none"


def shift_points(metrics: dict, tasks) -> dict[int, dict[str, list[tuple[float, float]]]]:
    """Per width and task: (measured KL(teacher || data), the students' mean student/teacher return) of
    every dataset (offline and composed), at full size."""
    points: dict[int, dict[str, list[tuple[float, float]]]] = {}
    for label, info in metrics["groups"].items():
        if not plain(info):
            continue
        for task in tasks:
            data = info["data"] if info["data"] != OFFLINE_DATA else metrics["pairing_levels"][task]
            measured = metrics["shift"].get(task, {}).get(data)
            if measured:
                points.setdefault(info["width"], {}).setdefault(task, []).append(
                    (measured["kl"], metrics["students"][label][task]["to_teacher"]["mean"]))
    return points


def shift_correlations(metrics: dict, tasks) -> dict[str, dict[str, dict]]:
    """Hypothesis 1 on a measured axis: per width and task, Spearman's rank correlation between the
    measured shift and the student/teacher return over the datasets (negative: more shift, less
    return). Per task: the tasks' KL scales differ (a teacher holding a pose is a near-degenerate
    set), so pooling them would rank tasks, not shifts."""
    out: dict[str, dict[str, dict]] = {}
    for width, by_task in sorted(shift_points(metrics, tasks).items()):
        for task, points in by_task.items():
            if len(points) >= 3:
                rho, p = spearmanr([q[0] for q in points], [q[1] for q in points])
                out.setdefault(str(width), {})[task] = {"spearman": float(rho), "p_value": float(p),
                                                        "points": len(points)}
    return out


def write_figures(metrics: dict, tasks) -> None:
    """Figure 5.8 (return against width, one line per dataset, 95% CI over seeds) and the return
    against the measured shift (one line per width)."""
    groups, table = metrics["groups"], metrics["students"]
    capacity: dict = {}
    shift: dict = {}
    for label, info in groups.items():
        if not plain(info):
            continue
        for task in tasks:
            r = table[label][task]["return"]
            capacity.setdefault(task, {}).setdefault(info["data"], []).append(
                (info["width"], r["mean"], r["ci_low"], r["ci_high"]))
            measured = metrics["shift"].get(task, {}).get(info["data"] if info["data"] != OFFLINE_DATA
                                                          else metrics["pairing_levels"][task])
            if measured:
                ratio = table[label][task]["to_teacher"]
                shift.setdefault(task, {}).setdefault(f"width {info['width']}", []).append(
                    (measured["kl"], ratio["mean"], ratio["ci_low"], ratio["ci_high"]))
    for panels in (capacity, shift):
        for series in panels.values():
            for points in series.values():
                points.sort(key=lambda p: p[0])
    if capacity:
        interval_panels(FIGURES / "capacity.png", capacity, "hidden width",
                        {t: "return (95% CI over seeds)" for t in tasks},
                        "Students by width and dataset (thesis Figure 5.8)", log_x=True)
    if shift:
        interval_panels(FIGURES / "shift_returns.png", shift, "KL(teacher states || dataset states), nats (kNN)",
                        {t: "student / teacher return" for t in tasks},
                        "Student return against the measured state shift (Hypothesis 1)")


if __name__ == "__main__":
    run_stage(main)
