"""eval stage: every policy of the study rolled out online, with 95% confidence intervals.

    python stages/eval.py

Evaluates, each on ``eval.seeds`` x ``eval.episodes`` episodes per task (the same episode seeds for
every policy): the behaviour snapshots (medium, expert), the teachers (every level, actor type and
seed), the naive multi-task baseline and every student, on the tasks they were trained for; and
each task's deterministic teacher on every other task's reward (cross-task table, thesis 6.4.5).
Writes results/eval/metrics.json (for `dvc metrics show/diff`), results/eval/returns.tsv (one row
per policy group and task, for `dvc plots`), results/eval/returns.json (every episode's return)
the bar chart results/eval/returns.png and the students' learning curves
results/eval/student_curves.png.
"""

from __future__ import annotations

import time
from collections import defaultdict

from common import (
    RESULTS,
    behaviour_checkpoint,
    load_params,
    require_inputs,
    run_paths,
    run_stage,
    section,
    study_config,
    teacher_name,
)
from distill_config import DistillGrid, distill_grid, pairing_levels, student_name, teacher_actor

from mop_core.config import from_mapping
from mop_core.data import atomic_path, write_json
from mop_core.evaluation import EvalConfig, Job, PolicySpec, episode_seeds, run_jobs, summarise_group
from mop_core.plots import learning_curves, read_curve, returns_bar_chart
from mop_core.runtime import progress_enabled

OUT = RESULTS / "eval"


def study_jobs(params: dict, study, grid: DistillGrid) -> tuple[list[Job], dict[str, dict[str, str]]]:
    """Every evaluation job of the study, and for each student group per task its teacher's group."""
    teachers = section(params, "train_teachers")
    multitask = section(params, "train_multitask")
    jobs: list[Job] = []
    reference: dict[str, dict[str, str]] = defaultdict(dict)
    for task in study.tasks:
        for level in ("medium", "expert"):
            jobs.append(Job(f"behaviour_{level}", 0, PolicySpec("behaviour", behaviour_checkpoint(task, level)), task))
        for level in study.levels:
            for actor in teachers["actors"]:
                for seed in teachers["seeds"]:
                    path = run_paths(teacher_name(task, level, actor, seed)).checkpoint
                    jobs.append(Job(f"teacher_{level}_{actor}", seed, PolicySpec("teacher", path), task))
            cross = run_paths(teacher_name(task, level, "deterministic", teachers["seeds"][0])).checkpoint
            for other in study.tasks:
                if other != task and "deterministic" in teachers["actors"]:
                    jobs.append(Job(f"cross_{level}_{task}", teachers["seeds"][0], PolicySpec("teacher", cross),
                                    other))
    for level in multitask["levels"]:
        for seed in multitask["seeds"]:
            path = run_paths(f"{level}-{seed}", "multitask").checkpoint
            for task in study.tasks:
                jobs.append(Job(f"multitask_{level}", seed, PolicySpec("multitask", path, task), task))
                reference[f"multitask_{level}"][task] = f"teacher_{level}_deterministic"
    for loss in grid.losses:
        for pairing in grid.pairings:
            levels = pairing_levels(pairing, study, "distill.pairings")
            for seed in grid.seeds:
                path = run_paths(student_name(loss, pairing, seed), "students").checkpoint
                for task, level in zip(study.tasks, levels):
                    group = f"student_{loss}_{pairing}"
                    jobs.append(Job(group, seed, PolicySpec("student", path, task), task))
                    reference[group][task] = f"teacher_{level}_{teacher_actor(loss)}"
    return jobs, reference


def cross_task_table(summary: dict, study, teachers: dict) -> dict:
    """``[level][teacher task][evaluation task]``: mean return of task i's teacher on task j's reward."""
    table: dict = {}
    if "deterministic" not in teachers["actors"]:
        return table
    for level in study.levels:
        table[level] = {}
        for source in study.tasks:
            row = {}
            for target in study.tasks:
                group = f"teacher_{level}_deterministic" if target == source else f"cross_{level}_{source}"
                row[target] = summary[target][group]["mean"]
            table[level][source] = row
    return table


def main() -> None:
    params = load_params()
    study = study_config(params)
    config = from_mapping(EvalConfig, section(params, "eval"), "eval")
    grid = distill_grid(params, study)
    jobs, reference = study_jobs(params, study, grid)
    require_inputs(sorted({job.policy.path for job in jobs}), "distill")

    seeds = episode_seeds(study.seed, config)
    started = time.perf_counter()
    results = run_jobs(jobs, seeds, study.episode_length, config, progress_enabled(study.progress))
    seconds = time.perf_counter() - started

    by_group: dict = defaultdict(lambda: defaultdict(dict))  # task -> group -> train seed -> returns
    for job, returns in zip(jobs, results):
        by_group[job.eval_task][job.group][job.train_seed] = returns
    summary = {task: {group: summarise_group(per_seed) for group, per_seed in groups.items()}
               for task, groups in by_group.items()}

    metrics: dict = {}
    for task in study.tasks:
        entry = {g: {k: v for k, v in s.items() if k != "train_seeds"} for g, s in summary[task].items()
                 if not g.startswith("cross_")}
        for group, teachers_of in reference.items():
            if task in teachers_of and group in summary[task] and teachers_of[task] in summary[task]:
                entry[f"{group}_to_teacher"] = summary[task][group]["mean"] / summary[task][teachers_of[task]]["mean"]
        metrics[task] = entry
    metrics["cross_task"] = cross_task_table(summary, study, section(params, "train_teachers"))
    env_steps = sum(r.size for r in results) * study.episode_length
    metrics["eval"] = {"seconds": round(seconds, 1), "jobs": len(jobs), "episodes_per_job": int(results[0].size),
                       "env_steps_per_second": round(env_steps / max(seconds, 1e-9), 1)}
    write_json(OUT / "metrics.json", metrics)
    write_json(OUT / "returns.json", {task: {group: {str(seed): r.tolist() for seed, r in per_seed.items()}
                                             for group, per_seed in groups.items()}
                                      for task, groups in by_group.items()})
    rows = ["task\tgroup\tlabel\treturn_mean\tci_low\tci_high\tn\tci_unit"]
    for task in study.tasks:
        for group, s in summary[task].items():
            rows.append(f"{task}\t{group}\t{task}/{group}\t{s['mean']:.3f}\t{s['ci_low']:.3f}\t{s['ci_high']:.3f}\t"
                        f"{s['n']}\t{s['ci_unit']}")
    with atomic_path(OUT / "returns.tsv") as tmp:
        tmp.write_text("\n".join(rows) + "\n")
    plotted = {task: {g: s for g, s in summary[task].items() if not g.startswith("cross_")} for task in study.tasks}
    returns_bar_chart(OUT / "returns.png", plotted,
                      f"returns over {config.seeds} eval seeds x {config.episodes} episodes (95% CI)")
    curves = {}
    for loss in grid.losses:
        for pairing in grid.pairings:
            for seed in grid.seeds:
                name = student_name(loss, pairing, seed)
                curves[name] = read_curve(run_paths(name, "students").curve)
    learning_curves(OUT / "student_curves.png", curves, list(study.tasks),
                    "students: evaluation return during distillation")
    for task in study.tasks:
        for group, s in plotted[task].items():
            print(f"{task:6s} {group:32s} {s['mean']:7.1f}  [{s['ci_low']:.1f}, {s['ci_high']:.1f}]  "
                  f"n={s['n']} {s['ci_unit']}s")
    print(f"eval: {len(jobs)} jobs in {seconds:.0f} s ({metrics['eval']['env_steps_per_second']:.0f} env steps/s)")


if __name__ == "__main__":
    run_stage(main)
