"""DAgger for a distillation group (thesis 5.3): at each round every student rolls out, its teachers label
the visited states, and they join the training states (mop_core.distill.corrections.DaggerConfig)."""

from __future__ import annotations

from typing import Callable, Sequence

import torch

from mop_core.distill.distiller import Distiller
from mop_core.distill.evaluation import Rollouts
from mop_core.distill.states import (
    teacher_outputs,
)
from mop_core.teacher_policies import Teacher


def with_dagger(distiller: Distiller, teachers: Sequence[Teacher], steps: int, seed: int,
                rollouts: Callable[..., Rollouts]) -> Callable[[], dict]:
    """The group's update: ``distiller.update``, preceded at each DAgger round's start (correction
    dagger) by :func:`dagger_round`. The round depends on the update count only, so a resumed run
    aggregates where an uninterrupted one does (the aggregated states are in the resume state)."""
    config = distiller.config
    rounds = config.dagger.round_starts(steps) if config.correction == "dagger" else {}
    if not rounds:
        return distiller.update

    def update() -> dict:
        if distiller.updates in rounds:
            dagger_round(distiller, teachers, rounds[distiller.updates], config.dagger.episodes, seed, rollouts)
        return distiller.update()
    return update


def dagger_round(distiller: Distiller, teachers: Sequence[Teacher], round_index: int, episodes: int, seed: int,
                 rollouts: Callable[..., Rollouts]) -> None:
    """One DAgger aggregation (mop_core.distill.corrections): every run's student rolls out ``episodes``
    episodes per task (seeds of round ``round_index``, the same for every run), the frozen teacher
    labels the visited states and they join that run's states."""
    students = [distiller.student(r) for r in range(distiller.runs)]
    round_seeds = [seed + 1000 * round_index + j for j in range(episodes)]
    for i, teacher in enumerate(teachers):
        for r, (_, states) in enumerate(rollouts(students, i, round_seeds, keep_states=True)):
            tensor = torch.as_tensor(states, dtype=torch.float32)  # the frozen teachers act on the CPU
            actions, std = teacher_outputs(teacher.actor, tensor)
            distiller.aggregate(r, i, tensor, actions, std)
