"""What a study's runs wrote, as the report and the verdicts read it: one owner of the result schema.

:class:`Run` is one trained model (its catalogue run, :mod:`mop_core.experiment.runs`, in ``origin``);
:class:`StudyResults` is everything the report shows (loaded by :func:`mop_core.report.document.load_results`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence


@dataclass(frozen=True)
class Run:
    """One trained model of the study: what it is (``key``: task/level/actor/loss/pairing), its
    training seed, its metrics record and learning-curve rows."""

    key: Mapping[str, str]
    seed: int
    metrics: dict
    curve: Sequence[Mapping[str, str]]
    origin: Any = None  # the catalogue's typed run (mop_core.experiment.runs: TeacherRun, MultitaskRun, StudentRun)


@dataclass
class StudyResults:
    """Everything the report shows, as the stages wrote it. Empty/None: not part of this run."""

    tasks: list[str]
    levels: list[str]
    settings: dict  # budgets shown in the header (profile values)
    collect: dict | None = None  # collect metrics (behaviour snapshots)
    datasets: dict[str, dict] = field(default_factory=dict)  # "<task>-<level>" -> dataset summary
    teachers: list[Run] = field(default_factory=list)  # key: task, level, actor
    multitask: list[Run] = field(default_factory=list)  # key: level
    students: list[Run] = field(default_factory=list)  # plain MOP students; key: loss, pairing
    variants: list[Run] = field(default_factory=list)  # common-structure students; key: loss, variant, pairing
    substitutes: list[Run] = field(default_factory=list)  # a substituted task set's; key: + substitute
    pairing_levels: dict[str, list[str]] = field(default_factory=dict)  # pairing -> level per task
    evaluation: dict | None = None  # eval metrics (CIs per task and group, cross_task)
    shared: dict | None = None  # shared_computation metrics
    figures: dict[str, str] = field(default_factory=dict)  # name -> path relative to the report
