"""Where a study's files live, relative to the repository root (the DVC outputs of dvc.yaml).

- ``data/``: DVC-cached artefacts: behaviour snapshots, datasets, relabelled rewards, checkpoints;
  ``data/resume/`` holds resume files (not outputs: ``dvc repro`` deletes a stage's outputs before
  it runs, and a resume file must survive that);
- ``results/``: what a person reads: metrics JSON, learning-curve TSVs, figures, the report;
  ``results/metrics.json`` holds the headline numbers and ``results/timings/`` every run's seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RunPaths:
    """Where a training run writes: the final checkpoint, its metrics, its curve, the resume file, and
    its timing record (seconds and machine facts, :mod:`mop_core.storage.timings`; None: not written)."""

    checkpoint: Path
    metrics: Path
    curve: Path
    resume: Path
    timing: Path | None = None


LEVELS = ("expert", "medium", "medium_replay")  # the dataset levels (D4RL's names) a study's files are named by
DATA = Path("data")
RESULTS = Path("results")
TIMINGS = RESULTS / "timings"
# Each stage's metrics file (readable with `dvc metrics show <path>`; dvc.yaml's metrics: are the timings):
# their paths are spelled here only, for writers and readers.
COLLECT_METRICS = RESULTS / "collect" / "metrics.json"  # snapshot returns, R_random per task
RELABEL_METRICS = RESULTS / "relabel" / "metrics.json"  # per dataset: the physics check's largest error
COMPOSE_METRICS = RESULTS / "compose" / "metrics.json"  # each composed dataset's composition and returns
EVAL_METRICS = RESULTS / "eval" / "metrics.json"  # every policy group's returns, raw and normalised
SHARED_METRICS = RESULTS / "shared_computation" / "metrics.json"  # Table 6.1 per student group
SHIFT_METRICS = RESULTS / "state_shift" / "metrics.json"  # each dataset's shift, the state_shift students
#: The keys each of these records always holds (mop_core.storage.files.read_record refuses an emptied or foreign one).
RECORD_KEYS: dict[Path, tuple[str, ...]] = {
    SHIFT_METRICS: ("pairing", "measure", "shift", "students"),
    EVAL_METRICS: ("aggregate", "cross_task", "eval", "normalisation"),
    SHARED_METRICS: ("episodes_per_task", "groups", "students"),
}
VERDICTS = RESULTS / "verdicts.json"  # every finding's verdict and effects
HEADLINE_METRICS = RESULTS / "metrics.json"  # the headline numbers and the verdict counts


@dataclass(frozen=True)
class CollectPaths:
    """Where the collect step of one task writes (chosen by the stage, never by the library)."""

    checkpoints: dict[str, Path]  # "medium"/"expert" -> .pt
    datasets: dict[str, Path]  # level -> .hdf5
    dataset_metrics: dict[str, Path]  # level -> .json
    curve: Path  # learning curve .tsv
    resume: Path | None = None  # the TD3 run's resume file (None: no resume files)


def behaviour_checkpoint(task: str, level: str) -> Path:
    return DATA / "behaviour" / task / f"{level}.pt"


def dataset_file(task: str, level: str) -> Path:
    return DATA / "datasets" / f"{task}-{level}.hdf5"


REFERENCE = "reference"  # the compose stage's held-out teacher episodes (not a composition name)
HELDOUT_SUFFIX = "_heldout"  # a composed dataset's held-out episodes: ``<name>_heldout``


def composed_file(task: str, level: str, name: str) -> Path:
    """A composed dataset of task's ``level`` teacher's rollouts (thesis 5.2.4; mop_core.shift.compose), its
    held-out episodes (``heldout_name(name)``) or the teacher's reference episodes (``REFERENCE``)."""
    return DATA / "composed" / f"{task}-{level}-{name}.hdf5"


def heldout_name(name: str) -> str:
    """The file name of composed dataset ``name``'s held-out episodes (same composition, other seeds)."""
    return f"{name}{HELDOUT_SUFFIX}"


def relabel_file(task: str, level: str) -> Path:
    return DATA / "relabelled" / f"{task}-{level}.hdf5"


def dataset_summary_file(task: str, level: str) -> Path:
    return RESULTS / "collect" / "datasets" / f"{task}-{level}.json"


def collect_paths(task: str) -> CollectPaths:
    """Every file the collect step of one task writes."""
    return CollectPaths(
        checkpoints={level: behaviour_checkpoint(task, level) for level in ("medium", "expert")},
        datasets={level: dataset_file(task, level) for level in LEVELS},
        dataset_metrics={level: dataset_summary_file(task, level) for level in LEVELS},
        curve=RESULTS / "collect" / "curves" / f"{task}.tsv",
        resume=DATA / "resume" / f"collect-{task}.pt",
    )


def run_paths(name: str, family: str, entry: str | None = None) -> RunPaths:
    """A training run's final checkpoint (DVC output), metrics and curve (results/), resume file and timing.

    ``entry``: the run is one of a group trained together in one process (teachers: every task and
    seed of a (level, actor type); students: every seed of a (loss, pairing)); its checkpoint, metrics
    and curve lie in a folder named after the group (the group's DVC outputs), and the resume file and
    timing record are the group's."""
    sub = Path() if entry is None else Path(entry)
    owner = name if entry is None else entry
    return RunPaths(checkpoint=DATA / family / sub / f"{name}.pt",
                    metrics=RESULTS / family / "metrics" / sub / f"{name}.json",
                    curve=RESULTS / family / "curves" / sub / f"{name}.tsv",
                    resume=DATA / "resume" / f"{family}-{owner}.pt", timing=timing_file(family, owner))


def timing_file(stage: str, name: str | None = None) -> Path:
    """results/timings/<stage>.json, or results/timings/<family>/<run>.json for one run of a matrix stage."""
    return TIMINGS / stage / f"{name}.json" if name is not None else TIMINGS / f"{stage}.json"


def tau_curves_dir(name: str, entry: str) -> Path:
    """results/students/tau/<group>/<student>/: per_state_tau_<a|b>_layer<k>.tsv (step, tau), one curve each."""
    return RESULTS / "students" / "tau" / entry / name


def student_inputs_file(entry: str) -> Path:
    """The student_inputs stage's record of what the students of entry ``entry`` read (its distill
    entry's dependency)."""
    return DATA / "student_inputs" / f"{entry}.json"


def stage_dir(stage: str) -> Path:
    """results/<stage>/: a stage's own results (eval, shared_computation, relabel, ...)."""
    return RESULTS / stage
