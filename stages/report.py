"""report stage: results/report.md and its figures, from the run's result files (mop_core/report.py).

    python stages/report.py      # or: dvc repro report

Reads only what the other stages wrote under results/ (metrics JSON, learning-curve TSVs, figures)
plus params.yaml for the study grid; a missing file means that part of the study was not run, and
its section says so. Writes results/report.md and results/report/*.png.
"""

from __future__ import annotations

from pathlib import Path

from common import RESULTS, load_params, run_paths, run_stage, section, study_config, teacher_name
from distill_config import distill_grid, pairing_levels, student_name
from teacher_config import multitask_grid, teacher_grid

from mop_core.data import atomic_path
from mop_core.data import read_json as read_json_file
from mop_core.plots import read_curve
from mop_core.report import Run, StudyResults, render_report

REPORT = RESULTS / "report.md"
FIGURES = RESULTS / "report"


def read_json(path: Path) -> dict | None:
    """A result file's content, or None where that part of the study was not run."""
    return read_json_file(path) if path.is_file() else None


def load_run(name: str, family: str, key: dict, seed: int) -> Run | None:
    paths = run_paths(name, family)
    metrics = read_json(paths.metrics)
    if metrics is None:
        return None
    return Run(key, seed, metrics, read_curve(paths.curve) if paths.curve.is_file() else [])


def link(path: Path) -> str:
    """A path relative to the report's folder (results/)."""
    return path.relative_to(RESULTS).as_posix()


def settings(params: dict, results: StudyResults) -> dict:
    teachers, distill = section(params, "train_teachers"), section(params, "distill")
    evaluation = section(params, "eval")
    summary = (f"collect {params['collect']['schedule']['total_steps']} TD3 gradient steps per task "
               f"(medium at {params['collect']['schedule']['medium_step']}); PBRL teachers "
               f"{teachers['schedule']['steps']} steps, seeds {teachers['seeds']}; students "
               f"{distill['schedule']['steps']} steps, seeds {distill['seeds']}; eval {evaluation['episodes']} "
               "episodes per policy and task")
    timing = {}
    if results.collect:
        timing["collect"] = results.collect.get("stage_seconds")
    for label, runs in (("train_teachers", results.teachers), ("train_multitask", results.multitask),
                        ("distill", results.students)):
        if runs:
            timing[label] = sum(r.metrics.get("train_seconds", 0.0) for r in runs)
    if results.evaluation:
        timing["eval"] = results.evaluation.get("eval", {}).get("seconds")
    if results.shared:
        timing["shared_computation"] = results.shared.get("seconds")
    return {"summary": summary, "timing": {k: v for k, v in timing.items() if v is not None},
            "teacher_seed": distill["teacher_seed"],
            "snapshot_eval_episodes": params["collect"]["schedule"].get("snapshot_eval_episodes")}


def main() -> None:
    params = load_params()
    study = study_config(params)
    grid = distill_grid(params, study)
    teachers_params, multitask_params = teacher_grid(params), multitask_grid(params, study)
    results = StudyResults(tasks=list(study.tasks), levels=list(study.levels), settings={})
    results.collect = read_json(RESULTS / "collect" / "metrics.json")
    for task in study.tasks:
        for level in ("expert", "medium", "medium_replay"):
            dataset = read_json(RESULTS / "collect" / "datasets" / f"{task}-{level}.json")
            if dataset:
                results.datasets[f"{task}-{level}"] = dataset
    for task in study.tasks:
        for level in study.levels:
            for actor in teachers_params.actors:
                for seed in teachers_params.seeds:
                    run = load_run(teacher_name(task, level, actor, seed), "teachers",
                                   {"task": task, "level": level, "actor": actor}, seed)
                    results.teachers += [run] if run else []
    for level in multitask_params.levels:
        for seed in multitask_params.seeds:
            run = load_run(f"{level}-{seed}", "multitask", {"level": level}, seed)
            results.multitask += [run] if run else []
    for loss in grid.losses:
        for pairing in grid.pairings:
            results.pairing_levels[pairing] = list(pairing_levels(pairing, study, "distill.pairings"))
            for seed in grid.seeds:
                run = load_run(student_name(loss, pairing, seed), "students", {"loss": loss, "pairing": pairing}, seed)
                results.students += [run] if run else []
    results.evaluation = read_json(RESULTS / "eval" / "metrics.json")
    results.shared = read_json(RESULTS / "shared_computation" / "metrics.json")
    figures: dict = {}
    for name, path in (("eval_returns", RESULTS / "eval" / "returns.png"),
                       ("tau_during_training", RESULTS / "shared_computation" / "tau_during_training.png")):
        if path.is_file():
            figures[name] = link(path)
    sorted_figures = {}
    for loss in grid.losses:
        for pairing in grid.pairings:
            path = RESULTS / "shared_computation" / "figures" / f"{student_name(loss, pairing, grid.seeds[0])}.png"
            if path.is_file():
                sorted_figures[f"{loss} {pairing} (seed {grid.seeds[0]})"] = link(path)
    figures["sorted_activations"] = sorted_figures
    results.figures = figures
    results.settings = settings(params, results)

    markdown = render_report(results, FIGURES, link(FIGURES) + "/")
    with atomic_path(REPORT) as tmp:
        tmp.write_text(markdown)
    print(f"report: wrote {REPORT} ({len(markdown.splitlines())} lines) and {FIGURES}/")


if __name__ == "__main__":
    run_stage(main)
