"""The report's section on common structure at the computational level (thesis 6.3): the student
width sweep (Figure 6.4) and the ranking regularisers (Figure 6.5), each next to the plain MOP
MSE students of the same pairing.

Returns are the eval stage's (per task: mean over training seeds with its Student-t interval over
those seeds, n in each cell); per-state tau is each student's final per-state tau on the distill
stage's probe states (the same offline states for every student of the pairing), mean and
Student-t 95% interval over the group's seeds. Under 3 seeds there is no interval.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from mop_core.experiment.runs import student_group, student_recipe
from mop_core.experiment.variants import Ranking, Variant, Width
from mop_core.plots import interval_panels
from mop_core.report.format import eval_entry, fmt, fmt_ci, fmt_normalised, not_run, table
from mop_core.report.results import Run, StudyResults
from mop_core.statistics import MIN_SEEDS_FOR_SEED_CI, TAU_BOUNDS
from mop_core.statistics import seed_interval as interval_over_seeds

TAU_VARIANT = "a"  # the thesis's formula (6.2.2); tau-b is in the shared computation section
PROBE_STATES = {"offline": "offline dataset states", "visited": "states the student visited"}  # distill.probe_source


def seed_interval(values: Sequence[float], bounds: tuple[float, float] | None = TAU_BOUNDS
                  ) -> tuple[float, float | None, float | None]:
    """(mean, low, high) over training seeds (mop_core.statistics.seed_interval: none under
    MIN_SEEDS_FOR_SEED_CI seeds; cut at ``bounds``, a tau's [-1, 1] by default)."""
    ci = interval_over_seeds(values, bounds)
    return ci["mean"], ci["ci_low"], ci["ci_high"]


def fmt_interval(interval: tuple[float, float | None, float | None], digits: int = 3) -> str:
    mean, low, high = interval
    return fmt(mean, digits) + ("" if low is None else f" [{fmt(low, digits)}, {fmt(high, digits)}]")


def final_tau(runs: Sequence[Run], layer: int, variant: str = TAU_VARIANT) -> list[float]:
    """Each run's final per-state tau of hidden layer ``layer`` (1-based) on the probe states."""
    key = f"per_state_tau_{variant}_layer{layer}"
    return [float(r.metrics["per_state_tau"]["final"][key]) for r in runs
            if key in r.metrics.get("per_state_tau", {}).get("final", {})]


def layers_of(runs: Sequence[Run]) -> list[int]:
    final = next((r.metrics["per_state_tau"]["final"] for r in runs if r.metrics.get("per_state_tau")), {})
    return sorted({int(k.rsplit("layer", 1)[1]) for k in final if k.startswith(f"per_state_tau_{TAU_VARIANT}_")})


def task_interval(results: StudyResults, task: str, group: str) -> tuple[float, float | None, float | None] | None:
    entry = eval_entry(results, task, group)
    if entry is None:
        return None
    return entry["mean"], entry.get("ci_low"), entry.get("ci_high")


def comparison(results: StudyResults, rows: Sequence[tuple[object, str, Sequence[Run]]], what: str,
               figure: Path, link: str, xlabel: str, title: str, log_x: bool) -> list[str]:
    """A table and a two-panel figure (return per task; per-state tau per layer) of student groups
    ``rows``: (x label or value, recipe, runs)."""
    pairing = results.settings.get("structure_pairing", "medium")
    layers = sorted({layer for _, _, runs in rows for layer in layers_of(runs)})
    table_rows, returns, taus = [], {}, {}
    for x, recipe, runs in rows:
        group = student_group(recipe, pairing)
        cells = [str(x), recipe, str(len(runs))]
        for task in results.tasks:
            entry = eval_entry(results, task, group)
            cells += [fmt_ci(entry), fmt_normalised(entry)]
            interval = task_interval(results, task, group)
            if interval:
                returns.setdefault(task, []).append((x, *interval))
        for layer in layers:
            values = final_tau(runs, layer)
            cells.append(fmt_interval(seed_interval(values)) if values else "n/a")
            if values:
                taus.setdefault(f"layer {layer}", []).append((x, *seed_interval(values)))
        table_rows.append(cells)
    header = [what, "students", "seeds"]
    for task in results.tasks:
        header += [f"return on {task} [95% CI]", f"{task} normalised"]
    header += [f"per-state tau-{TAU_VARIANT} layer {layer} [95% CI]" for layer in layers]
    sources = sorted({r.metrics["per_state_tau"].get("probe_source", "offline") for _, _, runs in rows
                      for r in runs if r.metrics.get("per_state_tau")})
    tau_panel = "per-state tau on probe states" + (f" ({', '.join(PROBE_STATES.get(s, s) for s in sources)})"
                                                   if sources else "")
    interval_panels(figure, {"return": returns, tau_panel: taus}, xlabel,
                    {"return": "episode return (eval stage)",
                     tau_panel: f"final per-state tau-{TAU_VARIANT} on probe states"}, title, log_x)
    return [f"![{title}]({link})", "", table(header, table_rows), ""]


def structure_section(results: StudyResults, figure_dir: Path, link_prefix: str) -> str:
    """Section 7a: the width sweep (6.3.1) and the ranking regularisers (6.3.2)."""
    out = ["## 7a. Common structure at the computational level (thesis 6.3, Figures 6.4 and 6.5)", ""]
    variants = [r for r in results.variants if isinstance(r.origin.variant, (Width, Ranking))]
    if not variants:
        return "\n".join(out + [not_run("the common-structure students", "Set `common_structure.widths` or "
                                        "`common_structure.ranking_losses` and run `dvc repro`."), ""])
    pairing = results.settings.get("structure_pairing", "medium")
    plain = [r for r in results.students if r.key["loss"] == "mse" and r.key["pairing"] == pairing]
    by_variant: dict[Variant, list[Run]] = {}
    for run in variants:
        by_variant.setdefault(run.origin.variant, []).append(run)
    plain_width = results.settings.get("student_width", "plain")
    widths = sorted([(v.width, v) for v in by_variant if isinstance(v, Width)], key=lambda pair: pair[0])
    if widths:
        rows = [(w, student_recipe("mse", v), by_variant[v]) for w, v in widths]
        if plain and isinstance(plain_width, int):
            rows = sorted(rows + [(plain_width, "mse", plain)], key=lambda row: row[0])
        out += ["### Student width (thesis 6.3.1, Figure 6.4)", ""]
        out += comparison(results, rows, "hidden width", figure_dir / "width.png", f"{link_prefix}width.png",
                          "hidden width (every layer)", "MSE students by width", log_x=True)
        out += [f"Every layer of the student w<width> wide; `mse` is plain MOP at "
                f"`distill.student.hidden_sizes` (width {plain_width}). Same teachers, states and seeds.", ""]
    ranking = [v for v in by_variant if isinstance(v, Ranking)]
    if ranking:
        rows = ([("none", "mse", plain)] if plain else []) + [
            (v.loss, student_recipe("mse", v), by_variant[v]) for v in ranking]
        settings = results.settings.get("ranking", {})
        out += ["### Ranking regularisation (thesis 6.3.2, Figure 6.5)", ""]
        out += comparison(results, rows, "ranking loss", figure_dir / "ranking.png", f"{link_prefix}ranking.png",
                          "ranking loss", f"MSE students with ranking regularisation (lambda = "
                          f"{settings.get('weight', 'n/a')})", log_x=False)
        out += [f"Loss = MSE + lambda sum_j w_j mean_(i != k) L_rank(l_j(s, i), sg[l_j(s, k)]) over every hidden "
                f"layer j and ordered pair of task ids (symmetric in the tasks; mop_core/distill/ranking.py), on "
                f"{settings.get('states', 'n/a')} state(s) per task per step (`distill.ranking.states`; the thesis "
                "compares whole batches). Pairwise logistic: mean over the n(n-1) off-diagonal neuron pairs; "
                "listwise: softmax cross-entropy of the labels' distribution against the scores'; NDCG through "
                f"ApproxNDCG's smooth ranks (temperature {settings.get('temperature', 'n/a')}), because the "
                "thesis's sort-based NDCG has zero gradient almost everywhere. Each variant student has its "
                "plain MOP counterpart's seed: the same initialisation and state stream, the regulariser the only "
                "difference.", ""]
    out += ["Returns: eval stage, mean over training seeds with the Student-t 95% interval over those seeds "
            "(cells give n). Per-state tau: each student's final value on the distill stage's probe states "
            "(the same offline states for every student of the pairing), mean [Student-t 95% interval] over "
            f"seeds (none under {MIN_SEEDS_FOR_SEED_CI} seeds). What the thesis claims of these groups (6.3.1, "
            "6.3.2) and whether this run reproduces it: the verdict table at the top (width_degrades_return, "
            "width_degrades_tau, pairwise_highest_tau, pairwise_costs_return, ndcg_no_effect, "
            "listwise_raises_layer1_tau, listwise_keeps_return, listwise_layer2_at_baseline).", ""]
    return "\n".join(out)

