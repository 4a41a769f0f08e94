"""The distill params section as typed configs, and what a study's students learn from.

A *pairing* names the dataset level of each study task's teacher, joined by ``+`` in task order
(``expert+medium``: stand's expert teacher with walk's medium teacher, Appendix E); a single level
pairs every task with that level.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from common import StudyConfig, section

from mop_core.config import ConfigError, from_mapping, require, require_unique
from mop_core.distill.distiller import DistillConfig
from mop_core.distill.losses import LOSSES
from mop_core.training import TrainSchedule

SECTION = "distill"
GRID_KEYS = ("losses", "pairings", "seeds", "teacher_seed", "threads", "schedule")


@dataclass(frozen=True)
class DistillGrid:
    """The students of a study: one per (loss, pairing, seed), and how they train."""

    losses: tuple[str, ...]
    pairings: tuple[str, ...]
    seeds: tuple[int, ...]
    teacher_seed: int  # which train_teachers seed the students learn from
    threads: int
    schedule: TrainSchedule


def pairing_levels(pairing: str, study: StudyConfig, key: str = "--pairing") -> tuple[str, ...]:
    """The teacher level per study task of a pairing (``medium`` or ``expert+medium``)."""
    levels = tuple(pairing.split("+"))
    if len(levels) == 1:
        levels = levels * len(study.tasks)
    if len(levels) != len(study.tasks):
        raise ConfigError(f"{key}: expected one level or one per study task ({len(study.tasks)}) joined by '+', "
                          f"got {pairing!r}")
    for level in levels:
        require(level in study.levels, key, f"levels among study.levels {list(study.levels)}", pairing)
    return levels


def teacher_actor(loss: str) -> str:
    """KL distils Gaussian teachers; MSE and Q the deterministic ones (thesis 5.1.3)."""
    return "gaussian" if loss == "kl" else "deterministic"


def distill_grid(params: dict[str, Any], study: StudyConfig) -> DistillGrid:
    raw = section(params, SECTION)
    grid = {k: raw.get(k) for k in GRID_KEYS}
    for key in ("losses", "pairings", "seeds"):
        require(isinstance(grid[key], list) and grid[key], f"{SECTION}.{key}", "a non-empty list", grid[key])
    for loss in grid["losses"]:
        require(loss in LOSSES, f"{SECTION}.losses", f"entries among {LOSSES}", grid["losses"])
    for pairing in grid["pairings"]:
        pairing_levels(str(pairing), study, f"{SECTION}.pairings")
    for seed in grid["seeds"]:
        require(isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0, f"{SECTION}.seeds",
                "non-negative integers", grid["seeds"])
    for key in ("losses", "pairings", "seeds"):
        require_unique(grid[key], f"{SECTION}.{key}")
    same = {}
    for pairing in grid["pairings"]:  # 'medium' and 'medium+medium' name the same students
        levels = pairing_levels(str(pairing), study, f"{SECTION}.pairings")
        require(levels not in same, f"{SECTION}.pairings", f"distinct pairings ({same.get(levels)!r} and "
                f"{pairing!r} both pair the tasks with {'+'.join(levels)})", grid["pairings"])
        same[levels] = pairing
    teachers = section(params, "train_teachers")  # typed and checked by the params stage (study_params.py)
    require(grid["teacher_seed"] in teachers.get("seeds", []), f"{SECTION}.teacher_seed",
            f"one of train_teachers.seeds {teachers.get('seeds')}", grid["teacher_seed"])
    for loss in grid["losses"]:
        actor = teacher_actor(loss)
        require(actor in teachers.get("actors", []), f"{SECTION}.losses",
                f"{actor} teachers for the {loss} loss: add {actor} to train_teachers.actors", grid["losses"])
    threads = grid["threads"] if grid["threads"] is not None else 1
    require(isinstance(threads, int) and not isinstance(threads, bool) and threads >= 1, f"{SECTION}.threads",
            "a positive integer", threads)
    schedule = from_mapping(TrainSchedule, grid["schedule"] or {}, f"{SECTION}.schedule")
    return DistillGrid(tuple(grid["losses"]), tuple(str(p) for p in grid["pairings"]), tuple(grid["seeds"]),
                       grid["teacher_seed"], threads, schedule)


def distill_config(params: dict[str, Any], loss: str) -> DistillConfig:
    raw = {k: v for k, v in section(params, SECTION).items() if k not in GRID_KEYS}
    if "loss" in raw:
        raise ConfigError(f"{SECTION}.loss: set the losses in {SECTION}.losses instead")
    return from_mapping(DistillConfig, raw | {"loss": loss}, SECTION)


def student_name(loss: str, pairing: str, seed: int) -> str:
    return f"{loss}-{pairing}-{seed}"
