"""What the verdicts read: a run's results (mop_core.report.document.StudyResults and the state_shift record)
as per-seed numbers of named policy groups, the unit every effect of mop_core.report.verdicts is built from.

Returns are the eval stage's (``seed_means`` per group and task), as normalised scores
``100 (R - R_random) / (R_expert - R_random)`` so that margins and effects mean the same on every
task. Tau comes from the shared_computation stage (Table 6.1/6.2's measures on visited states, per
student) or from the distill runs' probe states (Figures 6.4b/6.5b: the same offline states for every
student of a pairing, at initialisation and at the end). Group names are built by mop_core.experiment.runs'
own functions, never parsed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from mop_core.experiment.runs import representation_group, student_group, student_recipe, teacher_group
from mop_core.experiment.variants import Composed, Ranking, Sharing, SingleTask, Variant, Width
from mop_core.report.results import StudyResults

Seeds = dict[int, float]  # training seed (or a group member's position) -> value


@dataclass(frozen=True)
class Evidence:
    """Accessors over one run's results. ``settings``: the report's (study grid values)."""

    results: StudyResults
    shift: Mapping | None = None  # results/state_shift/metrics.json

    @property
    def tasks(self) -> list[str]:
        return self.results.tasks

    @property
    def settings(self) -> Mapping:
        return self.results.settings

    @property
    def pairing(self) -> str:
        """The pairing every comparison of plain and variant students uses (common_structure's)."""
        return self.settings.get("structure_pairing") or next(iter(self.results.pairing_levels), "medium")

    def level(self, task: str, pairing: str | None = None) -> str:
        pairing = pairing or self.pairing
        levels = self.results.pairing_levels.get(pairing, [pairing] * len(self.tasks))
        return levels[self.tasks.index(task)] if task in self.tasks else levels[-1]

    # ---- eval-stage returns ----------------------------------------------------------------------
    def entry(self, group: str, task: str) -> dict | None:
        return (self.results.evaluation or {}).get(task, {}).get(group)

    def scale(self, task: str) -> float:
        """Normalised points per unit of return on ``task``."""
        norm = (self.results.evaluation or {}).get("normalisation", {}).get(task)
        return 100.0 / (norm["expert_return"] - norm["random_return"]) if norm else float("nan")

    def normalise(self, task: str, value: float) -> float:
        norm = self.results.evaluation["normalisation"][task]
        return self.scale(task) * (value - norm["random_return"])

    def scores(self, group: str, task: str) -> Seeds | None:
        """Per training seed: the run's normalised score (mean over its eval episodes)."""
        entry = self.entry(group, task)
        if entry is None:
            return None
        return {int(seed): self.normalise(task, mean) for seed, mean in entry["seed_means"].items()}

    def task_mean(self, group: str, tasks: Sequence[str] | None = None) -> Seeds | None:
        """Per seed the mean over ``tasks`` (default: the study's) of the group's normalised scores."""
        per_task = [self.scores(group, task) for task in tasks or self.tasks]
        if any(p is None for p in per_task):
            return None
        seeds = sorted(set.intersection(*(set(p) for p in per_task)))
        return {s: float(np.mean([p[s] for p in per_task])) for s in seeds}

    def run(self, group: str, task: str) -> tuple[float, float | None, int] | None:
        """A policy trained once as a fixed target (teacher run ``teacher_seed``): its normalised mean,
        sd over its episodes and episode count."""
        entry = self.entry(group, task)
        if entry is None:
            return None
        seed = str(self.settings.get("teacher_seed", 0))
        run = entry.get("runs", {}).get(seed, entry)
        sd = run.get("std")
        return self.normalise(task, run["mean"]), None if sd is None else sd * self.scale(task), run["n"]

    def teacher_runs(self, task: str, level: str, actor: str = "deterministic") -> list:
        """The teacher runs (every training seed) of one task, level and actor type."""
        return [r for r in self.results.teachers if r.key == {"task": task, "level": level, "actor": actor}]

    def teacher_ratios(self, task: str, level: str, actor: str = "deterministic") -> Seeds | None:
        """Per training seed: the teacher's final return over its dataset's mean return (the teachers
        stage's ``return_ratio``, its own final evaluation)."""
        out = {r.seed: float(r.metrics["return_ratio"]) for r in self.teacher_runs(task, level, actor)
               if "return_ratio" in r.metrics}
        return out or None

    def teacher_late_gain(self, task: str, level: str, actor: str = "deterministic") -> Seeds | None:
        """Per training seed: how much the teacher's learning curve still rose at the end, in units of its
        dataset's mean return: the mean evaluation return of the curve's last quarter of gradient steps
        minus that of its third quarter (None where a curve has no point in either quarter)."""
        out = {}
        for run in self.teacher_runs(task, level, actor):
            steps = float(run.metrics.get("gradient_steps") or 0)
            points = [(float(row["step"]), float(row["return_mean"])) for row in run.curve]
            third = [r for s, r in points if 0.5 * steps < s <= 0.75 * steps]
            last = [r for s, r in points if s > 0.75 * steps]
            scale = float(run.metrics.get("dataset_return_mean") or 0.0)
            if third and last and scale:
                out[run.seed] = (float(np.mean(last)) - float(np.mean(third))) / scale
        return out or None

    # ---- group names -----------------------------------------------------------------------------
    def student(self, variant: Variant | None = None, loss: str = "mse", scope: str | None = None) -> str:
        return student_group(student_recipe(loss, variant), scope or self.pairing)

    def teacher(self, task: str, actor: str = "deterministic") -> str:
        return teacher_group(self.level(task), actor)

    def structure(self, variant: Variant | None = None, loss: str = "mse", scope: str | None = None) -> str:
        return representation_group(student_recipe(loss, variant), scope or self.pairing)

    @staticmethod
    def width(width: int) -> Variant:
        return Width(width)

    @staticmethod
    def ranking(loss: str) -> Variant:
        return Ranking(loss)

    @staticmethod
    def sharing(kind: str, judge: str = "") -> Variant:
        return Sharing(kind, judge)

    @staticmethod
    def single(task: str) -> Variant:
        return SingleTask(task)

    @staticmethod
    def composed(dataset: str, width: int) -> Variant:
        return Composed(dataset, width)

    # ---- tau -------------------------------------------------------------------------------------
    def layers(self) -> list[int]:
        shared = self.results.shared or {}
        group = next(iter(shared.get("groups", {}).values()), None)
        pair = next(iter((group or {}).get("pairs", {}).values()), {})
        return sorted(int(name.removeprefix("layer")) for name in pair)

    def sc_tau(self, group: str, layer: int, measure: str = "average_tau_a", pair: str | None = None
               ) -> Seeds | None:
        """shared_computation's tau of each student of ``group`` at ``layer``: ``average_tau_a`` (Table
        6.2's measure, thesis 6.2.3) or ``per_state_tau_a``; keyed by the member's position (members are
        listed in distill.seeds order, so two groups' positions pair the same seeds)."""
        shared = self.results.shared or {}
        summary = shared.get("groups", {}).get(group)
        if not summary:
            return None
        pair = pair or next(iter(summary["pairs"]))
        out = {}
        for position, member in enumerate(summary.get("members", [])):
            cell = shared["students"][member]["pairs"][pair][f"layer{layer}"][measure]
            out[position] = float(cell["mean"] if isinstance(cell, Mapping) else cell)
        return out or None

    def probe_tau(self, variant: Variant | None = None, layer: int = 1, at: str = "final", loss: str = "mse"
                  ) -> Seeds | None:
        """Each student's per-state tau-a at ``layer`` on the distill stage's probe states, ``final`` or
        ``at_init``."""
        runs = [r for r in self.results.students + self.results.variants
                if r.origin.loss == loss and r.origin.variant == variant and r.key["pairing"] == self.pairing]
        key = f"per_state_tau_a_layer{layer}"
        out = {r.seed: float(r.metrics["per_state_tau"][at][key]) for r in runs
               if key in r.metrics.get("per_state_tau", {}).get(at, {})}
        return out or None

