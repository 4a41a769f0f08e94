"""shared_computation stage: how much of each student's computation its tasks share (thesis 6.2).

    python stages/shared_computation.py

Every student of the distill grid acts online on each of its tasks (``shared_computation.episodes``
episodes per task; the thesis used 1000); its post-ReLU activations on the visited states are
compared across task ids: per state (Kendall's tau-a and tau-b, mean +- sd over states), on task
averages (tau-a and tau-b of the mean activations) and by linear CKA (mop_core/shared_computation.py); the same
measures of an untrained copy of each group's first student on its states are the reference. Writes
- results/shared_computation/metrics.json: Table 6.1 per (loss, pairing) group (mean over the
  group's seeds) and per student (dvc metrics);
- results/shared_computation/students/<student>.json: everything measured, incl. the mean activations;
- results/shared_computation/figures/<student>.png: the sorted mean activations (Figure 6.3b);
- results/shared_computation/tau_during_training.png: the per-state tau logged while distilling
  (Figure 6.4b), dotted lines at each student's value at initialisation.
"""

from __future__ import annotations

import time

import torch
from common import RESULTS, load_params, require_inputs, run_paths, run_stage, section, study_config
from distill_config import distill_grid, student_name

from mop_core.config import from_mapping, require
from mop_core.data import read_json, write_json
from mop_core.distill.run import load_student
from mop_core.plots import metric_curves, read_curve, sorted_activations
from mop_core.runtime import derive_seeds, progress_enabled, set_threads
from mop_core.shared_computation import (
    TIES_NOTE,
    SharedComputationConfig,
    collect_visited,
    measure_student,
    rollout_jobs,
    summarise_students,
    untrained_like,
)

OUT = RESULTS / "shared_computation"
SECTION = "shared_computation"


def shared_computation_config(params: dict) -> tuple[int, SharedComputationConfig]:
    """The measurement's torch threads and the rollouts' settings."""
    raw = dict(section(params, SECTION))
    threads = raw.pop("threads", 1)
    require(isinstance(threads, int) and not isinstance(threads, bool) and threads >= 1, f"{SECTION}.threads",
            "a positive integer", threads)
    return threads, from_mapping(SharedComputationConfig, raw, SECTION)


def main() -> None:
    params = load_params()
    study = study_config(params)
    threads, config = shared_computation_config(params)
    require(len(study.tasks) >= 2, "study.tasks", "at least two tasks to compare task ids", list(study.tasks))
    grid = distill_grid(params, study)
    groups = {f"{loss}_{pairing}": [student_name(loss, pairing, seed) for seed in grid.seeds]
              for loss in grid.losses for pairing in grid.pairings}
    names = [name for members in groups.values() for name in members]
    paths = {name: run_paths(name, "students") for name in names}
    require_inputs([f for p in paths.values() for f in (p.checkpoint, p.curve, p.metrics)], "distill")

    first_student = {members[0]: group for group, members in groups.items()}
    started = time.perf_counter()
    students = {name: load_student(paths[name].checkpoint) for name in names}
    # each student's rollouts in its checkpoint's task order (its task ids), not study.tasks' order
    jobs = rollout_jobs({name: (paths[name].checkpoint, students[name].tasks) for name in names}, study.tasks)
    visited = collect_visited(jobs, study.seed, study.episode_length, config, progress_enabled(study.progress))
    rollout_seconds = time.perf_counter() - started
    set_threads(threads)

    records, untrained = {}, {}
    for n, name in enumerate(names):
        loaded = students[name]
        mine = visited[n * len(loaded.tasks):(n + 1) * len(loaded.tasks)]
        states = [torch.as_tensor(obs) for obs, _ in mine]
        record = measure_student(loaded.student, loaded.tasks, states)
        record["student_return"] = {task: float(returns.mean()) for task, (_, returns) in zip(loaded.tasks, mine)}
        records[name] = record
        group = first_student.get(name)
        if group is not None:  # the reference: an untrained copy on the same states, once per group
            seed = derive_seeds([study.seed, SECTION, "untrained", group], ("init",))["init"]
            reference = measure_student(untrained_like(loaded.student, seed), loaded.tasks, states)
            untrained[group] = {"student_states": name, "pairs": reference["pairs"]}
        write_json(OUT / "students" / f"{name}.json", record)
        sorted_activations(OUT / "figures" / f"{name}.png", record["mean_activations"],
                           f"{name}: mean activation per neuron over {config.episodes} episodes per task")
    seconds = time.perf_counter() - started

    def compact(record: dict) -> dict:
        return {k: v for k, v in record.items() if k != "mean_activations"}

    metrics = {"note": TIES_NOTE, "episodes_per_task": config.episodes,
               "seconds": round(seconds, 1), "rollout_seconds": round(rollout_seconds, 1),
               "groups": {group: summarise_students([records[name] for name in members])
                          | {"untrained": untrained[group]} for group, members in groups.items()},
               "students": {name: compact(record) for name, record in records.items()}}
    write_json(OUT / "metrics.json", metrics)

    curves = {name: read_curve(paths[name].curve) for name in names}
    tau_records = {name: read_json(paths[name].metrics).get("per_state_tau") for name in names}
    keys = sorted({key for record in tau_records.values() if record for key in record["at_init"]},
                  key=lambda k: (k.split("_layer")[0][-1] != "a", int(k.split("_layer")[1])))  # tau-a panels first
    if keys:
        sources = sorted({record["probe_source"] for record in tau_records.values() if record})
        init = {name: [record["at_init"].get(key, float("nan")) for key in keys]
                for name, record in tau_records.items() if record}
        metric_curves(OUT / "tau_during_training.png", curves, keys, init, "per-state Kendall tau",
                      f"per-state tau during distillation on {'/'.join(sources)} probe states "
                      "(dotted: at initialisation)")
    else:  # students trained without probe states: say so in the figure's place
        metric_curves(OUT / "tau_during_training.png", {}, ["per_state_tau (distill.probe_states = 0)"], None,
                      "per-state Kendall tau", "no per-state tau was logged during distillation")
    for group, summary in metrics["groups"].items():
        for pair, layers in summary["pairs"].items():
            for layer, row in layers.items():
                ref = summary["untrained"]["pairs"][pair][layer]
                print(f"{group:16s} {pair:12s} {layer}: per-state tau-a/b {row['per_state_tau_a_mean']:.3f}/"
                      f"{row['per_state_tau_b_mean']:.3f}  average tau-a/b {row['average_tau_a']:.3f}/"
                      f"{row['average_tau_b']:.3f}  linear CKA {row['linear_cka']:.3f}  ({summary['students']} "
                      f"students; untrained tau-b: {ref['per_state_tau_b']['mean']:.3f}, {ref['average_tau_b']:.3f})")
    print(f"shared_computation: {len(names)} students in {seconds:.0f} s (rollouts {rollout_seconds:.0f} s)")


if __name__ == "__main__":
    run_stage(main)
