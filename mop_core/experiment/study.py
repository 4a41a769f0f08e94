"""The study's grid as typed configs: its tasks and levels, and which teachers, baselines and
students it trains (the catalogue, mop_core.experiment.catalogue, lists the runs they make).

A stage reads params.yaml (stages/common.py) and hands the mapping here; nothing here reads a file.
A bad value raises ConfigError naming its key (``distill.pairings``, ``train_teachers.seeds``).
Each learner's own settings are typed next to it (``teacher_config`` in mop_core.teachers,
``distill_config`` in mop_core.distill.distiller, ...); mop_core.study_params checks the whole file.
This module imports no training code, so a stage that reads the grid depends on no learner's code.

A *pairing* names the dataset level of each study task's teacher, joined by ``+`` in task order
(``expert+medium``: stand's expert teacher with walk's medium teacher, thesis Appendix E); a
single level pairs every task with that level.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import torch

from mop_core.config import ConfigError, from_mapping, require, require_unique
from mop_core.experiment.variants import OFFLINE_DATA, SHIFT_CORRECTIONS
from mop_core.learning.nn import ACTOR_TYPES
from mop_core.learning.runtime import CUDA_MATMULS, resolve_device, resolve_threads, resolve_workers, set_cuda_matmul
from mop_core.learning.schedule import TrainSchedule
from mop_core.storage.layout import LEVELS
from mop_core.walker.tasks import check_task_list, get_task, substitute_base

SECTIONS = ("study", "collect", "relabel", "train_teachers", "train_multitask", "distill", "common_structure",
            "data_sharing", "state_shift", "eval", "shared_computation")
RANKING_LOSS_NAMES = ("pairwise", "listwise", "approx_ndcg")  # mop_core.distill.ranking.RANKING_LOSSES (tested equal)


def require_widths(widths: tuple[int, ...], key: str) -> None:
    """A grid's student widths: distinct positive integers (the hidden width of every student layer)."""
    require(all(isinstance(w, int) and not isinstance(w, bool) and w >= 1 for w in widths), key,
            "a list of positive integers (hidden width of every student layer)", list(widths))
    require_unique(widths, key)


@dataclass(frozen=True)
class StudyConfig:
    """The study grid and process settings shared by all stages."""

    tasks: tuple[str, ...]  # walker tasks of the study (any subset of the registry, any order)
    levels: tuple[str, ...] = LEVELS  # dataset levels later stages study (collect always writes all)
    seed: int = 0  # study seed; every task/stage derives its own seeds from it
    episode_length: int = 1000  # control steps per walker episode (1000 = dm_control's 25 s)
    device: str = "auto"  # "auto" (CUDA if present), "cpu", "cuda[:N]"
    cuda_matmul: str = "fp32"  # CUDA float32 matmuls: fp32, or tf32 (faster, coarser; no effect on a CPU)
    progress: bool = True  # tqdm progress bars (MOP_PROGRESS=0 switches them off)

    def __post_init__(self) -> None:
        check_task_list(self.tasks, "tasks")
        for i, level in enumerate(self.levels):
            require(level in LEVELS, f"levels[{i}]", f"one of {', '.join(LEVELS)}", level)
        require(len(self.levels) > 0 and len(set(self.levels)) == len(self.levels), "levels",
                "a non-empty list without repeats", list(self.levels))
        require(self.seed >= 0, "seed", "a non-negative integer", self.seed)
        require(self.episode_length > 0, "episode_length", "a positive integer", self.episode_length)
        require(self.cuda_matmul in CUDA_MATMULS, "cuda_matmul", f"one of {', '.join(CUDA_MATMULS)}",
                self.cuda_matmul)


@dataclass(frozen=True)
class TeacherGrid:
    """The train_teachers section: one teacher per (task, level, actor, seed) and how each trains."""

    actors: tuple[str, ...]  # PBRL actor types (deterministic; gaussian for the KL loss)
    seeds: tuple[int, ...]  # training seeds
    schedule: dict[str, Any]  # TrainSchedule fields; steps: one number, or one per dataset level (schedule_for)
    threads: int | str = 1  # torch threads (matrix stages run one after another); auto: this process's cores
    pbrl: dict[str, Any] = field(default_factory=dict)  # PBRLConfig fields except actor (checked per actor)

    def __post_init__(self) -> None:
        require(len(self.actors) > 0, "actors", "a non-empty list", list(self.actors))
        for i, actor in enumerate(self.actors):
            require(actor in ACTOR_TYPES, f"actors[{i}]", f"one of {', '.join(ACTOR_TYPES)}", actor)
        require_unique(self.actors, "actors")
        require(len(self.seeds) > 0 and all(s >= 0 for s in self.seeds), "seeds", "a non-empty list of "
                "non-negative integers", list(self.seeds))
        require_unique(self.seeds, "seeds")
        object.__setattr__(self, "threads", resolve_threads(self.threads, "threads"))
        if "actor" in self.pbrl:
            raise ConfigError("pbrl.actor: set the actor types in train_teachers.actors instead")
        steps = self.schedule.get("steps")
        if isinstance(steps, Mapping):
            require(len(steps) > 0, "schedule.steps", "a number of steps, or one per dataset level", dict(steps))
            for level in steps:
                require(level in LEVELS, f"schedule.steps.{level}", f"one of {', '.join(LEVELS)}", level)
                self.schedule_for(level)
        else:
            self.schedule_for(None)

    def schedule_for(self, level: str | None) -> TrainSchedule:
        """How a teacher of dataset ``level`` trains: ``schedule`` with its level's steps where ``steps`` is a
        mapping of levels (expert data needs longer than medium at this budget: docs/teachers.md)."""
        raw = dict(self.schedule)
        per_level = isinstance(raw.get("steps"), Mapping)
        if per_level:
            if level not in raw["steps"]:
                raise ConfigError(f"schedule.steps: expected a number of steps for level {level!r} (every study "
                                  f"level), got {dict(raw['steps'])}")
            raw["steps"] = raw["steps"][level]
        try:
            return from_mapping(TrainSchedule, raw, "schedule")
        except ConfigError as err:
            if per_level and str(err).startswith("schedule.steps:"):
                raise ConfigError(str(err).replace("schedule.steps:", f"schedule.steps.{level}:", 1)) from None
            raise


@dataclass(frozen=True)
class MultitaskGrid:
    """The train_multitask section: one naive multi-task PBRL baseline per (level, seed), a
    train_multitask entry per level."""

    levels: tuple[str, ...]
    seeds: tuple[int, ...]

    def __post_init__(self) -> None:
        require_unique(self.levels, "levels")
        require(all(s >= 0 for s in self.seeds), "seeds", "non-negative integers", list(self.seeds))
        require_unique(self.seeds, "seeds")


DISTILL_GRID_KEYS = ("losses", "pairings", "seeds", "teacher_seed", "threads", "schedule")


@dataclass(frozen=True)
class DistillGrid:
    """The students of a study: one per (loss, pairing, seed), and how they train."""

    losses: tuple[str, ...]
    pairings: tuple[str, ...]
    seeds: tuple[int, ...]
    teacher_seed: int  # which train_teachers seed the students learn from
    threads: int
    schedule: TrainSchedule


@dataclass(frozen=True)
class StructureGrid:
    """The common_structure section (thesis 6.3): MSE students of one distill pairing next to plain
    MOP, one group of ``distill.seeds`` per width (6.3.1) and per ranking loss (6.3.2); and per task of
    ``single_task``, students distilled on that task alone (its teacher and dataset), the "no
    sharing" reference of the shared-computation measures: two networks that share no weight.
    Empty lists train none."""

    pairing: str
    widths: tuple[int, ...] = ()
    ranking_losses: tuple[str, ...] = ()
    single_task: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        require_widths(self.widths, "widths")
        for i, loss in enumerate(self.ranking_losses):
            require(loss in RANKING_LOSS_NAMES, f"ranking_losses[{i}]", f"one of {', '.join(RANKING_LOSS_NAMES)}",
                    loss)
        require_unique(self.ranking_losses, "ranking_losses")
        require_unique(self.single_task, "single_task")
        require(len(self.single_task) != 1, "single_task", "[] or two or more study tasks (the reference compares "
                "a pair of single-task students)", list(self.single_task))


SHARING_TEACHERS = ("ds", "oqs")  # mop_core.experiment.runs.SHARING_KINDS (tested equal)
SHARING_STUDENTS = {"ds": "ds", "oqs_own": "oqs", "oqs_target": "oqs"}  # student variant -> teachers it needs
# the students of a substituted task set: MOP's (its substitute's own teacher, on D_{base->substitute}, trains
# with the OQS teachers) and the data-sharing ones
SUBSTITUTE_STUDENTS = {"mop": "oqs"} | SHARING_STUDENTS


@dataclass(frozen=True)
class SharingGrid:
    """The data_sharing section (thesis 6.4): per level, teachers on relabelled data D_{j->i} (``ds``:
    one per task on the union over j; ``oqs``: one per pair j != i) and MSE students of them (``ds``;
    ``oqs_own`` / ``oqs_target``: Q-switch targets judged by each candidate's own critics or by the
    target task's), next to plain MOP of the same level. Empty lists train none.

    ``substitutes`` (6.4.5, 7.3): tasks no behaviour policy collects for (``stand_still``), each
    standing in for its base task (the study task its reward derives from: :func:`substitute_base`)
    in a second task set, whose datasets are the base task's relabelled to it; on that set the MOP
    teachers (the substitute's on D_{base->substitute}), the ``teachers`` kinds and the
    ``substitute_students`` (``mop``, ``ds``, ``oqs_own``, ``oqs_target``) are trained as on the
    study's tasks."""

    levels: tuple[str, ...] = ()
    teachers: tuple[str, ...] = ()
    students: tuple[str, ...] = ()
    substitutes: tuple[str, ...] = ()
    substitute_students: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for key, known in (("teachers", SHARING_TEACHERS), ("students", tuple(SHARING_STUDENTS)),
                           ("substitute_students", tuple(SUBSTITUTE_STUDENTS))):
            for i, name in enumerate(getattr(self, key)):
                require(name in known, f"{key}[{i}]", f"one of {', '.join(known)}", name)
            require_unique(getattr(self, key), key)
        require_unique(self.levels, "levels")
        require_unique(self.substitutes, "substitutes")
        for key, needs in (("students", SHARING_STUDENTS), ("substitute_students", SUBSTITUTE_STUDENTS)):
            for i, student in enumerate(getattr(self, key)):
                require(needs[student] in self.teachers, f"{key}[{i}]",
                        f"its {needs[student]} teachers in teachers", student)
        require(not self.substitutes or "oqs" in self.teachers, "substitutes", "oqs in teachers (a substitute's "
                "own teacher, on its base task's data, trains with the OQS teachers)", list(self.substitutes))


@dataclass(frozen=True)
class ShiftGrid:
    """The state_shift section (thesis 5.2): per study task, datasets composed from the ``pairing``'s
    MOP teacher's rollouts (``datasets``, each a ``compositions`` entry: the share of episodes the
    teacher acts in, the rest noisy or random; mop_core.shift.compose), MSE students of every ``widths`` on
    each (5.2.4, Figure 5.8; the widest one the distill student's is 5.2.3's online-vs-offline
    comparison on the online dataset) and on ``data_percents``% of each task's offline dataset; and
    the shift between every dataset and the teacher's visited states (``measure``: mop_core.shift.measures);
    and the students that correct for the shift (thesis 5.3: ``corrections``,
    reweight and the DAgger reference, on each of ``correction_datasets``, a composed dataset or
    ``offline``, at each of ``correction_widths``; their settings: distill.reweight, distill.dagger).
    Empty lists train none. The data and measure settings are typed where they are used
    (mop_core.shift.compose.compose_config, mop_core.shift.study.measure_config)."""

    pairing: str = ""
    datasets: tuple[str, ...] = ()
    compositions: dict[str, Any] = field(default_factory=dict)
    episodes: int = 100
    noise_std: float = 1.0
    reference_episodes: int = 20
    heldout_episodes: int = 10
    rollout_envs: int = 10
    workers: int | str = 2  # compose's rollout processes; auto: the cores this process may use
    widths: tuple[int, ...] = ()
    data_percents: tuple[int, ...] = ()
    corrections: tuple[str, ...] = ()
    correction_datasets: tuple[str, ...] = ()
    correction_widths: tuple[int, ...] = ()
    measure: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        require_widths(self.widths, "widths")
        require(all(isinstance(p, int) and not isinstance(p, bool) and 1 <= p <= 99 for p in self.data_percents),
                "data_percents", "a list of whole percentages in [1, 99] (100 is plain MOP)", list(self.data_percents))
        require_unique(self.data_percents, "data_percents")
        require_unique(self.datasets, "datasets")
        object.__setattr__(self, "workers", resolve_workers(self.workers, "workers"))
        require(not (self.widths and not self.datasets), "widths", "[] when no datasets are composed",
                list(self.widths))
        require(all(c in SHIFT_CORRECTIONS for c in self.corrections), "corrections",
                f"a list of {list(SHIFT_CORRECTIONS)}", list(self.corrections))
        require_unique(self.corrections, "corrections")
        for i, name in enumerate(self.correction_datasets):
            require(name == OFFLINE_DATA or name in self.datasets, f"correction_datasets[{i}]",
                    f"{OFFLINE_DATA!r} (the pairing's collect dataset) or one of datasets {list(self.datasets)}", name)
        require_unique(self.correction_datasets, "correction_datasets")
        require_widths(self.correction_widths, "correction_widths")
        require(not self.corrections or (self.correction_datasets and self.correction_widths),
                "corrections", "[] unless correction_datasets and correction_widths are set", list(self.corrections))
        require(not any(n != OFFLINE_DATA for n in self.correction_datasets) or self.datasets,
                "correction_datasets", "composed datasets only when datasets are composed",
                list(self.correction_datasets))

    @property
    def trains_students(self) -> bool:
        """Whether the section trains any student (composed, dataset share or correction)."""
        return bool(self.datasets and self.widths or self.data_percents or self.corrections)


def shift_grid(params: Mapping[str, Any], study: StudyConfig) -> ShiftGrid:
    """The state_shift section (absent: none), its pairing checked against the distill pairings (the
    MOP students its students are compared with) and deterministic teachers (they compose the data)."""
    if "state_shift" not in params:
        return ShiftGrid()
    grid = from_mapping(ShiftGrid, section(params, "state_shift"), "state_shift")
    if not (grid.datasets or grid.data_percents or grid.corrections):
        return grid
    require_distill_pairing(params, study, grid.pairing, "state_shift.pairing", "its students")
    actors = section(params, "train_teachers").get("actors", [])
    require("deterministic" in actors, "state_shift", "deterministic teachers in train_teachers.actors (they "
            "compose the datasets; the students are MSE students)", actors)
    require(len(study.tasks) >= 2, "state_shift", "at least two study.tasks (multi-task students)",
            list(study.tasks))
    return grid


# ---- sections -------------------------------------------------------------------------------------
def check_sections(params: Mapping[str, Any], where: str = "params.yaml") -> None:
    """Refuse a section no stage reads (a misspelled ``distil:`` would otherwise be ignored)."""
    unknown = sorted(set(params) - set(SECTIONS), key=str)
    if unknown:
        raise ConfigError(f"{unknown[0]}: unknown section in {where}; known: {', '.join(SECTIONS)}")


def section(params: Mapping[str, Any], name: str) -> Any:
    if name not in params:
        raise ConfigError(f"{name}: missing section in params.yaml")
    return params[name]


def typed_section(params: Mapping[str, Any], name: str, config_type: type):
    """Section ``name`` as ``config_type`` (unknown keys and bad values raise ConfigError under ``name``)."""
    return from_mapping(config_type, section(params, name), name)


def positive_threads(value: Any, key: str) -> int:
    """A threads param: a positive integer, or ``auto`` (the cores this process may use)."""
    return resolve_threads(value, key)


def study_config(params: Mapping[str, Any]) -> StudyConfig:
    return from_mapping(StudyConfig, section(params, "study"), "study")


def study_device(study: StudyConfig) -> torch.device:
    """The training stages' device (``study.device``), with this process's CUDA float32 matmuls set to
    ``study.cuda_matmul`` (mop_core.learning.runtime.set_cuda_matmul)."""
    device = resolve_device(study.device, "study.device")
    set_cuda_matmul(study.cuda_matmul)
    return device


def teacher_grid(params: Mapping[str, Any]) -> TeacherGrid:
    return from_mapping(TeacherGrid, section(params, "train_teachers"), "train_teachers")


def multitask_grid(params: Mapping[str, Any], study: StudyConfig) -> MultitaskGrid:
    grid = from_mapping(MultitaskGrid, section(params, "train_multitask"), "train_multitask")
    for i, level in enumerate(grid.levels):
        require(level in study.levels, f"train_multitask.levels[{i}]", f"one of study.levels {list(study.levels)}",
                level)
    return grid


def parse_pairing(pairing: str, study: StudyConfig, key: str = "distill.pairings") -> tuple[str, ...]:
    """The teacher level per study task that ``pairing`` names, however it is spelled (an alias such as
    ``medium+medium`` included: :func:`pairing_levels` refuses it)."""
    levels = tuple(pairing.split("+"))
    if len(levels) == 1:
        levels = levels * len(study.tasks)
    if len(levels) != len(study.tasks):
        raise ConfigError(f"{key}: expected one level or one per study task ({len(study.tasks)}) joined by '+', "
                          f"got {pairing!r}")
    for level in levels:
        require(level in study.levels, key, f"levels among study.levels {list(study.levels)}", pairing)
    return levels


def pairing_levels(pairing: str, study: StudyConfig, key: str = "distill.pairings") -> tuple[str, ...]:
    """The teacher level per study task of a pairing (``medium`` or ``expert+medium``). A pairing is
    spelled one way only: the students' files and every cross-section reference are named by the
    spelling, so one level for every task is written as that level (``medium``, not ``medium+medium``)."""
    levels = parse_pairing(pairing, study, key)
    require(not ("+" in pairing and len(set(levels)) == 1), key, f"{levels[0]!r} (a pairing of one level for "
            "every study task is spelled as that level: the students' files are named by the spelling)", pairing)
    return levels


def require_distill_pairing(params: Mapping[str, Any], study: StudyConfig, pairing: str, key: str, who: str) -> None:
    """``pairing`` (at ``key``) names the levels of one of distill.pairings: ``who`` are compared with those
    MOP students."""
    levels = pairing_levels(pairing, study, key)
    pairings = [pairing_levels(str(p), study, "distill.pairings") for p in section(params, "distill").get(
        "pairings") or []]
    require(levels in pairings, key, f"one of distill.pairings {section(params, 'distill').get('pairings')} "
            f"(the MOP students {who} are compared with)", pairing)


def structure_grid(params: Mapping[str, Any], study: StudyConfig) -> StructureGrid:
    """The common_structure section, its pairing checked against the study's levels and distill.pairings."""
    grid = from_mapping(StructureGrid, section(params, "common_structure"), "common_structure")
    require_distill_pairing(params, study, grid.pairing, "common_structure.pairing", "the variants")
    for i, task in enumerate(grid.single_task):
        require(task in study.tasks, f"common_structure.single_task[{i}]", f"one of study.tasks {list(study.tasks)}",
                task)
    if grid.widths or grid.ranking_losses or grid.single_task:
        actors = section(params, "train_teachers").get("actors", [])
        require("deterministic" in actors, "common_structure", "deterministic teachers in train_teachers.actors "
                "(the variants are MSE students)", actors)
    return grid


def sharing_grid(params: Mapping[str, Any], study: StudyConfig) -> SharingGrid:
    """The data_sharing section (absent: none), its levels checked against the study and the MOP
    students they are compared with (a distill pairing of that level for every task)."""
    grid = from_mapping(SharingGrid, section(params, "data_sharing"), "data_sharing")
    pairings = [pairing_levels(str(p), study, "distill.pairings") for p in section(params, "distill").get(
        "pairings") or []]
    for i, level in enumerate(grid.levels):
        require(level in study.levels, f"data_sharing.levels[{i}]", f"one of study.levels {list(study.levels)}",
                level)
        require((level,) * len(study.tasks) in pairings, f"data_sharing.levels[{i}]", "a level with a distill "
                "pairing of it (the MOP students the data-sharing students are compared with)", level)
    for i, task in enumerate(grid.substitutes):
        get_task(task, f"data_sharing.substitutes[{i}]")
        require(task not in study.tasks and substitute_base(task) in study.tasks, f"data_sharing.substitutes[{i}]",
                f"a task outside study.tasks whose base task (the one its reward derives from) is one of "
                f"study.tasks {list(study.tasks)}", task)
    if grid.levels and (grid.teachers or grid.students or grid.substitutes):
        require(len(study.tasks) >= 2, "data_sharing", "at least two study.tasks (data is shared between tasks)",
                list(study.tasks))
        actors = section(params, "train_teachers").get("actors", [])
        require("deterministic" in actors, "data_sharing", "deterministic teachers in train_teachers.actors "
                "(OQS reuses MOP's; the students are MSE students)", actors)
    return grid


def distill_grid(params: Mapping[str, Any], study: StudyConfig, losses: Mapping[str, str]) -> DistillGrid:
    """The distill section's grid; ``losses``: the known loss names and the teacher actor type each
    distils (mop_core.experiment.catalogue.LOSS_ACTORS, from the loss table)."""
    raw = section(params, "distill")
    grid = {k: raw.get(k) for k in DISTILL_GRID_KEYS}
    for key in ("losses", "pairings", "seeds"):
        require(isinstance(grid[key], list) and grid[key], f"distill.{key}", "a non-empty list", grid[key])
    for loss in grid["losses"]:
        require(loss in losses, "distill.losses", f"entries among {tuple(losses)}", grid["losses"])
    for pairing in grid["pairings"]:
        parse_pairing(str(pairing), study, "distill.pairings")
    for seed in grid["seeds"]:
        require(isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0, "distill.seeds",
                "non-negative integers", grid["seeds"])
    for key in ("losses", "pairings", "seeds"):
        require_unique(grid[key], f"distill.{key}")
    same = {}
    for pairing in grid["pairings"]:  # 'medium' and 'medium+medium' name the same students
        levels = parse_pairing(str(pairing), study, "distill.pairings")
        require(levels not in same, "distill.pairings", f"distinct pairings ({same.get(levels)!r} and "
                f"{pairing!r} both pair the tasks with {'+'.join(levels)})", grid["pairings"])
        same[levels] = pairing
    for pairing in grid["pairings"]:  # the one spelling of each (after the repeats, which name both)
        pairing_levels(str(pairing), study, "distill.pairings")
    teachers = section(params, "train_teachers")  # typed by teacher_grid; read raw so each error names its key
    require(isinstance(grid["teacher_seed"], int) and not isinstance(grid["teacher_seed"], bool),
            "distill.teacher_seed", "an integer", grid["teacher_seed"])
    require(grid["teacher_seed"] in teachers.get("seeds", []), "distill.teacher_seed",
            f"one of train_teachers.seeds {teachers.get('seeds')}", grid["teacher_seed"])
    for loss in grid["losses"]:
        actor = losses[loss]
        require(actor in teachers.get("actors", []), "distill.losses",
                f"{actor} teachers for the {loss} loss: add {actor} to train_teachers.actors", grid["losses"])
    threads = positive_threads(grid["threads"] if grid["threads"] is not None else 1, "distill.threads")
    schedule = from_mapping(TrainSchedule, grid["schedule"] or {}, "distill.schedule")
    return DistillGrid(tuple(grid["losses"]), tuple(str(p) for p in grid["pairings"]), tuple(grid["seeds"]),
                       grid["teacher_seed"], threads, schedule)


GAUSSIAN_ACTIONS = ("mean", "sample")


@dataclass(frozen=True)
class EvalConfig:
    """How much evaluation: ``episodes`` episodes per (policy, task), the same seeds for every policy."""

    episodes: int = 30  # per policy and task: the CI unit of a policy trained once
    rollout_envs: int = 30  # walkers stepped together in one process
    workers: int | str = 2  # processes (one torch thread each); auto: the cores this process may use
    bootstrap_reps: int = 2000  # replicates of the stratified bootstrap (IQM, probability of improvement)
    gaussian_student_action: str = "mean"  # KL students act by their mean, or by a sample (the reference code)
    transfer_tasks: tuple[str, ...] = ()  # tasks no policy trains on: the cross-task teachers are evaluated on
    #   them too (thesis Table 6.3 with a task such as stand_still, 6.4.5)

    def __post_init__(self) -> None:
        require(self.episodes >= 2, "episodes", "an integer >= 2 (a confidence interval needs two units)",
                self.episodes)
        for name in ("rollout_envs", "bootstrap_reps"):
            require(getattr(self, name) >= 1, name, "a positive integer", getattr(self, name))
        object.__setattr__(self, "workers", resolve_workers(self.workers, "workers"))
        require(self.gaussian_student_action in GAUSSIAN_ACTIONS, "gaussian_student_action",
                f"one of {GAUSSIAN_ACTIONS}", self.gaussian_student_action)
        if self.transfer_tasks:
            check_task_list(self.transfer_tasks, "transfer_tasks")
