"""The state_shift stage's work (thesis 5.2, issue 18): how far each dataset's states lie from the
states the teacher visits, measured (mop_core.shift), next to how the students distilled on them do.

1. :func:`measure_shift`: per study task, every dataset (the collect levels, the composed datasets)
   against the reference: held-out episodes of the teacher (mop_core.compose). Per dataset D and
   teacher-visited states T, on ``states`` states of each, standardised by the task's pooled
   mean and standard deviation (one transform per task, so its datasets are comparable):

   - ``kl``: the kNN estimate of KL(T || D) in nats (what the teacher visits that D lacks: the
     student is trained on D and acts on T), with a bootstrap percentile interval and its
     split-half null (T against T at half the sample size: what "no shift" gives; the estimator
     is biased low in 24 dimensions, so read values as a ranking against that null);
   - ``auc``: the held-out ROC AUC of a classifier telling T (1) from D (0) (0.5: no shift), and
     ``ess``: the effective sample share ``(sum w)^2 / (n sum w^2)`` of the density ratio
     ``w = p_T / p_D`` it implies on D's states (1: uniform weights; small: a few of D's states
     carry the teacher's distribution, what reweighted distillation would rely on).

2. :func:`student_table`: per state-shift student group (composed data x width, dataset share) and
   per reference group (plain MOP; the common_structure widths on the offline data), each task's
   return from the distill runs' final evaluations: mean over training seeds with a Student-t 95%
   interval over them (n = seeds), its normalised score and ratio to the teacher.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import torch

from mop_core.config import from_mapping, require
from mop_core.shift import ClassifierConfig, classifier_test, draw, effective_share, knn_kl
from mop_core.statistics import MIN_SEEDS_FOR_SEED_CI, confidence_interval, normalised_score


@dataclass(frozen=True)
class MeasureConfig:
    """How the shift is measured (the ``state_shift.measure`` params)."""

    states: int = 10000  # states drawn from each set (without replacement; all if fewer)
    k: int = 5  # kNN estimator's neighbour
    bootstrap: int = 10  # random half-samples of the kNN estimate's interval and of its null
    classifier_epochs: int = 10
    threads: int = 2  # torch threads

    def __post_init__(self) -> None:
        require(self.states >= 100, "states", "at least 100", self.states)
        require(1 <= self.k < self.states // 2, "k", f"in [1, states / 2) (the null halves {self.states} states)",
                self.k)
        require(self.bootstrap >= 2, "bootstrap", "at least 2 half-samples", self.bootstrap)
        require(self.classifier_epochs >= 1, "classifier_epochs", "a positive integer", self.classifier_epochs)
        require(self.threads >= 1, "threads", "a positive integer", self.threads)


ACTION_ERRORS = ("train", "heldout", "visited")  # where a student's action error to its teacher is measured


def measure_config(grid) -> MeasureConfig:
    """The measure settings of a :class:`mop_core.study.ShiftGrid`."""
    return from_mapping(MeasureConfig, grid.measure or {}, "state_shift.measure")


def half_estimates(x: np.ndarray, y: np.ndarray, statistic, reps: int, seed: int) -> list[float]:
    """``statistic`` on ``reps`` pairs of random halves of x and y (drawn without replacement): the
    kNN estimator's spread at one sample size, the size its split-half null is computed at (a
    bootstrap resample repeats states, which the estimator counts once: another, smaller sample)."""
    rng = np.random.default_rng(seed)
    half_x, half_y = len(x) // 2, len(y) // 2
    return [statistic(x[np.sort(rng.choice(len(x), half_x, replace=False))],
                      y[np.sort(rng.choice(len(y), half_y, replace=False))]) for _ in range(reps)]


def null_estimates(x: np.ndarray, statistic, reps: int, seed: int) -> list[float]:
    """``statistic`` between two disjoint random halves of x, ``reps`` times: what no shift gives."""
    rng = np.random.default_rng(seed)
    half = len(x) // 2
    values = []
    for _ in range(reps):
        order = rng.permutation(len(x))
        values.append(statistic(x[np.sort(order[:half])], x[np.sort(order[half:2 * half])]))
    return values


def _summary(values: Sequence[float]) -> dict[str, float]:
    low, high = np.percentile(values, [2.5, 97.5])
    return {"mean": float(np.mean(values)), "low": float(low), "high": float(high)}


def measure_shift(sets: Mapping[str, np.ndarray], reference: np.ndarray, config: MeasureConfig, seed: int
                  ) -> dict[str, dict]:
    """Every set of ``sets`` against the teacher's ``reference`` states (module docstring, item 1)."""
    rng = np.random.default_rng(seed)
    teacher = draw(reference, config.states, rng)
    drawn = {name: draw(states, config.states, rng) for name, states in sets.items()}
    pooled = np.concatenate([teacher, *drawn.values()])
    mean, std = pooled.mean(0), np.maximum(pooled.std(0), 1e-6)
    teacher = (teacher - mean) / std

    def kl(x: np.ndarray, y: np.ndarray) -> float:
        return knn_kl(x, y, config.k)

    null = _summary(null_estimates(teacher, kl, config.bootstrap, seed))
    out = {"reference": {"states": len(teacher), "kl_null": null["mean"], "kl_null_low": null["low"],
                         "kl_null_high": null["high"]}}
    for i, (name, states) in enumerate(drawn.items()):
        data = (states - mean) / std
        halves = _summary(half_estimates(teacher, data, kl, config.bootstrap, seed + 1 + i))
        classifier = classifier_test(teacher, data, ClassifierConfig(epochs=config.classifier_epochs, seed=seed + i))
        ratio = classifier.density_ratio(torch.as_tensor(data))
        out[name] = {"states": len(data), "kl": halves["mean"], "kl_low": halves["low"], "kl_high": halves["high"],
                     "kl_full": kl(teacher, data), "auc": classifier.auc, "ess": effective_share(ratio),
                     "ratio_p99": float(np.percentile(ratio, 99))}
    return out


def seed_interval(values: Sequence[float]) -> dict:
    """Mean over training seeds with a Student-t 95% interval (none below MIN_SEEDS_FOR_SEED_CI seeds)."""
    ci = confidence_interval(values)
    if ci["n"] < MIN_SEEDS_FOR_SEED_CI:
        ci["ci_low"] = ci["ci_high"] = None
    return ci


def student_table(groups: Mapping[str, Sequence[Mapping]], tasks: Sequence[str], norms: Mapping[str, Mapping]
                  ) -> dict[str, dict]:
    """Per group (label -> its students' distill metrics records) and task: return, normalised score
    and ratio to the teacher, each a mean over the students (training seeds) with its t-interval."""
    table: dict[str, dict] = {}
    for label, records in groups.items():
        if not records:
            continue
        row = {"seeds": [r["seed"] for r in records]}
        for task in tasks:
            returns = [r[task]["return_mean"] for r in records]
            norm = norms[task]
            row[task] = {"return": seed_interval(returns),
                         "normalised": seed_interval(list(normalised_score(np.array(returns), norm["random_return"],
                                                                           norm["expert_return"]))),
                         "to_teacher": seed_interval([r[task]["student_to_teacher"] for r in records]),
                         "teacher_return": records[0][task]["teacher_return_mean"],
                         "episodes_per_seed": records[0][task]["eval_episodes"]}
            errors = [r[task].get("action_mse", {}) for r in records]
            row[task]["action_mse"] = {kind: seed_interval([e[kind] for e in errors])
                                       for kind in ACTION_ERRORS if all(kind in e for e in errors)}
        table[label] = row
    return table


def correction_table(records: Mapping[str, Sequence[Mapping]], groups: Mapping[str, Mapping], tasks: Sequence[str]
                     ) -> dict[str, dict]:
    """Per correcting group (``groups[label]["correction"]`` reweight or dagger), its gain over the plain
    students on the same data and width (the group whose info matches with correction none), per
    task: the return difference paired by training seed, mean with its t-interval over the seeds
    (each pair shares its seed's initialisation; the data or its weighting differs)."""
    out: dict[str, dict] = {}
    for label, info in groups.items():
        if info.get("correction", "none") == "none":
            continue
        base = next((other for other, o in groups.items() if o.get("correction", "none") == "none"
                     and (o["data"], o["width"], o["percent"]) == (info["data"], info["width"], info["percent"])),
                    None)
        if base is None or base not in records:
            continue
        plain_by_seed = {r["seed"]: r for r in records[base]}
        pairs = [(r, plain_by_seed[r["seed"]]) for r in records[label] if r["seed"] in plain_by_seed]
        if not pairs:
            continue
        out[label] = {"plain": base, "correction": info["correction"], "data": info["data"], "width": info["width"],
                      "seeds": [r["seed"] for r, _ in pairs]}
        for task in tasks:
            out[label][task] = {
                "gain": seed_interval([r[task]["return_mean"] - b[task]["return_mean"] for r, b in pairs]),
                "to_teacher_gain": seed_interval([r[task]["student_to_teacher"] - b[task]["student_to_teacher"]
                                                  for r, b in pairs]),
                "reweight": records[label][0][task].get("reweight")}  # the weights' AUC, ESS (shared by seeds)
    return out
