"""The train_teachers and train_multitask params sections as typed configs (train_multitask trains
with train_teachers' PBRL settings, as the thesis does)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from common import StudyConfig, section

from mop_core.agents.pbrl import ACTOR_TYPES, PBRLConfig
from mop_core.config import ConfigError, from_mapping, require, require_unique
from mop_core.teachers import TeacherConfig
from mop_core.training import TrainSchedule

SECTION = "train_teachers"
MULTITASK = "train_multitask"


@dataclass(frozen=True)
class TeacherGrid:
    """The train_teachers section: one teacher per (task, level, actor, seed) and how each trains."""

    actors: tuple[str, ...]  # PBRL actor types (deterministic; gaussian for the KL loss)
    seeds: tuple[int, ...]  # training seeds
    schedule: TrainSchedule
    threads: int = 1  # torch threads (matrix stages run one after another)
    pbrl: dict[str, Any] = field(default_factory=dict)  # PBRLConfig fields except actor (checked per actor)

    def __post_init__(self) -> None:
        require(len(self.actors) > 0, "actors", "a non-empty list", list(self.actors))
        for i, actor in enumerate(self.actors):
            require(actor in ACTOR_TYPES, f"actors[{i}]", f"one of {', '.join(ACTOR_TYPES)}", actor)
        require_unique(self.actors, "actors")
        require(len(self.seeds) > 0 and all(s >= 0 for s in self.seeds), "seeds", "a non-empty list of "
                "non-negative integers", list(self.seeds))
        require_unique(self.seeds, "seeds")
        require(self.threads >= 1, "threads", "a positive integer", self.threads)
        if "actor" in self.pbrl:
            raise ConfigError(f"pbrl.actor: set the actor types in {SECTION}.actors instead")


@dataclass(frozen=True)
class MultitaskGrid:
    """The train_multitask section: one naive multi-task PBRL baseline per (level, seed)."""

    levels: tuple[str, ...]
    seeds: tuple[int, ...]

    def __post_init__(self) -> None:
        require_unique(self.levels, "levels")
        require(all(s >= 0 for s in self.seeds), "seeds", "non-negative integers", list(self.seeds))
        require_unique(self.seeds, "seeds")


def teacher_grid(params: dict[str, Any]) -> TeacherGrid:
    return from_mapping(TeacherGrid, section(params, SECTION), SECTION)


def multitask_grid(params: dict[str, Any], study: StudyConfig) -> MultitaskGrid:
    grid = from_mapping(MultitaskGrid, section(params, MULTITASK), MULTITASK)
    for i, level in enumerate(grid.levels):
        require(level in study.levels, f"{MULTITASK}.levels[{i}]", f"one of study.levels {list(study.levels)}",
                level)
    return grid


def teacher_config(params: dict[str, Any], study: StudyConfig, actor: str = "deterministic") -> TeacherConfig:
    grid = teacher_grid(params)
    pbrl = from_mapping(PBRLConfig, dict(grid.pbrl) | {"actor": actor}, f"{SECTION}.pbrl")
    return TeacherConfig(pbrl=pbrl, schedule=grid.schedule, episode_length=study.episode_length)


def training_threads(params: dict[str, Any]) -> int:
    return teacher_grid(params).threads


def check_level_and_seed(study: StudyConfig, level: str, seed: int) -> None:
    """The matrix arguments every PBRL stage takes, checked against the study before any compute."""
    if level not in study.levels:
        raise ConfigError(f"--level: expected one of study.levels {list(study.levels)}, got {level!r}")
    require(seed >= 0, "--seed", "a non-negative integer", seed)
