"""The one results loader: everything a study's stages wrote, as typed runs (:class:`~mop_core.report.results.Run`,
their catalogue run in ``origin``) in one :class:`~mop_core.report.results.StudyResults`."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from mop_core.experiment.catalogue import Catalogue
from mop_core.report.results import Run, StudyResults
from mop_core.storage.artifacts import read_curve
from mop_core.storage.files import read_record
from mop_core.storage.layout import (
    COLLECT_METRICS,
    EVAL_METRICS,
    LEVELS,
    RESULTS,
    SHARED_METRICS,
    dataset_summary_file,
    stage_dir,
)


def read_optional(path: Path) -> dict | None:
    """A result record's content (a mapping with the keys its writer always writes:
    mop_core.storage.files.read_record), or None where that part of the study was not run."""
    return read_record(path) if path.is_file() else None


def load_run(run, key: dict) -> Run | None:
    """A trained run's metrics and curve (None if its metrics were not written)."""
    metrics = read_optional(run.paths.metrics)
    if metrics is None:
        return None
    return Run(key, run.seed, metrics, read_curve(run.paths.curve) if run.paths.curve.is_file() else [], run)


def settings(params: Mapping[str, Any]) -> dict:
    """The header's budgets (the params' values)."""
    collect, teachers = params["collect"]["schedule"], params["train_teachers"]
    distill, evaluation = params["distill"], params["eval"]
    medium = (f"medium at {collect['medium_step']}" if not collect.get("medium_target_return") else
              "medium: the first evaluation at or above the published medium return, else the best one; each task's "
              "step in section 1")
    if collect.get("expert_return"):
        medium = (f"until the expert criterion {collect['expert_return']} holds over {collect['expert_eval_episodes']} "
                  "episodes; medium: the earlier snapshot nearest the published medium return; each task's step in "
                  "section 1")
    steps = f"at most {collect['total_steps']}" if collect.get("expert_return") else str(collect["total_steps"])
    summary = (f"collect {steps} TD3 gradient steps per task ({medium}); "
               f"PBRL teachers {teachers['schedule']['steps']} steps, seeds {teachers['seeds']}; students "
               f"{distill['schedule']['steps']} steps, seeds {distill['seeds']}; eval {evaluation['episodes']} "
               "episodes per policy and task")
    if params.get("study", {}).get("cuda_matmul") == "tf32":  # issue 39: where TF32 is used, the report says so
        summary += ("; CUDA float32 matmuls in TF32 (study.cuda_matmul: faster and coarser than fp32, no effect on "
                    "a CPU; benchmarks/tf32_check.py compares a study with its fp32 twin)")
    hidden = distill.get("student", {}).get("hidden_sizes", [])
    return {"summary": summary,
            "teacher_seed": distill["teacher_seed"], "snapshot_eval_episodes": collect.get("snapshot_eval_episodes"),
            "student_width": hidden[0] if hidden and len(set(hidden)) == 1 else "plain",
            "ranking": dict(distill.get("ranking", {})),
            "structure_pairing": params.get("common_structure", {}).get("pairing"),
            # the study grid the verdicts (mop_core.report.findings) look their groups up in
            "widths": list(params.get("common_structure", {}).get("widths", [])),
            "ranking_losses": list(params.get("common_structure", {}).get("ranking_losses", [])),
            "single_task": list(params.get("common_structure", {}).get("single_task", [])),
            "shift_widths": list(params.get("state_shift", {}).get("widths", [])),
            "shift_datasets": list(params.get("state_shift", {}).get("datasets", []))}


def load_results(catalogue: Catalogue, params: Mapping[str, Any]) -> StudyResults:
    """Everything the stages wrote for the catalogue's runs (absent files: parts not run)."""
    results = StudyResults(tasks=list(catalogue.tasks), levels=list(catalogue.levels), settings={})
    results.collect = read_optional(COLLECT_METRICS)
    for task in catalogue.tasks:
        for level in LEVELS:
            dataset = read_optional(dataset_summary_file(task, level))
            if dataset:
                results.datasets[f"{task}-{level}"] = dataset
    for t in catalogue.teachers:
        run = load_run(t, {"task": t.task, "level": t.level, "actor": t.actor})
        results.teachers += [run] if run else []
    for m in catalogue.multitask:
        run = load_run(m, {"level": m.level})
        results.multitask += [run] if run else []
    for s in catalogue.students:
        results.pairing_levels[s.pairing] = list(s.levels)
        kind = results.substitutes if s.substitute else results.variants if s.variant else results.students
        key = {"loss": s.loss} | ({"variant": s.variant.name} if s.variant else {}) | {"pairing": s.pairing} | (
            {"substitute": s.substitute} if s.substitute else {})
        run = load_run(s, key)
        kind += [run] if run else []
    results.evaluation = read_optional(EVAL_METRICS)
    shared = stage_dir("shared_computation")
    results.shared = read_optional(SHARED_METRICS)
    figures: dict = {}
    for name, path in (("eval_returns", EVAL_METRICS.parent / "returns.png"),
                       ("tau_during_training", shared / "tau_during_training.png")):
        if path.is_file():
            figures[name] = path.relative_to(RESULTS).as_posix()
    sorted_figures = {}
    for members in catalogue.student_groups().values():
        path = shared / "figures" / f"{members[0].name}.png"
        if path.is_file():
            sorted_figures[f"{members[0].recipe} {members[0].scope} (seed {members[0].seed})"] = \
                path.relative_to(RESULTS).as_posix()
    figures["sorted_activations"] = sorted_figures
    results.figures = figures
    results.settings = settings(params)
    return results
