"""The report's shared-computation section (thesis Table 6.1, Figures 6.3 and 6.4b): Kendall tau and CKA
per layer and task pair, the measures beyond CKA, and the dormant and task-selective neurons."""

from __future__ import annotations

from typing import Mapping

from mop_core.experiment.runs import (
    representation_group,
)
from mop_core.report.format import (
    fmt,
    not_run,
    table,
)
from mop_core.report.results import StudyResults

# ---- sections --------------------------------------------------------------------------------------


def tau_pair(row: Mapping, key: str, digits: int = 3) -> str:
    """``tau-a / tau-b`` of one table cell (``key`` is e.g. ``average_tau``)."""
    return f"{fmt(row[f'{key}_a'], digits)} / {fmt(row[f'{key}_b'], digits)}"


def beyond_cka_cells(row: Mapping) -> list[str]:
    """Procrustes, debiased CKA and task selectivity cells of a Table 6.1 row (n/a in an older record)."""
    def cell(key: str) -> str:
        value = fmt(row.get(key), 3)
        return value + (f" (sd {fmt(row[f'{key}_seed_sd'], 3)})" if f"{key}_seed_sd" in row else "")
    return [cell("procrustes"), cell("debiased_cka"),
            f"{fmt(row.get('selectivity_mean'), 3)} / {fmt(row.get('selective_share'), 3)}"]


def activity_lines(shared: Mapping) -> list[str]:
    """The share of zero activations, and of dead and dormant neurons, per student, task and layer."""
    out = []
    zero = []
    for name, record in shared["students"].items():
        for task, fractions in record["zero_fraction"].items():
            zero.append(f"{name} {task}: " + " / ".join(fmt(f, 2) for f in fractions.values()))
    out += ["Share of zero activations per layer (layer 1 / 2 / ...): " + "; ".join(zero) + ".", ""]
    dormant = [f"{name} {task}: " + " / ".join(f"{fmt(shares['0.0'], 2)}, {fmt(shares['0.1'], 2)}"
                                                for shares in layers.values())
               for name, record in shared["students"].items() for task, layers in record.get("dormant", {}).items()]
    if dormant:
        out += ["Dead and dormant neurons on the task's own states under its own id (Sokar et al. 2023: "
                "E|h_k| / mean_l E|h_l| <= tau; per layer: tau = 0 (dead), tau = 0.1): " + "; ".join(dormant) + ".",
                ""]
    return out


def shared_section(results: StudyResults) -> str:
    out = ["## 7. Shared computation (thesis Table 6.1, Figures 6.3 and 6.4b)", ""]
    if results.shared is None:
        return "\n".join(out + [not_run("the shared_computation stage", "Run `dvc repro shared_computation`."), ""])
    shared = results.shared
    rows = []
    study_order = list(dict.fromkeys(
        [representation_group(r.key["loss"], r.key["pairing"]) for r in results.students]
        + [r.origin.representation_group for r in results.variants]))
    ordered = sorted(shared["groups"], key=lambda g: study_order.index(g) if g in study_order else len(study_order))
    for group in ordered:  # the study's loss order (mse, q, kl), not the JSON file's sorted keys
        summary = shared["groups"][group]
        label = f"{group} (no sharing: single-task students)" if "no_sharing" in summary else group
        for pair, layers in summary["pairs"].items():
            for layer, row in layers.items():
                rows.append([label, pair, layer.removeprefix("layer"),
                             f"{fmt(row['per_state_tau_a_mean'], 3)} +- {fmt(row['per_state_tau_a_sd'], 3)}",
                             f"{fmt(row['per_state_tau_b_mean'], 3)} +- {fmt(row['per_state_tau_b_sd'], 3)}",
                             f"{tau_pair(row, 'average_tau')} (sd {fmt(row['average_tau_a_seed_sd'], 3)} / "
                             f"{fmt(row['average_tau_b_seed_sd'], 3)})",
                             f"{fmt(row['linear_cka'], 3)} (sd {fmt(row['linear_cka_seed_sd'], 3)})",
                             *beyond_cka_cells(row), summary["students"]])
                ref = summary.get("untrained", {}).get("pairs", {}).get(pair, {}).get(layer)
                if ref:
                    rows.append([f"{group}, untrained copy", pair, layer.removeprefix("layer"),
                                 f"{fmt(ref['per_state_tau_a']['mean'], 3)} +- {fmt(ref['per_state_tau_a']['sd'], 3)}",
                                 f"{fmt(ref['per_state_tau_b']['mean'], 3)} +- {fmt(ref['per_state_tau_b']['sd'], 3)}",
                                 tau_pair(ref, "average_tau"), fmt(ref["linear_cka"], 3), *beyond_cka_cells(ref),
                                 "-"])
    out += [f"Each student acted online for {shared['episodes_per_task']} episodes per task; its post-ReLU "
            "activations on the visited states are compared across task ids. Per state: Kendall's tau between a "
            "state's activations under the two task ids, mean +- sd over states (s ~ D_i u D_j), averaged over the "
            "group's students. Average: tau between the tasks' mean activations over their own states. Both "
            "variants: **tau-a** is the thesis's formula (6.2.2) and its reference code's, so it is the column to "
            "compare with the thesis's Tables 6.1/6.2; **tau-b** corrects for the ties of ReLU zeros. Linear CKA: "
            "the activation matrices under the two ids over the same states (6.2.4's proposal). In brackets: sd "
            "over the group's students. 'untrained copy' rows: the same measures of a freshly initialised network "
            "of the same shape on the same states (the group's first student's), the level a number should be "
            "read against. 'no sharing' rows (`common_structure.single_task`): per seed, each task's student "
            "distilled on that task alone, on the states it visits itself; network i stands for task id i, so the "
            "measures compare two networks that share no weight: per-state and average tau are then chance "
            "agreement of neurons that correspond by index only, while CKA and Procrustes (invariant to rotating "
            "the neurons) say how alike two unshared solutions are anyway; a multi-task student's number means "
            "shared computation only where it is above both references.", "",
            table(["student group", "tasks", "layer", "per-state tau-a (mean +- sd)", "per-state tau-b (mean +- sd)",
                   "average tau-a / tau-b", "linear CKA", "Procrustes", "debiased CKA",
                   "task selectivity: mean / share >= 0.5", "students"], rows), "",
            "Beyond CKA (linear CKA is saturated: near 1 for trained students and their untrained copies alike): "
            "orthogonal Procrustes similarity of the centred, normalised activation matrices under the two ids; "
            "CKA from the unbiased HSIC estimator (debiased CKA, Nguyen et al. 2021: plain CKA is inflated when "
            "the width is large against the states); per neuron, the share of its activation variance over "
            "(state, id) that the task id explains, averaged over the neurons that vary, and the share of all "
            "neurons it explains at least half of (mop_core/representations/similarity.py).", "",
            f"Ties: {shared['note']}", ""]
    out += activity_lines(shared)
    for group, path in results.figures.get("sorted_activations", {}).items():
        out += [f"![{group}]({path})", "",
                f"Figure 6.3b for {group}: neurons sorted by the first task's mean activation; an increasing "
                "trend of the other task's curve means the tasks rank their neurons alike.", ""]
    tau_curve = results.figures.get("tau_during_training")
    if tau_curve:
        init = {r.key["loss"] + " " + r.key["pairing"] + f" seed {r.seed}": r.metrics.get("per_state_tau")
                for r in results.students if r.metrics.get("per_state_tau")}
        sources = sorted({v["probe_source"] for v in init.values()})
        where = {"offline": "a fixed probe set of offline dataset states (the same states for every student)",
                 "visited": "states the student visited in that evaluation's episodes (the reference code's choice)"}
        out += [f"![per-state tau during distillation]({tau_curve})", "",
                "Figure 6.4b analogue: per-state tau-a and tau-b on "
                + "; ".join(where[s] for s in sources) + " (`distill.probe_source`), logged at every evaluation; "
                "dotted lines: the same student at initialisation.", ""]
        if init:
            def layers(values: Mapping[str, float], variant: str) -> str:
                return " / ".join(fmt(v, 3) for k, v in values.items() if k.startswith(f"per_state_tau_{variant}_"))
            out += [table(["student", "probe states per task", "tau-a at init / end (per layer)",
                           "tau-b at init / end (per layer)"],
                          [[name, v["probe_states_per_task"],
                            f"{layers(v['at_init'], 'a')} -> {layers(v['final'], 'a')}",
                            f"{layers(v['at_init'], 'b')} -> {layers(v['final'], 'b')}"] for name, v in init.items()]),
                    ""]
    return "\n".join(out)
