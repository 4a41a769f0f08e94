"""The shared_computation stage's work: how much of each student's computation its tasks share
(thesis 6.2, Table 6.1, Figures 6.3b and 6.4b), for every student group of a catalogue.

Every student acts online on each of its tasks; its post-ReLU activations on the visited states are
compared across task ids (:func:`mop_core.shared_computation.measure_student`). Two references: the
same measures of an untrained copy of each group's first student on its states, and of each seed's
single-task students (``common_structure.single_task``) measured against each other, network i
standing for task id i (the no-sharing null, group ``mse-single_<pairing>``).
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from mop_core.distill.checkpoint import load_student
from mop_core.experiment.catalogue import Catalogue
from mop_core.experiment.runs import no_sharing_group
from mop_core.learning.runtime import configure_compute, derive_seeds
from mop_core.plots import metric_curves, sorted_activations
from mop_core.shared_computation import (
    TIES_NOTE,
    SharedComputationConfig,
    collect_visited,
    measure_networks,
    measure_student,
    rollout_jobs,
    separate_hidden,
    summarise_students,
    untrained_like,
)
from mop_core.storage.artifacts import read_curve
from mop_core.storage.files import read_json, write_json


def compact(record: dict) -> dict:
    return {k: v for k, v in record.items() if k != "mean_activations"}


def measure_catalogue(catalogue: Catalogue, config: SharedComputationConfig, threads: int, episode_length: int,
                      out: Path, progress: bool = False) -> tuple[dict, dict]:
    """Measure every multi-task student, and per seed each pairing's single-task students against each
    other (the no-sharing reference); write out/students/<name>.json and out/figures/<name>.png;
    return the metrics record (Table 6.1 per group: mean over its seeds, and per student) and the
    seconds taken (``seconds``, ``rollout_seconds``: the stage's timing record)."""
    groups = {members[0].representation_group: members
              for members in catalogue.student_groups().values() if not members[0].single_task}
    singles = catalogue.single_task_students()
    runs = [run for members in groups.values() for run in members]
    single_runs = [run for by_seed in singles.values() for members in by_seed.values() for run in members]
    first_student = {members[0].name: group for group, members in groups.items()}
    started = time.perf_counter()
    students = {run.name: load_student(run.paths.checkpoint) for run in runs + single_runs}
    # each student's rollouts in its checkpoint's task order (its task ids), not study.tasks' order
    jobs = [job for run in runs + single_runs
            for job in rollout_jobs({run.name: (run.paths.checkpoint, students[run.name].tasks)}, run.tasks)]
    flat = iter(collect_visited(jobs, catalogue.study_seed, episode_length, config, progress))
    visited = {run.name: [next(flat) for _ in students[run.name].tasks] for run in runs + single_runs}
    rollout_seconds = time.perf_counter() - started
    configure_compute(threads)

    records, untrained = {}, {}
    for run in runs:
        loaded, mine = students[run.name], visited[run.name]
        states = [torch.as_tensor(obs) for obs, _ in mine]
        record = measure_student(loaded.student, loaded.tasks, states)
        record["student_return"] = {task: float(returns.mean()) for task, (_, returns) in zip(loaded.tasks, mine)}
        records[run.name] = record
        group = first_student.get(run.name)
        if group is not None:  # the reference: an untrained copy on the same states, once per group
            seed = derive_seeds([catalogue.study_seed, "shared_computation", "untrained", group], ("init",))["init"]
            reference = measure_student(untrained_like(loaded.student, seed), loaded.tasks, states)
            untrained[group] = {"student_states": run.name, "pairs": reference["pairs"]}
        _write_student(out, run.name, record, config.episodes)
    summaries = {group: summarise_students([records[run.name] for run in members])
                 | {"untrained": untrained[group], "members": [run.name for run in members]}
                 for group, members in groups.items()}
    for pairing, by_seed in singles.items():  # the no-sharing reference: network i stands for task id i
        names = []
        for seed, members in by_seed.items():
            name = f"{no_sharing_group(pairing)}-{seed}"
            mine = [visited[run.name][0] for run in members]
            record = measure_networks(separate_hidden([students[run.name].student for run in members]),
                                      [run.tasks[0] for run in members], [torch.as_tensor(obs) for obs, _ in mine])
            record["student_return"] = {run.tasks[0]: float(returns.mean()) for run, (_, returns) in zip(members, mine)}
            record["networks"] = [run.name for run in members]
            records[name] = record
            names.append(name)
            _write_student(out, name, record, config.episodes)
        summaries[no_sharing_group(pairing)] = summarise_students([records[name] for name in names]) | {
            "members": names,
            "no_sharing": "each task's own single-task student (one seed per record), network i standing for id i"}
    seconds = time.perf_counter() - started
    return {"note": TIES_NOTE, "episodes_per_task": config.episodes, "groups": summaries,
            "students": {name: compact(record) for name, record in records.items()}}, {
        "seconds": seconds, "rollout_seconds": round(rollout_seconds, 1), "students": len(runs) + len(single_runs)}


def _write_student(out: Path, name: str, record: dict, episodes: int) -> None:
    write_json(out / "students" / f"{name}.json", record)
    sorted_activations(out / "figures" / f"{name}.png", record["mean_activations"],
                       f"{name}: mean activation per neuron over {episodes} episodes per task")


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
                ref = summary.get("untrained", {}).get("pairs", {}).get(pair, {}).get(layer)
                against = (f"untrained tau-b: {ref['per_state_tau_b']['mean']:.3f}, {ref['average_tau_b']:.3f}" if ref
                           else "no-sharing reference")
                print(f"{group:16s} {pair:12s} {layer}: per-state tau-a/b {row['per_state_tau_a_mean']:.3f}/"
                      f"{row['per_state_tau_b_mean']:.3f}  average tau-a/b {row['average_tau_a']:.3f}/"
                      f"{row['average_tau_b']:.3f}  linear CKA {row['linear_cka']:.3f}  ({summary['students']} "
                      f"students; {against})")
    print(f"shared_computation: {len(metrics['students'])} students in {timing['seconds']:.0f} s "
          f"(rollouts {timing['rollout_seconds']:.0f} s)")
