"""The state_shift stage's work (thesis 5.2): how far each dataset's states lie from the
states the teacher visits, measured (mop_core.shift.measures), next to how the students distilled on them do.

1. :func:`measure_shift`: per study task, every dataset (the collect levels, the composed datasets)
   against the reference: held-out episodes of the teacher (mop_core.shift.compose). Per dataset D and
   teacher-visited states T, standardised by the task's pooled mean and standard deviation (one
   transform per task, so its datasets are comparable), every split by whole episodes (an
   episode's states are near-duplicates, so halves sharing episodes read "no shift" whatever D):

   - ``kl``: the kNN estimate of KL(T || D) in nats (what the teacher visits that D lacks: the
     student is trained on D and acts on T), the mean over ``bootstrap`` random episode-halves
     with its range over them (``kl_min``, ``kl_max``: a range, not a confidence interval). Each
     half: T's episodes dealt into two disjoint halves A and B; ``kl_states`` states of A against
     as many states of B (the null: T against T, what "no shift" gives) and against as many states
     of D drawn from as many of its whole episodes as B has (the estimate, on the null's footing:
     a D drawn like T reads within the null). Each half's estimate is paired with its null (the
     same states of A): ``kl_excess`` is the mean of their difference, ``above_null`` the share of
     halves in which D reads above the null, and ``within_null`` is False when that share is at
     least ABOVE_NULL (a sign rule: under no shift each half is a coin flip). Pairing matters: a
     rare kind of episode in A (stand: a teacher episode that falls) sends the null and every
     estimate of that half up together, so the unpaired ranges overlap even for a clear shift. The
     estimator is biased low in 24 dimensions and an episode's states are near-duplicates (tens of
     nats even under no shift), so read values against the null;
   - ``auc``: the ROC AUC of a classifier telling T (1) from D (0) (0.5: no shift), cross-fitted
     over two folds of whole episodes of each set (each fold scored by the classifier trained on
     the other; the mean of the two), on ``states`` states of each; ``ess``: the effective sample
     share ``(sum w)^2 / (n sum w^2)`` of the density ratio ``w = p_T / p_D`` it implies on D's
     states, each from the classifier that did not see its episode (1: uniform weights; small: a
     few of D's states carry the teacher's distribution, what reweighted distillation relies on).

2. :func:`student_table`: per state-shift student group (composed data x width, dataset share) and
   per reference group (plain MOP; the common_structure widths on the offline data), each task's
   return from the eval stage (:func:`eval_returns`: the same numbers every other section of the
   report shows): mean over training seeds with a Student-t 95% interval over them (n = seeds, cut
   at 0), its normalised score and ratio to the teacher run's eval-stage return; the action errors
   come from the distill runs' own final evaluations (the states the students visit).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from mop_core.config import from_mapping, require
from mop_core.data import read_dataset
from mop_core.learning.runtime import resolve_threads
from mop_core.shift.measures import (
    ClassifierConfig,
    crossfit_test,
    draw_rows,
    effective_share,
    episode_folds,
    episode_ids,
    episode_sample,
    knn_kl,
    row_episodes,
)
from mop_core.statistics import RETURN_BOUNDS, normalised_score, seed_interval
from mop_core.storage.layout import REFERENCE


@dataclass(frozen=True)
class MeasureConfig:
    """How the shift is measured (the ``state_shift.measure`` params)."""

    states: int = 10000  # states drawn from each set (without replacement; all if fewer)
    k: int = 5  # kNN estimator's neighbour
    bootstrap: int = 10  # random episode-halves of T: the kNN estimate's and its null's mean and range
    classifier_epochs: int = 10
    threads: int | str = 2  # torch threads; auto: this process's cores

    def __post_init__(self) -> None:
        require(self.states >= 100, "states", "at least 100", self.states)
        require(1 <= self.k < self.states // 2, "k", f"in [1, states / 2) (the null halves {self.states} states)",
                self.k)
        require(self.bootstrap >= 2, "bootstrap", "at least 2 episode-halves", self.bootstrap)
        require(self.classifier_epochs >= 1, "classifier_epochs", "a positive integer", self.classifier_epochs)
        object.__setattr__(self, "threads", resolve_threads(self.threads, "threads"))


ACTION_ERRORS = ("train", "heldout", "visited")  # where a student's action error to its teacher is measured


def measure_config(grid) -> MeasureConfig:
    """The measure settings of a :class:`mop_core.experiment.study.ShiftGrid`."""
    return from_mapping(MeasureConfig, grid.measure or {}, "state_shift.measure")


CLASSIFIER_FOLDS = 2  # folds of whole episodes the classifier is cross-fitted over
ABOVE_NULL = 0.9  # a set reading above the null of the same half in at least this share of halves: shifted


def read_states(paths: Mapping[str, object]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Per name, a dataset file's observations and the episode id of each row (from its ``timeouts``
    and ``terminals``: the rows of an episode share an id)."""
    states, episodes = {}, {}
    for name, path in paths.items():
        arrays = read_dataset(path).arrays
        states[name] = arrays["observations"]
        episodes[name] = episode_ids(arrays["timeouts"] | arrays["terminals"])
    return states, episodes


def episode_halves(teacher: np.ndarray, teacher_ids: np.ndarray, sets: Mapping[str, tuple[np.ndarray, np.ndarray]],
                   statistic, config: MeasureConfig, rng: np.random.Generator) -> tuple[list[float], dict, int]:
    """``statistic`` on ``config.bootstrap`` random episode-halves (module docstring, item 1): per half,
    T's episodes are dealt into halves A and B, and the same states of A are compared with as many
    states of B (the null) and of as many whole episodes of each set (the estimates). Returns the
    null's values, each set's values and the states per side."""
    null: list[float] = []
    values: dict[str, list[float]] = {name: [] for name in sets}
    size = 0
    for _ in range(config.bootstrap):
        half = episode_folds(teacher_ids, 2, rng)
        first, second = np.flatnonzero(half == 0), np.flatnonzero(half == 1)
        size = min(config.states // 2, len(first), len(second))
        x = teacher[draw_rows(first, size, rng)]
        null.append(statistic(x, teacher[draw_rows(second, size, rng)]))
        episodes = len(np.unique(teacher_ids[second]))
        for name, (data, ids) in sets.items():
            values[name].append(statistic(x, data[draw_rows(episode_sample(ids, episodes, rng), size, rng)]))
    return null, values, size


def _range(values: Sequence[float]) -> tuple[float, float, float]:
    return float(np.mean(values)), float(np.min(values)), float(np.max(values))


def measure_shift(sets: Mapping[str, np.ndarray], reference: np.ndarray, config: MeasureConfig, seed: int,
                  episodes: Mapping[str, np.ndarray] | None = None) -> dict[str, dict]:
    """Every set of ``sets`` against the teacher's ``reference`` states (module docstring, item 1).
    ``episodes``: per set name (and ``"reference"``) the episode id of each row (:func:`read_states`);
    a set without them has independent rows (each its own episode)."""
    episodes = episodes or {}
    rng = np.random.default_rng(seed)
    teacher_ids = row_episodes(episodes.get(REFERENCE), len(reference))
    ids = {name: row_episodes(episodes.get(name), len(states)) for name, states in sets.items()}
    pooled = np.concatenate([np.asarray(s[draw_rows(np.arange(len(s)), config.states, rng)], dtype=np.float32)
                             for s in (reference, *sets.values())])  # the scale only: no split
    mean, std = pooled.mean(0), np.maximum(pooled.std(0), 1e-6)
    teacher = (np.asarray(reference, dtype=np.float32) - mean) / std
    data = {name: ((np.asarray(states, dtype=np.float32) - mean) / std, ids[name]) for name, states in sets.items()}

    def kl(x: np.ndarray, y: np.ndarray) -> float:
        return knn_kl(x, y, config.k)

    null, values, size = episode_halves(teacher, teacher_ids, data, kl, config, rng)
    null_mean, null_min, null_max = _range(null)
    teacher_rows = draw_rows(np.arange(len(teacher)), config.states, rng)
    count = len(np.unique(teacher_ids))
    out = {"reference": {"states": len(teacher_rows), "episodes": count, "halves": config.bootstrap,
                         "kl_states": size, "kl_episodes": count // 2, "kl_null": null_mean,
                         "kl_null_min": null_min, "kl_null_max": null_max}}
    for i, (name, (states, set_ids)) in enumerate(data.items()):
        rows = draw_rows(np.arange(len(states)), config.states, rng)
        classifier = crossfit_test(teacher[teacher_rows], states[rows],
                                   ClassifierConfig(epochs=config.classifier_epochs, seed=seed + i),
                                   x_episodes=teacher_ids[teacher_rows], y_episodes=set_ids[rows],
                                   folds=CLASSIFIER_FOLDS)
        estimate, low, high = _range(values[name])
        excess = np.asarray(values[name]) - np.asarray(null)  # paired: the same states of T's half A
        above = float(np.mean(excess > 0))
        out[name] = {"states": len(rows), "episodes": len(np.unique(set_ids)), "kl": estimate, "kl_min": low,
                     "kl_max": high, "kl_excess": float(excess.mean()), "above_null": above,
                     "within_null": bool(above < ABOVE_NULL), "auc": classifier.auc,
                     "ess": effective_share(classifier.ratio), "ratio_p99": float(np.percentile(classifier.ratio, 99))}
    return out


def eval_returns(evaluation: Mapping, runs_by_label: Mapping[str, Sequence], tasks: Sequence[str],
                 teacher_groups: Mapping[str, str], teacher_seed: int) -> tuple[dict, dict]:
    """The eval stage's returns (``results/eval/metrics.json``) of every run of each group, per task in
    the runs' order (``seed_means``: each run's mean over the eval stage's episodes), and per task the
    eval-stage return of the teacher run the students learned from (group ``teacher_groups[task]``,
    seed ``teacher_seed``): the numbers every other section of the report shows for these policies."""
    returns = {label: {task: [evaluation[task][run.group]["seed_means"][str(run.seed)] for run in runs]
                       for task in tasks} for label, runs in runs_by_label.items()}
    teachers = {}
    for task in tasks:
        entry = evaluation[task][teacher_groups[task]]
        teachers[task] = entry.get("runs", {}).get(str(teacher_seed), entry)["mean"]
    return returns, teachers


def student_table(records: Mapping[str, Sequence[Mapping]], returns: Mapping[str, Mapping[str, Sequence[float]]],
                  teacher_returns: Mapping[str, float], tasks: Sequence[str], norms: Mapping[str, Mapping],
                  eval_episodes: int) -> dict[str, dict]:
    """Per group (label -> its students' distill metrics records, one per training seed) and task: the
    eval stage's return (``returns[label][task]``, the records' order), normalised score and ratio to
    the teacher run's eval-stage return, each a mean over the students with its t-interval (cut at 0),
    the per-seed returns, and the action errors of the distill runs' own final evaluations."""
    table: dict[str, dict] = {}
    for label, group in records.items():
        if not group:
            continue
        row = {"seeds": [r["seed"] for r in group]}
        for task in tasks:
            values, norm = list(returns[label][task]), norms[task]
            row[task] = {"return": seed_interval(values, RETURN_BOUNDS), "seed_returns": values,
                         "normalised": seed_interval(list(normalised_score(np.array(values), norm["random_return"],
                                                                           norm["expert_return"]))),
                         "to_teacher": seed_interval([v / teacher_returns[task] for v in values], RETURN_BOUNDS),
                         "teacher_return": teacher_returns[task], "episodes_per_seed": eval_episodes}
            errors = [r[task].get("action_mse", {}) for r in group]
            row[task]["action_mse"] = {kind: seed_interval([e[kind] for e in errors], RETURN_BOUNDS)
                                       for kind in ACTION_ERRORS if all(kind in e for e in errors)}
        table[label] = row
    return table


def correction_table(table: Mapping[str, Mapping], records: Mapping[str, Sequence[Mapping]],
                     groups: Mapping[str, Mapping], tasks: Sequence[str]) -> dict[str, dict]:
    """Per correcting group (``groups[label]["correction"]`` reweight or dagger), its gain over the plain
    students on the same data and width (the group whose info matches with correction none), per
    task: the difference of their eval-stage returns (``table``: :func:`student_table`) paired by
    training seed, mean with its t-interval over the seeds (each pair shares its seed's
    initialisation; the data or its weighting differs)."""
    out: dict[str, dict] = {}
    for label, info in groups.items():
        if info.get("correction", "none") == "none":
            continue
        base = next((other for other, o in groups.items() if o.get("correction", "none") == "none"
                     and (o["data"], o["width"], o["percent"]) == (info["data"], info["width"], info["percent"])),
                    None)
        if base is None or base not in table or label not in table:
            continue
        seeds = [s for s in table[label]["seeds"] if s in table[base]["seeds"]]
        if not seeds:
            continue
        out[label] = {"plain": base, "correction": info["correction"], "data": info["data"], "width": info["width"],
                      "seeds": seeds}

        def per_seed(which: str, task: str) -> dict[int, float]:
            return dict(zip(table[which]["seeds"], table[which][task]["seed_returns"]))
        for task in tasks:
            mine, plain = per_seed(label, task), per_seed(base, task)
            teacher = table[label][task]["teacher_return"]
            out[label][task] = {
                "gain": seed_interval([mine[s] - plain[s] for s in seeds]),
                "to_teacher_gain": seed_interval([(mine[s] - plain[s]) / teacher for s in seeds]),
                "reweight": records[label][0][task].get("reweight")}  # the weights' AUC, ESS (shared by seeds)
    return out
