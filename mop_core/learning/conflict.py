"""Gradient conflict between tasks (PCGrad's measure, Yu et al. 2020), the number behind thesis
5.1.2's explanation of naive multi-task failure: tasks that share weights pull them apart.

For tasks i and k sharing weights theta: ``cos(g_i, g_k)`` with ``g_i = d L_i / d theta`` on a batch
of task i's states. A negative cosine is a conflict (a step for task i undoes part of task k's);
PCGrad projects such gradients, this module only measures them. Both the naive multi-task actor
(:class:`mop_core.agents.pbrl_multitask.MultiTaskPBRL`) and a student group
(:class:`mop_core.distill.distiller.Distiller`) log the cosine as a curve during training.
"""

from __future__ import annotations

import itertools
import math
from typing import Sequence

import torch


def flat_gradient(loss: torch.Tensor, params: Sequence[torch.Tensor], runs: int = 1) -> torch.Tensor:
    """``d loss / d params`` flattened per run: ``[runs, P]``. Each parameter's leading dimension is
    the run (a vectorised group's ``[R, ...]`` weights) when ``runs > 1``; parameters the loss does
    not reach contribute zeros. Leaves every ``.grad`` untouched (``torch.autograd.grad``)."""
    grads = torch.autograd.grad(loss, list(params), allow_unused=True)
    return torch.cat([(g if g is not None else torch.zeros_like(p)).reshape(runs, -1)
                      for g, p in zip(grads, params)], dim=1)


def pairwise_cosines(gradients: Sequence[torch.Tensor], tasks: Sequence[str]) -> list[dict[str, float]]:
    """Per run: ``grad_cosine_<i>-<k>`` for every task pair (``gradients[i]``: task i's ``[runs, P]``)
    and ``grad_cosine``, their mean (NaN with one task)."""
    if len(gradients) != len(tasks):
        raise ValueError(f"gradients: expected one per task ({len(tasks)}), got {len(gradients)}")
    runs = gradients[0].shape[0]
    out: list[dict[str, float]] = [{} for _ in range(runs)]
    for i, k in itertools.combinations(range(len(tasks)), 2):
        cosines = torch.nn.functional.cosine_similarity(gradients[i], gradients[k], dim=1)
        for r in range(runs):
            out[r][f"grad_cosine_{tasks[i]}-{tasks[k]}"] = float(cosines[r])
    for row in out:
        row["grad_cosine"] = sum(row.values()) / len(row) if row else math.nan
    return out
