"""What every stage script shares: reading params.yaml, checking inputs, the run lock, exit codes.

Stage scripts are the only code that reads params.yaml; mop_core receives the parsed mapping
(mop_core.experiment.study types the grid, mop_core.experiment.catalogue lists the study's runs,
mop_core.storage.layout places
files, each learner's module types its own section).
"""

from __future__ import annotations

import argparse
import fcntl
import os
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from mop_core.config import ConfigError, InputFileError, OutputFileError
from mop_core.experiment.study import StudyConfig, check_sections
from mop_core.learning.runtime import CriterionNotMetError, TrainingDivergedError, die_with_parent
from mop_core.storage.layout import DATA

PARAMS = Path("params.yaml")
LOCKS = DATA / "locks"  # run locks (not a DVC output; ignored by git)
PARAMS_CHECKED = DATA / "params_checked.txt"  # the params stage's output; every stage depends on it


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
    check_sections(params, str(path))
    return params


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


def run_stage(main, doc: str | None = None) -> None:
    """Run a stage's ``main`` holding its run lock and dying with its parent (``dvc repro``); a
    configuration error, a bad input file, a full disk, a diverged run or a busy lock prints one clear
    line (naming the key, the file or the run) and exits with status 2. A stage that takes no arguments
    passes its docstring ``doc``: ``--help`` prints it and any argument is refused before any compute
    (a stage that parses its own flags passes none)."""
    if doc is not None:
        argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    try:
        die_with_parent()
        hold_run_lock(sys.argv)
        main()
    except (ConfigError, InputFileError, OutputFileError, TrainingDivergedError, CriterionNotMetError,
            StageBusyError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)


def check_level_and_seed(study: StudyConfig, level: str, seed: int) -> None:
    """The matrix arguments every PBRL stage takes, checked against the study before any compute."""
    if level not in study.levels:
        raise ConfigError(f"--level: expected one of study.levels {list(study.levels)}, got {level!r}")
    if seed < 0:
        raise ConfigError(f"--seed: expected a non-negative integer, got {seed!r}")
