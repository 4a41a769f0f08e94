"""The study's headline numbers in one small file (``results/metrics.json``, the DVC metrics that
``dvc metrics diff`` and ``dvc exp show`` compare experiments by):

- ``normalised_return.<group>.<task>``: the mean normalised score 100 (R - R_random) / (R_expert -
  R_random) of every policy group the eval stage rolled out (behaviour levels, teachers, the
  multi-task baseline, each student group), mean over its training seeds;
- ``per_state_tau_a`` / ``per_state_tau_b`` ``.<student group>.<task pair>.<layer>``: the mean
  per-state Kendall tau between the student's activations under the two task ids (thesis Table 6.1;
  tau-a is the thesis's formula, tau-b removes tied neurons), mean over the group's seeds.

Everything else (intervals, seeds, per-run records) stays in each stage's own files; times are in
results/timings/.
"""

from __future__ import annotations

from typing import Any, Mapping

from mop_core.experiment.runs import is_cross_group

TAU_KEYS = ("per_state_tau_a", "per_state_tau_b")


def headline_metrics(evaluation: Mapping[str, Any] | None, shared: Mapping[str, Any] | None,
                     tasks: list[str]) -> dict[str, Any]:
    """The headline record from the eval and shared_computation metrics (a part not run is left out)."""
    out: dict[str, Any] = {}
    if evaluation:
        scores: dict[str, dict[str, float]] = {}
        for task in tasks:
            for group, entry in evaluation.get(task, {}).items():
                if isinstance(entry, Mapping) and "normalised" in entry and not is_cross_group(group):
                    scores.setdefault(group, {})[task] = round(float(entry["normalised"]["mean"]), 2)
        out["normalised_return"] = scores
    if shared:
        for key in TAU_KEYS:
            out[key] = {group: {pair: {layer: round(float(row[f"{key}_mean"]), 4) for layer, row in layers.items()}
                                for pair, layers in summary["pairs"].items()}
                        for group, summary in shared.get("groups", {}).items()}
    return out
