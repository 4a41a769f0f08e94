"""The shared_computation stage's work: how much of each student's computation its tasks share
(thesis 6.2, Table 6.1, Figures 6.3b and 6.4b), for every student group of a catalogue.

Every student acts online on each of its tasks; its post-ReLU activations on the visited states are
compared across task ids (:func:`mop_core.shared_computation.measure_student`); the same measures of
an untrained copy of each group's first student on its states are the reference.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from mop_core.catalogue import Catalogue
from mop_core.data import read_json, write_json
from mop_core.distill.run import load_student
from mop_core.plots import metric_curves, read_curve, sorted_activations
from mop_core.runtime import configure_compute, derive_seeds
from mop_core.shared_computation import (
    TIES_NOTE,
    SharedComputationConfig,
    collect_visited,
    measure_student,
    rollout_jobs,
    summarise_students,
    untrained_like,
)


def compact(record: dict) -> dict:
    return {k: v for k, v in record.items() if k != "mean_activations"}


def measure_catalogue(catalogue: Catalogue, config: SharedComputationConfig, threads: int, episode_length: int,
                      out: Path, progress: bool = False) -> tuple[dict, dict]:
    """Measure every student; write out/students/<name>.json and out/figures/<name>.png; return the
    metrics record (Table 6.1 per group: mean over its seeds, and per student) and the seconds taken
    (``seconds``, ``rollout_seconds``: the stage's timing record)."""
    groups = {members[0].structure_group: members
              for members in catalogue.student_groups().values()}
    runs = [run for members in groups.values() for run in members]
    first_student = {members[0].name: group for group, members in groups.items()}
    started = time.perf_counter()
    students = {run.name: load_student(run.paths.checkpoint) for run in runs}
    # each student's rollouts in its checkpoint's task order (its task ids), not study.tasks' order
    jobs = rollout_jobs({run.name: (run.paths.checkpoint, students[run.name].tasks) for run in runs}, catalogue.tasks)
    visited = collect_visited(jobs, catalogue.study_seed, episode_length, config, progress)
    rollout_seconds = time.perf_counter() - started
    configure_compute(threads)

    records, untrained = {}, {}
    for n, run in enumerate(runs):
        loaded = students[run.name]
        mine = visited[n * len(loaded.tasks):(n + 1) * len(loaded.tasks)]
        states = [torch.as_tensor(obs) for obs, _ in mine]
        record = measure_student(loaded.student, loaded.tasks, states)
        record["student_return"] = {task: float(returns.mean()) for task, (_, returns) in zip(loaded.tasks, mine)}
        records[run.name] = record
        group = first_student.get(run.name)
        if group is not None:  # the reference: an untrained copy on the same states, once per group
            seed = derive_seeds([catalogue.study_seed, "shared_computation", "untrained", group], ("init",))["init"]
            reference = measure_student(untrained_like(loaded.student, seed), loaded.tasks, states)
            untrained[group] = {"student_states": run.name, "pairs": reference["pairs"]}
        write_json(out / "students" / f"{run.name}.json", record)
        sorted_activations(out / "figures" / f"{run.name}.png", record["mean_activations"],
                           f"{run.name}: mean activation per neuron over {config.episodes} episodes per task")
    seconds = time.perf_counter() - started
    return {"note": TIES_NOTE, "episodes_per_task": config.episodes,
            "groups": {group: summarise_students([records[run.name] for run in members])
                       | {"untrained": untrained[group]} for group, members in groups.items()},
            "students": {name: compact(record) for name, record in records.items()}}, {
        "seconds": seconds, "rollout_seconds": round(rollout_seconds, 1), "students": len(runs)}


def tau_during_training_figure(catalogue: Catalogue, path: Path) -> None:
    """Figure 6.4b: the per-state tau each student logged while distilling, dotted at initialisation."""
    curves = {run.name: read_curve(run.paths.curve) for run in catalogue.students}
    tau_records = {run.name: read_json(run.paths.metrics).get("per_state_tau") for run in catalogue.students}
    keys = sorted({key for record in tau_records.values() if record for key in record["at_init"]},
                  key=lambda k: (k.split("_layer")[0][-1] != "a", int(k.split("_layer")[1])))  # tau-a panels first
    if keys:
        sources = sorted({record["probe_source"] for record in tau_records.values() if record})
        init = {name: [record["at_init"].get(key, float("nan")) for key in keys]
                for name, record in tau_records.items() if record}
        metric_curves(path, curves, keys, init, "per-state Kendall tau",
                      f"per-state tau during distillation on {'/'.join(sources)} probe states "
                      "(dotted: at initialisation)")
    else:  # students trained without probe states: say so in the figure's place
        metric_curves(path, {}, ["per_state_tau (distill.probe_states = 0)"], None,
                      "per-state Kendall tau", "no per-state tau was logged during distillation")


def print_summary(metrics: dict, timing: dict) -> None:
    for group, summary in metrics["groups"].items():
        for pair, layers in summary["pairs"].items():
            for layer, row in layers.items():
                ref = summary["untrained"]["pairs"][pair][layer]
                print(f"{group:16s} {pair:12s} {layer}: per-state tau-a/b {row['per_state_tau_a_mean']:.3f}/"
                      f"{row['per_state_tau_b_mean']:.3f}  average tau-a/b {row['average_tau_a']:.3f}/"
                      f"{row['average_tau_b']:.3f}  linear CKA {row['linear_cka']:.3f}  ({summary['students']} "
                      f"students; untrained tau-b: {ref['per_state_tau_b']['mean']:.3f}, {ref['average_tau_b']:.3f})")
    print(f"shared_computation: {len(metrics['students'])} students in {timing['seconds']:.0f} s "
          f"(rollouts {timing['rollout_seconds']:.0f} s)")
