"""The kinds of run a study trains and evaluates, what each is called and where its files are.

- :class:`BehaviourRun`: a TD3 snapshot of the collect stage (medium, expert) per task;
- :class:`TeacherRun`: a PBRL teacher per (task, level, actor type, seed); every task and seed of a
  (level, actor type) trains in one train_teachers entry, as one vectorised group (its ``batch``);
- :class:`MultitaskRun`: the naive multi-task PBRL baseline per (level, seed);
- :class:`StudentRun`: a distilled student per (loss, pairing, seed), with the teachers it learns
  from (one per study task); every seed of a (loss, pairing) trains in one distill entry, as one
  vectorised group (its ``batch``). A common-structure variant (thesis 6.3: a width, a ranking
  regulariser) is a student with a ``variant``, trained in its own distill_width / distill_ranking
  entry.

Each run has a ``name`` (its files), a ``group`` (the eval stage's key: the runs whose returns form
one confidence interval, e.g. every seed of a student) and its file paths (mop_core.layout). The
group names are made here and nowhere else. Which runs a study has: mop_core.catalogue.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mop_core.artifacts import RunPaths
from mop_core.layout import behaviour_checkpoint, dataset_file, relabel_file, run_paths, tau_curves_dir

BEHAVIOUR_LEVELS = ("medium", "expert")  # the collect stage's snapshots


# ---- evaluation group names (one place: the eval stage writes them, the report reads them) ---------
def behaviour_group(level: str) -> str:
    return f"behaviour_{level}"


def teacher_group(level: str, actor: str) -> str:
    return f"teacher_{level}_{actor}"


def teacher_batch(level: str, actor: str) -> str:
    """The train_teachers entry (and file folder) of every task and seed of a (level, actor type):
    ``<level>-<actor>``, trained as one vectorised group."""
    return f"{level}-{actor}"


def multitask_group(level: str) -> str:
    return f"multitask_{level}"


WIDTH_PREFIX, RANKING_PREFIX = "w", "rank_"  # common-structure variants (thesis 6.3): mop_core.distill.variants


def width_variant(width: int) -> str:
    """The variant of students whose every hidden layer is ``width`` wide (6.3.1)."""
    return f"{WIDTH_PREFIX}{width}"


def ranking_variant(loss: str) -> str:
    """The variant of students trained with the ranking regulariser of ranking loss ``loss`` (6.3.2)."""
    return f"{RANKING_PREFIX}{loss}"


def student_recipe(loss: str, variant: str = "") -> str:
    """What a student learned by: its loss, and its common-structure variant if any (``mse``,
    ``mse-w16``, ``mse-rank_pairwise``: mop_core.distill.variants)."""
    return f"{loss}-{variant}" if variant else loss


def student_group(recipe: str, pairing: str) -> str:
    return f"student_{recipe}_{pairing}"


def student_batch(recipe: str, pairing: str) -> str:
    """The distill entry (and file folder) of every seed of a (recipe, pairing): ``<recipe>-<pairing>``."""
    return f"{recipe}-{pairing}"


def structure_group(recipe: str, pairing: str) -> str:
    """The shared_computation stage's key of a student group (Table 6.1 rows)."""
    return f"{recipe}_{pairing}"


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
    family = "teachers"

    @property
    def name(self) -> str:
        return f"{self.task}-{self.level}-{self.actor}-{self.seed}"

    @property
    def group(self) -> str:
        return teacher_group(self.level, self.actor)

    @property
    def batch(self) -> str:
        """The train_teachers entry that trains this teacher with every other task and seed of its
        (level, actor type), as one vectorised group: ``<level>-<actor>``, the folder of its files."""
        return teacher_batch(self.level, self.actor)

    @property
    def paths(self) -> RunPaths:
        return run_paths(self.name, self.family, self.batch)

    @property
    def dataset(self) -> Path:
        return dataset_file(self.task, self.level)

    @property
    def relabel(self) -> Path:
        return relabel_file(self.task, self.level)


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
    def paths(self) -> RunPaths:
        return run_paths(self.name, self.family)

    def reference_group(self) -> str:
        """The single-task teachers it is compared with (every seed's)."""
        return teacher_group(self.level, "deterministic")


@dataclass(frozen=True)
class StudentRun:
    loss: str
    pairing: str
    seed: int
    teachers: tuple[TeacherRun, ...]  # one per task, in task-id order
    variant: str = ""  # a common-structure variant (w16, rank_pairwise: mop_core.distill.variants); "" = MOP
    family = "students"

    @property
    def recipe(self) -> str:
        return student_recipe(self.loss, self.variant)

    @property
    def name(self) -> str:
        return f"{self.recipe}-{self.pairing}-{self.seed}"

    @property
    def batch(self) -> str:
        """The distill entry that trains this student with every other seed of its (recipe, pairing),
        as one vectorised group: ``<recipe>-<pairing>``, the folder of its files."""
        return student_batch(self.recipe, self.pairing)

    @property
    def group(self) -> str:
        return student_group(self.recipe, self.pairing)

    @property
    def structure_group(self) -> str:
        return structure_group(self.recipe, self.pairing)

    @property
    def paths(self) -> RunPaths:
        return run_paths(self.name, self.family, self.batch)

    @property
    def tau_dir(self) -> Path:
        """results/students/tau/<batch>/<name>/: one ``dvc plots`` curve per logged per-state tau."""
        return tau_curves_dir(self.name, self.batch)

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(t.task for t in self.teachers)

    @property
    def levels(self) -> tuple[str, ...]:
        return tuple(t.level for t in self.teachers)

    @property
    def datasets(self) -> tuple[Path, ...]:
        """Each task's offline dataset: the one its teacher was trained on."""
        return tuple(t.dataset for t in self.teachers)

    @property
    def teacher_seed(self) -> int:
        return self.teachers[0].seed
