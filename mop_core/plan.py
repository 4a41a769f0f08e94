"""What a profile costs: its schedules times measured rates, per stage, in hours on one machine.

    python -m mop_core.plan profiles/thesis.yaml --rates benchmarks/rates/<device>.json
    python -m mop_core.plan profiles/thesis.yaml --scale 0.001 --out short.yaml   # a shortened copy

The rates file is what ``benchmarks/bench_rates.py`` measured on a device at that profile's sizes
(TD3, PBRL and student-group updates/s, batched rollout control steps/s). The estimate counts, per
stage, the gradient updates its runs take and the environment steps they roll out (learning-curve
evaluations, datasets, final evaluations), and divides each by its rate:

    hours = sum over runs (updates / update_rate + env_steps / rollout_rate) / 3600

Assumptions, printed with the table: the runs of a stage execute one after another on one device
(dvc repro runs one stage at a time; the collect stage's task processes and a distill entry's seeds
are the exceptions it models); a student group of R seeds costs the time per update interpolated
between the measured R = 1 and R = 8; the KL loss costs what MSE does (the same network, no critic);
collect steps one walker per TD3 update at the single-environment rate; the common-structure students
(distill_width, distill_ranking) cost what plain MSE students do (no rate is measured for other widths
or for the ranking regulariser: a lower bound for width 512 and for the regulariser) and a single-task
student (distill_single) its task's share of a multi-task student's update; a data-sharing
teacher (train_shared_teachers) costs what a deterministic teacher does (its data is larger, its
updates are not) and a data-sharing or substituted-set student (distill_sharing, distill_substitute)
what a plain MSE student does; the state-shift students (distill_composed, distill_size,
distill_corrected) too, whatever their width (a lower bound for width 512; a reweighted student's
classifier is left out, DAgger's rollouts are counted), and compose rolls out its pools at the rollout rate, its
task processes in waves of ``state_shift.workers`` (the state_shift stage's measures, seconds, are
left out). It is an estimate from rates measured in isolation, not a measurement of the stages.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import yaml


@dataclass(frozen=True)
class Rates:
    """Measured rates (benchmarks/bench_rates.py) on one device."""

    device: str
    td3: float  # updates/s
    pbrl: Mapping[str, float]  # actor type -> updates/s
    student: Mapping[str, Mapping[int, float]]  # loss -> group size R -> group updates/s
    rollout: float  # control steps/s, batched walkers under one policy
    single_env: float  # control steps/s, one walker stepped with one policy call per step

    @classmethod
    def from_json(cls, record: Mapping[str, Any]) -> "Rates":
        student = {loss: {int(r): float(v) for r, v in by_r.items()}
                   for loss, by_r in record["student_group_updates_per_second"].items()}
        return cls(str(record["machine"].get("gpu", record["device"])), float(record["td3_updates_per_second"]),
                   dict(record["pbrl_updates_per_second"]), student,
                   float(record["rollout_control_steps_per_second"]),
                   float(record["single_env_control_steps_per_second"]))

    def student_seconds_per_update(self, loss: str, runs: int) -> float:
        """Seconds per update of a group of ``runs`` students: interpolated between the measured sizes."""
        by_r = self.student["mse" if loss == "kl" else loss]
        sizes = sorted(by_r)
        if runs in by_r:
            return 1.0 / by_r[runs]
        low = max([r for r in sizes if r < runs], default=sizes[0])
        high = min([r for r in sizes if r > runs], default=sizes[-1])
        if low == high:  # beyond the measured sizes: linear in the runs from the nearest one
            return runs / low / by_r[low]
        t_low, t_high = 1.0 / by_r[low], 1.0 / by_r[high]
        return t_low + (t_high - t_low) * (runs - low) / (high - low)


def _evaluation_steps(schedule: Mapping[str, Any], episode_length: int, policies: int = 1,
                      final_is_last_point: bool = False) -> int:
    """Control steps of a run's learning-curve and final evaluations (per policy and task).
    ``final_is_last_point``: the curve's last point is the final evaluation (students)."""
    evaluations = math.ceil(schedule["steps"] / schedule["eval_every"]) - int(final_is_last_point)
    return policies * episode_length * (evaluations * schedule["eval_episodes"] + schedule["final_eval_episodes"])


def stage_hours(params: Mapping[str, Any], rates: Rates) -> dict[str, tuple[int, float]]:
    """stage -> (runs, hours on one device)."""
    study = params["study"]
    tasks, levels, length = study["tasks"], study["levels"], study["episode_length"]
    out: dict[str, tuple[int, float]] = {}

    collect = params["collect"]
    sched, sizes = collect["schedule"], collect["datasets"]
    env_steps = sched["warmup_steps"] + sched["total_steps"]
    rollouts = length * (sizes["expert_episodes"] + sizes["medium_episodes"] + sched["random_episodes"]
                         + sched["total_steps"] // sched["eval_every"] * sched["eval_episodes"]
                         + 2 * sched["snapshot_eval_episodes"])
    per_task = sched["total_steps"] / rates.td3 + env_steps / rates.single_env + rollouts / rates.rollout
    waves = math.ceil(len(tasks) / collect["parallel"]["workers"])
    out["collect"] = (len(tasks), waves * per_task / 3600)

    teachers = params["train_teachers"]
    t_sched = teachers["schedule"]
    seconds = 0.0
    runs = 0
    for actor in teachers["actors"]:
        count = len(tasks) * len(levels) * len(teachers["seeds"])
        runs += count
        seconds += count * (t_sched["steps"] / rates.pbrl[actor] + _evaluation_steps(t_sched, length) / rates.rollout)
    out["train_teachers"] = (runs, seconds / 3600)

    multitask = params["train_multitask"]
    count = len(multitask["levels"]) * len(multitask["seeds"])
    per_run = (len(tasks) * t_sched["steps"] / rates.pbrl["deterministic"]
               + _evaluation_steps(t_sched, length, len(tasks)) / rates.rollout)
    out["train_multitask"] = (count, count * per_run / 3600)

    distill = params["distill"]
    d_sched = distill["schedule"]
    seeds = len(distill["seeds"])
    seconds = 0.0
    for loss in distill["losses"]:
        per_entry = (d_sched["steps"] * rates.student_seconds_per_update(loss, seeds)
                     + seeds * _evaluation_steps(d_sched, length, len(tasks), final_is_last_point=True) / rates.rollout)
        seconds += len(distill["pairings"]) * per_entry
    students = len(distill["losses"]) * len(distill["pairings"]) * seeds
    out["distill"] = (students, seconds / 3600)
    structure = params.get("common_structure", {})
    per_entry = (d_sched["steps"] * rates.student_seconds_per_update("mse", seeds)
                 + seeds * _evaluation_steps(d_sched, length, len(tasks), final_is_last_point=True) / rates.rollout)
    for stage, key in (("distill_width", "widths"), ("distill_ranking", "ranking_losses")):
        entries = len(structure.get(key, []))
        out[stage] = (entries * seeds, entries * per_entry / 3600)
        students += entries * seeds
    singles = len(structure.get("single_task", []))  # one task per student: its share of a multi-task update
    out["distill_single"] = (singles * seeds, singles * (
        d_sched["steps"] * rates.student_seconds_per_update("mse", seeds) / max(len(tasks), 1)
        + seeds * _evaluation_steps(d_sched, length, 1, final_is_last_point=True) / rates.rollout) / 3600)

    sharing = params.get("data_sharing", {})
    sharing_levels, kinds = sharing.get("levels", []), sharing.get("teachers", [])
    substitutes = len(sharing.get("substitutes", []))
    # a substitute's set adds its own teacher, its DS teacher and its OQS teachers (m - 1 from other data), and
    # each other task's OQS teacher from the substitute's data is the study set's from its base task's (reused)
    shared_teachers = len(sharing_levels) * (
        len(tasks) * ("ds" in kinds) + len(tasks) * (len(tasks) - 1) * ("oqs" in kinds)
        + substitutes * (1 + ("ds" in kinds) + (len(tasks) - 1) * ("oqs" in kinds)))
    per_teacher = (t_sched["steps"] / rates.pbrl["deterministic"] + _evaluation_steps(t_sched, length) / rates.rollout)
    out["train_shared_teachers"] = (shared_teachers, shared_teachers * per_teacher / 3600)
    entries = len(sharing_levels) * len(sharing.get("students", []))
    out["distill_sharing"] = (entries * seeds, entries * per_entry / 3600)
    students += entries * seeds
    entries = substitutes * len(sharing_levels) * len(sharing.get("substitute_students", []))
    out["distill_substitute"] = (entries * seeds, entries * per_entry / 3600)
    students += entries * seeds

    shift = params.get("state_shift", {})
    datasets, episodes = shift.get("datasets", []), shift.get("episodes", 0)
    pools = {"teacher": 0, "noise": 0, "random": 0}  # mop_core.compose.ComposeConfig.pool_sizes
    for name in datasets:
        composition = shift["compositions"][name]
        teacher = min(episodes, max(1, round(composition["teacher_share"] * episodes)))
        pools["teacher"] = max(pools["teacher"], teacher)
        if teacher < episodes:
            rest = composition.get("rest", "noise")
            pools[rest] = max(pools[rest], episodes - teacher)
    heldout = shift.get("heldout_episodes", 0)  # per dataset, its composition's held-out episodes (pools of their own)
    composed = (sum(pools.values()) + shift.get("reference_episodes", 0) + len(datasets) * heldout) * length \
        if datasets else 0
    waves = math.ceil(len(tasks) / max(shift.get("workers", 1), 1))
    out["compose"] = (len(tasks) * len(datasets), waves * composed / rates.rollout / 3600)
    entries = len(datasets) * len(shift.get("widths", []))  # the plain width's rate: wide ones cost more
    out["distill_composed"] = (entries * seeds, entries * per_entry / 3600)
    entries = len(shift.get("data_percents", []))
    out["distill_size"] = (entries * seeds, entries * per_entry / 3600)
    corrections = shift.get("corrections", [])
    entries = len(shift.get("correction_datasets", [])) * len(shift.get("correction_widths", []))
    dagger = params["distill"].get("dagger", {})  # its rounds' rollouts: every seed's student, per task
    dagger_steps = dagger.get("rounds", 0) * dagger.get("episodes", 0) * seeds * len(tasks) * length
    out["distill_corrected"] = (len(corrections) * entries * seeds, entries * (
        len(corrections) * per_entry + ("dagger" in corrections) * dagger_steps / rates.rollout) / 3600)

    policies = (2 * len(tasks)  # behaviour medium and expert
                + shared_teachers
                + len(tasks) * len(levels) * len(teachers["actors"]) * len(teachers["seeds"])
                + len(levels) * len(tasks) * (len(tasks) - 1)  # cross-task teachers
                + count * len(tasks) + students * len(tasks) + singles * seeds
                + len(tasks) * sum(out[s][0] for s in ("distill_composed", "distill_size", "distill_corrected")))
    out["eval"] = (policies, policies * params["eval"]["episodes"] * length / rates.rollout / 3600)
    shared = params["shared_computation"]
    out["shared_computation"] = (students + singles * seeds, (students * len(tasks) + singles * seeds)
                                 * shared["episodes"] * length / rates.rollout / 3600)
    return out


# every schedule length and episode count of a profile: (section path, key, floor)
SCALED = [(("collect", "schedule"), "total_steps", 20), (("collect", "schedule"), "medium_step", 10),
          (("collect", "schedule"), "warmup_steps", 10), (("collect", "schedule"), "eval_every", 10),
          (("collect", "schedule"), "checkpoint_every", 10), (("collect", "schedule"), "eval_episodes", 1),
          (("collect", "schedule"), "snapshot_eval_episodes", 1), (("collect", "schedule"), "random_episodes", 1),
          (("collect", "datasets"), "expert_episodes", 2), (("collect", "datasets"), "medium_episodes", 2),
          (("eval",), "episodes", 2), (("shared_computation",), "episodes", 1),
          (("state_shift",), "episodes", 2), (("state_shift",), "reference_episodes", 2),
          (("state_shift",), "heldout_episodes", 1), (("distill", "dagger"), "episodes", 1)] + [
    ((section, "schedule"), key, floor) for section in ("train_teachers", "distill")
    for key, floor in (("steps", 10), ("eval_every", 5), ("checkpoint_every", 5), ("eval_episodes", 1),
                       ("final_eval_episodes", 1))]


def scaled_profile(params: Mapping[str, Any], fraction: float, max_evaluations: int | None = None) -> dict:
    """A copy of ``params`` with every schedule length and episode count times ``fraction`` (rounded,
    at least a floor that keeps each stage meaningful): the same grid of runs, sizes and code paths,
    shortened, e.g. a smoke run of the thesis profile on a new machine. Batch sizes are capped at the
    data a shortened profile produces. ``max_evaluations``: at most this many learning-curve
    evaluations per run (a shortened run's time otherwise goes to rolling out its curve)."""
    out = json.loads(json.dumps(params))
    for path, key, floor in SCALED:
        section = out
        for name in path:
            section = section[name]
        section[key] = max(floor, round(section[key] * fraction))
    if max_evaluations is not None:
        for schedule, steps in ((out["collect"]["schedule"], "total_steps"),
                                (out["train_teachers"]["schedule"], "steps"), (out["distill"]["schedule"], "steps")):
            schedule["eval_every"] = max(schedule["eval_every"], -(-schedule[steps] // max_evaluations))
    collect = out["collect"]["schedule"]
    collect["medium_step"] = min(collect["medium_step"], collect["total_steps"] // 2)
    collect["medium_target_return"] = None
    transitions = min(out["collect"]["datasets"][k] for k in ("expert_episodes", "medium_episodes")) * out[
        "study"]["episode_length"]
    transitions = min(transitions, collect["warmup_steps"] + collect["medium_step"])  # medium_replay
    for section in (out["train_teachers"]["pbrl"], out["distill"]):
        section["batch_size"] = min(section["batch_size"], transitions)
    shift, length = out.get("state_shift", {}), out["study"]["episode_length"]
    if shift.get("datasets"):  # a composed dataset's states
        out["distill"]["batch_size"] = min(out["distill"]["batch_size"], shift["episodes"] * length)
    for percent in shift.get("data_percents") or []:  # the fewest whole episodes of a dataset share
        episodes = max(1, round(percent / 100 * out["collect"]["datasets"]["medium_episodes"]))
        out["distill"]["batch_size"] = min(out["distill"]["batch_size"], episodes * length)
    ranking = out["distill"].get("ranking")
    if ranking:  # the regulariser compares states of the step's batch
        ranking["states"] = min(ranking["states"], out["distill"]["batch_size"])
    td3 = out["collect"]["td3"]
    td3["batch_size"] = min(td3["batch_size"], collect["warmup_steps"] + collect["total_steps"])
    return out


def one_level_grid(params: Mapping[str, Any]) -> dict:
    """A copy of ``params`` whose grid keeps the first study level only, one teacher and one multi-task
    seed, and the pairing of that level (every loss and distill seed stay): each stage still runs, with
    a handful of runs instead of the thesis's hundred (dvc's per-stage overhead dominates a smoke run)."""
    out = json.loads(json.dumps(params))
    level = out["study"]["levels"][0]
    out["study"]["levels"] = [level]
    out["train_teachers"]["seeds"] = out["train_teachers"]["seeds"][:1]
    out["train_multitask"].update(levels=[level], seeds=out["train_multitask"]["seeds"][:1])
    out["distill"].update(pairings=[level], teacher_seed=out["train_teachers"]["seeds"][0])
    if "common_structure" in out:
        out["common_structure"]["pairing"] = level
    if out.get("data_sharing", {}).get("levels"):
        out["data_sharing"]["levels"] = [level]
    if "state_shift" in out:
        out["state_shift"]["pairing"] = level
    return out


def plan_table(params: Mapping[str, Any], rates: Rates) -> str:
    rows = stage_hours(params, rates)
    lines = [f"Estimated cost on {rates.device} (one device, stages one after another):", "",
             "| stage | runs | seconds | hours |", "|---|---|---|---|"]
    lines += [f"| {stage} | {runs} | {hours * 3600:.0f} | {hours:.2f} |" for stage, (runs, hours) in rows.items()]
    total = sum(h for _, h in rows.values())
    lines.append(f"| **total** | | **{total * 3600:.0f}** | **{total:.1f}** |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="A profile's estimated cost from measured rates")
    parser.add_argument("profile", help="a params file, e.g. profiles/thesis.yaml")
    parser.add_argument("--rates", help="a JSON written by benchmarks/bench_rates.py")
    parser.add_argument("--scale", type=float, help="write the profile shortened to this fraction (--out)")
    parser.add_argument("--one-level", action="store_true", help="with --scale: one level, one teacher seed")
    parser.add_argument("--max-evaluations", type=int, help="with --scale: learning-curve points per run")
    parser.add_argument("--out", help="where --scale writes the shortened profile")
    args = parser.parse_args(argv)
    params = yaml.safe_load(Path(args.profile).read_text())
    if args.scale is not None:
        if not args.out or not 0 < args.scale <= 1:
            parser.error("--scale needs a fraction in (0, 1] and --out")
        params = scaled_profile(params, args.scale, args.max_evaluations)
        params = one_level_grid(params) if args.one_level else params
        Path(args.out).write_text(yaml.safe_dump(params, sort_keys=False))
        if args.rates is None:
            return
    if args.rates is None:
        parser.error("--rates: a JSON written by benchmarks/bench_rates.py")
    rates = Rates.from_json(json.loads(Path(args.rates).read_text()))
    print(plan_table(params, rates))
    print("\nAssumptions: " + " ".join(__doc__.split("Assumptions, printed with the table: ")[1].split()))


if __name__ == "__main__":
    main()
