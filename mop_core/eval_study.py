"""The eval stage's work: every policy of a catalogue rolled out online, summarised and compared.

:func:`evaluate_study` runs the catalogue's jobs (:meth:`~mop_core.experiment.catalogue.Catalogue.eval_jobs`)
and returns, per task and policy group, the mean return with its 95% interval (unit and n said,
:func:`mop_core.statistics.summarise_group`), each as a normalised score
``100 (R - R_random) / (R_expert - R_random)`` too (R_random measured by the collect stage, R_expert
the published level of :mod:`mop_core.walker.tasks`); each student's and baseline's ratio to the teachers it
is compared with; aggregates (IQM of normalised scores per group, probability of improvement of
each student group over its teachers and over the other losses: stratified bootstrap); and the
cross-task table (each task's deterministic teacher on every task's reward, thesis 6.4.5).
:func:`write_eval_outputs` writes the metrics, the tables for ``dvc plots`` and the figures.
"""

from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mop_core.config import ConfigError
from mop_core.evaluation import episode_seeds, run_jobs
from mop_core.experiment.catalogue import Catalogue, Reference
from mop_core.experiment.runs import cross_group, is_cross_group, teacher_group
from mop_core.experiment.study import EvalConfig
from mop_core.learning.runtime import derive_seeds
from mop_core.plots import learning_curves, returns_bar_chart
from mop_core.statistics import (
    improvement_summary,
    iqm_summary,
    normalised_score,
    paired_difference,
    ratio_to_teacher,
    summarise_group,
)
from mop_core.storage.artifacts import read_curve
from mop_core.storage.files import atomic_path, read_json, write_json
from mop_core.storage.timings import per_second, write_timing
from mop_core.walker.tasks import get_task

AGGREGATE_NOTE = ("IQM: interquartile mean of normalised scores pooled over tasks; probability of improvement "
                  "P(X > Y): per task the share of (x, y) run pairs with x > y (ties 1/2), averaged over tasks; "
                  "X vs teachers compares with the teacher runs X learned from. As in rliable, a run (one training "
                  "seed of a policy) is scored by its mean normalised return over its evaluation episodes, and the "
                  "95% percentile intervals come from a stratified bootstrap ({reps} replicates) over runs within "
                  "each task (Agarwal et al. 2021); a side with fewer than 3 runs gets no interval. Groups that share "
                  "training seeds are compared paired: the per-seed difference of their scores, mean over tasks, "
                  "with a Student-t 95% interval over the seeds. A group's IQM pools the tasks its policies were "
                  "trained for; a teacher group pools the study's tasks only (a substitute task's teachers, e.g. "
                  "stand_still's on stand's data, share the group names of the study set's teachers of their kind).")


@dataclass
class StudyEvaluation:
    """Every job's returns, grouped: ``returns[task][group][train seed]`` and the same as normalised
    scores ``scores[group][task][train seed]``; ``summary[task][group]`` their intervals."""

    returns: dict
    scores: dict
    summary: dict
    jobs: int
    seconds: float
    env_steps: int


def normalisers(tasks, collect_metrics: Path) -> dict[str, dict]:
    """Per task: R_random (measured by the collect stage) and R_expert (published, mop_core.walker.tasks)."""
    collect = read_json(collect_metrics)
    out = {}
    for task in tasks:
        if "random_return" not in collect.get(task, {}):
            raise ConfigError(f"{collect_metrics}: no random_return for task {task!r}; rerun `dvc repro collect`")
        out[task] = {"random_return": collect[task]["random_return"],
                     "random_episodes": collect[task]["random_episodes"],
                     "expert_return": get_task(task).expert_return, "expert_source": "UTDS task.json"}
    return out


def substitute_normalisers(substitutes: dict[str, str], norms: dict, study_seed: int, episode_length: int,
                           rollout_envs: int) -> dict[str, dict]:
    """Per substitute task (-> its base task, data_sharing.substitutes): R_random measured here, as
    many uniformly random episodes as collect ran for the base task (no collect run covers a
    substitute), and R_expert published (mop_core.walker.tasks)."""
    from mop_core.collect import random_returns

    out = {}
    for task, base in substitutes.items():
        episodes = norms[base]["random_episodes"]
        seeds = derive_seeds([study_seed, "eval", "random", task], ("episodes", "policy"))
        returns = random_returns(task, episodes, seeds["episodes"], episode_length, rollout_envs, seeds["policy"])
        out[task] = {"random_return": float(returns.mean()), "random_episodes": episodes,
                     "random_source": "eval stage", "expert_return": get_task(task).expert_return,
                     "expert_source": "UTDS task.json"}
    return out


def evaluate_study(catalogue: Catalogue, config: EvalConfig, episode_length: int, norms: dict,
                   progress: bool = False) -> StudyEvaluation:
    """Roll out every job of the catalogue (the same episode seeds for all) and summarise per group."""
    jobs = catalogue.eval_jobs(config.gaussian_student_action == "sample", config.transfer_tasks)
    started = time.perf_counter()
    results = run_jobs(jobs, episode_seeds(catalogue.study_seed, config), episode_length, config, progress)
    seconds = time.perf_counter() - started
    returns: dict = defaultdict(lambda: defaultdict(dict))
    scores: dict = defaultdict(lambda: defaultdict(dict))
    for job, r in zip(jobs, results):
        returns[job.eval_task][job.group][job.train_seed] = r
        if job.eval_task in norms:  # a transfer task has no measured R_random: returns only
            n = norms[job.eval_task]
            scores[job.group][job.eval_task][job.train_seed] = normalised_score(r, n["random_return"],
                                                                                n["expert_return"])
    none: dict = {}
    summary = {task: {group: summarise_group(per_seed, norms.get(task, none).get("random_return"),
                                             norms.get(task, none).get("expert_return"))
                      for group, per_seed in groups.items()} for task, groups in returns.items()}
    return StudyEvaluation(returns, scores, summary, len(jobs), seconds,
                           sum(r.size for r in results) * episode_length)


def ratio_entries(summary: dict, references: dict[str, dict[str, Reference]], task: str) -> dict[str, float]:
    """``<group>_to_teacher``: each compared group's mean over its reference teachers' on ``task``."""
    out = {}
    for group, by_task in references.items():
        ref = by_task.get(task)
        if ref is not None and group in summary[task] and ref.group in summary[task]:
            out[f"{group}_to_teacher"] = ratio_to_teacher(summary[task][group], summary[task][ref.group], ref.seed)
    return out


def iqm_tasks(group: str, tasks, catalogue: Catalogue) -> list[str]:
    """The tasks a group's IQM pools: every task for a student or baseline group; the study's tasks
    for the others (teachers: a substitute's teacher shares its kind's group name, so pooling its
    task would mix the study set's teachers with the substitute set's)."""
    students = {run.group for run in catalogue.students} | {run.group for run in catalogue.multitask}
    return [task for task in tasks if group in students or task in catalogue.tasks]


def run_scores(scores: dict, group: str, task: str, seed: int | None = None) -> dict[int, float]:
    """``{train seed: the run's mean normalised score over its episodes}`` of a group on a task (only
    ``seed`` where given): rliable's unit, one score per run."""
    runs = scores[group][task]
    return {s: float(np.mean(runs[s])) for s in sorted(runs) if seed is None or s == seed}


def aggregates(scores: dict, catalogue: Catalogue, config: EvalConfig) -> dict:
    """IQM per group, probabilities of improvement and paired differences, on run scores."""
    def matrix(group: str, tasks, seed_by_task: dict | None = None) -> dict[str, np.ndarray]:
        return {t: np.array(list(run_scores(scores, group, t, (seed_by_task or {}).get(t)).values())) for t in tasks}

    def seed_of(name: str) -> int:
        return derive_seeds([catalogue.study_seed, "eval", "bootstrap", name], ("bootstrap",))["bootstrap"]

    reps = config.bootstrap_reps
    iqm = {group: iqm_summary(matrix(group, iqm_tasks(group, scores[group], catalogue)), reps, seed_of(group))
           for group in scores if not is_cross_group(group)}
    improvement, paired = {}, {}
    for group, by_task in catalogue.references().items():
        if group not in scores:
            continue
        tasks, name = list(scores[group]), f"{group}_vs_teachers"
        teachers = {t: np.array(list(run_scores(scores, by_task[t].group, t, by_task[t].seed).values()))
                    for t in tasks}
        improvement[name] = improvement_summary(matrix(group, tasks), teachers, reps, seed_of(name))
    for x, y in catalogue.student_comparisons():
        tasks, name = list(scores[x]), f"{x}_vs_{y}"
        improvement[name] = improvement_summary(matrix(x, tasks), matrix(y, tasks), reps, seed_of(name))
        paired[name] = paired_difference({t: run_scores(scores, x, t) for t in tasks},
                                         {t: run_scores(scores, y, t) for t in tasks})
    return {"iqm_normalised": iqm, "probability_of_improvement": improvement, "paired_difference": paired,
            "note": AGGREGATE_NOTE.format(reps=reps)}


def cross_task_table(summary: dict, catalogue: Catalogue, transfer_tasks: tuple[str, ...] = ()) -> dict:
    """``[level][teacher task][evaluation task]``: the return of task i's deterministic teacher (seed
    ``teacher_seed``) on task j's reward, j over the study's tasks and then ``transfer_tasks``: its
    mean and 95% interval over that one run's episodes (``ci_unit`` episode, ``n``)."""
    table: dict = {}
    seed = str(catalogue.teacher_seed)
    for teacher in catalogue.cross_task_teachers():
        group = teacher_group(teacher.level, "deterministic")
        row = table.setdefault(teacher.level, {}).setdefault(teacher.task, {})
        for target in (*catalogue.tasks, *transfer_tasks):
            entry = summary[target][group if target == teacher.task else cross_group(teacher.level, teacher.task)]
            run = entry["runs"][seed] if "runs" in entry else entry  # the teacher_seed run's own episodes
            row[target] = {key: run[key] for key in ("mean", "ci_low", "ci_high", "n", "ci_unit")}
    return table


def eval_metrics(evaluation: StudyEvaluation, catalogue: Catalogue, config: EvalConfig, norms: dict) -> dict:
    """The eval stage's metrics record (``dvc metrics show``)."""
    summary, references = evaluation.summary, catalogue.references()
    metrics: dict = {}
    for task in catalogue.eval_tasks:
        entry = {g: {k: v for k, v in s.items() if k != "train_seeds"} for g, s in summary[task].items()
                 if not is_cross_group(g)}
        metrics[task] = entry | ratio_entries(summary, references, task)
    metrics["normalisation"] = norms
    metrics["aggregate"] = aggregates(evaluation.scores, catalogue, config)
    metrics["cross_task"] = cross_task_table(summary, catalogue, config.transfer_tasks)
    metrics["eval"] = {"jobs": evaluation.jobs, "episodes_per_job": config.episodes,
                       "gaussian_student_action": config.gaussian_student_action}
    return metrics


def write_eval_timing(path: Path, evaluation: StudyEvaluation) -> dict:
    """The eval stage's timing record: rollout seconds and environment steps per second."""
    return write_timing(path, evaluation.seconds, jobs=evaluation.jobs, env_steps=evaluation.env_steps,
                        env_steps_per_second=per_second(evaluation.env_steps, evaluation.seconds))


TSV_HEADER = ("task\tgroup\tlabel\treturn_mean\tci_low\tci_high\tn\tci_unit\tnormalised_mean\tnormalised_ci_low\t"
              "normalised_ci_high")


def returns_table(summary: dict, tasks) -> str:
    """One row per (task, group): the table ``dvc plots`` draws."""
    rows = [TSV_HEADER]
    for task in tasks:
        for group, s in summary[task].items():
            z = s["normalised"]
            rows.append(f"{task}\t{group}\t{task}/{group}\t{s['mean']:.3f}\t{s['ci_low']:.3f}\t{s['ci_high']:.3f}\t"
                        f"{s['n']}\t{s['ci_unit']}\t{z['mean']:.3f}\t{z['ci_low']:.3f}\t{z['ci_high']:.3f}")
    return "\n".join(rows) + "\n"


def write_eval_outputs(out: Path, evaluation: StudyEvaluation, metrics: dict, catalogue: Catalogue,
                       config: EvalConfig) -> dict:
    """metrics.json, returns.json (every episode), returns.tsv, returns.png and student_curves.png;
    returns the per-task summaries drawn (cross-task groups left out)."""
    write_json(out / "metrics.json", metrics)
    write_json(out / "returns.json", {task: {group: {str(seed): r.tolist() for seed, r in per_seed.items()}
                                             for group, per_seed in groups.items()}
                                      for task, groups in evaluation.returns.items()})
    with atomic_path(out / "returns.tsv") as tmp:
        tmp.write_text(returns_table(evaluation.summary, catalogue.eval_tasks))
    plotted = {task: {g: s for g, s in evaluation.summary[task].items() if not is_cross_group(g)}
               for task in catalogue.eval_tasks}
    returns_bar_chart(out / "returns.png", plotted,
                      f"returns, {config.episodes} episodes per run (95% CI; unit and n per bar)")
    curves = {run.name: read_curve(run.paths.curve) for run in catalogue.students}
    learning_curves(out / "student_curves.png", curves, list(catalogue.eval_tasks),
                    "students: evaluation return during distillation")
    return plotted


def print_summary(plotted: dict, metrics: dict, timing: dict) -> None:
    for task, groups in plotted.items():
        for group, s in groups.items():
            print(f"{task:6s} {group:32s} {s['mean']:7.1f}  [{s['ci_low']:.1f}, {s['ci_high']:.1f}]  "
                  f"n={s['n']} {s['ci_unit']}s  normalised {s['normalised']['mean']:.1f}")
    for name, entry in metrics["aggregate"]["probability_of_improvement"].items():
        interval = (f"[{entry['ci_low']:.2f}, {entry['ci_high']:.2f}]" if entry["ci_low"] is not None
                    else "(no interval: fewer than 3 runs)")
        print(f"P({name.replace('_vs_', ' > ')}) = {entry['value']:.2f} {interval}")
    print(f"eval: {timing['jobs']} jobs in {timing['seconds']:.0f} s ({timing['env_steps_per_second']:.0f} "
          "env steps/s)")
