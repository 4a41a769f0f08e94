"""The study catalogue: every run a study's params define, what each learned from, and which
policies the eval stage rolls out on which tasks.

:func:`build_catalogue` makes it from the params' grid (:mod:`mop_core.experiment.study`); every stage and the
report ask it rather than looping over the params' grids themselves. The run kinds, their names and
evaluation groups are in :mod:`mop_core.experiment.runs`; a student's teachers follow from the loss table
(:data:`mop_core.experiment.losses.LOSS_KINDS`: KL distils Gaussian teachers). A new run kind is a class in
mop_core.experiment.runs, its entries in :func:`build_catalogue` and its jobs in :meth:`Catalogue.eval_jobs`.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from mop_core.config import InputFileError
from mop_core.data.hdf5 import read_dataset_attrs
from mop_core.experiment.losses import LOSS_KINDS
from mop_core.experiment.runs import (
    BEHAVIOUR_LEVELS,
    BehaviourRun,
    MultitaskRun,
    StudentRun,
    TeacherRun,
    cross_group,
    own_teacher,
    relabelled_teacher_runs,
)
from mop_core.experiment.study import (
    distill_grid,
    multitask_grid,
    pairing_levels,
    sharing_grid,
    shift_grid,
    structure_grid,
    study_config,
    teacher_grid,
)
from mop_core.experiment.variants import SHARING_VARIANTS, VARIANTS, Sharing, Variant
from mop_core.learning.runtime import derive_seeds
from mop_core.storage.artifacts import file_sha256
from mop_core.walker.tasks import data_tasks, substitute_tasks

LOSS_ACTORS = {name: loss.teacher_actor for name, loss in LOSS_KINDS.items()}  # what distill_grid checks


def group_by(runs: Sequence[Any], attribute: str) -> dict[str, list]:
    """``runs`` by the value of one of their attributes (an entry, a group), in the runs' order."""
    out: dict[str, list] = {}
    for run in runs:
        out.setdefault(getattr(run, attribute), []).append(run)
    return out


@dataclass(frozen=True)
class Job:
    """Roll the policy of ``checkpoint`` (under task id ``task_id`` if it is multi-task) out on
    ``eval_task``; ``group``/``train_seed`` say whose confidence interval it joins. ``sample_seed``:
    a Gaussian student acts by sampling from a generator of this seed instead of by its mean."""

    group: str
    train_seed: int
    checkpoint: Path
    eval_task: str
    task_id: str | None = None
    sample_seed: int | None = None


@dataclass(frozen=True)
class Reference:
    """What a group is compared with on one task: a teacher group and, for students, the seed of the
    teacher run they learned from (None: the teacher group's mean over its seeds)."""

    group: str
    seed: int | None = None


@dataclass(frozen=True)
class Catalogue:
    """Every run of one study, in the order the stages process and report them."""

    tasks: tuple[str, ...]
    levels: tuple[str, ...]
    study_seed: int
    behaviour: tuple[BehaviourRun, ...]
    teachers: tuple[TeacherRun, ...]
    multitask: tuple[MultitaskRun, ...]
    students: tuple[StudentRun, ...]
    teacher_seed: int  # the teacher seed students learn from and cross-task tables show
    teacher_actors: tuple[str, ...]
    relabelled_teachers: tuple[TeacherRun, ...] = ()  # teachers on relabelled data (data_sharing: DS, OQS)
    # the state-shift students (thesis 5.2: composed data x width, dataset size, corrections). The eval
    # stage rolls them out like every policy; the state_shift stage reads their returns from it
    shift_students: tuple[StudentRun, ...] = ()
    # per study task, the deterministic teacher (seed teacher_seed) of the state_shift pairing's level whose
    # rollouts compose its datasets (the compose stage's; the state-shift students learn from them); ()
    # when state_shift.datasets composes none
    composing_teachers: tuple[TeacherRun, ...] = ()

    def student_entries(self) -> dict[str, list[StudentRun]]:
        """distill entry (``<loss>-<pairing>``) -> the students it trains together (one per seed)."""
        return group_by(self.students + self.shift_students, "entry")

    def student_groups(self) -> dict[str, list[StudentRun]]:
        """group -> its students (one per seed), in grid order."""
        return group_by(self.students, "group")

    def cross_task_teachers(self) -> list[TeacherRun]:
        """The deterministic teachers (seed ``teacher_seed``) evaluated on every other task (thesis 6.4.5)."""
        if "deterministic" not in self.teacher_actors:
            return []
        return [TeacherRun(task, level, "deterministic", self.teacher_seed) for level in self.levels
                for task in self.tasks]

    def eval_jobs(self, sample_gaussian_students: bool = False, transfer_tasks: Sequence[str] = ()) -> list[Job]:
        """Every policy on the tasks it was trained for, and the cross-task teachers on the other study
        tasks and on ``transfer_tasks`` (tasks no policy trains on)."""
        jobs = []
        cross = {(t.task, t.level): t for t in self.cross_task_teachers()}
        for task in self.tasks:
            jobs += [Job(b.group, 0, b.checkpoint, task) for b in self.behaviour if b.task == task]
            for level in self.levels:
                jobs += [Job(t.group, t.seed, t.paths.checkpoint, task) for t in self.teachers
                         if t.task == task and t.level == level]
                if (task, level) in cross:
                    jobs += [Job(cross_group(level, task), self.teacher_seed, cross[task, level].paths.checkpoint,
                                 other) for other in (*self.tasks, *transfer_tasks) if other != task]
        for task in self.eval_tasks:
            for level in self.levels:
                jobs += [Job(t.group, t.seed, t.paths.checkpoint, task) for t in self.relabelled_teachers
                         if t.task == task and t.level == level]
        for run in self.multitask:
            jobs += [Job(run.group, run.seed, run.paths.checkpoint, task, task) for task in run.tasks]
        for run in self.students + self.shift_students:
            sample = sample_gaussian_students and LOSS_KINDS[run.loss].gaussian_student
            jobs += [Job(run.group, run.seed, run.paths.checkpoint, task, task,
                         self.sample_seed(run, task) if sample else None) for task in run.tasks]
        return jobs

    def sample_seed(self, run: StudentRun, task: str) -> int:
        return derive_seeds([self.study_seed, "eval", "sample", run.name, task], ("sample",))["sample"]

    def references(self) -> dict[str, dict[str, Reference]]:
        """group -> task -> the teachers it is compared with (multi-task baseline and students)."""
        out: dict[str, dict[str, Reference]] = {}
        for run in self.multitask:
            for task in run.tasks:
                out.setdefault(run.group, {})[task] = Reference(run.reference_group())
        for run in self.students:
            for teacher in run.teachers:
                out.setdefault(run.group, {})[teacher.task] = Reference(teacher.group, run.teacher_seed)
        return out

    def mop_students(self) -> list[StudentRun]:
        """The plain MOP students (no common-structure variant)."""
        return [run for run in self.students if not run.variant]

    def variant_students(self) -> list[StudentRun]:
        """The common-structure and data-sharing variants' students of the study's tasks (thesis 6.3, 6.4)."""
        return [run for run in self.students if run.variant and not run.substitute]

    def substitute_students(self) -> list[StudentRun]:
        """The students of a substituted task set (data_sharing.substitutes: MOP, DS, OQS on it)."""
        return [run for run in self.students if run.substitute]

    @property
    def eval_tasks(self) -> tuple[str, ...]:
        """Every task a policy is trained for: the study's and the substitutes (in that order)."""
        return self.tasks + tuple(dict.fromkeys(run.substitute for run in self.students if run.substitute))

    def single_task_students(self) -> dict[str, dict[int, list[StudentRun]]]:
        """The no-sharing reference: pairing -> seed -> that seed's single-task students (task order)."""
        out: dict[str, dict[int, list[StudentRun]]] = {}
        for run in self.students:
            if run.single_task:
                out.setdefault(run.pairing, {}).setdefault(run.seed, []).append(run)
        return out

    def sharing_students(self) -> list[StudentRun]:
        """The data-sharing students of the study's tasks (thesis 6.4: DS, OQS)."""
        return [run for run in self.students if run.pooled_states and not run.substitute]

    def relabelled_teacher_entries(self) -> dict[str, list[TeacherRun]]:
        """train_relabelled_teachers entry (``<kind>-<level>-<actor>``) -> the teachers it trains together."""
        return group_by(self.relabelled_teachers, "entry")

    def student_comparisons(self) -> list[tuple[str, str]]:
        """(X, Y) student groups compared head to head: every pair of losses on the same pairing, and
        each common-structure variant against the plain MSE students of its pairing."""
        by_pairing: dict[str, list[str]] = {}
        for run in self.mop_students():
            groups = by_pairing.setdefault(run.pairing, [])
            if run.group not in groups:
                groups.append(run.group)
        pairs = [pair for groups in by_pairing.values() for pair in itertools.combinations(groups, 2)]
        for run in self.variant_students():
            plain = StudentRun("mse", run.pairing, run.seed, run.teachers).group
            if (run.group, plain) not in pairs and plain in by_pairing.get(run.pairing, []):
                pairs.append((run.group, plain))
        mop = {run.scope: run.group for run in self.substitute_students() if run.variant == Sharing("mop")}
        for run in self.substitute_students():  # against MOP's student of the same substituted task set
            if run.variant != Sharing("mop") and run.scope in mop and (run.group, mop[run.scope]) not in pairs:
                pairs.append((run.group, mop[run.scope]))
        return pairs

    def teacher_entries(self) -> dict[str, list[TeacherRun]]:
        """train_teachers entry (``<level>-<actor>``) -> the teachers it trains together (every task and seed)."""
        return group_by(self.teachers, "entry")

    def distill_stages(self) -> dict[str, dict[str, list[StudentRun]]]:
        """dvc.yaml distill stage (:attr:`StudentRun.stage`) -> its entries (:meth:`student_entries`)."""
        stages: dict[str, dict[str, list[StudentRun]]] = {}
        for entry, runs in self.student_entries().items():
            stages.setdefault(runs[0].stage, {})[entry] = runs
        return stages


def make_student(loss: str, pairing: str, seed: int, tasks: tuple[str, ...], levels: tuple[str, ...],
                 teacher_seed: int, variant: Variant | None = None) -> StudentRun:
    """The student of (loss, pairing, seed[, variant]): per task, the teacher of the pairing's level,
    the loss's actor type and ``teacher_seed``."""
    actor = LOSS_KINDS[loss].teacher_actor
    return StudentRun(loss, pairing, seed, tuple(TeacherRun(task, level, actor, teacher_seed)
                                                 for task, level in zip(tasks, levels)), variant)


def make_sharing_student(variant: Sharing, level: str, seed: int, tasks: tuple[str, ...],
                         teacher_seed: int, substitute: str = "") -> StudentRun:
    """A data-sharing MSE student (thesis 6.4) of one level, on the union of the tasks' datasets:
    ``ds`` learns from the DS teachers; ``oqs_<judge>`` from the Q-switch over task i's teachers on
    D_{j->i} for every j (i = j: MOP's own teacher, reused), its ``teachers`` MOP's. With a
    ``substitute``, on the substituted task set (``tasks`` with its base task replaced, the base's
    datasets relabelled to it); there ``Sharing("mop")`` is plain MOP's student of that set."""
    if substitute:
        tasks = substitute_tasks(tasks, substitute)
    data = data_tasks(tasks, substitute)
    own = tuple(own_teacher(task, source, level, teacher_seed) for task, source in zip(tasks, data))
    where = {"substitute": substitute}
    if variant.kind == "mop":
        return StudentRun("mse", level, seed, own, variant, **where)
    if variant.kind == "ds":
        shared = tuple(TeacherRun(task, level, "deterministic", teacher_seed, data) for task in tasks)
        return StudentRun("mse", level, seed, shared, variant, **where)
    candidates = tuple(tuple(own[i] if j == data[i] else TeacherRun(task, level, "deterministic", teacher_seed, (j,))
                             for j in data) for i, task in enumerate(tasks))
    return StudentRun("mse", level, seed, own, variant, candidates, **where)


def make_structure_student(variant: Variant, pairing: str, seed: int, tasks: tuple[str, ...], levels: tuple[str, ...],
                           teacher_seed: int) -> StudentRun:
    """A common-structure MSE student (thesis 6.3) of the study's ``tasks`` (the pairing's ``levels``,
    one per task); a single-task variant learns from that task's teacher alone."""
    task = variant.only_task
    if task is not None:
        i = tasks.index(task)
        tasks, levels = (task,), (levels[i],)
    return make_student("mse", pairing, seed, tasks, levels, teacher_seed, variant)


def section_variants(section: str, grid: Any) -> tuple[Variant, ...]:
    """The variants of every registered family of params section ``section`` with keys, from its typed
    ``grid``: family by family in registration order (dvc.yaml's stage order)."""
    return tuple(v for family in VARIANTS.values() if family.section == section and family.keys
                 for v in family.grid(grid))


def shift_variants(params: Mapping[str, Any]) -> tuple[str, tuple[Variant, ...]]:
    """The state_shift section's pairing and student variants: per composed dataset every width, the
    dataset sizes, then per correction, dataset and width the correcting students."""
    grid = shift_grid(params, study_config(params))
    return grid.pairing, section_variants("state_shift", grid)


def structure_variants(params: Mapping[str, Any]) -> tuple[str, tuple[Variant, ...]]:
    """The common_structure section's pairing and student variants (widths, ranking losses, then the
    single-task students)."""
    grid = structure_grid(params, study_config(params))
    return grid.pairing, section_variants("common_structure", grid)


def build_catalogue(params: Mapping[str, Any]) -> Catalogue:
    """Every run the params define (the same order as the dvc.yaml matrices)."""
    study = study_config(params)
    teacher, multitask = teacher_grid(params), multitask_grid(params, study)
    grid = distill_grid(params, study, LOSS_ACTORS)
    teachers = tuple(TeacherRun(task, level, actor, seed) for task in study.tasks for level in study.levels
                     for actor in teacher.actors for seed in teacher.seeds)
    students = tuple(make_student(loss, pairing, seed, study.tasks,
                                  pairing_levels(pairing, study, "distill.pairings"), grid.teacher_seed)
                     for loss in grid.losses for pairing in grid.pairings for seed in grid.seeds)
    structure_pairing, variants = structure_variants(params)
    structure_levels = pairing_levels(structure_pairing, study, "common_structure.pairing")
    students += tuple(make_structure_student(variant, structure_pairing, seed, study.tasks, structure_levels,
                                             grid.teacher_seed)
                      for variant in variants for seed in grid.seeds)
    shift_pairing, shift = shift_variants(params)
    shift_levels = pairing_levels(shift_pairing, study, "state_shift.pairing")
    composing = tuple(TeacherRun(task, level, "deterministic", grid.teacher_seed) for task, level in
                      zip(study.tasks, shift_levels)) if shift_grid(params, study).datasets else ()
    shift_students = tuple(make_student("mse", shift_pairing, seed, study.tasks, shift_levels,
                                        grid.teacher_seed, variant) for variant in shift for seed in grid.seeds)
    sharing = sharing_grid(params, study)
    relabelled_teachers = tuple(t for level in sharing.levels for t in relabelled_teacher_runs(
        study.tasks, level, sharing.teachers, grid.teacher_seed, sharing.substitutes))
    students += tuple(make_sharing_student(SHARING_VARIANTS[name], level, seed, study.tasks, grid.teacher_seed)
                      for level in sharing.levels for name in sharing.students for seed in grid.seeds)
    students += tuple(make_sharing_student(SHARING_VARIANTS[name], level, seed, study.tasks, grid.teacher_seed,
                                           substitute)
                      for substitute in sharing.substitutes for level in sharing.levels
                      for name in sharing.substitute_students for seed in grid.seeds)
    return Catalogue(
        tasks=study.tasks, levels=study.levels, study_seed=study.seed,
        behaviour=tuple(BehaviourRun(task, level) for task in study.tasks for level in BEHAVIOUR_LEVELS),
        teachers=teachers,
        multitask=tuple(MultitaskRun(level, seed, study.tasks) for level in multitask.levels
                        for seed in multitask.seeds),
        students=students, teacher_seed=grid.teacher_seed, teacher_actors=teacher.actors,
        relabelled_teachers=relabelled_teachers, shift_students=shift_students, composing_teachers=composing)


def student_inputs(runs: list[StudentRun]) -> dict:
    """What the students of one distill entry read, by content: each teacher checkpoint's SHA-256 and
    each dataset's content hash (every seed of a (loss, pairing) learns from the same teachers). The
    ``student_inputs`` stage writes one such record per entry, and each ``distill`` entry depends on
    its own record only, so retraining one teacher reruns just the students that learn from it (DVC
    cannot list a matrix entry's dependencies per entry: treeverse/dvc#8171)."""
    first = runs[0]
    if any(run.all_teachers != first.all_teachers for run in runs):
        raise ValueError(f"runs: the students of {first.entry} must learn from the same teachers")
    datasets = list(dict.fromkeys([*first.input_datasets, *(d for t in first.all_teachers for d in t.datasets)]))
    return {"students": [run.name for run in runs], "tasks": list(first.tasks),
            "teachers": [{"path": t.paths.checkpoint.as_posix(), "sha256": file_sha256(t.paths.checkpoint)}
                         for t in first.all_teachers],
            "datasets": [{"path": d.as_posix(), "content_sha256": str(read_dataset_attrs(d)["content_sha256"])}
                         for d in datasets]}


def check_student_inputs(runs: list[StudentRun], record: dict, where: Path) -> None:
    """Refuse to distil from files that changed since ``student_inputs`` recorded them."""
    now = student_inputs(runs)
    if record == now:
        return
    changed = [new["path"] for kind in ("teachers", "datasets")
               for old, new in zip(record.get(kind, []), now[kind]) if old != new]
    what = changed[0] if changed else f"the inputs of students {runs[0].entry}"
    raise InputFileError(f"{what}: changed since {where} was written; run `dvc repro` (student_inputs first)")
