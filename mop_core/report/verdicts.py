"""Effects and verdicts: how the report decides whether this run reproduces a finding.

A finding (mop_core.report.findings) is measured as one or more :class:`Effect` cells (e.g. one per task or
layer): a signed quantity with its 95% interval, the interval's unit and n. Its :class:`Claim` says
what the thesis asserts about that quantity: above 0, below 0, or equal to 0 within a margin.
:func:`cell_verdict` then applies one rule, the same for every row:

- no interval (fewer than 3 runs on a side, or not run at this profile): *inconclusive*, with why;
- ``above`` / ``below``: the interval excludes 0 on the claimed side -> *reproduced*; on the other
  side -> *contradicted*; it contains 0 -> *inconclusive* (intervals overlap);
- ``equal`` (within +-margin, two one-sided tests): the interval lies inside the margin ->
  *reproduced*; wholly outside it -> *contradicted*; otherwise *inconclusive*.

A finding's verdict is its cells' when they agree; otherwise *inconclusive* with each cell's verdict
named (e.g. "reproduced at layer 2, inconclusive at layer 1"), unless one cell contradicts a claim
that must hold on every cell, which makes the whole finding contradicted.

The smallest effect this profile could detect (:attr:`Effect.detectable`) is the interval's half-width:
a true effect smaller than that cannot move the interval off 0 at this n and spread.

Effects over runs (:func:`paired`, :func:`versus_run`, :func:`versus_constant`) follow
mop_core.statistics: Student-t over training seeds (paired by seed where two groups share them), never
over the episodes of one run; a comparison of single runs (:func:`single_runs`) has no interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Mapping, Sequence

import numpy as np
from scipy import stats

from mop_core.statistics import MIN_SEEDS_FOR_SEED_CI, seed_interval

REPRODUCED, CONTRADICTED, INCONCLUSIVE = "reproduced", "contradicted", "inconclusive"


class Sense(Enum):
    ABOVE = "above"  # the thesis says the effect is > 0
    BELOW = "below"  # < 0
    EQUAL = "equal"  # |effect| <= margin


@dataclass(frozen=True)
class Claim:
    """What the thesis asserts about an effect: its sign, or equality within ``margin`` (same unit)."""

    sense: Sense
    margin: float = 0.0

    def text(self) -> str:
        return {Sense.ABOVE: "> 0", Sense.BELOW: "< 0"}.get(self.sense, f"within +-{self.margin:g}")


ABOVE, BELOW = Claim(Sense.ABOVE), Claim(Sense.BELOW)


def equal_within(margin: float) -> Claim:
    return Claim(Sense.EQUAL, margin)


@dataclass(frozen=True)
class Effect:
    """One measured cell: ``value`` with its 95% interval [low, high] (None: no interval), over ``n``
    units of kind ``unit``; ``label`` names the cell (a task, a layer), ``why`` says why there is no
    interval or what is not run."""

    label: str
    value: float | None
    low: float | None = None
    high: float | None = None
    n: int = 0
    unit: str = ""
    why: str = ""

    @property
    def decided(self) -> bool:
        return self.value is not None and self.low is not None and self.high is not None

    @property
    def detectable(self) -> float | None:
        """The interval's half-width: the smallest |effect| this profile could tell from 0."""
        return None if not self.decided else (self.high - self.low) / 2


def not_run(label: str, why: str) -> Effect:
    return Effect(label, None, why=why)


def paired(label: str, x: Mapping[int, float], y: Mapping[int, float], unit: str = "paired training seeds"
           ) -> Effect:
    """x - y paired by training seed (the seeds both have): mean and t-interval over the differences.
    A side that is None (a group this run does not have) makes a not-run cell."""
    if not x or not y:
        return not_run(label, "not run at this profile")
    seeds = sorted(set(x) & set(y))
    if not seeds:
        return not_run(label, "no training seed in common")
    ci = seed_interval([x[s] - y[s] for s in seeds])
    why = "" if ci["ci_low"] is not None else f"{len(seeds)} seeds: fewer than {MIN_SEEDS_FOR_SEED_CI}"
    return Effect(label, ci["mean"], ci["ci_low"], ci["ci_high"], len(seeds), unit, why)


def versus_run(label: str, x: Mapping[int, float], run_mean: float, run_sd: float | None, run_episodes: int
               ) -> Effect:
    """Training seeds x (>= 3) against one fixed run (e.g. the teacher run they were distilled from):
    mean(x) - run_mean with a Welch interval combining the seeds' spread and the run's evaluation noise
    (its episodes). The run is the fixed target, not a sample of its algorithm."""
    if not x:
        return not_run(label, "not run at this profile")
    values = np.array(list(x.values()), dtype=np.float64)
    if len(values) < MIN_SEEDS_FOR_SEED_CI:
        return Effect(label, float(values.mean()) - run_mean, n=len(values), unit="training seeds",
                      why=f"{len(values)} training seeds: fewer than {MIN_SEEDS_FOR_SEED_CI}")
    var_x = values.var(ddof=1) / len(values)
    var_r = (run_sd or 0.0) ** 2 / run_episodes if run_episodes > 1 else 0.0  # one episode: no spread known
    se = math.sqrt(var_x + var_r)
    df = (var_x + var_r) ** 2 / (var_x ** 2 / (len(values) - 1) + (var_r ** 2 / (run_episodes - 1) if var_r else 0.0))
    half = float(stats.t.ppf(0.975, df)) * se
    value = float(values.mean()) - run_mean
    return Effect(label, value, value - half, value + half, len(values),
                  f"training seeds vs {run_episodes} episodes of the one run")


def unpaired(label: str, x: Mapping[int, float], y: Mapping[int, float]) -> Effect:
    """Two groups of independently trained runs (>= 3 each, e.g. teachers of two algorithms):
    mean(x) - mean(y) with a Welch t-interval over their training seeds (unpaired: seed s of one
    algorithm shares nothing with seed s of the other)."""
    a, b = (np.array(list(v.values()), dtype=np.float64) for v in (x, y))
    value = float(a.mean() - b.mean())
    n = min(len(a), len(b))
    if n < MIN_SEEDS_FOR_SEED_CI:
        return Effect(label, value, n=n, unit="training seeds per side",
                      why=f"{n} training seed(s) per side: fewer than {MIN_SEEDS_FOR_SEED_CI}")
    var_a, var_b = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    se = math.sqrt(var_a + var_b)
    if se == 0:
        return Effect(label, value, value, value, n, "training seeds per side (unpaired)")
    df = (var_a + var_b) ** 2 / (var_a ** 2 / (len(a) - 1) + var_b ** 2 / (len(b) - 1))
    half = float(stats.t.ppf(0.975, df)) * se
    return Effect(label, value, value - half, value + half, n, "training seeds per side (unpaired)")


def versus_constant(label: str, x: Mapping[int, float], constant: float) -> Effect:
    """Training seeds x against a published number: mean(x) - constant, t-interval over the seeds."""
    return paired(label, x, {s: constant for s in x or {}}, "training seeds")


def single_runs(label: str, a: Mapping | None, b: Mapping | None) -> Effect:
    """Two policies trained once each (eval-stage entries): the difference of their means, no interval
    (an interval over one run's episodes says nothing about another training seed)."""
    if a is None or b is None:
        return not_run(label, "not evaluated in this run")
    runs = min(len(a.get("seed_means", {})) or 1, len(b.get("seed_means", {})) or 1)
    return Effect(label, a["mean"] - b["mean"], n=runs, unit="run(s) per side",
                  why=f"{runs} run per side: no interval over runs")


def cell_verdict(effect: Effect, claim: Claim) -> tuple[str, str]:
    """(verdict, reason) of one cell under the module's rule."""
    if effect.value is None:
        return INCONCLUSIVE, effect.why or "not run"
    if not effect.decided:
        return INCONCLUSIVE, effect.why or "no interval"
    low, high = effect.low, effect.high
    if claim.sense is Sense.EQUAL:
        if -claim.margin <= low and high <= claim.margin:
            return REPRODUCED, f"interval within +-{claim.margin:g}"
        if high < -claim.margin or low > claim.margin:
            return CONTRADICTED, f"interval outside +-{claim.margin:g}"
        return INCONCLUSIVE, f"interval crosses +-{claim.margin:g}"
    if low > 0 or high < 0:
        agrees = (low > 0) == (claim.sense is Sense.ABOVE)
        return (REPRODUCED, "interval excludes 0") if agrees else (CONTRADICTED, "interval excludes 0, opposite sign")
    return INCONCLUSIVE, "interval contains 0"


def finding_verdict(effects: Sequence[Effect], claim: Claim, every_cell: bool = True) -> tuple[str, str]:
    """A finding's verdict from its cells: theirs when they agree; with ``every_cell`` (the claim holds
    on each cell: each task, each layer) one contradicted cell contradicts it; otherwise inconclusive,
    naming each cell's verdict. No cell: not run."""
    if not effects:
        return INCONCLUSIVE, "not run at this profile"
    cells = [(effect.label, *cell_verdict(effect, claim)) for effect in effects]
    verdicts = {v for _, v, _ in cells}
    if len(verdicts) == 1:
        reasons = list(dict.fromkeys(r for _, _, r in cells))
        return cells[0][1], "; ".join(reasons)
    named = "; ".join(f"{label}: {v}" for label, v, _ in cells)
    if every_cell and CONTRADICTED in verdicts:
        return CONTRADICTED, named
    return INCONCLUSIVE, named
