"""The state_shift stage's plan and what it derives from its student table (mop_core.shift.study):
which students each table row holds and what the row is (:func:`student_groups`, :func:`describe`:
from the catalogue's typed variants), the stage's inputs and measures per task (:class:`ShiftStage`),
Hypothesis 1 on the measured axis (:func:`shift_correlations`) and the figures (Figure 5.8's return
against width; return against the measured shift)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

from scipy.stats import spearmanr

from mop_core.experiment.catalogue import Catalogue
from mop_core.experiment.runs import StudentRun, teacher_group
from mop_core.experiment.study import pairing_levels, section, shift_grid, study_config
from mop_core.experiment.variants import OFFLINE_DATA, Composed, Corrected, Size, Variant, Width
from mop_core.learning.runtime import derive_seeds
from mop_core.plots import interval_panels
from mop_core.shift.study import (
    MeasureConfig,
    correction_table,
    eval_returns,
    measure_config,
    measure_shift,
    read_states,
    student_table,
)
from mop_core.storage.files import read_json
from mop_core.storage.layout import LEVELS, REFERENCE, composed_file, dataset_file


def describe(variant: Variant | None, width: int) -> dict:
    """What a table row of students of ``variant`` is: its data (offline, a composed dataset), width,
    dataset share and state-shift correction (none, reweight, dagger). Plain MOP students (None) and
    the common_structure widths are the offline data at their width; ``width``: plain MOP's."""
    info = {"data": OFFLINE_DATA, "width": width, "percent": 100, "correction": "none"}
    match variant:
        case None:
            return info
        case Width(width=w):
            return info | {"width": w}
        case Composed(dataset=data, width=w):
            return info | {"data": data, "width": w}
        case Corrected(method=method, dataset=data, width=w):
            return info | {"data": data, "width": w, "correction": method}
        case Size(percent=percent):
            return info | {"percent": percent}
    raise ValueError(f"{variant}: not a student of the state_shift table (a {variant.family} variant)")


def reference_label(width: int) -> str:
    """The table row of the offline students of ``width`` (plain MOP's, a common_structure width's)."""
    return f"{OFFLINE_DATA}_w{width}"


def student_groups(catalogue: Catalogue, pairing: str, width: int) -> dict[str, tuple[Variant | None, list]]:
    """The state_shift table's rows: label -> (variant, its students, one per seed). First the references
    on the offline data, the catalogue's plain MOP MSE students (``offline_w<width>``) and its
    common_structure width students (``offline_w<w>``) of the state_shift ``pairing``; then the
    state-shift students by variant (labelled by its name), in the catalogue's order. A width student
    of plain MOP's width takes the plain students' row."""
    references: dict[Variant | None, list[StudentRun]] = {}
    for run in catalogue.students:
        if run.pairing == pairing and run.loss == "mse" and (run.variant is None or isinstance(run.variant, Width)):
            references.setdefault(run.variant, []).append(run)
    groups = {reference_label(describe(variant, width)["width"]): (variant, runs)
              for variant, runs in references.items()}
    for run in catalogue.shift_students:
        groups.setdefault(run.variant.name, (run.variant, []))[1].append(run)
    return groups


@dataclass(frozen=True)
class ShiftStage:
    """The state_shift stage of one study: every dataset of each task measured against its teacher's
    reference episodes (the collect levels, the composed ``datasets``), and the student table's
    ``groups`` (:func:`student_groups`) next to the teacher runs they learned from."""

    tasks: tuple[str, ...]
    study_seed: int
    pairing: str
    measure: MeasureConfig
    width: int  # plain MOP's (distill.student) hidden width
    teacher_seed: int
    datasets: tuple[str, ...] = ()
    levels: tuple[str, ...] = ()  # the pairing's level per task; () when the stage has nothing to do
    groups: Mapping[str, tuple[Variant | None, list]] = field(default_factory=dict)

    @property
    def active(self) -> bool:
        """Whether it measures a composed dataset or tables a student."""
        return bool(self.levels)

    def start_metrics(self) -> dict:
        metrics: dict[str, Any] = {"pairing": self.pairing, "measure": vars(self.measure).copy(), "shift": {},
                                   "students": {}}
        return metrics | ({"pairing_levels": dict(zip(self.tasks, self.levels))} if self.active else {})

    def dataset_files(self, task: str) -> dict[str, Path]:
        """The files measured for ``task``: the reference, each collect level, each composed dataset."""
        level = self.levels[self.tasks.index(task)]
        return {"reference": composed_file(task, level, REFERENCE), **{lv: dataset_file(task, lv) for lv in LEVELS},
                **{name: composed_file(task, level, name) for name in self.datasets}}

    @property
    def measured_tasks(self) -> tuple[str, ...]:
        return self.tasks if self.active and self.datasets else ()

    def inputs(self, evaluation: Path) -> dict[str, list[Path]]:
        """The stage that writes each input -> its files (``evaluation``: the eval stage's metrics)."""
        files = [self.dataset_files(task) for task in self.measured_tasks]
        return {"compose": [path for f in files for name, path in f.items() if name not in LEVELS],
                "collect": [path for f in files for name, path in f.items() if name in LEVELS],
                "distill": [run.paths.metrics for _, runs in self.groups.values() for run in runs],
                "eval": [evaluation]}

    def add_shift(self, metrics: dict, task: str) -> dict[str, dict]:
        """Every dataset of ``task`` against its teacher's reference (mop_core.shift.study.measure_shift),
        into ``metrics`` (:meth:`start_metrics`'s); returns it."""
        states, episodes = read_states(self.dataset_files(task))  # observations and each row's episode
        reference = states.pop("reference")
        seed = derive_seeds([self.study_seed, "state_shift", task], ("measure",))["measure"] % (2 ** 31)
        metrics["shift"][task] = measure_shift(states, reference, self.measure, seed, episodes)
        return metrics["shift"][task]

    def add_students(self, metrics: dict, evaluation: Mapping, norms: Mapping[str, Mapping]) -> None:
        """The student table (mop_core.shift.study.student_table: the eval stage's ``evaluation``), what
        each row is, the corrections' gains and Hypothesis 1's correlations, into ``metrics``."""
        runs = {label: runs for label, (_, runs) in self.groups.items()}
        records = {label: [read_json(run.paths.metrics) for run in group] for label, group in runs.items()}
        teachers = {task: teacher_group(level, "deterministic") for task, level in zip(self.tasks, self.levels)}
        returns, teacher_returns = eval_returns(evaluation, runs, self.tasks, teachers, self.teacher_seed)
        table = student_table(records, returns, teacher_returns, self.tasks, norms,
                              evaluation["eval"]["episodes_per_job"])
        groups = {label: describe(self.groups[label][0], self.width) for label in table}
        metrics.update(students=table, normalisers=dict(norms), student_width=self.width, groups=groups,
                       corrections=correction_table(table, records, groups, self.tasks))
        metrics["hypothesis"] = shift_correlations(metrics, self.tasks)


def shift_stage(params: Mapping[str, Any], catalogue: Catalogue) -> ShiftStage:
    """The state_shift stage of ``params`` (its section, plain MOP's width) and ``catalogue``'s students."""
    study = study_config(params)
    grid = shift_grid(params, study)
    stage = ShiftStage(study.tasks, study.seed, grid.pairing, measure_config(grid),
                       section(params, "distill")["student"]["hidden_sizes"][0], catalogue.teacher_seed)
    if not grid.trains_students and not grid.datasets:
        return stage
    return replace(stage, datasets=grid.datasets, levels=pairing_levels(grid.pairing, study, "state_shift.pairing"),
                   groups=student_groups(catalogue, grid.pairing, stage.width))


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


def clear_figures(figures: Path) -> None:
    """The figures folder (a folder output), without the figures of an earlier run: a run writes the
    figures its params produce (none without students)."""
    figures.mkdir(parents=True, exist_ok=True)
    for old in figures.glob("*.png"):
        old.unlink()


def write_figures(metrics: dict, tasks, figures: Path) -> None:
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
        interval_panels(figures / "capacity.png", capacity, "hidden width",
                        {t: "return (95% CI over seeds)" for t in tasks},
                        "Students by width and dataset (thesis Figure 5.8)", log_x=True)
    if shift:
        interval_panels(figures / "shift_returns.png", shift, "KL(teacher states || dataset states), nats (kNN)",
                        {t: "student / teacher return" for t in tasks},
                        "Student return against the measured state shift (Hypothesis 1)")
