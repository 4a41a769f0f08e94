"""The study report: one Markdown page with tables and figures, in the thesis's order.

:func:`render_report` turns a :class:`StudyResults` (everything a run wrote, loaded by the report
stage) into Markdown and draws the learning-curve figures it links. Sections follow the thesis:
behaviour policies (Table 4.1), teachers vs behaviour (Figure 5.1), naive multi-task vs single-task
(Figure 5.3), distillation losses (Figure 5.4), student vs teachers per dataset pairing
(Appendix E), shared computation (Table 6.1, Figures 6.3 and 6.4b), cross-task teachers
(Table 6.3). Every number comes from the results; a section whose stage or runs are not part of
the study says so. Learning-curve bands are 95% Student-t intervals over training seeds (none with
one seed); evaluation intervals are the eval stage's (``ci_unit`` says over what).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

from mop_core.evaluation import confidence_interval
from mop_core.plots import band_curves


@dataclass(frozen=True)
class Run:
    """One trained model of the study: what it is (``key``: task/level/actor/loss/pairing), its
    training seed, its metrics record and learning-curve rows."""

    key: Mapping[str, str]
    seed: int
    metrics: dict
    curve: Sequence[Mapping[str, str]]


@dataclass
class StudyResults:
    """Everything the report shows, as the stages wrote it. Empty/None: not part of this run."""

    tasks: list[str]
    levels: list[str]
    settings: dict  # budgets shown in the header (profile values)
    collect: dict | None = None  # collect metrics (behaviour snapshots)
    datasets: dict[str, dict] = field(default_factory=dict)  # "<task>-<level>" -> dataset summary
    teachers: list[Run] = field(default_factory=list)  # key: task, level, actor
    multitask: list[Run] = field(default_factory=list)  # key: level
    students: list[Run] = field(default_factory=list)  # key: loss, pairing
    pairing_levels: dict[str, list[str]] = field(default_factory=dict)  # pairing -> level per task
    evaluation: dict | None = None  # eval metrics (CIs per task and group, cross_task)
    shared: dict | None = None  # shared_computation metrics
    figures: dict[str, str] = field(default_factory=dict)  # name -> path relative to the report


def fmt(value: float | None, digits: int = 1) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def fmt_ci(entry: Mapping | None) -> str:
    """``mean [low, high]`` of an eval-stage group (``mean`` alone when the interval is undefined)."""
    if entry is None:
        return "not evaluated"
    if entry.get("ci_low") is None:
        return fmt(entry["mean"])
    return f"{fmt(entry['mean'])} [{fmt(entry['ci_low'])}, {fmt(entry['ci_high'])}]"


def ci_caption(entries: Sequence[Mapping]) -> str:
    """Which units the intervals of ``entries`` are over, e.g. '2 training seeds' / '3 eval seeds'."""
    units = sorted({(e["n"], e["ci_unit"].replace("_", " ")) for e in entries if e})
    return ", ".join(f"{n} {unit}s" for n, unit in units) or "no evaluation"


def seeds_text(n: int) -> str:
    """'1 seed, no interval' / '3 seeds, 95% CI': how a learning curve of n runs is drawn."""
    return "1 seed, no interval" if n == 1 else f"{n} seeds, 95% CI"


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
    if len(per_run) > 1:
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


# ---- sections --------------------------------------------------------------------------------------
def header(results: StudyResults) -> str:
    s = results.settings
    lines = ["# MOP study report", "",
             f"Tasks: {', '.join(results.tasks)}. Teacher levels: {', '.join(results.levels)}. "
             f"Profile budgets: {s.get('summary', 'see params.yaml')}.", "",
             "Every number below is read from this run's result files (results/); figures are PNG files next "
             "to them. Section titles name the thesis table or figure each one reproduces.", ""]
    timing = s.get("timing")
    if timing:
        lines += ["Stage times (s): " + ", ".join(f"{k} {fmt(v, 0)}" for k, v in timing.items()), ""]
    return "\n".join(lines)


def behaviour_section(results: StudyResults) -> str:
    out = ["## 1. Behaviour policies (thesis Table 4.1)", ""]
    if results.collect is None:
        return "\n".join(out + [not_run("the collect stage", "Run `dvc repro collect`."), ""])
    snapshot_episodes = results.settings.get("snapshot_eval_episodes", "?")
    rows = []
    for task in results.tasks:
        for level in ("medium", "expert"):
            c = results.collect.get(task, {})
            rows.append([f"{task} ({level})", c.get(f"{level}_gradient_steps", "n/a"),
                         fmt(c.get(f"{level}_return")), fmt_ci(eval_entry(results, task, f"behaviour_{level}"))])
    evals = [eval_entry(results, t, f"behaviour_{lv}") for t in results.tasks for lv in ("medium", "expert")]
    out += [table(["policy", "gradient steps", f"final return (collect, {snapshot_episodes} episodes)",
                   "eval return [95% CI]"], rows), "",
            f"Eval column: the eval stage's common episode seeds; intervals over {ci_caption(evals)}.", ""]
    rows = []
    for task in results.tasks:
        for level in ("expert", "medium", "medium_replay"):
            d = results.datasets.get(f"{task}-{level}")
            if d:
                rows.append([f"{task}-{level}", d.get("transitions", "n/a"), d.get("complete_episodes", "n/a"),
                             f"{fmt(d.get('return_mean'))} +- {fmt(d.get('return_std'))}",
                             f"{fmt(d.get('return_min'))} .. {fmt(d.get('return_max'))}"])
    if rows:
        out += ["Offline datasets (episode returns of their complete episodes):", "",
                table(["dataset", "transitions", "complete episodes", "return mean +- sd", "min .. max"], rows), ""]
    return "\n".join(out)


def teachers_section(results: StudyResults, figure_dir: Path, link_prefix: str) -> str:
    out = ["## 2. Teachers vs behaviour (thesis Figure 5.1)", ""]
    if not results.teachers:
        return "\n".join(out + [not_run("the train_teachers stage", "Run `dvc repro train_teachers`."), ""])
    groups = group_runs(results.teachers, "task", "level", "actor")
    panels: dict = {task: {} for task in results.tasks}
    references: dict = {task: {} for task in results.tasks}
    rows = []
    for (task, level, actor), runs in groups.items():
        band = seed_band([r.curve for r in runs], "return_mean")
        if band:
            panels[task][f"{level} {actor} ({seeds_text(len(runs))})"] = band
        dataset = results.datasets.get(f"{task}-{level}", {}).get("return_mean")
        if dataset is not None:
            references[task][f"{level} dataset"] = dataset
        entry = eval_entry(results, task, f"teacher_{level}_{actor}")
        trained = [r.metrics.get("return_mean", float("nan")) for r in runs]
        ratio = entry["mean"] / dataset if entry and dataset else None
        rows.append([task, level, actor, len(runs), fmt(sum(trained) / len(trained)), fmt_ci(entry), fmt(dataset),
                     fmt(ratio, 2)])
    name = "teachers.png"
    band_curves(figure_dir / name, panels, references, "episode return",
                "PBRL teachers: evaluation return during training (dashed: dataset mean)")
    out += [f"![teachers]({link_prefix}{name})", "",
            f"{curve_caption(list(groups.values()))}; dashed lines: mean episode return of the dataset the teacher "
            "learned from.", "",
            table(["task", "level", "actor", "seeds", "final return (training-end eval)", "eval return [95% CI]",
                   "dataset return", "eval / dataset"], rows), "",
            f"Eval intervals over {ci_caption([eval_entry(results, r[0], f'teacher_{r[1]}_{r[2]}') for r in rows])}.",
            ""]
    return "\n".join(out)


def multitask_section(results: StudyResults, figure_dir: Path, link_prefix: str) -> str:
    out = ["## 3. Naive multi-task PBRL vs single-task teachers (thesis Figure 5.3)", ""]
    if not results.multitask:
        return "\n".join(out + [not_run("the train_multitask stage", "Set train_multitask.levels and run "
                                        "`dvc repro train_multitask`."), ""])
    panels: dict = {task: {} for task in results.tasks}
    rows, drawn = [], []
    for (level,), runs in group_runs(results.multitask, "level").items():
        teachers = group_runs(results.teachers, "task", "level", "actor")
        for task in results.tasks:
            band = seed_band([r.curve for r in runs], f"return_mean_{task}")
            if band:
                panels[task][f"multi-task {level} ({seeds_text(len(runs))})"] = band
                drawn.append(runs)
            single = teachers.get((task, level, "deterministic"), [])
            single_band = seed_band([r.curve for r in single], "return_mean")
            if single_band:
                panels[task][f"single-task {level} ({seeds_text(len(single))})"] = single_band
                drawn.append(single)
            mt, st = eval_entry(results, task, f"multitask_{level}"), eval_entry(results, task,
                                                                                 f"teacher_{level}_deterministic")
            rows.append([task, level, fmt_ci(mt), fmt_ci(st), fmt(mt["mean"] / st["mean"], 2) if mt and st else "n/a"])
    name = "multitask.png"
    band_curves(figure_dir / name, panels, {}, "episode return",
                "naive multi-task PBRL (one actor) vs single-task PBRL")
    out += [f"![multitask]({link_prefix}{name})", "",
            f"{curve_caption(drawn)}. The multi-task agent "
            "counts gradient steps per task.", "",
            table(["task", "level", "multi-task eval [95% CI]", "single-task teacher eval [95% CI]",
                   "multi / single"], rows), ""]
    return "\n".join(out)


def losses_section(results: StudyResults, figure_dir: Path, link_prefix: str) -> str:
    out = ["## 4. Distillation losses (thesis Figure 5.4)", ""]
    if not results.students:
        return "\n".join(out + [not_run("the distill stage", "Run `dvc repro distill`."), ""])
    panels: dict = {task: {} for task in results.tasks}
    references: dict = {task: {} for task in results.tasks}
    rows = []
    student_groups = group_runs(results.students, "loss", "pairing")
    for (loss, pairing), runs in student_groups.items():
        levels = results.pairing_levels.get(pairing, [pairing] * len(results.tasks))
        actor = "gaussian" if loss == "kl" else "deterministic"
        for task, level in zip(results.tasks, levels):
            band = seed_band([r.curve for r in runs], f"return_mean_{task}")
            if band:
                panels[task][f"{loss} {pairing} ({seeds_text(len(runs))})"] = band
            teacher = eval_entry(results, task, f"teacher_{level}_{actor}")
            if teacher:
                references[task][f"{level} {actor} teacher"] = teacher["mean"]
            student = eval_entry(results, task, f"student_{loss}_{pairing}")
            key = f"action_mse_{task}"
            mse = [float(r.curve[-1][key]) for r in runs if r.curve and key in r.curve[-1]]
            rows.append([loss, pairing, task, len(runs), fmt_ci(student), fmt_ci(teacher),
                         fmt(student["mean"] / teacher["mean"], 2) if student and teacher else "n/a",
                         fmt(sum(mse) / len(mse), 4) if mse else "n/a"])
    name = "losses.png"
    band_curves(figure_dir / name, panels, references, "episode return",
                "students by distillation loss (dashed: teacher eval mean)")
    out += [f"![losses]({link_prefix}{name})", "",
            f"{curve_caption(list(student_groups.values()))}; MSE and Q distil the deterministic "
            "teachers, KL the Gaussian ones. Dashed: each teacher's eval-stage mean.", "",
            table(["loss", "pairing", "task", "seeds", "student eval [95% CI]", "teacher eval [95% CI]",
                   "student / teacher", "final action MSE"], rows), "",
            "Student intervals over "
            f"{ci_caption([eval_entry(results, r[2], f'student_{r[0]}_{r[1]}') for r in rows])}.",
            ""]
    return "\n".join(out)


def pairings_section(results: StudyResults) -> str:
    out = ["## 5. Student vs teachers per dataset pairing (thesis Appendix E)", ""]
    if not results.students:
        return "\n".join(out + [not_run("the distill stage", "Run `dvc repro distill`."), ""])
    pairings = sorted({r.key["pairing"] for r in results.students})
    loss = "mse" if any(r.key["loss"] == "mse" for r in results.students) else results.students[0].key["loss"]
    actor = "gaussian" if loss == "kl" else "deterministic"
    rows = []
    for pairing in pairings:
        levels = results.pairing_levels.get(pairing, [pairing] * len(results.tasks))
        for task, level in zip(results.tasks, levels):
            student = eval_entry(results, task, f"student_{loss}_{pairing}")
            teacher = eval_entry(results, task, f"teacher_{level}_{actor}")
            rows.append([pairing, task, level, fmt_ci(student), fmt_ci(teacher),
                         fmt(student["mean"] / teacher["mean"], 2) if student and teacher else "n/a"])
    if len(pairings) == 1:
        out += [f"*Only the pairing {pairings[0]} is part of this run; Appendix E's pairings (e.g. expert+medium) "
                "are a `distill.pairings` change with the levels in `study.levels` (profiles/thesis.yaml runs "
                "all nine).*", ""]
    out += [table(["pairing", "task", "teacher level", f"{loss} student eval [95% CI]", "teacher eval [95% CI]",
                   "student / teacher"], rows), ""]
    return "\n".join(out)


def shared_section(results: StudyResults) -> str:
    out = ["## 6. Shared computation (thesis Table 6.1, Figures 6.3 and 6.4b)", ""]
    if results.shared is None:
        return "\n".join(out + [not_run("the shared_computation stage", "Run `dvc repro shared_computation`."), ""])
    shared = results.shared
    rows = []
    study_order = list(dict.fromkeys(f"{r.key['loss']}_{r.key['pairing']}" for r in results.students))
    ordered = sorted(shared["groups"], key=lambda g: study_order.index(g) if g in study_order else len(study_order))
    for group in ordered:  # the study's loss order (mse, q, kl), not the JSON file's sorted keys
        summary = shared["groups"][group]
        for pair, layers in summary["pairs"].items():
            for layer, row in layers.items():
                rows.append([group, pair, layer.removeprefix("layer"),
                             f"{fmt(row['per_state_tau_mean'], 3)} +- {fmt(row['per_state_tau_sd'], 3)}",
                             f"{fmt(row['average_tau'], 3)} (sd {fmt(row['average_tau_seed_sd'], 3)})",
                             f"{fmt(row['linear_cka'], 3)} (sd {fmt(row['linear_cka_seed_sd'], 3)})",
                             summary["students"]])
                ref = summary.get("untrained", {}).get("pairs", {}).get(pair, {}).get(layer)
                if ref:
                    rows.append([f"{group}, untrained copy", pair, layer.removeprefix("layer"),
                                 f"{fmt(ref['per_state_tau']['mean'], 3)} +- {fmt(ref['per_state_tau']['sd'], 3)}",
                                 fmt(ref["average_tau"], 3), fmt(ref["linear_cka"], 3), "-"])
    out += [f"Each student acted online for {shared['episodes_per_task']} episodes per task; its post-ReLU "
            "activations on the visited states are compared across task ids. Per state: Kendall's tau-b "
            "between a state's activations under the two task ids, mean +- sd over states (s ~ D_i u D_j), "
            "averaged over the group's students. Average: tau-b between the tasks' mean activations over their "
            "own states. Linear CKA: the activation matrices under the two ids over the same states (6.2.4's "
            "proposal). In brackets: sd over the group's students. 'untrained copy' rows: the same measures of "
            "a freshly initialised network of the same shape on the same states (the group's first student's), "
            "the level a number should be read against.", "",
            table(["student group", "tasks", "layer", "per-state tau (mean +- sd)", "average tau", "linear CKA",
                   "students"], rows), "", f"Ties: {shared['note']}", ""]
    zero = []
    for name, record in shared["students"].items():
        for task, fractions in record["zero_fraction"].items():
            zero.append(f"{name} {task}: " + " / ".join(fmt(f, 2) for f in fractions.values()))
    out += ["Share of zero activations per layer (layer 1 / 2 / ...): " + "; ".join(zero) + ".", ""]
    for group, path in results.figures.get("sorted_activations", {}).items():
        out += [f"![{group}]({path})", "",
                f"Figure 6.3b for {group}: neurons sorted by the first task's mean activation; an increasing "
                "trend of the other task's curve means the tasks rank their neurons alike.", ""]
    tau_curve = results.figures.get("tau_during_training")
    if tau_curve:
        init = {r.key["loss"] + " " + r.key["pairing"] + f" seed {r.seed}": r.metrics.get("per_state_tau")
                for r in results.students if r.metrics.get("per_state_tau")}
        out += [f"![per-state tau during distillation]({tau_curve})", "",
                "Figure 6.4b analogue: per-state tau on a fixed probe set of distillation states, logged at every "
                "evaluation; dotted lines: the same student at initialisation.", ""]
        if init:
            out += [table(["student", "probe states per task", "tau at init (per layer)", "tau at end (per layer)"],
                          [[name, v["probe_states_per_task"], " / ".join(fmt(x, 3) for x in v["at_init"].values()),
                            " / ".join(fmt(x, 3) for x in v["final"].values())] for name, v in init.items()]), ""]
    return "\n".join(out)


def cross_task_section(results: StudyResults) -> str:
    out = ["## 7. Cross-task teachers (thesis Table 6.3)", ""]
    cross = (results.evaluation or {}).get("cross_task")
    if not cross:
        return "\n".join(out + [not_run("cross-task evaluation", "It needs deterministic teachers and the eval "
                                        "stage (`dvc repro eval`)."), ""])
    rows = []
    for level, by_teacher in cross.items():
        for teacher, by_task in by_teacher.items():
            rows.append([level, f"{teacher} teacher"] + [fmt(by_task[t]) for t in results.tasks])
    best = []
    for level, by_teacher in cross.items():
        for task in results.tasks:
            winner = max(by_teacher, key=lambda t: by_teacher[t][task])
            best.append(f"{level} {task}: the {winner} teacher ({fmt(by_teacher[winner][task])})")
    out += [table(["level", "policy"] + [f"return on {t}" for t in results.tasks], rows), "",
            "Mean eval return of each task's deterministic teacher under every task's reward (same episode seeds "
            "as section 2). Best per task: " + "; ".join(best) + ".", ""]
    return "\n".join(out)


def render_report(results: StudyResults, figure_dir: Path, link_prefix: str) -> str:
    """The report's Markdown; draws its own figures into ``figure_dir`` (linked as ``link_prefix`` +
    file name)."""
    figure_dir.mkdir(parents=True, exist_ok=True)
    sections = [header(results), behaviour_section(results), teachers_section(results, figure_dir, link_prefix),
                multitask_section(results, figure_dir, link_prefix), losses_section(results, figure_dir, link_prefix),
                pairings_section(results), shared_section(results), cross_task_section(results)]
    extra = results.figures.get("eval_returns")
    if extra:
        sections.append(f"## Appendix: every evaluated policy\n\n![returns]({extra})\n")
    return "\n".join(sections)
