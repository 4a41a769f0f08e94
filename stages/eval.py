"""eval stage: every policy of the study rolled out online, with 95% confidence intervals.

    python stages/eval.py

Evaluates, each on ``eval.episodes`` episodes per task (the same episode seeds for every policy):
the behaviour snapshots (medium, expert), the teachers (every level, actor type and seed), the naive
multi-task baseline and every student, on the tasks they were trained for; and each task's
deterministic teacher (seed ``distill.teacher_seed``) on every other task's reward (cross-task table,
thesis 6.4.5). Every return is also a normalised score ``100 (R - R_random) / (R_expert - R_random)``
(R_random from the collect stage, R_expert the published level of mop_core.tasks). Aggregates:
IQM of normalised scores per group and the probability of improvement of each student group over
the teachers it learned from and over the other losses (stratified bootstrap, mop_core.statistics).

Writes results/eval/metrics.json (for `dvc metrics show/diff`), results/eval/returns.tsv (one row
per policy group and task, for `dvc plots`), results/eval/returns.json (every episode's return),
the bar chart results/eval/returns.png and the students' learning curves
results/eval/student_curves.png.
"""

from __future__ import annotations

import itertools
import time
from collections import defaultdict

import numpy as np
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
from teacher_config import TeacherGrid, multitask_grid, teacher_grid

from mop_core.config import ConfigError, from_mapping
from mop_core.data import atomic_path, read_json, write_json
from mop_core.evaluation import (
    EvalConfig,
    Job,
    PolicySpec,
    episode_seeds,
    improvement_summary,
    iqm_summary,
    ratio_to_teacher,
    run_jobs,
    summarise_group,
)
from mop_core.plots import learning_curves, read_curve, returns_bar_chart
from mop_core.runtime import derive_seeds, progress_enabled
from mop_core.statistics import normalised_score
from mop_core.tasks import get_task

OUT = RESULTS / "eval"
COLLECT_METRICS = RESULTS / "collect" / "metrics.json"


def study_jobs(params: dict, study, grid: DistillGrid, config: EvalConfig
               ) -> tuple[list[Job], dict[str, dict[str, str]]]:
    """Every evaluation job of the study, and for each student/baseline group per task the teacher
    group it is compared with (students: the teachers of seed ``distill.teacher_seed`` they learned from)."""
    teachers = teacher_grid(params)
    multitask = multitask_grid(params, study)
    jobs: list[Job] = []
    reference: dict[str, dict[str, str]] = defaultdict(dict)
    for task in study.tasks:
        for level in ("medium", "expert"):
            jobs.append(Job(f"behaviour_{level}", 0, PolicySpec("behaviour", behaviour_checkpoint(task, level)), task))
        for level in study.levels:
            for actor in teachers.actors:
                for seed in teachers.seeds:
                    path = run_paths(teacher_name(task, level, actor, seed)).checkpoint
                    jobs.append(Job(f"teacher_{level}_{actor}", seed, PolicySpec("teacher", path), task))
            if "deterministic" in teachers.actors:
                cross = run_paths(teacher_name(task, level, "deterministic", grid.teacher_seed)).checkpoint
                for other in study.tasks:
                    if other != task:
                        jobs.append(Job(f"cross_{level}_{task}", grid.teacher_seed, PolicySpec("teacher", cross),
                                        other))
    for level in multitask.levels:
        for seed in multitask.seeds:
            path = run_paths(f"{level}-{seed}", "multitask").checkpoint
            for task in study.tasks:
                jobs.append(Job(f"multitask_{level}", seed, PolicySpec("multitask", path, task), task))
                reference[f"multitask_{level}"][task] = f"teacher_{level}_deterministic"
    sample = config.gaussian_student_action == "sample"
    for loss in grid.losses:
        for pairing in grid.pairings:
            levels = pairing_levels(pairing, study, "distill.pairings")
            for seed in grid.seeds:
                name = student_name(loss, pairing, seed)
                path = run_paths(name, "students").checkpoint
                for task, level in zip(study.tasks, levels):
                    group = f"student_{loss}_{pairing}"
                    sample_seed = (derive_seeds([study.seed, "eval", "sample", name, task], ("sample",))["sample"]
                                   if sample and loss == "kl" else None)
                    jobs.append(Job(group, seed, PolicySpec("student", path, task, sample_seed), task))
                    reference[group][task] = f"teacher_{level}_{teacher_actor(loss)}"
    return jobs, reference


def eval_config(params: dict) -> EvalConfig:
    return from_mapping(EvalConfig, section(params, "eval"), "eval")


def normalisers(study) -> dict[str, dict]:
    """Per task: R_random (measured by the collect stage) and R_expert (published, mop_core.tasks)."""
    collect = read_json(COLLECT_METRICS)
    out = {}
    for task in study.tasks:
        if "random_return" not in collect.get(task, {}):
            raise ConfigError(f"{COLLECT_METRICS}: no random_return for task {task!r}; rerun `dvc repro collect`")
        out[task] = {"random_return": collect[task]["random_return"],
                     "random_episodes": collect[task]["random_episodes"],
                     "expert_return": get_task(task).expert_return, "expert_source": "UTDS task.json"}
    return out


def cross_task_table(summary: dict, study, teachers: TeacherGrid, teacher_seed: int) -> dict:
    """``[level][teacher task][evaluation task]``: mean return of task i's deterministic teacher (seed
    ``teacher_seed``) on task j's reward."""
    table: dict = {}
    if "deterministic" not in teachers.actors:
        return table
    for level in study.levels:
        table[level] = {}
        for source in study.tasks:
            table[level][source] = {
                target: summary[target][f"teacher_{level}_deterministic"]["seed_means"][str(teacher_seed)]
                if target == source else summary[target][f"cross_{level}_{source}"]["mean"]
                for target in study.tasks}
    return table


def aggregates(scores: dict, reference: dict, grid: DistillGrid, config: EvalConfig, study_seed: int) -> dict:
    """IQM per group and probabilities of improvement, on normalised scores.

    ``scores[group][task][seed]``: normalised scores of one run's episodes."""
    def pooled(group: str, task: str, seed: int | None = None) -> np.ndarray:
        runs = scores[group][task]
        return runs[seed] if seed is not None else np.concatenate([runs[s] for s in sorted(runs)])

    def seed_of(name: str) -> int:
        return derive_seeds([study_seed, "eval", "bootstrap", name], ("bootstrap",))["bootstrap"]

    groups = [g for g in scores if not g.startswith("cross_")]
    iqm = {group: iqm_summary({task: pooled(group, task) for task in scores[group]}, config.bootstrap_reps,
                              seed_of(group)) for group in groups}
    improvement = {}
    for group, teachers_of in reference.items():
        if group not in scores:
            continue
        tasks = list(scores[group])
        teacher_seed = grid.teacher_seed if group.startswith("student_") else None
        name = f"{group}_vs_teachers"
        improvement[name] = improvement_summary({t: pooled(group, t) for t in tasks},
                                                {t: pooled(teachers_of[t], t, teacher_seed) for t in tasks},
                                                config.bootstrap_reps, seed_of(name))
    for pairing in grid.pairings:
        for a, b in itertools.combinations(grid.losses, 2):
            x, y = f"student_{a}_{pairing}", f"student_{b}_{pairing}"
            tasks = list(scores[x])
            improvement[f"{x}_vs_{y}"] = improvement_summary({t: pooled(x, t) for t in tasks},
                                                             {t: pooled(y, t) for t in tasks},
                                                             config.bootstrap_reps, seed_of(f"{x}_vs_{y}"))
    return {"iqm_normalised": iqm, "probability_of_improvement": improvement,
            "note": "IQM: interquartile mean of normalised scores pooled over tasks; probability of improvement "
                    "P(X > Y): per task the share of (x, y) score pairs with x > y (ties 1/2), averaged over tasks; "
                    "X vs teachers compares with the teacher runs X learned from. 95% percentile intervals of a "
                    f"stratified bootstrap ({config.bootstrap_reps} replicates) over runs x episodes within each "
                    "task (Agarwal et al. 2021, rliable)."}


def main() -> None:
    params = load_params()
    study = study_config(params)
    config = eval_config(params)
    grid = distill_grid(params, study)
    jobs, reference = study_jobs(params, study, grid, config)
    require_inputs(sorted({job.policy.path for job in jobs}), "distill")
    require_inputs([COLLECT_METRICS], "collect")
    norms = normalisers(study)

    seeds = episode_seeds(study.seed, config)
    started = time.perf_counter()
    results = run_jobs(jobs, seeds, study.episode_length, config, progress_enabled(study.progress))
    seconds = time.perf_counter() - started

    by_group: dict = defaultdict(lambda: defaultdict(dict))  # task -> group -> train seed -> returns
    scores: dict = defaultdict(lambda: defaultdict(dict))  # group -> task -> train seed -> normalised scores
    for job, returns in zip(jobs, results):
        by_group[job.eval_task][job.group][job.train_seed] = returns
        n = norms[job.eval_task]
        scores[job.group][job.eval_task][job.train_seed] = normalised_score(returns, n["random_return"],
                                                                            n["expert_return"])
    summary = {task: {group: summarise_group(per_seed, norms[task]["random_return"], norms[task]["expert_return"])
                      for group, per_seed in groups.items()} for task, groups in by_group.items()}

    metrics: dict = {}
    for task in study.tasks:
        entry = {g: {k: v for k, v in s.items() if k != "train_seeds"} for g, s in summary[task].items()
                 if not g.startswith("cross_")}
        for group, teachers_of in reference.items():
            if task in teachers_of and group in summary[task] and teachers_of[task] in summary[task]:
                seed = grid.teacher_seed if group.startswith("student_") else None  # what it learned from
                entry[f"{group}_to_teacher"] = ratio_to_teacher(summary[task][group], summary[task][teachers_of[task]],
                                                                seed)
        metrics[task] = entry
    metrics["normalisation"] = norms
    metrics["aggregate"] = aggregates(scores, reference, grid, config, study.seed)
    metrics["cross_task"] = cross_task_table(summary, study, teacher_grid(params), grid.teacher_seed)
    env_steps = sum(r.size for r in results) * study.episode_length
    metrics["eval"] = {"seconds": round(seconds, 1), "jobs": len(jobs), "episodes_per_job": config.episodes,
                       "gaussian_student_action": config.gaussian_student_action,
                       "env_steps_per_second": round(env_steps / max(seconds, 1e-9), 1)}
    write_json(OUT / "metrics.json", metrics)
    write_json(OUT / "returns.json", {task: {group: {str(seed): r.tolist() for seed, r in per_seed.items()}
                                             for group, per_seed in groups.items()}
                                      for task, groups in by_group.items()})
    rows = ["task\tgroup\tlabel\treturn_mean\tci_low\tci_high\tn\tci_unit\tnormalised_mean\tnormalised_ci_low\t"
            "normalised_ci_high"]
    for task in study.tasks:
        for group, s in summary[task].items():
            z = s["normalised"]
            rows.append(f"{task}\t{group}\t{task}/{group}\t{s['mean']:.3f}\t{s['ci_low']:.3f}\t{s['ci_high']:.3f}\t"
                        f"{s['n']}\t{s['ci_unit']}\t{z['mean']:.3f}\t{z['ci_low']:.3f}\t{z['ci_high']:.3f}")
    with atomic_path(OUT / "returns.tsv") as tmp:
        tmp.write_text("\n".join(rows) + "\n")
    plotted = {task: {g: s for g, s in summary[task].items() if not g.startswith("cross_")} for task in study.tasks}
    returns_bar_chart(OUT / "returns.png", plotted,
                      f"returns, {config.episodes} episodes per run (95% CI; unit and n per bar)")
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
                  f"n={s['n']} {s['ci_unit']}s  normalised {s['normalised']['mean']:.1f}")
    for name, entry in metrics["aggregate"]["probability_of_improvement"].items():
        print(f"P({name.replace('_vs_', ' > ')}) = {entry['value']:.2f} "
              f"[{entry['ci_low']:.2f}, {entry['ci_high']:.2f}]")
    print(f"eval: {len(jobs)} jobs in {seconds:.0f} s ({metrics['eval']['env_steps_per_second']:.0f} env steps/s)")


if __name__ == "__main__":
    run_stage(main)
