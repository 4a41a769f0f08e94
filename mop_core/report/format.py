"""How the report writes numbers: intervals with their unit and n, normalised scores, tables, captions,
and the lookups every section shares (an eval entry, a not-run line)."""

from __future__ import annotations

import math
from typing import Mapping, Sequence

from mop_core.report.results import Run, StudyResults
from mop_core.statistics import MIN_SEEDS_FOR_SEED_CI, confidence_interval


def fmt(value: float | None, digits: int = 1) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def unit_text(entry: Mapping) -> str:
    """How many units an interval is over, e.g. 'n=30 episodes', 'n=60 episodes of 2 seeds', 'n=3 seeds'."""
    cut = "; cut at 0: too few runs for a t-interval" if entry.get("cut_at_bound") else ""
    if entry.get("ci_unit") == "training_seed":
        return f"n={entry['n']} seeds{cut}"
    seeds = len(entry.get("seed_means", {}))
    return f"n={entry['n']} episodes" + (f" of {seeds} seeds" if seeds > 1 else "") + cut


def fmt_ci(entry: Mapping | None) -> str:
    """``mean [low, high] (n=..)`` of an eval-stage group (``mean (n=1)`` when the interval is undefined)."""
    if entry is None:
        return "not evaluated"
    if entry.get("ci_low") is None:
        return f"{fmt(entry['mean'])} (n={entry.get('n', 1)})"
    return f"{fmt(entry['mean'])} [{fmt(entry['ci_low'])}, {fmt(entry['ci_high'])}] ({unit_text(entry)})"


def fmt_normalised(entry: Mapping | None) -> str:
    """The same mean and interval as normalised scores (100 = published expert, 0 = random)."""
    z = (entry or {}).get("normalised")
    if not z:
        return "n/a"
    if z.get("ci_low") is None:
        return fmt(z["mean"])
    return f"{fmt(z['mean'])} [{fmt(z['ci_low'])}, {fmt(z['ci_high'])}]"


def seed_means_text(entry: Mapping | None) -> str:
    """Each training seed's mean return ('426.0 / 426.2'), or '-' for a policy trained once."""
    means = (entry or {}).get("seed_means", {})
    return " / ".join(fmt(v) for v in means.values()) if len(means) > 1 else "-"


def ci_caption(entries: Sequence[Mapping | None]) -> str:
    """What the 95% intervals of ``entries`` are over, in words, with their n."""
    parts = []
    episodes = sorted({(e["n"], len(e.get("seed_means", {})) or 1) for e in entries
                       if e and e.get("ci_unit") == "episode"})
    for n, seeds in episodes:
        parts.append(f"{n} evaluation episodes of one trained policy" if seeds == 1 else
                     f"{n} evaluation episodes pooled over {seeds} training seeds (fewer than 3 seeds: no interval "
                     "over seeds; the seed means are listed)")
    for n in sorted({e["n"] for e in entries if e and e.get("ci_unit") == "training_seed"}):
        parts.append(f"the means of {n} training seeds")
    if not parts:
        return "no evaluation"
    return "Student-t 95% intervals over " + "; over ".join(parts)


def seeds_text(n: int) -> str:
    """'1 seed, no interval' / '2 seeds, no interval' / '3 seeds, 95% CI': how a curve of n runs is drawn."""
    if n < MIN_SEEDS_FOR_SEED_CI:
        return f"{n} seed{'s' if n > 1 else ''}, no interval"
    return f"{n} seeds, 95% CI"


def curve_caption(groups: Sequence[Sequence[Run]]) -> str:
    counts = sorted({len(runs) for runs in groups})
    return "Learning curves: mean over training seeds per line (" + "; ".join(seeds_text(n) for n in counts) + ")"


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def seed_band(curves: Sequence[Sequence[Mapping[str, str]]], key: str) -> dict | None:
    """Mean and 95% t-interval over seeds of column ``key`` at the steps every curve has."""
    per_run = [{float(r["step"]): float(r[key]) for r in rows if key in r} for rows in curves]
    per_run = [run for run in per_run if run]
    if not per_run:
        return None
    steps = sorted(set.intersection(*(set(run) for run in per_run)))
    stats = [confidence_interval([run[s] for run in per_run]) for s in steps]
    band = {"step": steps, "mean": [s["mean"] for s in stats], "ci_low": None, "ci_high": None}
    if len(per_run) >= MIN_SEEDS_FOR_SEED_CI:  # a t-interval over 2 seeds (t = 12.7) is no interval
        band["ci_low"], band["ci_high"] = [s["ci_low"] for s in stats], [s["ci_high"] for s in stats]
    return band


def group_runs(runs: Sequence[Run], *fields: str) -> dict[tuple, list[Run]]:
    groups: dict[tuple, list[Run]] = {}
    for run in runs:
        groups.setdefault(tuple(run.key[f] for f in fields), []).append(run)
    return groups


def eval_entry(results: StudyResults, task: str, group: str) -> dict | None:
    if results.evaluation is None:
        return None
    return results.evaluation.get(task, {}).get(group)


def not_run(what: str, how: str) -> str:
    return f"*Not part of this run: {what}. {how}*"


def normalisation_text(results: StudyResults) -> str:
    """How returns become normalised scores in this run (R_random measured, R_expert published)."""
    norms = (results.evaluation or {}).get("normalisation")
    if not norms:
        return ""
    parts = [f"{task}: R_random {fmt(n['random_return'])} ({n['random_episodes']} uniformly random episodes, collect "
             f"stage), R_expert {fmt(n['expert_return'])}" for task, n in norms.items()]
    return ("Normalised score = 100 (R - R_random) / (R_expert - R_random), R_expert the published expert level "
            f"({next(iter(norms.values()))['expert_source']}): " + "; ".join(parts) + ".")
