"""The distillation losses as the study sees them (thesis 4.2, 5.1): each one's name, the PBRL actor type
of the teachers it distils, whether its student is Gaussian and whether it needs the teachers' critics.
Torch-free, so the catalogue knows which teachers a student learns from without importing the learner;
mop_core.distill.losses adds each loss's computation to these.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LossKind:
    """A distillation loss and what it needs."""

    name: str
    teacher_actor: str  # the PBRL actor type of the teachers it distils: "deterministic" or "gaussian"
    gaussian_student: bool  # the student has a diagonal Gaussian head (mean, log std)
    needs_critics: bool  # the teachers' critic ensembles are part of the loss


LOSS_KINDS: dict[str, LossKind] = {
    "mse": LossKind("mse", "deterministic", gaussian_student=False, needs_critics=False),
    "q": LossKind("q", "deterministic", gaussian_student=False, needs_critics=True),
    "kl": LossKind("kl", "gaussian", gaussian_student=True, needs_critics=False),
}
