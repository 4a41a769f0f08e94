"""The train_teachers params section as typed configs (shared by train_teachers and train_multitask,
which the thesis trains with identical settings)."""

from __future__ import annotations

from typing import Any

from common import StudyConfig, section

from mop_core.agents.pbrl import PBRLConfig
from mop_core.config import ConfigError, from_mapping, require
from mop_core.teachers import TeacherConfig
from mop_core.training import TrainSchedule

SECTION = "train_teachers"


def teacher_config(params: dict[str, Any], study: StudyConfig, actor: str = "deterministic") -> TeacherConfig:
    raw = section(params, SECTION)
    if "actor" in raw.get("pbrl", {}):
        raise ConfigError(f"{SECTION}.pbrl.actor: set the actor types in {SECTION}.actors instead")
    pbrl = from_mapping(PBRLConfig, dict(raw.get("pbrl", {})) | {"actor": actor}, f"{SECTION}.pbrl")
    schedule = from_mapping(TrainSchedule, raw.get("schedule", {}), f"{SECTION}.schedule")
    return TeacherConfig(pbrl=pbrl, schedule=schedule, episode_length=study.episode_length)


def training_threads(params: dict[str, Any]) -> int:
    threads = section(params, SECTION).get("threads", 1)
    require(isinstance(threads, int) and threads >= 1, f"{SECTION}.threads", "a positive integer", threads)
    return threads


def check_level_and_seed(study: StudyConfig, level: str, seed: int) -> None:
    """The matrix arguments every PBRL stage takes, checked against the study before any compute."""
    if level not in study.levels:
        raise ConfigError(f"--level: expected one of study.levels {list(study.levels)}, got {level!r}")
    require(seed >= 0, "--seed", "a non-negative integer", seed)
