"""One loader for every policy checkpoint of a study: ``load_policy(path) -> Policy``.

Every checkpoint the stages write carries ``kind`` (what wrote it); the package versions it was
written with are in the run's timing record (results/timings/), not in the checkpoint, so that the
same weights are the same bytes on any machine. :func:`load_policy` reads the kind and rebuilds the
acting network the same way for all of them; a Policy maps observations ``[K, 24]`` to actions
``[K, 6]`` (float64), as the rollouts (:mod:`mop_core.walker.rollout`) step them. Gaussian actors act by
their mean unless a student is given a ``sample_seed``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from mop_core.agents.td3 import actor_from_checkpoint
from mop_core.collect import BEHAVIOUR_KIND
from mop_core.config import InputFileError
from mop_core.distill.checkpoint import STUDENT_KIND, student_from_checkpoint
from mop_core.learning.nn import NumpyPolicy, numpy_policy
from mop_core.storage.artifacts import read_torch_file
from mop_core.teacher_policies import MULTITASK_KIND, TEACHER_KIND, multitask_from_checkpoint, teacher_from_checkpoint

Policy = NumpyPolicy
TASK_CONDITIONED = (MULTITASK_KIND, STUDENT_KIND)  # kinds that act under a task id

_LOADERS: dict[str, Callable[[dict, str | None, int | None], Policy]] = {
    BEHAVIOUR_KIND: lambda payload, task, sample_seed: numpy_policy(actor_from_checkpoint(payload)),
    TEACHER_KIND: lambda payload, task, sample_seed: teacher_from_checkpoint(payload).act,
    MULTITASK_KIND: lambda payload, task, sample_seed: multitask_from_checkpoint(payload).policy(task),
    STUDENT_KIND: lambda payload, task, sample_seed: student_from_checkpoint(payload).policy(task, sample_seed),
}
POLICY_KINDS = tuple(_LOADERS)


def checkpoint_kind(payload: object) -> str | None:
    return payload.get("kind") if isinstance(payload, dict) else None


def load_policy(path: str | Path, task: str | None = None, sample_seed: int | None = None) -> Policy:
    """The policy of any study checkpoint; ``task``: the task id a multi-task policy acts under;
    ``sample_seed``: a Gaussian student samples its actions from a generator of this seed."""
    payload = read_torch_file(path)
    kind = checkpoint_kind(payload)
    if kind not in _LOADERS:
        raise InputFileError(f"{path}: not a policy checkpoint of this study (kind {kind!r}; expected one of "
                             f"{', '.join(POLICY_KINDS)}); rerun the stage that writes it")
    if kind in TASK_CONDITIONED and task is None:
        raise ValueError(f"task: a {kind} checkpoint acts under a task id; name the task ({path})")
    return _LOADERS[kind](payload, task, sample_seed)
