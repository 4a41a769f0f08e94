"""What every file a stage reads must be, in one place, checked before any compute.

The catalogue's typed runs say what each file is: a dataset's task and level; a composed dataset's
composition, held-out flag, episode counts and the teacher whose rollouts made it; a checkpoint's task(s),
level, seed, widths and settings; a result record's keys. Each file says what it holds (HDF5 attributes,
checkpoint fields, a JSON record's keys). A reader compares the two for every file it will read, and a
mismatch is one :class:`~mop_core.config.InputFileError` naming the file, what it holds and what was
expected, before any compute: a file swapped, copied or edited between stages is refused by name, never
trained on or measured. The student_inputs stage checks the files before it records their hashes, so a
swapped file is not laundered into the record the distill entries depend on.

A result record's keys are checked where it is read (mop_core.storage.files.read_record, the keys beside
the paths in mop_core.storage.layout.RECORD_KEYS).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from mop_core.config import InputFileError, to_dict
from mop_core.data.hdf5 import read_dataset_attrs
from mop_core.distill.checkpoint import STUDENT_KIND
from mop_core.distill.config import distill_config
from mop_core.experiment.catalogue import Catalogue, check_student_inputs
from mop_core.experiment.runs import StudentRun, TeacherRun
from mop_core.experiment.study import shift_grid, study_config
from mop_core.shift.compose import compose_config
from mop_core.storage.artifacts import load_checkpoint, read_torch_file
from mop_core.storage.files import read_json
from mop_core.storage.layout import LEVELS, REFERENCE, composed_file, dataset_file, heldout_name
from mop_core.teachers import TeacherConfig, check_teacher_checkpoint, teacher_config


@dataclass(frozen=True)
class FileSpec:
    """What one input file must hold: ``fields`` (attribute -> value), written by stage ``writer``;
    ``made_from``: the teacher checkpoint whose actor (its ``actor_sha256``) the file's episodes were
    rolled out with (its ``behaviour_sha256`` attribute)."""

    path: Path
    what: str  # what the catalogue says the file is, e.g. "stand-medium composed dataset 'online'"
    fields: Mapping[str, Any]
    writer: str
    made_from: Path | None = None


def mismatch(path: Path, key: str, found: Any, expected: Any, what: str, writer: str) -> InputFileError:
    return InputFileError(f"{path}: holds {key}={found!r}, expected {expected!r} ({what}); was another file "
                          f"copied here? rerun `dvc repro {writer}`")


def compare(spec: FileSpec, found: Mapping[str, Any]) -> None:
    """Raise for the first field of ``spec`` that ``found`` (the file's own attributes) does not hold."""
    for key, value in spec.fields.items():
        if found.get(key) != value:
            raise mismatch(spec.path, key, found.get(key), value, spec.what, spec.writer)


@dataclass
class Provenance:
    """What every dataset of a study must be (``datasets``: path -> spec), from its catalogue and its
    composed-data settings; the checks each reader runs before any compute."""

    datasets: dict[Path, FileSpec] = field(default_factory=dict)
    _actor_sha256: dict[Path, str] = field(default_factory=dict)

    @classmethod
    def of(cls, catalogue: Catalogue, compose: Any | None = None) -> "Provenance":
        """``compose``: the study's :class:`mop_core.shift.compose.ComposeConfig` (None: no composed data)."""
        specs = {}
        for task in catalogue.tasks:
            for level in LEVELS:
                path = dataset_file(task, level)
                specs[path] = FileSpec(path, f"collect's {task}-{level} dataset", {"task": task, "level": level},
                                       "collect")
        for teacher in catalogue.composing_teachers if compose is not None else ():
            specs |= {s.path: s for s in composed_specs(teacher, compose)}
        return cls(specs)

    @classmethod
    def of_params(cls, params: Mapping[str, Any], catalogue: Catalogue) -> "Provenance":
        """:meth:`of` with the params' composed-data settings (the state_shift section)."""
        grid = shift_grid(params, study_config(params))
        return cls.of(catalogue, compose_config(grid) if grid.datasets else None)

    def check_datasets(self, paths: Iterable[Path]) -> None:
        """Each file's attributes against what the catalogue says it is (a path the study does not name
        is a programming error: ValueError)."""
        for path in dict.fromkeys(Path(p) for p in paths):
            if path not in self.datasets:
                raise ValueError(f"{path}: not a dataset of this study's catalogue")
            spec = self.datasets[path]
            found = read_dataset_attrs(path)
            compare(spec, found)
            if spec.made_from is not None:
                actor = self.actor_sha256(spec.made_from)
                if found.get("behaviour_sha256") != actor:
                    raise InputFileError(
                        f"{path}: rolled out by a policy of actor {str(found.get('behaviour_sha256'))[:12]}..., "
                        f"expected {spec.made_from}'s ({actor[:12]}...; {spec.what}); a dataset composed from "
                        "another teacher? rerun `dvc repro compose`")

    def actor_sha256(self, checkpoint: Path) -> str:
        if checkpoint not in self._actor_sha256:
            payload = read_torch_file(checkpoint)
            self._actor_sha256[checkpoint] = str(payload.get("actor_sha256", "")) if isinstance(payload, dict) else ""
        return self._actor_sha256[checkpoint]


def composed_specs(teacher: TeacherRun, compose: Any) -> list[FileSpec]:
    """The files the compose stage writes from ``teacher``'s rollouts: each composed dataset, its held-out
    episodes, and the reference episodes (mop_core.shift.compose.compose_task's attributes)."""
    base = {"task": teacher.task, "level": teacher.level}
    where = f"{teacher.task}-{teacher.level}"
    specs = []
    for name in compose.datasets:
        composition = compose.compositions[name]
        for file_name, heldout in ((name, False), (heldout_name(name), True)):
            teacher_episodes, rest_episodes = compose.counts(name, heldout)
            fields = base | {"composition": name, "heldout": int(heldout), "teacher_episodes": teacher_episodes,
                             "rest_episodes": rest_episodes, "rest": composition.rest,
                             "noise_std": compose.noise_std}
            path = composed_file(teacher.task, teacher.level, file_name)
            specs.append(FileSpec(path, f"{where} composed dataset {file_name!r}", fields, "compose",
                                  teacher.paths.checkpoint))
    path = composed_file(teacher.task, teacher.level, REFERENCE)
    specs.append(FileSpec(path, f"{where} reference episodes", base | {
        "composition": REFERENCE, "heldout": 0, "teacher_episodes": compose.reference_episodes, "rest_episodes": 0},
        "compose", teacher.paths.checkpoint))
    return specs


def check_teachers(teachers: Iterable[TeacherRun], study_seed: int, teacher_config: Callable[[str, str], TeacherConfig],
                   data: bool = True) -> None:
    """Each teacher checkpoint was trained as the study now says: task, level, seed, PBRL settings (widths
    included), steps and, with ``data``, the content of the datasets it learned from (a reader without the
    datasets among its DVC inputs passes False); ``teacher_config(actor, level)``: the expected
    :class:`mop_core.teachers.TeacherConfig`."""
    for t in dict.fromkeys(teachers):
        sources = "+".join(str(read_dataset_attrs(d)["content_sha256"]) for d in t.datasets) if data else None
        check_teacher_checkpoint(t.paths.checkpoint, t.task, t.level, t.seed, study_seed,
                                 teacher_config(t.actor, t.level), sources)


def check_students(students: Iterable[StudentRun], study_seed: int, distill_config: Callable[[str], Any]) -> None:
    """Each student checkpoint is the run the catalogue names: its tasks, seed, study seed and every
    distillation setting (widths included: ``run.configure(distill_config(loss))``)."""
    for run in students:
        path = run.paths.checkpoint
        payload = load_checkpoint(path, STUDENT_KIND)
        what = f"student {run.name}"
        compare(FileSpec(path, what, {"tasks": list(run.tasks), "seed": run.seed, "study_seed": study_seed},
                         run.stage), payload)
        expected, found = flat(to_dict(run.configure(distill_config(run.loss)))), flat(payload.get("distill_config"))
        for key, value in expected.items():
            if found.get(key) != value:
                raise mismatch(path, f"distill_config.{key}", found.get(key), value, what, run.stage)


def check_policies(params: Mapping[str, Any], catalogue: Catalogue, students_only: bool = False) -> None:
    """Before a stage rolls out or measures the study's policies: every PBRL teacher (MOP's and the
    relabelled-data ones) and every student checkpoint is the run the catalogue names, by the params'
    settings (:func:`check_teachers` without the datasets, :func:`check_students`); ``students_only``: the
    distill students alone (shared_computation's inputs)."""
    study = study_config(params)
    if not students_only:
        check_teachers((*catalogue.teachers, *catalogue.relabelled_teachers), study.seed,
                       lambda actor, level: teacher_config(params, study, actor, level), data=False)
    students = catalogue.students if students_only else (*catalogue.students, *catalogue.shift_students)
    check_students(students, study.seed, lambda loss: distill_config(params, loss))


def check_student_sources(params: Mapping[str, Any], catalogue: Catalogue, runs: list[StudentRun],
                          record: Path) -> None:
    """Before a distill entry trains: each teacher was trained as the study now says (dataset content
    included), each dataset it reads (states, held-out and reference episodes) is the one the catalogue
    names, and the files are the ones the student_inputs stage recorded (``record``, the DVC dependency of
    these students)."""
    study = study_config(params)
    check_teachers(runs[0].all_teachers, study.seed, lambda actor, level: teacher_config(params, study, actor, level))
    Provenance.of_params(params, catalogue).check_datasets(d for run in runs for d in run.input_datasets)
    check_student_inputs(runs, read_json(record), record)


def flat(mapping: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping as dotted keys (``student.hidden_sizes``); lists compared whole."""
    if not isinstance(mapping, Mapping):
        return {}
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if isinstance(value, Mapping):
            out |= flat(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = list(value) if isinstance(value, tuple) else value
    return out
