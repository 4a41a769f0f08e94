"""Student variants of the common-structure experiments (thesis 6.3), each a change of one
distillation setting next to plain MOP:

- ``w<width>`` (6.3.1, Figure 6.4): every hidden layer ``width`` wide instead of
  ``distill.student.hidden_sizes`` (same depth);
- ``rank_<loss>`` (6.3.2, Figure 6.5): the ranking regulariser with ranking loss ``<loss>``
  (``distill.ranking``'s weight, layer weights, states and temperature; mop_core.ranking).

The single-task students (``single_<task>``, the no-sharing reference of shared_computation) keep
every setting too: they learn from one task's teacher and dataset only (one task id;
mop_core.catalogue.make_structure_student).

The data-sharing students (6.4: ``ds``, ``oqs_own``, ``oqs_target``; ``mop``, plain MOP on a substituted
task set) keep every distillation setting:
what changes is what they learn from (other teachers, the union of the tasks' states:
mop_core.catalogue.make_sharing_student), so their config is plain MOP's.

The state-shift students (thesis 5.2, the ``state_shift`` section) keep every setting but one:
``on_<dataset>_w<width>`` (5.2.4, Figure 5.8) learn on a composed dataset (mop_core.compose: what the
students read, StudentRun.datasets) with every hidden layer ``width`` wide; ``data<percent>`` learn on
``percent``% of the whole episodes of each task's dataset (``data_fraction``). The correcting students
``<correction>_<dataset>_w<width>`` (5.3, issue 18 part 6) learn on a composed dataset or the offline
one (``offline``) at that width with ``correction`` reweight or dagger (mop_core.distill.corrections;
its settings: distill.reweight, distill.dagger).

A variant's students are named ``<loss>-<variant>-<pairing>-<seed>`` (the names: mop_core.runs);
plain MOP students have no variant. The study's variants come from the ``common_structure`` params section
(mop_core.study.structure_grid).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from mop_core.ranking import RANKING_LOSSES
from mop_core.runs import RANKING_PREFIX, WIDTH_PREFIX, correction_parts, shift_data, single_task_of, size_percent
from mop_core.study import SUBSTITUTE_STUDENTS

if TYPE_CHECKING:
    from mop_core.distill.distiller import DistillConfig


def variant_config(config: "DistillConfig", variant: str) -> "DistillConfig":
    """``config`` with ``variant``'s change ("" = plain MOP: unchanged)."""
    if not variant or variant in SUBSTITUTE_STUDENTS or single_task_of(variant):
        return config
    if variant.startswith(RANKING_PREFIX) and variant[len(RANKING_PREFIX):] in RANKING_LOSSES:
        return replace(config, ranking=replace(config.ranking, loss=variant[len(RANKING_PREFIX):]))
    correction = correction_parts(variant)
    if correction:
        config = replace(config, correction=correction[0])
    if shift_data(variant):
        variant = f"{WIDTH_PREFIX}{shift_data(variant)[1]}"  # the data is the run's; the width is the config's
    percent = size_percent(variant)
    if percent is not None:
        return replace(config, data_fraction=percent / 100)
    width = variant[len(WIDTH_PREFIX):]
    if variant.startswith(WIDTH_PREFIX) and width.isdigit() and int(width) >= 1:
        sizes = (int(width),) * len(config.student.hidden_sizes)
        return replace(config, student=replace(config.student, hidden_sizes=sizes))
    raise ValueError(f"variant: expected '', w<width>, rank_<one of {tuple(RANKING_LOSSES)}>, single_<task>, "
                     f"on_<composed dataset>_w<width>, <reweight|dagger>_<dataset>_w<width>, data<percent> "
                     f"or one of {tuple(SUBSTITUTE_STUDENTS)}, "
                     f"got {variant!r}")
