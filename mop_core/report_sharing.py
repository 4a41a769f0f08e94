"""The report's section on data sharing and the offline Q-switch (thesis 6.4): Figure 6.9 (teachers
and students of MOP, DS and OQS per level), Table 6.2 (Kendall's tau per layer) and how often each
OQS candidate teacher gave the label.

Returns are the eval stage's (a teacher trained once: interval over its episodes; a student group:
over its training seeds, n in each cell). Tau is the shared_computation stage's per-state tau
(mean +- sd over states, averaged over the group's students), the measure of the thesis's Table 6.2.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from mop_core.plots import interval_panels
from mop_core.report import Run, StudyResults, eval_entry, fmt, fmt_ci, fmt_normalised, not_run, table
from mop_core.report_structure import fmt_interval, seed_interval
from mop_core.runs import no_sharing_group, structure_group, student_group, student_recipe, teacher_group

# Thesis Table 6.2 (walk x stand students, tau-a per layer, one seed): the reference the measured
# rows sit next to. Expert x Expert's OQS row has no approach label in the thesis's text; it is the
# third row.
THESIS_TABLE_6_2 = {"medium": {"MOP": (0.067, 0.15), "DS": (0.52, 0.67), "OQS": (0.68, 0.76)},
                    "expert": {"MOP": (0.16, 0.36), "DS": (0.44, 0.62), "OQS": (0.43, 0.72)}}
STUDENT_LABELS = {"": "MOP", "ds": "DS", "oqs_own": "OQS (own critics)", "oqs_target": "OQS (target critic)"}


def sharing_levels(results: StudyResults) -> list[str]:
    return list(dict.fromkeys(r.key["pairing"] for r in results.variants if r.key["variant"] in STUDENT_LABELS))


def teacher_rows(results: StudyResults, level: str, task: str) -> list[tuple[str, str]]:
    """(label, eval group) of every teacher of ``task`` at ``level``: MOP's, DS's, each OQS candidate's."""
    rows = [("MOP teacher", teacher_group(level, "deterministic")), ("DS teacher", f"teacher_ds_{level}_deterministic")]
    rows += [(f"OQS teacher on D_{other}->{task}", f"teacher_from_{other}_{level}_deterministic")
             for other in results.tasks if other != task]
    return [(label, group) for label, group in rows if eval_entry(results, task, group)]


def student_rows(results: StudyResults, level: str, task: str) -> list[tuple[str, str]]:
    rows = [(f"{label} student", student_group(student_recipe("mse", variant), level))
            for variant, label in STUDENT_LABELS.items()]
    return [(label, group) for label, group in rows if eval_entry(results, task, group)]


def short_label(label: str) -> str:
    """The figure's x tick of a table row: MOP, DS, OQS data (the teacher on another task's data), OQS own,
    OQS target (the students by judge)."""
    if label.startswith("OQS teacher"):
        return "OQS data j->i"
    return {"OQS (own critics) student": "OQS own", "OQS (target critic) student": "OQS target"}.get(
        label, label.removesuffix(" teacher").removesuffix(" student"))


def point(entry: dict) -> tuple[float, float | None, float | None]:
    return entry["mean"], entry.get("ci_low"), entry.get("ci_high")


def returns_lines(results: StudyResults, levels: Sequence[str], figure: Path, link: str) -> list[str]:
    panels: dict = {}
    rows = []
    for level in levels:
        for task in results.tasks:
            mop = eval_entry(results, task, teacher_group(level, "deterministic"))
            for kind, members in (("teachers", teacher_rows(results, level, task)),
                                  ("students", student_rows(results, level, task))):
                series = panels.setdefault(f"return on {task}", {}).setdefault(f"{level} {kind}", [])
                for label, group in members:
                    entry = eval_entry(results, task, group)
                    series.append((short_label(label), *point(entry)))
                    ratio = fmt(entry["mean"] / mop["mean"], 2) if mop else "n/a"
                    rows.append([level, task, label, fmt_ci(entry), fmt_normalised(entry), ratio])
    interval_panels(figure, panels, "approach", {name: "episode return (eval stage)" for name in panels},
                    "MOP, data sharing (DS) and offline Q-switch (OQS): teachers and students")
    return [f"![Figure 6.9]({link})", "",
            table(["level", "task", "policy", "return [95% CI]", "normalised", "/ MOP teacher"], rows), "",
            "Teachers are trained once (interval over their evaluation episodes); students are groups of training "
            "seeds (interval over seeds, n in each cell). MOP teacher: D_i->i (the train_teachers teacher, reused as "
            "OQS's i = j candidate); DS teacher: the union over j of D_j->i; OQS teacher on D_j->i: task i's "
            "rewards on task j's data (in the figure: 'OQS data j->i'; the OQS students by judge: 'OQS own', 'OQS "
            "target'). DS and OQS students learn on the union of the tasks' datasets.", ""]


def seed_tau(shared: dict, summary: dict, pair: str, layer: str, variant: str) -> str:
    """The group's per-state tau: mean over its students [95% CI over them] (no interval under 3)."""
    values = [shared["students"][name]["pairs"][pair][layer][f"per_state_tau_{variant}"]["mean"]
              for name in summary.get("members", []) if name in shared.get("students", {})]
    if not values:
        return fmt(summary["pairs"][pair][layer][f"per_state_tau_{variant}_mean"], 3)
    return fmt_interval(seed_interval(values))


def tau_lines(results: StudyResults, levels: Sequence[str]) -> list[str]:
    shared = results.shared or {}
    groups = shared.get("groups", {})
    rows = []
    for level in levels:
        labelled = [(label, groups.get(structure_group(student_recipe("mse", variant), level)))
                    for variant, label in STUDENT_LABELS.items()]
        labelled += [("no sharing (single-task students)", groups.get(no_sharing_group(level)))]
        for label, summary in labelled:
            if not summary:
                continue
            thesis = THESIS_TABLE_6_2.get(level, {}).get(label.split(" ")[0])
            for pair, layers in summary["pairs"].items():
                for index, (layer, row) in enumerate(layers.items()):
                    reference = fmt(thesis[index], 3) if thesis and index < len(thesis) else "n/a"
                    rows.append([level, label, pair, layer.removeprefix("layer"),
                                 seed_tau(shared, summary, pair, layer, "a"), fmt(row["per_state_tau_a_sd"], 3),
                                 seed_tau(shared, summary, pair, layer, "b"),
                                 fmt(row.get("selectivity_mean"), 3), reference, summary["students"]])
    if not rows:
        return [not_run("Table 6.2", "It needs the shared_computation stage (`dvc repro shared_computation`)."), ""]
    return [table(["level", "students", "task pair", "layer", "per-state tau-a [95% CI over students]",
                   "sd over states", "per-state tau-b [95% CI]", "task selectivity", "thesis tau-a", "students"],
                  rows), "",
            "Table 6.2: per-state Kendall tau between a layer's activations under the two task ids on the states "
            "the students visit (section 7's measure): per student the mean over its states; the cell is the mean "
            "over the group's students (training seeds) with a Student-t 95% interval over them (n in the last "
            "column; none under 3), next to the sd over one student's states. tau-a is the thesis's formula. Task "
            "selectivity: the mean share of a neuron's activation variance explained by the task id (section 7). "
            "'no sharing': per seed, the two single-task students as if they were one student's two ids (section "
            "7's null). Thesis column: its Table 6.2 (one seed, walk x stand).", ""]


def q_switch_lines(results: StudyResults, levels: Sequence[str]) -> list[str]:
    rows = []
    for level in levels:
        for variant in ("oqs_own", "oqs_target"):
            runs: list[Run] = [r for r in results.variants if r.key["variant"] == variant and r.key["pairing"] == level]
            records = [r.metrics["q_switch"] for r in runs if "q_switch" in r.metrics]
            if not records:
                continue
            for task, shares in records[0].items():
                mean = {source: sum(rec[task][source] for rec in records) / len(records) for source in shares}
                cells = ", ".join(f"D_{source}->{task}: {fmt(share, 3)}" for source, share in mean.items())
                rows.append([level, STUDENT_LABELS[variant], task, cells])
    if not rows:
        return []
    return [table(["level", "students", "target task", "share of states each candidate labels"], rows), "",
            "Offline Q-switch (6.4.3): at every state of the union the label for task i is the action of "
            "argmax_j Q_ij(s, pi_ij(s)) (min over each critic ensemble). 'own critics': each candidate judged by "
            "its own critics, the thesis's rule, whose scales were trained separately; 'target critic': every "
            "candidate judged by task i's MOP teacher's critics, as QMP does online. Shares averaged over the "
            "group's students (the union's states are the same for every seed).", ""]


def sharing_section(results: StudyResults, figure_dir: Path, link_prefix: str) -> str:
    """Section 7b: data sharing (6.4.2) and the offline Q-switch (6.4.3)."""
    out = ["## 7b. Data sharing and offline Q-switch (thesis 6.4, Figure 6.9, Table 6.2)", ""]
    levels = sharing_levels(results)
    if not levels:
        return "\n".join(out + [not_run("the data-sharing students", "Set `data_sharing.levels`, `teachers` and "
                                        "`students` and run `dvc repro`."), ""])
    out += returns_lines(results, levels, figure_dir / "sharing.png", f"{link_prefix}sharing.png")
    out += tau_lines(results, levels)
    out += q_switch_lines(results, levels)
    out += ["Thesis (Figure 6.9, medium): the DS teacher beats MOP's on stand and matches it on walk, and the DS "
            "student is the best student; OQS's cross-task teacher is good at standing from walk data and poor at "
            "walking from stand data; the OQS student stays below its best teacher, which the thesis attributes to "
            "uncoordinated Q scales (the 'target critic' rows test that); tau rises MOP < DS < OQS (Table 6.2).", ""]
    return "\n".join(out)
