"""Statistics of evaluation returns: t-intervals, normalised scores and the aggregates of rliable.

- :func:`confidence_interval`: mean and Student-t interval ``mean +- t_{0.975, n-1} sd / sqrt(n)``
  over independent units (episodes of one trained policy, or the means of >= 3 training seeds);
  for a bounded quantity (a return >= 0, a squared error >= 0, a tau in [-1, 1]) an interval that
  reaches past the bound is cut there and flagged (``cut_at_bound``): n is too small for a t-interval.
- :func:`seed_interval`: the same over training seeds, with no interval under 3 seeds (the one rule
  every seed interval of the study follows).
- :func:`normalised_score`: ``100 (R - R_random) / (R_expert - R_random)`` (D4RL's convention).
- :func:`iqm`: the interquartile mean, ``scipy.stats.trim_mean(x, 0.25)`` over all scores (Agarwal
  et al. 2021, "Deep RL at the edge of the statistical precipice"; rliable's ``metrics.aggregate_iqm``).
- :func:`probability_of_improvement`: ``P(X > Y)`` averaged over tasks, per task the Mann-Whitney
  U statistic over all score pairs divided by ``n_x n_y`` (ties count 1/2; rliable's
  ``metrics.probability_of_improvement``).
- :func:`stratified_bootstrap`: percentile intervals of any of these from resampling the rows with
  replacement *within each task* (rliable's ``StratifiedBootstrap``/``StratifiedIndependentBootstrap``,
  ``method='percentile'``). Score matrices are ``[runs, tasks]``: as in rliable, a row is one training
  run scored by its mean return over its evaluation episodes, never an episode (episodes of one run
  are not independent samples of the algorithm: pooling 15 episodes of 3 runs as 45 shrinks an
  interval ~3x). Fewer than 3 runs in a stratum: no interval.
- :func:`paired_difference`: two groups that share training seeds (same teachers, data and
  initialisation seed) compared by the per-seed difference, mean over tasks, with a t-interval over
  the seeds.

Per policy group (:func:`summarise_group`), the 95% interval always says its unit and n:

- one trained policy: Student-t over its evaluation episodes (n = episodes);
- a group of >= 3 training seeds: Student-t over the seeds' mean returns (n = seeds), the interval
  the thesis's figures draw;
- a group of 2 seeds: a t-interval over 2 units has t(0.975, 1) = 12.7 and says nothing, so the
  group gets the per-episode interval over its pooled episodes (n = episodes; it ignores the
  between-seed variance) and lists each seed's mean.

Every function is vectorised over bootstrap replicates; results equal rliable's to float precision
(point estimates) and within Monte Carlo error (intervals, against ``rliable.library``):
tests/test_statistics.py.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

#: Fewer training seeds than this get no interval over seeds (t(0.975, 1) = 12.7 makes 2 seeds meaningless).
MIN_SEEDS_FOR_SEED_CI = 3


def confidence_interval(values: Sequence[float], confidence: float = 0.95,
                        bounds: tuple[float, float] | None = None) -> dict[str, float | int | None]:
    """Mean, sample standard deviation and the Student-t confidence interval of the mean.

    ``mean +- t_{(1+confidence)/2, n-1} * sd / sqrt(n)``; with one value the interval is undefined
    (None). ``bounds``: the range of the quantity (e.g. ``(0, inf)`` for a return); an interval end
    past a bound is cut at the bound and ``cut_at_bound`` is True (too few units for a t-interval).
    """
    x = np.asarray(values, dtype=np.float64)
    n = len(x)
    if n == 0:
        raise ValueError("values: expected at least one value")
    mean = float(x.mean())
    if n == 1:
        return {"mean": mean, "std": None, "ci_low": None, "ci_high": None, "n": 1}
    sd = float(x.std(ddof=1))
    from scipy import stats  # here, not at the top: scipy.stats costs 0.5 s to import in every stage process

    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1) * sd / math.sqrt(n))
    out = {"mean": mean, "std": sd, "ci_low": mean - half, "ci_high": mean + half, "n": n}
    if bounds is not None:
        low, high = bounds
        out["cut_at_bound"] = bool(out["ci_low"] < low or out["ci_high"] > high)
        out["ci_low"], out["ci_high"] = max(out["ci_low"], low), min(out["ci_high"], high)
    return out


#: The range of the quantities the study summarises over seeds (intervals are cut at these bounds).
RETURN_BOUNDS = (0.0, math.inf)  # episode returns (rewards in [0, 1]) and squared errors
TAU_BOUNDS = (-1.0, 1.0)


def seed_interval(values: Sequence[float], bounds: tuple[float, float] | None = None) -> dict:
    """Mean over training seeds with a Student-t 95% interval over them (``ci_unit`` training_seed);
    no interval (None) under MIN_SEEDS_FOR_SEED_CI seeds; cut at ``bounds`` (:func:`confidence_interval`)."""
    ci = confidence_interval(values, bounds=bounds) | {"ci_unit": "training_seed"}
    if ci["n"] < MIN_SEEDS_FOR_SEED_CI:
        ci["ci_low"] = ci["ci_high"] = None
    return ci


def normalised_score(returns, random_return: float, expert_return: float):
    """``100 (R - R_random) / (R_expert - R_random)``: 0 = a uniformly random policy, 100 = the
    published expert level. Works on floats and arrays."""
    if not expert_return > random_return:
        raise ValueError(f"expert_return: expected a value above random_return={random_return}, got {expert_return}")
    return 100.0 * (np.asarray(returns, dtype=np.float64) - random_return) / (expert_return - random_return)


def iqm(scores: np.ndarray) -> np.ndarray:
    """Interquartile mean over all but the leading axis: ``[..., n, tasks] -> [...]`` (a scalar for
    a single ``[n, tasks]`` matrix). The mean of the middle 50% of the scores, pooled over tasks."""
    scores = np.asarray(scores, dtype=np.float64)
    flat = scores.reshape(*scores.shape[:-2], -1)
    from scipy import stats

    return stats.trim_mean(flat, proportiontocut=0.25, axis=-1)


def probability_of_improvement(x: np.ndarray, y: np.ndarray, chunk: int = 256) -> np.ndarray:
    """``P(X > Y) + P(X = Y) / 2`` per task, averaged over tasks: ``[..., n, T], [..., m, T] -> [...]``.

    X's and Y's sample counts may differ; their task counts must agree.
    """
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.shape[-1] != y.shape[-1]:
        raise ValueError(f"x, y: expected the same number of tasks, got {x.shape[-1]} and {y.shape[-1]}")
    lead = x.shape[:-2]
    xs, ys = x.reshape(-1, *x.shape[-2:]), y.reshape(-1, *y.shape[-2:])
    out = []
    for start in range(0, len(xs), chunk):  # [b, n, 1, T] vs [b, 1, m, T]: every pair, chunked over b
        a, b = xs[start:start + chunk, :, None, :], ys[start:start + chunk, None, :, :]
        per_task = (a > b).mean(axis=(1, 2)) + 0.5 * (a == b).mean(axis=(1, 2))
        out.append(per_task.mean(axis=-1))
    return np.concatenate(out).reshape(lead)


def stratified_bootstrap(statistic: Callable[..., np.ndarray], samples: Sequence[np.ndarray], reps: int = 2000,
                         confidence: float = 0.95, seed: int = 0,
                         min_rows: int = MIN_SEEDS_FOR_SEED_CI) -> dict[str, float | None]:
    """Point estimate and percentile bootstrap interval of ``statistic(*samples)``.

    ``samples[k]`` is ``[n_k, T]``; each replicate draws, for every sample and every task
    independently, ``n_k`` rows with replacement from that task's column (stratified by task, the
    samples independent of each other). ``statistic`` takes arrays with a leading replicate axis
    (``[R, n_k, T]``) and returns ``[R]``. A sample with fewer than ``min_rows`` rows (runs) gets
    no interval (``ci_low`` = ``ci_high`` = None): a bootstrap over 1 or 2 runs is not an interval.
    """
    if reps < 1:
        raise ValueError(f"reps: expected a positive integer, got {reps}")
    arrays = [np.asarray(s, dtype=np.float64) for s in samples]
    for k, a in enumerate(arrays):
        if a.ndim != 2 or a.shape[0] < 1:
            raise ValueError(f"samples[{k}]: expected a [samples, tasks] matrix, got shape {a.shape}")
    rng = np.random.default_rng(seed)
    point = float(statistic(*[a[None] for a in arrays])[0])
    if min(a.shape[0] for a in arrays) < min_rows:
        return {"value": point, "ci_low": None, "ci_high": None, "reps": 0}
    resampled = []
    for a in arrays:
        n, tasks = a.shape
        rows = rng.integers(0, n, size=(reps, n, tasks))
        resampled.append(a[rows, np.arange(tasks)])
    values = statistic(*resampled)
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(values, [tail, 100 - tail])
    return {"value": point, "ci_low": float(low), "ci_high": float(high), "reps": reps}


def summarise_group(returns_by_seed: dict[int, np.ndarray], random_return: float | None = None,
                    expert_return: float | None = None) -> dict:
    """Mean and 95% CI of one group (one policy family on one task) from ``{train_seed: returns [episodes]}``.

    >= MIN_SEEDS_FOR_SEED_CI training seeds: over the seeds' means (``ci_unit`` training_seed);
    fewer: over all episodes pooled (``ci_unit`` episode). ``seed_means`` lists every seed's mean;
    with several seeds ``runs`` holds each seed's own per-episode interval. With the task's random and
    expert returns, ``normalised`` holds the same mean and interval as normalised scores (an affine
    map, so the interval maps exactly).
    """
    if not returns_by_seed:
        raise ValueError("returns_by_seed: expected at least one training seed")
    seeds = sorted(returns_by_seed)
    runs = {seed: np.asarray(returns_by_seed[seed], dtype=np.float64).ravel() for seed in seeds}
    if len(seeds) >= MIN_SEEDS_FOR_SEED_CI:
        summary = seed_interval([runs[s].mean() for s in seeds], RETURN_BOUNDS)
    else:
        summary = confidence_interval(np.concatenate([runs[s] for s in seeds]), bounds=RETURN_BOUNDS) | {
            "ci_unit": "episode"}
    summary |= {"episodes": int(sum(len(r) for r in runs.values())), "train_seeds": seeds,
                "seed_means": {str(s): float(runs[s].mean()) for s in seeds}}
    if len(seeds) > 1:
        summary["runs"] = {str(s): confidence_interval(runs[s], bounds=RETURN_BOUNDS) | {"ci_unit": "episode"}
                           for s in seeds}
    if random_return is not None and expert_return is not None:
        for entry in [summary, *summary.get("runs", {}).values()]:
            entry["normalised"] = {key: None if entry[key] is None else
                                   float(normalised_score(entry[key], random_return, expert_return))
                                   for key in ("mean", "ci_low", "ci_high")}
    return summary


def ratio_to_teacher(group: dict, teacher: dict, teacher_seed: int | None = None) -> float:
    """``group`` mean / the teacher's mean: of the teacher run ``teacher_seed`` (the one a student was
    distilled from), or of the teacher group's mean over its seeds (None)."""
    if teacher_seed is None:
        return group["mean"] / teacher["mean"]
    if str(teacher_seed) not in teacher["seed_means"]:
        raise ValueError(f"teacher_seed: {teacher_seed} is not among the teacher's evaluated seeds "
                         f"{list(teacher['seed_means'])}")
    return group["mean"] / teacher["seed_means"][str(teacher_seed)]


AGGREGATE_UNIT = "runs, stratified by task"


def score_matrix(runs_by_task: dict[str, np.ndarray]) -> np.ndarray:
    """``{task: run scores [runs]}`` -> ``[runs, tasks]`` (every task must have the same number of runs)."""
    lengths = {task: len(v) for task, v in runs_by_task.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"runs_by_task: expected the same number of runs per task, got {lengths}")
    return np.stack([np.asarray(v, dtype=np.float64) for v in runs_by_task.values()], axis=1)


def iqm_summary(runs_by_task: dict[str, np.ndarray], reps: int, seed: int) -> dict:
    """IQM of normalised scores pooled over tasks, with its stratified-bootstrap 95% interval over
    runs (rliable's recommended aggregate). ``runs_by_task[task]``: one score per training run (its
    mean over episodes). No lists in the record: ``dvc metrics show`` drops them."""
    matrix = score_matrix(runs_by_task)
    return stratified_bootstrap(iqm, [matrix], reps, seed=seed) | {
        "tasks": ", ".join(runs_by_task), "runs_per_task": int(matrix.shape[0]), "ci_unit": AGGREGATE_UNIT}


def improvement_summary(x_by_task: dict[str, np.ndarray], y_by_task: dict[str, np.ndarray], reps: int,
                        seed: int) -> dict:
    """P(X > Y) averaged over tasks (ties 1/2) over run scores, with its stratified-bootstrap 95%
    interval, X's and Y's runs resampled independently within each task (none under 3 runs a side)."""
    if list(x_by_task) != list(y_by_task):
        raise ValueError(f"x_by_task, y_by_task: expected the same tasks, got {list(x_by_task)} and {list(y_by_task)}")
    x, y = score_matrix(x_by_task), score_matrix(y_by_task)
    return stratified_bootstrap(probability_of_improvement, [x, y], reps, seed=seed) | {
        "tasks": ", ".join(x_by_task), "runs_x": int(x.shape[0]), "runs_y": int(y.shape[0]),
        "ci_unit": AGGREGATE_UNIT}


def paired_difference(x_by_task: dict[str, dict[int, float]], y_by_task: dict[str, dict[int, float]]) -> dict:
    """X - Y paired by training seed: per seed both groups have on every task, the mean over tasks of
    the difference of their run scores; mean and Student-t 95% interval over those seeds (``n``,
    ``ci_unit`` paired_seed; no interval under 3 seeds). The seeds paired are listed."""
    if list(x_by_task) != list(y_by_task):
        raise ValueError(f"x_by_task, y_by_task: expected the same tasks, got {list(x_by_task)} and {list(y_by_task)}")
    seeds = sorted(set.intersection(*(set(x_by_task[t]) & set(y_by_task[t]) for t in x_by_task)))
    if not seeds:
        raise ValueError("x_by_task, y_by_task: no training seed is shared on every task")
    diffs = [float(np.mean([x_by_task[t][s] - y_by_task[t][s] for t in x_by_task])) for s in seeds]
    return seed_interval(diffs) | {"ci_unit": "paired_seed", "seeds": ", ".join(map(str, seeds)),
                                   "tasks": ", ".join(x_by_task)}
