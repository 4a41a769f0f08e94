"""The kinds of run a study trains and evaluates, what each is called and where its files are.

- :class:`BehaviourRun`: a TD3 snapshot of the collect stage (medium, expert) per task;
- :class:`TeacherRun`: a PBRL teacher per (task, level, actor type, seed); every task and seed of a
  (level, actor type) trains in one train_teachers entry, as one vectorised group (its ``entry``).
  A teacher on relabelled data (thesis 6.4) names its ``sources``: the tasks whose datasets, with
  its own task's rewards, it learns from (D_{j->i}): every task for data sharing (DS), one other
  task for an offline Q-switch candidate (OQS); these train in the train_relabelled_teachers entries;
- :class:`MultitaskRun`: the naive multi-task PBRL baseline per (level, seed); every seed of a level trains
  in one train_multitask entry, as one vectorised group (its ``entry``);
- :class:`StudentRun`: a distilled student per (loss, pairing, seed), with the teachers it learns
  from (one per study task); every seed of a (loss, pairing) trains in one distill entry, as one
  vectorised group (its ``entry``). A common-structure variant (thesis 6.3: a width, a ranking
  regulariser) is a student with a ``variant``, trained in its own distill_width / distill_ranking
  entry; so are the single-task students (``single_<task>``: one task's teacher alone, the no-sharing
  reference of shared_computation; distill_single entries) and the data-sharing students (6.4: ``ds``,
  ``oqs_own``, ``oqs_target``), which learn from other teachers on the union of the tasks' datasets
  (distill_sharing entries).

Each run has a ``name`` (its files), a ``group`` (the eval stage's key: the runs whose returns form
one confidence interval, e.g. every seed of a student) and its file paths (mop_core.storage.layout). The
group names are made here and nowhere else. Which runs a study has: mop_core.experiment.catalogue.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from mop_core.experiment.variants import Variant
from mop_core.storage.layout import (
    REFERENCE,
    RunPaths,
    behaviour_checkpoint,
    composed_file,
    dataset_file,
    heldout_name,
    relabel_file,
    run_paths,
    tau_curves_dir,
)
from mop_core.walker.tasks import data_tasks, substitute_base, substitute_tasks

if TYPE_CHECKING:
    from mop_core.distill.config import DistillConfig

BEHAVIOUR_LEVELS = ("medium", "expert")  # the collect stage's snapshots


# ---- evaluation group names (one place: the eval stage writes them, the report reads them) ---------
def behaviour_group(level: str) -> str:
    return f"behaviour_{level}"


def teacher_group(level: str, actor: str) -> str:
    return f"teacher_{level}_{actor}"


def teacher_entry(level: str, actor: str) -> str:
    """The train_teachers entry (and file folder) of every task and seed of a (level, actor type):
    ``<level>-<actor>``, trained as one vectorised group."""
    return f"{level}-{actor}"


SHARING_KINDS = ("ds", "oqs")  # teachers on relabelled data (thesis 6.4.2, 6.4.3)


def sharing_teacher_entry(kind: str, level: str, actor: str) -> str:
    """The train_relabelled_teachers entry (and file folder) of the teachers of one sharing kind and level:
    ``ds-<level>-<actor>`` (one per task) or ``oqs-<level>-<actor>`` (one per task pair j != i)."""
    return f"{kind}-{level}-{actor}"


def multitask_group(level: str) -> str:
    return f"multitask_{level}"


def student_recipe(loss: str, variant: Variant | None = None) -> str:
    """What a student learned by: its loss, and its variant if any (``mse``, ``mse-w16``,
    ``mse-rank_pairwise``: mop_core.experiment.variants)."""
    return f"{loss}-{variant.name}" if variant else loss


def student_group(recipe: str, pairing: str) -> str:
    return f"student_{recipe}_{pairing}"


def student_entry(recipe: str, pairing: str) -> str:
    """The distill entry (and file folder) of every seed of a (recipe, pairing): ``<recipe>-<pairing>``."""
    return f"{recipe}-{pairing}"


def representation_group(recipe: str, pairing: str) -> str:
    """The shared_computation stage's key of a student group (Table 6.1 rows)."""
    return f"{recipe}_{pairing}"


def no_sharing_group(pairing: str) -> str:
    """The shared_computation key of the no-sharing reference: each task's single-task students of
    one seed measured against each other's as if they were one student's two task ids."""
    return representation_group("mse-single", pairing)


def cross_group(level: str, teacher_task: str) -> str:
    """Task ``teacher_task``'s deterministic teacher evaluated on another task's reward."""
    return f"cross_{level}_{teacher_task}"


def is_cross_group(group: str) -> bool:
    return group.startswith("cross_")


# ---- runs ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BehaviourRun:
    task: str
    level: str  # medium | expert

    @property
    def group(self) -> str:
        return behaviour_group(self.level)

    @property
    def checkpoint(self) -> Path:
        return behaviour_checkpoint(self.task, self.level)


@dataclass(frozen=True)
class TeacherRun:
    task: str
    level: str
    actor: str  # PBRL actor type: deterministic | gaussian
    seed: int
    sources: tuple[str, ...] = ()  # tasks whose level-datasets it learns from with ``task``'s rewards; () = (task,)
    family = "teachers"

    @property
    def data_tasks(self) -> tuple[str, ...]:
        """The tasks whose datasets (relabelled to ``task``) this teacher learns from: D_{j->task}."""
        return self.sources or (self.task,)

    @property
    def sharing(self) -> str:
        """"" (its own data, MOP), ``ds`` (the union of several tasks' data) or ``oqs`` (another task's)."""
        if self.data_tasks == (self.task,):
            return ""
        return "ds" if len(self.data_tasks) > 1 else "oqs"

    @property
    def name(self) -> str:
        if not self.sharing:
            return f"{self.task}-{self.level}-{self.actor}-{self.seed}"
        return f"{self.task}-from-{'+'.join(self.data_tasks)}-{self.level}-{self.actor}-{self.seed}"

    @property
    def group(self) -> str:
        """Eval group: MOP's teachers; DS's (``teacher_ds_<level>_<actor>``); OQS's candidates by source
        task (``teacher_from_<j>_<level>_<actor>``: task i's teacher on D_{j->i}, evaluated on i)."""
        if not self.sharing:
            return teacher_group(self.level, self.actor)
        kind = "ds" if self.sharing == "ds" else f"from_{self.data_tasks[0]}"
        return f"teacher_{kind}_{self.level}_{self.actor}"

    @property
    def entry(self) -> str:
        """The entry that trains this teacher with every other task and seed of its (level, actor type[,
        sharing kind]), as one vectorised group: ``<level>-<actor>`` (``<kind>-<level>-<actor>``), the
        folder of its files."""
        if not self.sharing:
            return teacher_entry(self.level, self.actor)
        return sharing_teacher_entry(self.sharing, self.level, self.actor)

    @property
    def paths(self) -> RunPaths:
        return run_paths(self.name, self.family, self.entry)

    @property
    def datasets(self) -> tuple[Path, ...]:
        """The datasets it learns from, one per data task (their rewards: :attr:`relabels`' ``task`` column)."""
        return tuple(dataset_file(j, self.level) for j in self.data_tasks)

    @property
    def relabels(self) -> tuple[Path, ...]:
        return tuple(relabel_file(j, self.level) for j in self.data_tasks)


@dataclass(frozen=True)
class MultitaskRun:
    level: str
    seed: int
    tasks: tuple[str, ...]
    family = "multitask"

    @property
    def name(self) -> str:
        return f"{self.level}-{self.seed}"

    @property
    def group(self) -> str:
        return multitask_group(self.level)

    @property
    def entry(self) -> str:
        """The train_multitask entry (and file folder) of every seed of its level, trained as one vectorised group."""
        return self.level

    @property
    def paths(self) -> RunPaths:
        return run_paths(self.name, self.family, self.entry)

    def reference_group(self) -> str:
        """The single-task teachers it is compared with (every seed's)."""
        return teacher_group(self.level, "deterministic")


@dataclass(frozen=True)
class StudentRun:
    loss: str
    pairing: str
    seed: int
    teachers: tuple[TeacherRun, ...]  # one per task, in task-id order
    variant: Variant | None = None  # its one change to plain MOP (mop_core.experiment.variants); None = plain MOP
    candidates: tuple[tuple[TeacherRun, ...], ...] = ()  # OQS: per task i, its teachers on D_{j->i} for every j
    substitute: str = ""  # the task standing in for its base task in this student's task set (data_sharing)
    family = "students"

    @property
    def recipe(self) -> str:
        return student_recipe(self.loss, self.variant)

    @property
    def scope(self) -> str:
        """Its pairing, and for a substituted task set the substitute first: ``medium``, ``stand_still-medium``."""
        return f"{self.substitute}-{self.pairing}" if self.substitute else self.pairing

    @property
    def data_tasks(self) -> tuple[str, ...]:
        """Per task, the task whose datasets hold its own states (a substitute's: its base task's)."""
        return data_tasks(self.tasks, self.substitute)

    @property
    def single_task(self) -> bool:
        """Distilled on one task alone (the no-sharing reference), not a multi-task student."""
        return bool(self.variant and self.variant.only_task)

    @property
    def pooled_states(self) -> bool:
        """States from the union of every task's dataset (DS, OQS), not each task's own."""
        return bool(self.variant and self.variant.pooled_states)

    @property
    def name(self) -> str:
        return f"{self.recipe}-{self.scope}-{self.seed}"

    @property
    def entry(self) -> str:
        """The distill entry that trains this student with every other seed of its (recipe, pairing),
        as one vectorised group: ``<recipe>-<pairing>``, the folder of its files."""
        return student_entry(self.recipe, self.scope)

    @property
    def group(self) -> str:
        return student_group(self.recipe, self.scope)

    @property
    def representation_group(self) -> str:
        return representation_group(self.recipe, self.scope)

    @property
    def paths(self) -> RunPaths:
        return run_paths(self.name, self.family, self.entry)

    @property
    def tau_dir(self) -> Path:
        """results/students/tau/<entry>/<name>/: one ``dvc plots`` curve per logged per-state tau."""
        return tau_curves_dir(self.name, self.entry)

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(t.task for t in self.teachers)

    @property
    def levels(self) -> tuple[str, ...]:
        return tuple(t.level for t in self.teachers)

    @property
    def composed(self) -> str:
        """The composed dataset it learns from (thesis 5.2.4; mop_core.shift.compose), "" for the offline data."""
        return self.variant.composed if self.variant else ""

    @property
    def correction(self) -> str:
        """How it corrects for the state shift (reweight, dagger: thesis 5.3), "" when it does not."""
        return self.variant.correction if self.variant else ""

    @property
    def heldout_datasets(self) -> tuple[Path, ...]:
        """Per task, held-out episodes of its data's distribution (a composed dataset's: mop_core.shift.compose),
        on which its action error off the training states is measured; () when there are none."""
        if not self.composed:
            return ()
        return tuple(composed_file(task, level, heldout_name(self.composed))
                     for task, level in zip(self.tasks, self.levels))

    @property
    def reference_datasets(self) -> tuple[Path, ...]:
        """A reweighted student's: per task, the teacher's held-out visited states (the compose stage's
        reference episodes) its density ratio is estimated against; () otherwise."""
        if self.correction != "reweight":
            return ()
        return tuple(composed_file(task, level, REFERENCE) for task, level in zip(self.tasks, self.levels))

    @property
    def input_datasets(self) -> tuple[Path, ...]:
        """Every dataset file it reads: its states, held-out episodes and reference states."""
        return (*self.datasets, *self.heldout_datasets, *self.reference_datasets)

    @property
    def datasets(self) -> tuple[Path, ...]:
        """Each task's own offline dataset (its MOP teacher's; the per-state tau probes come from it); a
        composed-data student's: the composed dataset of that teacher's rollouts."""
        if self.composed:
            return tuple(composed_file(task, level, self.composed) for task, level in zip(self.tasks, self.levels))
        return tuple(dataset_file(task, level) for task, level in zip(self.data_tasks, self.levels))

    @property
    def state_datasets(self) -> tuple[Path, ...]:
        """The union every task's distillation states come from (DS, OQS: D = U_i D_i); () = each
        task's own dataset."""
        return self.datasets if self.pooled_states else ()

    def upstream_files(self) -> dict[str, tuple[Path, ...]]:
        """Every file it reads, by the stage that writes it (checked present before any compute)."""
        own = "compose" if self.composed else "collect"
        files = {"train_teachers": tuple(t.paths.checkpoint for t in self.all_teachers), own: self.datasets}
        return files | {"compose": files.get("compose", ()) + self.heldout_datasets + self.reference_datasets}

    @property
    def all_teachers(self) -> tuple[TeacherRun, ...]:
        """Every teacher it reads: one per task, and for OQS every candidate (each once, task order)."""
        runs = list(self.teachers)
        for per_task in self.candidates:
            runs += [t for t in per_task if t not in runs]
        return tuple(runs)

    @property
    def teacher_seed(self) -> int:
        return self.teachers[0].seed

    @property
    def stage(self) -> str:
        """The dvc.yaml stage that trains it: ``distill`` for plain MOP, its variant's
        :attr:`~mop_core.experiment.variants.Variant.stage`, ``distill_substitute`` for a substituted task set."""
        return "distill_substitute" if self.substitute else self.variant.stage if self.variant else "distill"

    def configure(self, config: "DistillConfig") -> "DistillConfig":
        """The distillation config it trains with: ``config`` (plain MOP's, of its loss) with its variant's change."""
        return self.variant.apply(config) if self.variant else config


def own_teacher(task: str, data_task: str, level: str, seed: int) -> TeacherRun:
    """MOP's deterministic teacher of ``task`` on its own data, D_{data_task->task} (data_task = task
    but for a substitute, which learns from its base task's data)."""
    return TeacherRun(task, level, "deterministic", seed, () if data_task == task else (data_task,))


def sharing_teachers(tasks: Sequence[str], level: str, kinds: Sequence[str], seed: int,
                     data_tasks: Sequence[str] = ()) -> tuple[TeacherRun, ...]:
    """The teachers on relabelled data of one level (deterministic, seed ``seed``): ``ds``, per task i
    one on the union over every task j of D_{j->i}; ``oqs``, per pair j != i one on D_{j->i}.
    ``data_tasks``: per task, whose datasets are its own (default: its own; a substitute's base)."""
    data = tuple(data_tasks) or tuple(tasks)
    runs: list[TeacherRun] = []
    if "ds" in kinds:
        runs += [TeacherRun(task, level, "deterministic", seed, data) for task in tasks]
    if "oqs" in kinds:
        runs += [TeacherRun(task, level, "deterministic", seed, (source,)) for task, own in zip(tasks, data)
                 for source in data if source != own]
    return tuple(runs)


def relabelled_teacher_runs(tasks: Sequence[str], level: str, kinds: Sequence[str], seed: int,
                        substitutes: Sequence[str] = ()) -> tuple[TeacherRun, ...]:
    """Every teacher on relabelled data of one level (the train_relabelled_teachers entries), each once:
    :func:`sharing_teachers` on the study's ``tasks``; then per substitute (data_sharing) its own
    teacher on D_{base->substitute} and its task set's DS / OQS teachers not trained already (the
    other tasks' OQS teachers on the base task's data are the study set's)."""
    runs = list(sharing_teachers(tasks, level, kinds, seed))
    for substitute in substitutes:
        replaced = substitute_tasks(tuple(tasks), substitute)
        runs += [own_teacher(substitute, substitute_base(substitute), level, seed),
                 *sharing_teachers(replaced, level, kinds, seed, data_tasks(replaced, substitute))]
    return tuple(run for run in dict.fromkeys(runs) if run.sharing)
