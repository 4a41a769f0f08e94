"""The report's section on data sharing and the offline Q-switch (thesis 6.4): Figure 6.9 (teachers
and students of MOP, DS and OQS per level), Table 6.2 (Kendall's tau per layer) and how often each
OQS candidate teacher gave the label; the same on each substitute's task set ({stand_still, walk}:
data_sharing.substitutes, the thesis's recommended movement penalty, 6.4.5 / 7.3).

Returns are the eval stage's (a teacher trained once: interval over its episodes; a student group:
over its training seeds, n in each cell). Tau is the shared_computation stage's: the average tau
(the measure of the thesis's Table 6.2, 6.2.3) beside the thesis's values, and per-state tau in a
column of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from mop_core.experiment.runs import (
    TeacherRun,
    no_sharing_group,
    own_teacher,
    representation_group,
    student_group,
    student_recipe,
)
from mop_core.experiment.variants import Sharing, Variant
from mop_core.plots import interval_panels
from mop_core.report.common_structure import fmt_interval, seed_interval
from mop_core.report.format import eval_entry, fmt, fmt_ci, fmt_normalised, not_run, table
from mop_core.report.results import Run, StudyResults
from mop_core.walker.tasks import data_tasks, substitute_tasks

# Thesis Table 6.2 (walk x stand students, tau-a per layer, one seed): the reference the measured
# rows sit next to. Expert x Expert's OQS row has no approach label in the thesis's text; it is the
# third row.
THESIS_TABLE_6_2 = {"medium": {"MOP": (0.067, 0.15), "DS": (0.52, 0.67), "OQS": (0.68, 0.76)},
                    "expert": {"MOP": (0.16, 0.36), "DS": (0.44, 0.62), "OQS": (0.43, 0.72)}}
STUDENT_LABELS: dict[Variant | None, str] = {  # None: the study's plain MOP students
    None: "MOP", Sharing("ds"): "DS", Sharing("oqs", "own"): "OQS (own critics)",
    Sharing("oqs", "target"): "OQS (target critic)"}


@dataclass(frozen=True)
class TaskSet:
    """The tasks one comparison runs on: the study's, or a substitute's set (data_sharing.substitutes:
    the substitute in place of its base task, on the base task's data)."""

    tasks: tuple[str, ...]
    data: tuple[str, ...]  # per task, whose datasets are its own
    substitute: str = ""

    def scope(self, level: str) -> str:
        """The students' pairing part of their group names (mop_core.experiment.runs.StudentRun.scope)."""
        return f"{self.substitute}-{level}" if self.substitute else level

    def student_variant(self, variant: Variant | None) -> Variant | None:
        """A STUDENT_LABELS variant as this set's students have it (a substituted set's MOP students:
        ``Sharing("mop")``)."""
        return (Sharing("mop") if self.substitute else None) if variant is None else variant

    @property
    def title(self) -> str:
        names = "{" + ", ".join(self.tasks) + "}"
        if not self.substitute:
            return names
        return f"{names} ({self.substitute} on {self.data[self.tasks.index(self.substitute)]}'s data)"


def task_sets(results: StudyResults) -> list[TaskSet]:
    """The study's task set, then each substitute's (in the order its students were loaded)."""
    sets = [TaskSet(tuple(results.tasks), tuple(results.tasks))]
    for substitute in dict.fromkeys(r.key["substitute"] for r in results.substitutes):
        tasks = substitute_tasks(tuple(results.tasks), substitute)
        sets.append(TaskSet(tasks, data_tasks(tasks, substitute), substitute))
    return sets


def set_runs(results: StudyResults, task_set: TaskSet) -> list[Run]:
    """The data-sharing (and a substituted set's MOP) students of one task set."""
    if task_set.substitute:
        return [r for r in results.substitutes if r.key["substitute"] == task_set.substitute]
    return [r for r in results.variants if isinstance(r.origin.variant, Sharing)]


def sharing_levels(results: StudyResults) -> list[str]:
    return list(dict.fromkeys(r.key["pairing"] for r in results.variants if isinstance(r.origin.variant, Sharing)))


def teacher_rows(results: StudyResults, level: str, task: str, task_set: TaskSet | None = None
                 ) -> list[tuple[str, str]]:
    """(label, eval group) of every teacher of ``task`` at ``level``: MOP's, DS's, each OQS candidate's."""
    task_set = task_set or TaskSet(tuple(results.tasks), tuple(results.tasks))
    own = task_set.data[task_set.tasks.index(task)]
    rows = [("MOP teacher", own_teacher(task, own, level, 0).group),
            ("DS teacher", TeacherRun(task, level, "deterministic", 0, task_set.data).group)]
    rows += [(f"OQS teacher on D_{other}->{task}", TeacherRun(task, level, "deterministic", 0, (other,)).group)
             for other in task_set.data if other != own]
    return [(label, group) for label, group in rows if eval_entry(results, task, group)]


def student_rows(results: StudyResults, level: str, task: str, task_set: TaskSet | None = None
                 ) -> list[tuple[str, str]]:
    task_set = task_set or TaskSet(tuple(results.tasks), tuple(results.tasks))
    rows = [(f"{label} student", student_group(student_recipe("mse", task_set.student_variant(variant)),
                                               task_set.scope(level)))
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


def returns_lines(results: StudyResults, levels: Sequence[str], figure: Path, link: str,
                  task_set: TaskSet | None = None) -> list[str]:
    task_set = task_set or TaskSet(tuple(results.tasks), tuple(results.tasks))
    panels: dict = {}
    rows = []
    for level in levels:
        for task in task_set.tasks:
            teachers = teacher_rows(results, level, task, task_set)
            mop = eval_entry(results, task, teachers[0][1]) if teachers and teachers[0][0] == "MOP teacher" else None
            for kind, members in (("teachers", teachers), ("students", student_rows(results, level, task, task_set))):
                series = panels.setdefault(f"return on {task}", {}).setdefault(f"{level} {kind}", [])
                for label, group in members:
                    entry = eval_entry(results, task, group)
                    series.append((short_label(label), *point(entry)))
                    ratio = fmt(entry["mean"] / mop["mean"], 2) if mop else "n/a"
                    rows.append([level, task, label, fmt_ci(entry), fmt_normalised(entry), ratio])
    if not rows:
        return []
    interval_panels(figure, panels, "approach", {name: "episode return (eval stage)" for name in panels},
                    f"MOP, data sharing (DS) and offline Q-switch (OQS) on {task_set.title}: teachers and students")
    return [f"![Figure 6.9 on {task_set.title}]({link})", "",
            table(["level", "task", "policy", "return [95% CI]", "normalised", "/ MOP teacher"], rows), "",
            "Teachers are trained once (interval over their evaluation episodes); students are groups of training "
            "seeds (interval over seeds, n in each cell). MOP teacher: D_i->i (the train_teachers teacher, reused as "
            "OQS's i = j candidate); DS teacher: the union over j of D_j->i; OQS teacher on D_j->i: task i's "
            "rewards on task j's data (in the figure: 'OQS data j->i'; the OQS students by judge: 'OQS own', 'OQS "
            "target'). DS and OQS students learn on the union of the tasks' datasets.", ""]


def seed_tau(shared: dict, summary: dict, pair: str, layer: str, key: str) -> str:
    """The group's tau ``key`` (``average_tau_a``, ``per_state_tau_a``, ...): mean over its students
    [95% CI over them] (no interval under 3)."""
    values = []
    for name in summary.get("members", []):
        cell = shared.get("students", {}).get(name, {}).get("pairs", {}).get(pair, {}).get(layer, {}).get(key)
        if cell is not None:
            values.append(cell["mean"] if isinstance(cell, dict) else cell)
    if not values:
        row = summary["pairs"][pair][layer]
        return fmt(row.get(key, row.get(f"{key}_mean")), 3)
    return fmt_interval(seed_interval(values))


def tau_lines(results: StudyResults, levels: Sequence[str], sets: Sequence[TaskSet] = ()) -> list[str]:
    shared = results.shared or {}
    groups = shared.get("groups", {})
    rows = []
    for task_set in sets or task_sets(results):
        for level in levels:
            scope = task_set.scope(level)
            labelled = [(label, groups.get(representation_group(
                student_recipe("mse", task_set.student_variant(variant)), scope)))
                        for variant, label in STUDENT_LABELS.items()]
            if not task_set.substitute:
                labelled += [("no sharing (single-task students)", groups.get(no_sharing_group(level)))]
            for label, summary in labelled:
                if not summary:
                    continue
                thesis = None if task_set.substitute else THESIS_TABLE_6_2.get(level, {}).get(label.split(" ")[0])
                for pair, layers in summary["pairs"].items():
                    for index, (layer, row) in enumerate(layers.items()):
                        reference = fmt(thesis[index], 3) if thesis and index < len(thesis) else "n/a"
                        rows.append([level, label, pair, layer.removeprefix("layer"),
                                     seed_tau(shared, summary, pair, layer, "average_tau_a"), reference,
                                     seed_tau(shared, summary, pair, layer, "per_state_tau_a"),
                                     fmt(row["per_state_tau_a_sd"], 3),
                                     seed_tau(shared, summary, pair, layer, "per_state_tau_b"),
                                     fmt(row.get("selectivity_mean"), 3), summary["students"]])
    if not rows:
        return [not_run("Table 6.2", "It needs the shared_computation stage (`dvc repro shared_computation`)."), ""]
    return [table(["level", "students", "task pair", "layer", "average tau-a [95% CI over students]",
                   "thesis Table 6.2 (average tau-a)", "per-state tau-a [95% CI] (not Table 6.2's measure)",
                   "sd over states", "per-state tau-b [95% CI]", "task selectivity", "students"], rows), "",
            "Table 6.2: Kendall tau between a layer's activations under the two task ids on the states the "
            "students visit. The thesis's measure (6.2.3: average activations 'unless explicitly noted'; its Table "
            "6.2 carries no note, and its MOP row has the average measure's layer order) is the average tau: tau "
            "between each task's mean activations over its own states, so the thesis column sits beside it. "
            "Per-state tau (section 7's first measure: per state, then averaged over states) is a different number "
            "and has its own column. Each cell: the mean over the group's students (training seeds) with a "
            "Student-t 95% interval over them (n in the last column; none under 3; cut at tau's bounds); sd over "
            "states: one student's spread of per-state tau. tau-a is the thesis's formula. Task selectivity: the "
            "mean share of a neuron's activation variance explained by the task id (section 7). 'no sharing': per "
            "seed, the two single-task students as if they were one student's two ids (section 7's null). Thesis "
            "column: its Table 6.2 (one seed, walk x stand).", ""]


def q_switch_lines(results: StudyResults, levels: Sequence[str], sets: Sequence[TaskSet] = ()) -> list[str]:
    rows = []
    for task_set in sets or task_sets(results):
        for level in levels:
            for variant in (Sharing("oqs", "own"), Sharing("oqs", "target")):
                runs = [r for r in set_runs(results, task_set) if r.origin.variant == variant
                        and r.key["pairing"] == level]
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


SUBSTITUTE_NOTE = ("{title}: the thesis found no negative transfer between stand and walk because dm_control's "
                   "stand does not forbid moving (walking upright scores as standing, 6.4.5) and recommends a "
                   "movement penalty (7.3). Here {substitute} (section 8) learns from {base}'s datasets relabelled "
                   "to its reward, and walk's teacher loses at it (Table 6.3), so sharing data or switching to the "
                   "other task's teacher can now cost return: compare each DS and OQS row with MOP's on "
                   "{substitute}.")


def sharing_section(results: StudyResults, figure_dir: Path, link_prefix: str) -> str:
    """Section 7b: data sharing (6.4.2) and the offline Q-switch (6.4.3), on the study's tasks and on
    each substitute's task set."""
    out = ["## 7b. Data sharing and offline Q-switch (thesis 6.4, Figure 6.9, Table 6.2)", ""]
    levels = sharing_levels(results) or list(dict.fromkeys(r.key["pairing"] for r in results.substitutes))
    if not levels:
        return "\n".join(out + [not_run("the data-sharing students", "Set `data_sharing.levels`, `teachers` and "
                                        "`students` and run `dvc repro`."), ""])
    sets = task_sets(results)
    out += returns_lines(results, levels, figure_dir / "sharing.png", f"{link_prefix}sharing.png", sets[0])
    out += ["What the thesis claims of these rows (6.4.4, Figure 6.9, Table 6.2) and whether this run reproduces "
            "it: the verdict table at the top (ds_teacher_better_on_stand, ds_teacher_matches_on_walk, "
            "ds_student_replicates_teacher, ds_student_best, ds_raises_tau, oqs_highest_tau, table_6_2_*, "
            "oqs_data_teacher_*, oqs_student_below_best_teacher, oqs_student_worse). The 'target critic' rows "
            "test the thesis's explanation of OQS (uncoordinated Q scales).", ""]
    for task_set in sets[1:]:
        name = f"sharing_{task_set.substitute}.png"
        base = task_set.data[task_set.tasks.index(task_set.substitute)]
        out += [f"### Second task set: {task_set.title}", "",
                SUBSTITUTE_NOTE.format(title=task_set.title, substitute=task_set.substitute, base=base), ""]
        out += returns_lines(results, levels, figure_dir / name, f"{link_prefix}{name}", task_set)
    out += tau_lines(results, levels, sets)
    out += q_switch_lines(results, levels, sets)
    return "\n".join(out)
