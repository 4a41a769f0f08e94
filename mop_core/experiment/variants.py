"""Student variants: one change to a plain MOP student, as a typed, registered object.

A variant is a frozen dataclass of one *family*, registered in :data:`VARIANTS` (as d3rlpy registers
its algorithm configs with ``register_learnable``). It carries everything a consumer needs as fields:

- its :attr:`~Variant.name`, derived from the fields: the files of its students are
  ``<loss>-<name>-<pairing>-<seed>`` (mop_core.experiment.runs.StudentRun.name);
- :meth:`~Variant.apply`: the distillation config it trains with (the plain one with its change);
- the inputs it adds to a plain student's: a composed dataset its states come from
  (:attr:`~Variant.composed`), the reference states of a density-ratio correction
  (:attr:`~Variant.correction`), the union of every task's states (:attr:`~Variant.pooled_states`),
  the one task it is distilled on (:attr:`~Variant.only_task`);
- the dvc.yaml stage that trains its entries (:attr:`~Variant.stage`) and the params section that
  lists them (:attr:`~Variant.section`).

Families (thesis sections):

- :class:`Width` (6.3.1, Figure 6.4): every hidden layer ``width`` wide, same depth;
- :class:`Ranking` (6.3.2, Figure 6.5): the ranking regulariser with ranking loss ``loss``
  (mop_core.distill.ranking: L = L_distil + lambda * sum_l w_l L_rank(h_l(s, i), h_l(s, j)));
- :class:`SingleTask`: one task's teacher and dataset alone, the no-sharing reference of
  shared_computation;
- :class:`Sharing` (6.4): students on the union of the tasks' states D = U_i D_i, learning from DS
  teachers (on U_j D_{j->i}) or by the offline Q-switch over task i's teachers on D_{j->i}, each
  candidate judged by its own critics or by the target task's; ``mop``: plain MOP's students of a
  substituted task set;
- :class:`Composed` (5.2.4, Figure 5.8): states of a composed dataset (mop_core.shift.compose), every
  hidden layer ``width`` wide;
- :class:`Size` (5.2): ``percent``% of each task's dataset's whole episodes;
- :class:`Corrected` (5.3): a state-shift correction (reweight, dagger: mop_core.distill.corrections)
  on a composed dataset or the offline one, at width ``width``.

A new family is a class here with ``@register_variant`` and its :attr:`~Variant.keys`, those keys in its section's
typed grid (mop_core.experiment.study) and in the params files, and its distill stage in dvc.yaml: the catalogue
makes its students from :meth:`~Variant.grid`. Nothing parses a name back: consumers read fields.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from itertools import product
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

if TYPE_CHECKING:
    from mop_core.distill.config import DistillConfig

SHIFT_CORRECTIONS = ("reweight", "dagger")  # state_shift.corrections: Corrected.method
OFFLINE_DATA = "offline"  # a correction student's data that is the pairing's collect dataset, not a composed one



@dataclass(frozen=True)
class Variant(ABC):
    """One change to a plain MOP student (a family's base; see the module docstring)."""

    family: ClassVar[str]  # registry key
    stage: ClassVar[str]  # the dvc.yaml stage that trains its entries
    section: ClassVar[str]  # the params section that lists its variants
    keys: ClassVar[tuple[str, ...]] = ()  # the section's keys whose product lists them, in field order

    @classmethod
    def grid(cls, section_grid: Any) -> tuple["Variant", ...]:
        """Its variants in ``section_grid`` (its section's typed grid): one per combination of the values of
        its :attr:`keys`, the first key outermost (the order of its dvc.yaml matrix)."""
        return tuple(cls(*values) for values in product(*(getattr(section_grid, key) for key in cls.keys)))

    @property
    @abstractmethod
    def name(self) -> str:
        """Derived from the fields; the variant's part of its students' names."""

    def apply(self, config: "DistillConfig") -> "DistillConfig":
        """The distillation config its students train with: ``config`` (plain MOP's) with its change."""
        return config

    @property
    def composed(self) -> str:
        """The composed dataset its states come from (mop_core.shift.compose); "" = the offline datasets."""
        return ""

    @property
    def correction(self) -> str:
        """Its state-shift correction (reweight, dagger: thesis 5.3); "" = none."""
        return ""

    @property
    def pooled_states(self) -> bool:
        """States from the union of every task's dataset (DS, OQS), not each task's own."""
        return False

    @property
    def only_task(self) -> str | None:
        """The one task it is distilled on (a single-task student); None = every study task."""
        return None

    def __str__(self) -> str:
        return self.name


VARIANTS: dict[str, type[Variant]] = {}  # family -> class: every kind of student variant

V = TypeVar("V", bound=type[Variant])


def register_variant(cls: V) -> V:
    """Add a variant family to :data:`VARIANTS` (its ``family`` must be new)."""
    if cls.family in VARIANTS:
        raise ValueError(f"variant family {cls.family!r} is registered twice")
    VARIANTS[cls.family] = cls
    return cls


def _with_width(config: "DistillConfig", width: int) -> "DistillConfig":
    sizes = (width,) * len(config.student.hidden_sizes)
    return replace(config, student=replace(config.student, hidden_sizes=sizes))


@register_variant
@dataclass(frozen=True)
class Width(Variant):
    """Every hidden layer ``width`` wide instead of ``distill.student.hidden_sizes`` (6.3.1)."""

    width: int
    family: ClassVar[str] = "width"
    stage: ClassVar[str] = "distill_width"
    section: ClassVar[str] = "common_structure"
    keys: ClassVar[tuple[str, ...]] = ("widths",)

    @property
    def name(self) -> str:
        return f"w{self.width}"

    def apply(self, config: "DistillConfig") -> "DistillConfig":
        return _with_width(config, self.width)


@register_variant
@dataclass(frozen=True)
class Ranking(Variant):
    """The ranking regulariser of ranking loss ``loss`` (6.3.2; distill.ranking's other settings)."""

    loss: str
    family: ClassVar[str] = "ranking"
    stage: ClassVar[str] = "distill_ranking"
    section: ClassVar[str] = "common_structure"
    keys: ClassVar[tuple[str, ...]] = ("ranking_losses",)

    @property
    def name(self) -> str:
        return f"rank_{self.loss}"

    def apply(self, config: "DistillConfig") -> "DistillConfig":
        return replace(config, ranking=replace(config.ranking, loss=self.loss))


@register_variant
@dataclass(frozen=True)
class SingleTask(Variant):
    """Distilled on ``task`` alone (its teacher, its dataset, one task id): the no-sharing reference."""

    task: str
    family: ClassVar[str] = "single_task"
    stage: ClassVar[str] = "distill_single"
    section: ClassVar[str] = "common_structure"
    keys: ClassVar[tuple[str, ...]] = ("single_task",)

    @property
    def name(self) -> str:
        return f"single_{self.task}"

    @property
    def only_task(self) -> str | None:
        return self.task


SHARING_KINDS = ("mop", "ds", "oqs")
Q_SWITCH_JUDGES = ("own", "target")  # OQS: each candidate judged by its own critics, or by the target task's


@register_variant
@dataclass(frozen=True)
class Sharing(Variant):
    """A data-sharing student (6.4): ``ds`` (DS teachers), ``oqs`` with a ``judge`` (the offline
    Q-switch), or ``mop`` (plain MOP's student of a substituted task set, its own states)."""

    kind: str
    judge: str = ""
    family: ClassVar[str] = "sharing"
    stage: ClassVar[str] = "distill_sharing"
    section: ClassVar[str] = "data_sharing"  # no keys: the catalogue makes its students per level and
    # substitute from SHARING_VARIANTS

    def __post_init__(self) -> None:
        if self.kind not in SHARING_KINDS or (self.kind == "oqs") != (self.judge in Q_SWITCH_JUDGES):
            raise ValueError(f"Sharing: expected kind in {SHARING_KINDS} with a judge in {Q_SWITCH_JUDGES} "
                             f"for oqs only, got {self.kind!r}, {self.judge!r}")

    @property
    def name(self) -> str:
        return f"{self.kind}_{self.judge}" if self.judge else self.kind

    @property
    def pooled_states(self) -> bool:
        return self.kind != "mop"


SHARING_VARIANTS = {v.name: v for v in (Sharing("mop"), Sharing("ds"), Sharing("oqs", "own"), Sharing("oqs", "target"))}
"""The data_sharing students by the name the params give them (``students``, ``substitute_students``)."""


@register_variant
@dataclass(frozen=True)
class Composed(Variant):
    """States of the composed dataset ``dataset`` (5.2.4), every hidden layer ``width`` wide."""

    dataset: str
    width: int
    family: ClassVar[str] = "composed"
    stage: ClassVar[str] = "distill_composed"
    section: ClassVar[str] = "state_shift"
    keys: ClassVar[tuple[str, ...]] = ("datasets", "widths")

    @property
    def name(self) -> str:
        return f"on_{self.dataset}_w{self.width}"

    def apply(self, config: "DistillConfig") -> "DistillConfig":
        return _with_width(config, self.width)

    @property
    def composed(self) -> str:
        return self.dataset


@register_variant
@dataclass(frozen=True)
class Size(Variant):
    """``percent``% of the whole episodes of each task's dataset (``distill.data_fraction``)."""

    percent: int
    family: ClassVar[str] = "size"
    stage: ClassVar[str] = "distill_size"
    section: ClassVar[str] = "state_shift"
    keys: ClassVar[tuple[str, ...]] = ("data_percents",)

    @property
    def name(self) -> str:
        return f"data{self.percent}"

    def apply(self, config: "DistillConfig") -> "DistillConfig":
        return replace(config, data_fraction=self.percent / 100)


@register_variant
@dataclass(frozen=True)
class Corrected(Variant):
    """The state-shift correction ``method`` (reweight, dagger: 5.3) on ``dataset`` (a composed one or
    ``offline``, the pairing's collect dataset) at width ``width``."""

    method: str
    dataset: str
    width: int
    family: ClassVar[str] = "corrected"
    stage: ClassVar[str] = "distill_corrected"
    section: ClassVar[str] = "state_shift"
    keys: ClassVar[tuple[str, ...]] = ("corrections", "correction_datasets", "correction_widths")

    @property
    def name(self) -> str:
        return f"{self.method}_{self.dataset}_w{self.width}"

    def apply(self, config: "DistillConfig") -> "DistillConfig":
        return replace(_with_width(config, self.width), correction=self.method)

    @property
    def composed(self) -> str:
        return "" if self.dataset == OFFLINE_DATA else self.dataset

    @property
    def correction(self) -> str:
        return self.method
