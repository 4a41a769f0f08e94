"""A trained student's checkpoint read back: the student, its tasks and config, its policy per task id.

Needs no params.yaml: the checkpoint holds the distillation config (mop_core.distill.run writes it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from mop_core.config import from_mapping
from mop_core.distill.config import DistillConfig
from mop_core.distill.losses import LOSSES
from mop_core.distill.student import Student
from mop_core.learning.nn import numpy_policy, with_task_id
from mop_core.storage.artifacts import load_checkpoint

STUDENT_KIND = "mop_student"


def student_policy(student: Student, task_index: int, device: torch.device, sample_seed: int | None = None
                   ) -> Callable[[np.ndarray], np.ndarray]:
    """A numpy policy of the student for one task id. A Gaussian student acts with its mean, or, with
    ``sample_seed``, with samples ``clip(mu + sigma eps, -1, 1)`` from a generator of that seed."""
    generator = None
    if sample_seed is not None:
        if not student.gaussian:
            raise ValueError("sample_seed: only a Gaussian (KL) student has actions to sample")
        generator = torch.Generator(device).manual_seed(sample_seed)

    if generator is None:
        return numpy_policy(lambda x: student(x, task_index), device)
    return numpy_policy(lambda x: student.actor.rsample(with_task_id(x, task_index, student.num_tasks), generator)[0],
                        device)


@dataclass
class LoadedStudent:
    """A trained student rebuilt from its checkpoint, with the tasks its task ids stand for."""

    student: Student
    tasks: list[str]
    config: DistillConfig
    checkpoint: dict

    def policy(self, task: str, sample_seed: int | None = None) -> Callable[[np.ndarray], np.ndarray]:
        return student_policy(self.student, self.tasks.index(task), torch.device("cpu"), sample_seed)


def load_student(path: str | Path) -> LoadedStudent:
    """Rebuild a student from a ``distill_student`` checkpoint (no params.yaml needed)."""
    return student_from_checkpoint(load_checkpoint(path, STUDENT_KIND))


def student_from_checkpoint(payload: dict) -> LoadedStudent:
    config = from_mapping(DistillConfig, payload["distill_config"], "distill_config")
    student = Student(config.student, payload["obs_dim"], payload["act_dim"], len(payload["tasks"]),
                      gaussian=LOSSES[config.loss].gaussian_student)
    student.load_state_dict(payload["student"])
    return LoadedStudent(student.eval().requires_grad_(False), list(payload["tasks"]), config, payload)
