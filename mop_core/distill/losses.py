"""Distillation losses of thesis 5.1.3, per state; the caller averages over states and tasks.

With m tasks, task i's states s ~ D_i (or the teacher's online states), student pi^S(s, i) and
frozen teacher i:

- MSE:  L_MSE = 1/m sum_i E_s || pi_i^T(s) - pi^S(s, i) ||_2^2
- Q:    L_Q   = -1/m sum_i E_s [ Q_i^T(s, pi^S(s, i)) ]; Q_i^T is the teacher's critic ensemble,
        reduced over its members by ``min`` (the quantity the PBRL actor itself maximises, so the
        student is not drawn to actions only one member overrates) or ``mean``.
- KL:   L_KL  = 1/m sum_i E_s KL( N(mu^S, Sigma^S) || N(mu_i^T, Sigma_i^T) ), diagonal covariances:
        KL = 1/2 [ tr(Sigma_T^-1 Sigma_S) + (mu_T - mu_S)^T Sigma_T^-1 (mu_T - mu_S) - k
                   + ln(|Sigma_T| / |Sigma_S|) ].
        The thesis prints ``- ln(|Sigma_T| / |Sigma_S|)``, a sign slip: with it the "divergence" is
        not zero-minimised at Sigma_S = Sigma_T. The code implements the true KL (tested against
        a Monte Carlo estimate and torch.distributions).

Every task contributes the same number of states to a batch, so the mean over all rows of a batch
equals the thesis's 1/m sum over tasks of the per-task expectations.

:data:`LOSSES` is the table every other module asks (name -> :class:`Loss`): which teachers a
loss distils (KL: Gaussian teachers, thesis 5.1.3), which head the student needs, whether it needs
the teachers' critics, and the per-state loss itself. A new loss is one entry here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import torch

from mop_core.experiment.losses import LOSS_KINDS, LossKind

Q_REDUCTIONS = ("min", "mean")


def mse_per_state(student_actions: torch.Tensor, teacher_actions: torch.Tensor) -> torch.Tensor:
    """``||pi^T(s) - pi^S(s, i)||_2^2`` per row: ``[B, k], [B, k] -> [B]``."""
    return (teacher_actions - student_actions).pow(2).sum(-1)


def reduce_ensemble(q_values: torch.Tensor, reduction: str) -> torch.Tensor:
    """``[E, B] -> [B]``: the minimum or the mean over the critic ensemble."""
    if reduction == "min":
        return q_values.min(0).values
    if reduction == "mean":
        return q_values.mean(0)
    raise ValueError(f"reduction: expected one of {Q_REDUCTIONS}, got {reduction!r}")


def q_per_state(q_values: torch.Tensor, reduction: str) -> torch.Tensor:
    """``-Q^T(s, pi^S(s, i))`` per row from the ensemble's values ``[E, B]`` -> ``[B]``."""
    return -reduce_ensemble(q_values, reduction)


def gaussian_kl_per_state(mu_s: torch.Tensor, std_s: torch.Tensor, mu_t: torch.Tensor,
                          std_t: torch.Tensor) -> torch.Tensor:
    """``KL(N(mu_s, diag std_s^2) || N(mu_t, diag std_t^2))`` per row, closed form: ``[B, k] x 4 -> [B]``."""
    var_s, var_t = std_s.pow(2), std_t.pow(2)
    trace = (var_s / var_t).sum(-1)
    mahalanobis = ((mu_t - mu_s).pow(2) / var_t).sum(-1)
    log_det_ratio = (var_t.log() - var_s.log()).sum(-1)  # ln(|Sigma_T| / |Sigma_S|)
    return 0.5 * (trace + mahalanobis - mu_s.shape[-1] + log_det_ratio)


@dataclass(frozen=True)
class LossInputs:
    """One batch as a loss sees it: states of several tasks in blocks (``sizes[k]`` rows of task
    ``tasks[k]``), their task ids, the frozen teachers' outputs and, for the Q loss, their critics."""

    student: torch.nn.Module  # a Student ([B] rows) or a StudentGroup ([R, B] rows: one batch per run)
    obs: torch.Tensor  # [B, obs_dim] or [R, B, obs_dim]
    task_ids: torch.Tensor  # [B] (the same layout for every run)
    teacher_actions: torch.Tensor  # [(R,) B, k]: the teacher's action (a Gaussian teacher's mean)
    teacher_std: torch.Tensor | None  # [(R,) B, k]: a Gaussian teacher's std (None for deterministic teachers)
    tasks: Sequence[int]  # task index of each block
    sizes: Sequence[int]  # rows of each block
    critics: Sequence[torch.nn.Module]  # per task index: the teacher's critic ensemble (Q loss only)
    q_reduction: str = "min"


def _mse(x: LossInputs) -> tuple[torch.Tensor, torch.Tensor]:
    actions = x.student(x.obs, x.task_ids)
    return mse_per_state(actions, x.teacher_actions), actions


def _q(x: LossInputs) -> tuple[torch.Tensor, torch.Tensor]:
    actions = x.student(x.obs, x.task_ids)
    blocks = []
    for t, o, a in zip(x.tasks, x.obs.split(list(x.sizes), dim=-2), actions.split(list(x.sizes), dim=-2)):
        # every run's rows of task t through the one frozen critic ensemble, as one batch
        q = q_per_state(x.critics[t](o.reshape(-1, o.shape[-1]), a.reshape(-1, a.shape[-1])), x.q_reduction)
        blocks.append(q.reshape(o.shape[:-1]))
    return torch.cat(blocks, dim=-1), actions


def _kl(x: LossInputs) -> tuple[torch.Tensor, torch.Tensor]:
    mu, std = x.student.distribution(x.obs, x.task_ids)
    return gaussian_kl_per_state(mu, std, x.teacher_actions, x.teacher_std), mu


@dataclass(frozen=True)
class Loss(LossKind):
    """A distillation loss (:class:`~mop_core.experiment.losses.LossKind`) with its computation."""

    per_state: Callable[[LossInputs], tuple[torch.Tensor, torch.Tensor]]  # -> (loss [(R,) B], action [(R,) B, k])


_PER_STATE = {"mse": _mse, "q": _q, "kl": _kl}
LOSSES: dict[str, Loss] = {name: Loss(**vars(kind), per_state=_PER_STATE[name]) for name, kind in LOSS_KINDS.items()}


