"""What every stage script shares: reading params.yaml, the study settings, the output layout.

Stage scripts are the only code that reads params.yaml and decides paths; mop_core receives typed
configs and explicit paths.
"""

from __future__ import annotations

import fcntl
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from mop_core.artifacts import RunPaths
from mop_core.config import ConfigError, InputFileError, OutputFileError, from_mapping, require
from mop_core.data import LEVELS
from mop_core.runtime import TrainingDivergedError, die_with_parent
from mop_core.tasks import check_task_list

PARAMS = Path("params.yaml")
SECTIONS = ("study", "collect", "relabel", "train_teachers", "train_multitask", "distill", "eval",
            "shared_computation")
DATA = Path("data")
RESULTS = Path("results")
LOCKS = DATA / "locks"  # run locks (not a DVC output; ignored by git)
PARAMS_CHECKED = DATA / "params_checked.txt"  # the params stage's output; every stage depends on it


@dataclass(frozen=True)
class StudyConfig:
    """The study grid and process settings shared by all stages."""

    tasks: tuple[str, ...]  # walker tasks of the study (any subset of the registry, any order)
    levels: tuple[str, ...] = LEVELS  # dataset levels later stages study (collect always writes all)
    seed: int = 0  # study seed; every task/stage derives its own seeds from it
    episode_length: int = 1000  # control steps per walker episode (1000 = dm_control's 25 s)
    device: str = "auto"  # "auto" (CUDA if present), "cpu", "cuda[:N]"
    progress: bool = True  # tqdm progress bars (MOP_PROGRESS=0 switches them off)

    def __post_init__(self) -> None:
        check_task_list(self.tasks, "tasks")
        for i, level in enumerate(self.levels):
            require(level in LEVELS, f"levels[{i}]", f"one of {', '.join(LEVELS)}", level)
        require(len(self.levels) > 0 and len(set(self.levels)) == len(self.levels), "levels",
                "a non-empty list without repeats", list(self.levels))
        require(self.seed >= 0, "seed", "a non-negative integer", self.seed)
        require(self.episode_length > 0, "episode_length", "a positive integer", self.episode_length)


def load_params(path: Path = PARAMS) -> dict[str, Any]:
    if not path.is_file():
        raise ConfigError(f"{path}: parameter file not found (run from the repository root)")
    try:
        with path.open() as f:
            params = yaml.safe_load(f)
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(err).split())}") from None
    if not isinstance(params, dict):
        raise ConfigError(f"{path}: expected a mapping of sections, got {type(params).__name__}")
    check_sections(params, path)
    return params


def check_sections(params: dict[str, Any], path: Path = PARAMS) -> None:
    """Refuse a section no stage reads (a misspelled ``distil:`` would otherwise be ignored)."""
    unknown = sorted(set(params) - set(SECTIONS), key=str)
    if unknown:
        raise ConfigError(f"{unknown[0]}: unknown section in {path}; known: {', '.join(SECTIONS)}")


def section(params: dict[str, Any], name: str) -> Any:
    if name not in params:
        raise ConfigError(f"{name}: missing section in {PARAMS}")
    return params[name]


def study_config(params: dict[str, Any]) -> StudyConfig:
    return from_mapping(StudyConfig, section(params, "study"), "study")


# ---- output layout -------------------------------------------------------------------------------
def behaviour_checkpoint(task: str, level: str) -> Path:
    return DATA / "behaviour" / task / f"{level}.pt"


def dataset_file(task: str, level: str) -> Path:
    return DATA / "datasets" / f"{task}-{level}.hdf5"


def relabel_file(task: str, level: str) -> Path:
    return DATA / "relabelled" / f"{task}-{level}.hdf5"


def teacher_name(task: str, level: str, actor: str, seed: int) -> str:
    return f"{task}-{level}-{actor}-{seed}"


def run_paths(name: str, family: str = "teachers") -> RunPaths:
    """Final checkpoint (DVC output), metrics and curve (results/), resume file (not an output:
    ``dvc repro`` deletes outputs before a stage runs, and the resume file must survive that)."""
    return RunPaths(checkpoint=DATA / family / f"{name}.pt", metrics=RESULTS / family / "metrics" / f"{name}.json",
                    curve=RESULTS / family / "curves" / f"{name}.tsv", resume=DATA / "resume" / f"{family}-{name}.pt")


def require_inputs(paths, stage: str) -> None:
    """Fail before any compute when an upstream file is missing, naming it and the stage to run."""
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise ConfigError(f"missing input {', '.join(missing)}; run `dvc repro {stage}` first")


class StageBusyError(RuntimeError):
    """Another live process runs the same stage (and matrix entry)."""


def hold_run_lock(argv: list[str]) -> None:
    """Take this run's lock (``data/locks/<script>[--args].lock``, an flock released by the kernel when
    the process and its workers end, even after ``kill -9``); refuse to start if a live process holds it.

    Two processes training the same run would write the same resume file and outputs."""
    name = "-".join([Path(argv[0]).stem, *(a.lstrip("-") for a in argv[1:])])
    path = LOCKS / f"{name}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    handle = open(path, "a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = (handle.read().strip().splitlines() or ["unknown"])[-1]  # one line, whatever the file holds
        handle.close()
        raise StageBusyError(f"{path}: this run is already in progress ({holder}); wait for it to finish or "
                             "stop that process first") from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"pid {os.getpid()}, started {time.strftime('%Y-%m-%d %H:%M:%S')}: {' '.join(argv)}\n")
    handle.flush()
    _HELD_LOCKS.append(handle)  # open for the life of the process


_HELD_LOCKS: list = []


def run_stage(main) -> None:
    """Run a stage's ``main`` holding its run lock and dying with its parent (``dvc repro``); a
    configuration error, a bad input file, a full disk, a diverged run or a busy lock prints one clear
    line (naming the key, the file or the run) and exits with status 2."""
    try:
        die_with_parent()
        hold_run_lock(sys.argv)
        main()
    except (ConfigError, InputFileError, OutputFileError, TrainingDivergedError, StageBusyError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
