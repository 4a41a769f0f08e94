"""The study report: one Markdown page with tables and figures, in the thesis's order.

:func:`render_report` turns a :class:`StudyResults` (everything a run wrote, loaded by the report
stage) into Markdown and draws the learning-curve figures it links. Sections follow the thesis:
behaviour policies (Table 4.1), teachers vs behaviour (Figure 5.1), naive multi-task vs single-task
(Figure 5.3), distillation losses (Figure 5.4), student vs teachers per dataset pairing
(Appendix E), aggregate scores (IQM, probability of improvement), shared computation (Table 6.1,
Figures 6.3 and 6.4b), cross-task teachers (Table 6.3). Every number comes from the results; a
section whose stage or runs are not part of the study says so. Learning-curve bands are 95%
Student-t intervals over training seeds (none under 3 seeds); evaluation intervals are the eval
stage's (each cell says its unit and n).
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from mop_core.experiment.losses import LOSS_KINDS
from mop_core.experiment.runs import (
    BEHAVIOUR_LEVELS,
    behaviour_group,
    multitask_group,
    student_group,
    teacher_group,
)
from mop_core.plots import band_curves
from mop_core.report.format import (
    ci_caption,
    curve_caption,
    eval_entry,
    fmt,
    fmt_ci,
    fmt_normalised,
    group_runs,
    normalisation_text,
    not_run,
    seed_band,
    seed_means_text,
    seeds_text,
    table,
)
from mop_core.report.representations import shared_section
from mop_core.report.results import Run, StudyResults
from mop_core.statistics import MIN_SEEDS_FOR_SEED_CI, confidence_interval
from mop_core.storage.layout import LEVELS


# ---- sections --------------------------------------------------------------------------------------
def header(results: StudyResults) -> str:
    s = results.settings
    lines = ["# MOP study report", "",
             f"Tasks: {', '.join(results.tasks)}. Teacher levels: {', '.join(results.levels)}. "
             f"Profile budgets: {s.get('summary', 'see params.yaml')}.", "",
             "Every number below is read from this run's result files (results/); figures are PNG files next "
             "to them. Section titles name the thesis table or figure each one reproduces.", "",
             "**Intervals.** Every eval interval is a Student-t 95% interval and says its unit and n: over the "
             "evaluation episodes of one trained policy (evaluation noise only: it says nothing about another "
             "training seed), over the pooled episodes of a group with fewer than 3 training seeds (the seed means "
             "are listed beside it), or over the means of >= 3 training seeds; a quantity that cannot be negative "
             "(a return, a squared error) has its interval cut at 0 and marked where the t-interval of 3 seeds "
             "reaches below (too few runs for it). Aggregates (section 6) are rliable's: each run scored by its mean "
             "over its episodes, stratified-bootstrap intervals over runs, none under 3 runs. Learning-curve bands "
             "are over training seeds and drawn only with >= 3 seeds. Every return shown for a policy is the eval "
             "stage's.", "",
             "**What no interval covers.** Training seeds vary within a group; the behaviour data (one TD3 run per "
             f"task: collect) and the teachers students learn from (train_teachers seed {s.get('teacher_seed', '?')}) "
             "do not. Another behaviour run trains other data, and so does this commit on a machine that rounds "
             "otherwise (the float path in results/timings/collect.json; docs/timings.md, 'Float paths'); a verdict "
             "may move with them.", ""]
    lines += ["Stage times are in results/timings/ (`python -m mop_core.storage.timings` prints the table), not here: "
              "a rerun that reproduces the results leaves this report unchanged.", ""]
    return "\n".join(lines)


def behaviour_section(results: StudyResults) -> str:
    out = ["## 1. Behaviour policies (thesis Table 4.1)", ""]
    if results.collect is None:
        return "\n".join(out + [not_run("the collect stage", "Run `dvc repro collect`."), ""])
    snapshot_episodes = results.settings.get("snapshot_eval_episodes", "?")
    rows = []
    for task in results.tasks:
        for level in BEHAVIOUR_LEVELS:
            c = results.collect.get(task, {})
            entry = eval_entry(results, task, behaviour_group(level))
            rows.append([f"{task} ({level})", c.get(f"{level}_gradient_steps", "n/a"),
                         fmt(c.get(f"{level}_return")), fmt_ci(entry), fmt_normalised(entry)])
    evals = [eval_entry(results, t, behaviour_group(lv)) for t in results.tasks for lv in BEHAVIOUR_LEVELS]
    out += [table(["policy", "gradient steps", f"final return (collect, {snapshot_episodes} episodes)",
                   "eval return [95% CI]", "normalised [95% CI]"], rows), "",
            f"Eval columns: the eval stage's common episode seeds; {ci_caption(evals)}. {normalisation_text(results)}",
            ""]
    rows = []
    for task in results.tasks:
        for level in LEVELS:
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
        entry = eval_entry(results, task, teacher_group(level, actor))
        trained = [r.metrics.get("return_mean", float("nan")) for r in runs]
        ratio = entry["mean"] / dataset if entry and dataset else None
        entropy = [float(r.curve[-1]["entropy"]) for r in runs if r.curve and "entropy" in r.curve[-1]]
        rows.append([task, level, actor, len(runs), fmt(sum(trained) / len(trained)), fmt_ci(entry),
                     fmt_normalised(entry), fmt(dataset), fmt(ratio, 2),
                     fmt(sum(entropy) / len(entropy), 2) if entropy else "-"])
    name = "teachers.png"
    band_curves(figure_dir / name, panels, references, "episode return",
                "PBRL teachers: evaluation return during training (dashed: dataset mean)")
    out += [f"![teachers]({link_prefix}{name})", "",
            f"{curve_caption(list(groups.values()))}; dashed lines: mean episode return of the dataset the teacher "
            "learned from.", "",
            table(["task", "level", "actor", "seeds", "final return (training-end eval)", "eval return [95% CI]",
                   "normalised [95% CI]", "dataset return", "eval / dataset", "final entropy (nats)"], rows), "",
            f"Eval columns: {ci_caption([eval_entry(results, r[0], teacher_group(r[1], r[2])) for r in rows])}. "
            "Final entropy: the Gaussian actor's mean entropy on its training batches over the last evaluation "
            "interval; its log sigma is bounded smoothly to (log_std_min, log_std_max), so the entropy lies "
            "strictly between the bounds' values (at log sigma = 0 on all 6 dimensions: 8.51 nats).", ""]
    return "\n".join(out)


def multitask_section(results: StudyResults, figure_dir: Path, link_prefix: str) -> str:
    out = ["## 3. Naive multi-task PBRL vs single-task teachers (thesis Figure 5.3)", ""]
    if not results.multitask:
        return "\n".join(out + [not_run("the train_multitask stage", "Set train_multitask.levels and run "
                                        "`dvc repro train_multitask`."), ""])
    panels: dict = {task: {} for task in results.tasks}
    references: dict = {task: {} for task in results.tasks}
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
            mt = eval_entry(results, task, multitask_group(level))
            st = eval_entry(results, task, teacher_group(level, "deterministic"))
            for label, entry in ((f"multi-task {level}, eval stage", mt), (f"single-task {level}, eval stage", st)):
                if entry:
                    references[task][label] = entry["mean"]
            rows.append([task, level, fmt_ci(mt), fmt_ci(st), fmt_normalised(mt), fmt_normalised(st),
                         fmt(mt["mean"] / st["mean"], 2) if mt and st else "n/a"])
    name = "multitask.png"
    band_curves(figure_dir / name, panels, references, "episode return",
                "naive multi-task PBRL (one actor) vs single-task PBRL (grey: eval-stage means)")
    out += [f"![multitask]({link_prefix}{name})", "",
            f"{curve_caption(drawn)}. Both are drawn against gradient steps per task: a step of the multi-task "
            "agent is one update of each task's critic (and of the shared actor for each task in turn). The curves' "
            "points are the training runs' own evaluations (a few episodes each); the grey lines and the table are "
            "the eval stage's (more episodes, common seeds), which is where the two are compared.", "",
            table(["task", "level", "multi-task eval [95% CI]", "single-task teacher eval [95% CI]",
                   "multi-task normalised", "teacher normalised", "multi / single"], rows), "",
            ci_caption([eval_entry(results, r[0], multitask_group(r[1])) for r in rows]
                       + [eval_entry(results, r[0], teacher_group(r[1], "deterministic")) for r in rows]) + ".", ""]
    return "\n".join(out + conflict_lines(results, figure_dir, link_prefix))


def conflict_lines(results: StudyResults, figure_dir: Path, link_prefix: str) -> list[str]:
    """Thesis 5.1.2's explanation of naive multi-task failure as a number: the cosine between the
    tasks' gradients on the shared weights (mop_core/learning/conflict.py) during training, per task pair."""
    families = [(f"multi-task actor, {level}", runs)
                for (level,), runs in group_runs(results.multitask, "level").items()]
    families += [(f"{loss} students, {pairing}", runs)
                 for (loss, pairing), runs in group_runs(results.students, "loss", "pairing").items()]
    pairs = sorted({key[len("grad_cosine_"):] for _, runs in families for run in runs for row in run.curve[:1]
                    for key in row if key.startswith("grad_cosine_")})
    if not pairs:
        return []
    panels: dict = {pair: {} for pair in pairs}
    rows, drawn = [], []
    for label, runs in families:
        for pair in pairs:
            band = seed_band([r.curve for r in runs], f"grad_cosine_{pair}")
            if not band:
                continue
            panels[pair][f"{label} ({seeds_text(len(runs))})"] = band
            drawn.append(runs)
            finals = [float(r.curve[-1][f"grad_cosine_{pair}"]) for r in runs]
            ci = confidence_interval(finals, bounds=(-1.0, 1.0)) if len(finals) >= MIN_SEEDS_FOR_SEED_CI else None
            final = (f"{fmt(ci['mean'], 3)} [{fmt(ci['ci_low'], 3)}, {fmt(ci['ci_high'], 3)}] (n={len(finals)} seeds)"
                     if ci else f"{fmt(sum(finals) / len(finals), 3)} ({seeds_text(len(finals))})")
            rows.append([label, pair, fmt(min(band["mean"]), 3), final])
    name = "gradient_conflict.png"
    band_curves(figure_dir / name, panels, {}, "cos(g_i, g_k)", "gradient conflict on the shared weights")
    return ["### Gradient conflict (thesis 5.1.2 as a number)", "",
            f"![gradient conflict]({link_prefix}{name})", "",
            f"{curve_caption(drawn)}. Cosine between task i's and task k's gradients on the weights the tasks "
            "share (PCGrad's conflict measure, Yu et al. 2020; mop_core/learning/conflict.py), on a "
            "fresh batch of each "
            "task's states at every evaluation: the multi-task baseline's shared actor (each task's actor objective "
            "under its own critic), and the students' whole network (each task's distillation loss; the ranking "
            "regulariser left out). Below 0: a step for one task undoes part of the other's.", "",
            table(["model", "task pair", "lowest mean cosine", "final cosine [95% CI over seeds]"], rows), ""]


def teacher_run(results: StudyResults, task: str, group: str) -> dict | None:
    """The eval entry of the teacher run students learned from (seed ``teacher_seed`` of the group)."""
    entry = eval_entry(results, task, group)
    seed = str(results.settings.get("teacher_seed", 0))
    if entry and "runs" in entry and seed in entry["runs"]:
        return entry["runs"][seed]
    return entry


def distils(actor: str) -> str:
    """The losses that distil teachers of PBRL actor type ``actor`` (the loss table), e.g. 'MSE and Q'."""
    return " and ".join(name.upper() for name, loss in LOSS_KINDS.items() if loss.teacher_actor == actor)


def kl_rule_text(results: StudyResults) -> str:
    action = (results.evaluation or {}).get("eval", {}).get("gaussian_student_action", "mean")
    how = "by their mean" if action == "mean" else "by sampling from their Gaussian"
    return (f"KL students act {how} (`eval.gaussian_student_action: {action}`), Gaussian teachers by their mean. "
            "The thesis's reference code sampled KL students' actions while its teachers acted by the mean, so "
            "its KL numbers compare with this study's only under `gaussian_student_action: sample`.")


def student_rows(results: StudyResults, loss: str, pairing: str, runs: Sequence[Run]) -> list[list[str]]:
    """Per task: the student group's eval, seed means, normalised score, its teacher run's eval and the ratio."""
    levels = results.pairing_levels.get(pairing, [pairing] * len(results.tasks))
    actor = LOSS_KINDS[loss].teacher_actor
    rows = []
    for task, level in zip(results.tasks, levels):
        student = eval_entry(results, task, student_group(loss, pairing))
        teacher = teacher_run(results, task, teacher_group(level, actor))
        ratio = (results.evaluation or {}).get(task, {}).get(f"{student_group(loss, pairing)}_to_teacher")
        key = f"action_mse_{task}"
        mse = [float(r.curve[-1][key]) for r in runs if r.curve and key in r.curve[-1]]
        rows.append([loss, pairing, task, level, len(runs), fmt_ci(student), seed_means_text(student),
                     fmt_normalised(student), fmt_ci(teacher), fmt_normalised(teacher), fmt(ratio, 2),
                     fmt(sum(mse) / len(mse), 4) if mse else "n/a"])
    return rows


STUDENT_HEADER = ["loss", "pairing", "task", "teacher level", "seeds", "student eval [95% CI]", "seed means",
                  "student normalised", "teacher eval [95% CI]", "teacher normalised", "student / teacher",
                  "final action MSE"]


def student_caption(results: StudyResults, rows: Sequence[Sequence[str]]) -> str:
    students = [eval_entry(results, r[2], student_group(r[0], r[1])) for r in rows]
    teachers = [teacher_run(results, r[2], teacher_group(r[3], LOSS_KINDS[r[0]].teacher_actor)) for r in rows]
    return (f"Students: {ci_caption(students)}. Teachers (the run of seed {results.settings.get('teacher_seed', 0)} "
            f"the students learned from): {ci_caption(teachers)}. Student / teacher divides by that run's mean.")


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
        actor = LOSS_KINDS[loss].teacher_actor
        for task, level in zip(results.tasks, levels):
            band = seed_band([r.curve for r in runs], f"return_mean_{task}")
            if band:
                panels[task][f"{loss} {pairing} ({seeds_text(len(runs))})"] = band
            teacher = teacher_run(results, task, teacher_group(level, actor))
            if teacher:
                references[task][f"{level} {actor} teacher"] = teacher["mean"]
        rows += student_rows(results, loss, pairing, runs)
    name = "losses.png"
    band_curves(figure_dir / name, panels, references, "episode return",
                "students by distillation loss (grey lines: teacher eval means)")
    out += [f"![losses]({link_prefix}{name})", "",
            f"{curve_caption(list(student_groups.values()))}; {distils('deterministic')} distil the deterministic "
            f"teachers, {distils('gaussian')} the Gaussian ones. Grey lines: each teacher's eval-stage mean (named in "
            "the legend).", "",
            table(STUDENT_HEADER, rows), "", student_caption(results, rows), kl_rule_text(results), ""]
    return "\n".join(out)


def pairings_section(results: StudyResults) -> str:
    out = ["## 5. Student vs teachers per dataset pairing (thesis Appendix E)", ""]
    if not results.students:
        return "\n".join(out + [not_run("the distill stage", "Run `dvc repro distill`."), ""])
    pairings = sorted({r.key["pairing"] for r in results.students})
    loss = "mse" if any(r.key["loss"] == "mse" for r in results.students) else results.students[0].key["loss"]
    groups = group_runs(results.students, "loss", "pairing")
    rows = [row for pairing in pairings
            for row in student_rows(results, loss, pairing, groups.get((loss, pairing), []))]
    if len(pairings) == 1:
        out += [f"*Only the pairing {pairings[0]} is part of this run; Appendix E's pairings (e.g. expert+medium) "
                "are a `distill.pairings` change with the levels in `study.levels` (profiles/thesis.yaml runs "
                "all nine).*", ""]
    out += [table(STUDENT_HEADER, rows), "", student_caption(results, rows), ""]
    return "\n".join(out)


def fmt_aggregate(a: Mapping, digits: int = 1) -> str:
    """``value [low, high]``, or the value with why there is no interval."""
    if a.get("ci_low") is None:
        return f"{fmt(a['value'], digits)} (no interval: fewer than 3 runs)"
    return f"{fmt(a['value'], digits)} [{fmt(a['ci_low'], digits)}, {fmt(a['ci_high'], digits)}]"


def aggregate_section(results: StudyResults) -> str:
    out = ["## 6. Aggregate scores: IQM and probability of improvement (rliable)", ""]
    aggregate = (results.evaluation or {}).get("aggregate")
    if not aggregate:
        return "\n".join(out + [not_run("the eval stage's aggregates", "Run `dvc repro eval`."), ""])
    rows = [[group, a["tasks"], a["runs_per_task"], fmt_aggregate(a)]
            for group, a in aggregate["iqm_normalised"].items()]
    out += [table(["policy group", "tasks", "runs per task", "IQM normalised score [95% CI over runs]"], rows), ""]
    rows = [[name.split("_vs_")[0], name.split("_vs_")[1], f"{a['runs_x']} x {a['runs_y']}", fmt_aggregate(a, 2)]
            for name, a in aggregate["probability_of_improvement"].items()]
    out += [table(["X", "Y", "runs per task (X x Y)", "P(X > Y) [95% CI over runs]"], rows), ""]
    paired = aggregate.get("paired_difference", {})
    if paired:
        rows = [[name.split("_vs_")[0], name.split("_vs_")[1], a["seeds"],
                 f"{fmt(a['mean'])} [{fmt(a['ci_low'])}, {fmt(a['ci_high'])}] (n={a['n']} seeds)"
                 if a["ci_low"] is not None else f"{fmt(a['mean'])} (n={a['n']} seeds: no interval)"]
                for name, a in paired.items()]
        out += [table(["X", "Y", "paired seeds", "X - Y, normalised points, mean over tasks [95% CI over seeds]"],
                      rows), ""]
    out += [aggregate["note"],
            "P = 0.5: neither is better. With 3 runs a side the bootstrap has few distinct resamples and its "
            "interval is coarse; the paired differences (same seeds: same initialisation and data stream) are the "
            "sharper test, and the verdict table uses them.", ""]
    return "\n".join(out)


def cross_task_section(results: StudyResults) -> str:
    out = ["## 8. Cross-task teachers (thesis Table 6.3)", ""]
    cross = (results.evaluation or {}).get("cross_task")
    if not cross:
        return "\n".join(out + [not_run("cross-task evaluation", "It needs deterministic teachers and the eval "
                                        "stage (`dvc repro eval`)."), ""])
    targets = list(next(iter(next(iter(cross.values())).values())))
    rows, best = [], []
    for level, by_teacher in cross.items():
        for teacher, by_task in by_teacher.items():
            rows.append([level, f"{teacher} teacher"] + [fmt_ci(by_task[t]) for t in targets])
        for task in targets:
            winner = max(by_teacher, key=lambda t: by_teacher[t][task]["mean"])
            best.append(f"{level} {task}: the {winner} teacher ({fmt(by_teacher[winner][task]['mean'])})")
    transfer = [t for t in targets if t not in results.tasks]
    out += [table(["level", "policy"] + [f"return on {t}" for t in targets], rows), "",
            "Mean eval return [95% CI over the episodes of one teacher run] of each task's deterministic "
            "teacher under every task's reward (same episode seeds as section 2). Best per task: "
            + "; ".join(best) + ".", ""]
    if transfer:
        trained = sorted({r.key["substitute"] for r in results.substitutes} & set(transfer))
        where = (f" ({', '.join(trained)}: section 7b's second task set trains on it, from its base task's data)"
                 if trained else "")
        out += [f"{', '.join(transfer)}: not a study task (`eval.transfer_tasks`): no study teacher trains on it"
                f"{where}. " + " ".join(TRANSFER_NOTES.get(t, "") for t in transfer), ""]
    return "\n".join(out)


TRANSFER_NOTES = {
    "stand_still": "stand_still = stand x tol(|horizontal velocity|; bounds 0, margin 0.5 m/s, gaussian, 0.1) "
                   "(mop_core/walker/tasks.py): dm_control's stand does not forbid moving, so "
                   "walking upright earns the "
                   "full stand reward (the thesis's explanation of Table 6.3, 6.4.5); under stand_still a teacher "
                   "that walks at 1 m/s keeps 1e-4 of it.",
}


def render_report(results: StudyResults, figure_dir: Path, link_prefix: str,
                  later_sections: Sequence[str] = (), shift_sections: Sequence[str] = (), opening: str = "") -> str:
    """The report's Markdown; draws its own figures into ``figure_dir`` (linked as ``link_prefix`` +
    file name). ``opening`` (mop_core.report.verdict_section': the scale and the verdict table) follows the
    header; ``later_sections`` (Markdown, e.g. mop_core.report.common_structure's) follow section 7,
    ``shift_sections`` (mop_core.report.shift's, thesis 5.2) the distillation losses (section 4)."""
    figure_dir.mkdir(parents=True, exist_ok=True)
    sections = [header(results), *([opening] if opening else []), behaviour_section(results),
                teachers_section(results, figure_dir, link_prefix),
                multitask_section(results, figure_dir, link_prefix), losses_section(results, figure_dir, link_prefix),
                *shift_sections, pairings_section(results), aggregate_section(results), shared_section(results),
                *later_sections, cross_task_section(results)]
    extra = results.figures.get("eval_returns")
    if extra:
        sections.append(f"## Appendix: every evaluated policy\n\n![returns]({extra})\n")
    return "\n".join(sections)


# ---- loading a run's results ------------------------------------------------------------------------
