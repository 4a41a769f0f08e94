"""What a profile costs: its schedules times measured rates, per stage, in hours on one machine.

    python -m mop_core.plan profiles/thesis.yaml --rates benchmarks/gpu/rates.json   # rates: bench_rates.py
    python -m mop_core.plan profiles/thesis.yaml --scale 0.001 --out short.yaml   # a shortened copy

The rates file is what ``benchmarks/bench_rates.py`` measured on a device at that profile's sizes
(TD3, PBRL and student-group updates/s, batched rollout control steps/s). The estimate counts, per
stage, the gradient updates its runs take and the environment steps they roll out (learning-curve
evaluations, datasets, final evaluations), and divides each by its rate:

    hours = sum over runs (updates / update_rate + env_steps / rollout_rate) / 3600

Assumptions, printed with the table: the runs of a stage execute one after another on one device
(dvc repro runs one stage at a time; the collect stage's task processes and a distill entry's seeds
are the exceptions it models); a student group of R seeds, and a train_teachers or
train_relabelled_teachers entry's vectorised group of R teachers, costs the time per update
interpolated between the group sizes measured (R = 1, 8 and the profile's entry sizes; on CUDA:
updates replayed as CUDA graphs; a rates file without group rates: R single teachers), as one group
(a card without room for it trains it in waves, mop_core.learning.group_memory, which this does not
model); a train_multitask entry, its level's multi-task baselines as one group, costs its group's
measured time per update (R = 1 and the profile's seeds; a rates file without them: R single baselines
at the baseline's own rate, else a single teacher's); the KL loss costs what MSE does (the same network, no critic);
collect steps one walker per TD3 update at the single-environment rate; the common-structure students
(distill_width, distill_ranking) cost what plain MSE students do (no rate is measured for other widths
or for the ranking regulariser: a lower bound for width 512 and for the regulariser) and a single-task
student (distill_single) its task's share of a multi-task student's update; a data-sharing
teacher (train_relabelled_teachers) costs what a deterministic teacher of a group does (its data is
larger, its updates are not) and a data-sharing or substituted-set student (distill_sharing, distill_substitute)
what a plain MSE student does; the state-shift students (distill_composed, distill_size,
distill_corrected) too, whatever their width (a lower bound for width 512; a reweighted student's
classifier is left out, DAgger's rollouts are counted), and compose rolls out its pools at the rollout rate, its
task processes in waves of ``state_shift.workers`` (the state_shift stage's measures, seconds, are left
out); eval and shared computation roll out at the all-cores rate (``parallel_rollout``: jobs over every
core's process) where their ``workers`` is ``auto`` and the rates file has it, else at one process's
rate; collect's and compose's ``workers: auto`` are the measured machine's cores. It is an estimate from
rates measured in isolation, not a measurement of the stages.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import yaml

from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.runs import StudentRun
from mop_core.experiment.study import shift_grid, study_config
from mop_core.shift.compose import compose_config


@dataclass(frozen=True)
class Rates:
    """Measured rates (benchmarks/bench_rates.py) on one device."""

    device: str
    td3: float  # updates/s
    pbrl: Mapping[str, float]  # actor type -> updates/s
    student: Mapping[str, Mapping[int, float]]  # loss -> group size R -> group updates/s
    rollout: float  # control steps/s, batched walkers under one policy
    single_env: float  # control steps/s, one walker stepped with one policy call per step
    parallel_rollout: float | None = None  # control steps/s of eval-style jobs over every core's process
    cores: int = 1  # the processes parallel_rollout ran in: what ``workers: auto`` means on the device machine
    pbrl_group: Mapping[str, Mapping[int, float]] | None = None  # actor type -> group size R -> group updates/s
    multitask: float | None = None  # updates/s of the naive multi-task baseline (one task's step each)
    multitask_group: Mapping[int, float] | None = None  # group size R -> updates/s of R baselines as one group
    tf32: bool = False  # CUDA matmuls ran in TF32 (bench_rates.py --tf32, what study.cuda_matmul: tf32 runs)

    @classmethod
    def from_json(cls, record: Mapping[str, Any]) -> "Rates":
        student = {loss: {int(r): float(v) for r, v in by_r.items()}
                   for loss, by_r in record["student_group_updates_per_second"].items()}
        return cls(str(record["machine"].get("gpu", record["device"])), float(record["td3_updates_per_second"]),
                   dict(record["pbrl_updates_per_second"]), student,
                   float(record["rollout_control_steps_per_second"]),
                   float(record["single_env_control_steps_per_second"]),
                   record.get("parallel_rollout_control_steps_per_second"),  # absent from older rates files
                   int(record.get("parallel_rollout_workers", 1)),
                   {actor: {int(r): float(v) for r, v in by_r.items()}
                    for actor, by_r in record.get("pbrl_group_updates_per_second", {}).items()} or None,
                   record.get("pbrl_multitask_updates_per_second"),
                   {int(r): float(v) for r, v in record.get("pbrl_multitask_group_updates_per_second", {}).items()}
                   or None,  # absent from rates files before the baseline's seeds trained as one group
                   bool(record.get("tf32", False)))

    def rollout_over(self, workers: int | str) -> float:
        """Control steps/s of a stage's rollout jobs in ``workers`` processes: the all-cores rate where the
        profile says ``auto`` (or at least the measured count) and it was measured, else one process's."""
        spread = workers == "auto" or (isinstance(workers, int) and workers >= self.cores > 1)
        return self.parallel_rollout if spread and self.parallel_rollout else self.rollout

    def student_seconds_per_update(self, loss: str, runs: int) -> float:
        """Seconds per update of a group of ``runs`` students: interpolated between the measured sizes."""
        return _group_seconds(self.student["mse" if loss == "kl" else loss], runs)

    def teacher_seconds_per_update(self, actor: str, runs: int) -> float:
        """Seconds per update of a vectorised group of ``runs`` PBRL teachers (a train_teachers entry):
        interpolated between the measured group sizes; ``runs`` single updates where no group was measured."""
        if not self.pbrl_group or actor not in self.pbrl_group:
            return runs / self.pbrl[actor]
        return _group_seconds(self.pbrl_group[actor], runs)

    def multitask_seconds_per_update(self, runs: int) -> float:
        """Seconds per update of ``runs`` multi-task baselines as one group (a train_multitask entry):
        interpolated between the measured group sizes; ``runs`` single updates where no group was measured."""
        if not self.multitask_group:
            return runs / (self.multitask or self.pbrl["deterministic"])
        return _group_seconds(self.multitask_group, runs)


def _group_seconds(by_r: Mapping[int, float], runs: int) -> float:
    """Seconds per update of a group of ``runs``, from group updates/s measured at the sizes of ``by_r``:
    linear between the nearest measured sizes, and in the runs beyond them."""
    sizes = sorted(by_r)
    if runs in by_r:
        return 1.0 / by_r[runs]
    low = max([r for r in sizes if r < runs], default=sizes[0])
    high = min([r for r in sizes if r > runs], default=sizes[-1])
    if low == high:  # beyond the measured sizes: linear in the runs from the nearest one
        return runs / low / by_r[low]
    t_low, t_high = 1.0 / by_r[low], 1.0 / by_r[high]
    return t_low + (t_high - t_low) * (runs - low) / (high - low)


def teacher_schedule(params: Mapping[str, Any], level: str) -> dict:
    """train_teachers.schedule for a teacher of ``level`` (``steps`` may be one number per level)."""
    schedule = dict(params["train_teachers"]["schedule"])
    if isinstance(schedule["steps"], Mapping):
        schedule["steps"] = schedule["steps"][level]
    return schedule


def _evaluation_steps(schedule: Mapping[str, Any], episode_length: int, policies: int = 1,
                      final_is_last_point: bool = False) -> int:
    """Control steps of a run's learning-curve and final evaluations (per policy and task).
    ``final_is_last_point``: the curve's last point is the final evaluation (students)."""
    evaluations = math.ceil(schedule["steps"] / schedule["eval_every"]) - int(final_is_last_point)
    return policies * episode_length * (evaluations * schedule["eval_episodes"] + schedule["final_eval_episodes"])


def _hours(runs: Sequence, seconds: Callable[[Any], float]) -> tuple[int, float]:
    """(runs, hours): the runs' ``seconds`` each, one after another."""
    return len(runs), sum(seconds(run) for run in runs) / 3600


def _entry_seconds(runs: Sequence[StudentRun], params: Mapping[str, Any], study_tasks: int, rates: Rates) -> float:
    """One distill entry (its students, one per seed, one group): its updates (a single-task student's: its
    task's share of a multi-task update), every student's evaluations and a DAgger student's rollouts."""
    first, length, schedule = runs[0], params["study"]["episode_length"], params["distill"]["schedule"]
    tasks = len(first.tasks)
    seconds = (schedule["steps"] * rates.student_seconds_per_update(first.loss, len(runs)) / (study_tasks / tasks)
               + len(runs) * _evaluation_steps(schedule, length, tasks, final_is_last_point=True) / rates.rollout)
    if first.correction == "dagger":  # its rounds' rollouts: every seed's student, per task
        dagger = params["distill"].get("dagger", {})
        seconds += dagger.get("rounds", 0) * dagger.get("episodes", 0) * len(runs) * tasks * length / rates.rollout
    return seconds


# the dvc.yaml stages of the students in the table's order (distill .. distill_single, train_relabelled_teachers,
# distill_sharing, distill_substitute, compose, distill_composed .. distill_corrected); another family's stage follows
STUDENT_STAGES = ("distill", "distill_width", "distill_ranking", "distill_single", "distill_sharing",
                  "distill_substitute", "distill_composed", "distill_size", "distill_corrected")


def _compose_hours(params: Mapping[str, Any], rates: Rates) -> tuple[int, float]:
    """(tasks x composed datasets, hours): each task's pools, held-out pools and reference episodes
    (mop_core.shift.compose.ComposeConfig.pool_sizes, what compose_task rolls out), its processes in waves."""
    study = study_config(params)
    grid = shift_grid(params, study)
    config, teachers = compose_config(grid), build_catalogue(params).composing_teachers
    episodes = (sum(config.pool_sizes().values()) + sum(config.pool_sizes(heldout=True).values())
                + config.reference_episodes)
    workers = rates.cores if params["state_shift"].get("workers") == "auto" else grid.workers
    waves = math.ceil(len(teachers) / workers)
    return len(teachers) * len(config.datasets), waves * episodes * study.episode_length / rates.rollout / 3600


def stage_hours(params: Mapping[str, Any], rates: Rates) -> dict[str, tuple[int, float]]:
    """stage -> (runs, hours on one device): the runs of the params' catalogue (mop_core.experiment.catalogue), the
    eval stage's every job of it (transfer tasks included), compose's pools as compose_task rolls them."""
    catalogue = build_catalogue(params)
    tasks, length = catalogue.tasks, params["study"]["episode_length"]
    out: dict[str, tuple[int, float]] = {}

    collect = params["collect"]
    sched, sizes = collect["schedule"], collect["datasets"]
    env_steps = sched["warmup_steps"] + sched["total_steps"]
    rollouts = length * (sizes["expert_episodes"] + sizes["medium_episodes"] + sched["random_episodes"]
                         + sched["total_steps"] // sched["eval_every"] * sched["eval_episodes"]
                         + 2 * sched["snapshot_eval_episodes"])
    per_task = sched["total_steps"] / rates.td3 + env_steps / rates.single_env + rollouts / rates.rollout
    workers = collect["parallel"]["workers"]
    waves = math.ceil(len(tasks) / (rates.cores if workers == "auto" else workers))
    out["collect"] = (len(tasks), waves * per_task / 3600)

    t_sched = lambda level: teacher_schedule(params, level)  # noqa: E731
    entries: dict[tuple[str, str], list] = {}  # a train_teachers entry: one vectorised group per (level, actor)
    for run in catalogue.teachers:
        entries.setdefault((run.level, run.actor), []).append(run)
    out["train_teachers"] = (len(catalogue.teachers), sum(
        t_sched(level)["steps"] * rates.teacher_seconds_per_update(actor, len(runs))
        + len(runs) * _evaluation_steps(t_sched(level), length) / rates.rollout
        for (level, actor), runs in entries.items()) / 3600)
    baselines: dict[str, list] = {}  # a train_multitask entry: every seed of a level as one vectorised group
    for run in catalogue.multitask:
        baselines.setdefault(run.level, []).append(run)
    out["train_multitask"] = (len(catalogue.multitask), sum(
        len(tasks) * t_sched(level)["steps"] * rates.multitask_seconds_per_update(len(runs))
        + len(runs) * _evaluation_steps(t_sched(level), length, len(tasks)) / rates.rollout
        for level, runs in baselines.items()) / 3600)
    students = {stage: (sum(map(len, entries.values())), sum(_entry_seconds(runs, params, len(tasks), rates)
                                                              for runs in entries.values()) / 3600)
                for stage, entries in catalogue.distill_stages().items()}
    place = lambda stages: {stage: students.pop(stage, (0, 0.0)) for stage in stages}  # noqa: E731
    out |= place(STUDENT_STAGES[:4])
    # each a deterministic teacher's cost, one vectorised group per (level, kind) entry
    shared: dict[tuple[str, str], list] = {}
    for run in catalogue.relabelled_teachers:
        shared.setdefault((run.level, run.sharing), []).append(run)
    out["train_relabelled_teachers"] = (len(catalogue.relabelled_teachers), sum(
        t_sched(level)["steps"] * rates.teacher_seconds_per_update("deterministic", len(runs))
        + len(runs) * _evaluation_steps(t_sched(level), length) / rates.rollout
        for (level, _), runs in shared.items()) / 3600)
    out |= place(STUDENT_STAGES[4:6])
    out["compose"] = _compose_hours(params, rates)
    out |= place(STUDENT_STAGES[6:]) | students  # a family's stage not placed here: after the others

    transfer = tuple(params["eval"].get("transfer_tasks") or ())
    out["eval"] = _hours(catalogue.eval_jobs(transfer_tasks=transfer),
                         lambda _: params["eval"]["episodes"] * length / rates.rollout_over(params["eval"]["workers"]))
    shared_rate = rates.rollout_over(params["shared_computation"]["workers"])
    out["shared_computation"] = _hours(catalogue.students, lambda run: (
        len(run.tasks) * params["shared_computation"]["episodes"] * length / shared_rate))
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
        if isinstance(section[key], Mapping):  # one value per level (train_teachers.schedule.steps)
            section[key] = {name: max(floor, round(value * fraction)) for name, value in section[key].items()}
        else:
            section[key] = max(floor, round(section[key] * fraction))
    if max_evaluations is not None:
        for schedule, steps in ((out["collect"]["schedule"], "total_steps"),
                                (out["train_teachers"]["schedule"], "steps"), (out["distill"]["schedule"], "steps")):
            longest = max(schedule[steps].values()) if isinstance(schedule[steps], Mapping) else schedule[steps]
            schedule["eval_every"] = max(schedule["eval_every"], -(-longest // max_evaluations))
    collect = out["collect"]["schedule"]
    collect["medium_step"] = min(collect["medium_step"], collect["total_steps"] // 2)
    collect["medium_target_return"] = collect["expert_return"] = None  # a scaled run stops at its step counts
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


def _precision_note(profile_matmul: str, rates_tf32: bool) -> str:
    """The heading's word on precision: where the profile's ``study.cuda_matmul`` and the rates' differ, the
    plan is not the profile's cost (TF32 rates: too low for an fp32 study; fp32 rates: too high for TF32)."""
    rates_matmul = "tf32" if rates_tf32 else "fp32"
    if rates_matmul == profile_matmul:
        return "; CUDA matmuls in TF32 (study.cuda_matmul), as the rates ran" if rates_tf32 else ""
    return (f"; rates measured with CUDA matmuls in {rates_matmul.upper()}, not the {profile_matmul.upper()} "
            f"this profile runs (study.cuda_matmul)")


def plan_table(params: Mapping[str, Any], rates: Rates) -> str:
    rows = stage_hours(params, rates)
    on_cuda = rates.device != "cpu"  # the GPU's name (or cuda); the flag does nothing on a CPU: its rates fit either
    precision = _precision_note(params.get("study", {}).get("cuda_matmul", "fp32"), rates.tf32) if on_cuda else ""
    lines = [f"Estimated cost on {rates.device} (one device, stages one after another{precision}):", "",
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
    parser.add_argument("--workers", type=int, nargs="+", help="also the makespan on this many workers over the "
                                                               "DAG (mop_cluster.makespan)")
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
    if args.workers:
        from mop_cluster.makespan import estimated_seconds, profile_graph, table

        profile, rates_file = Path(args.out if args.scale is not None else args.profile), Path(args.rates)
        graph = profile_graph(profile)
        print(f"\nOn N workers, {len(graph.upstream)} entries (a stage's hours split evenly over its entries):\n")
        print(table(graph, estimated_seconds(profile, rates_file, graph), args.workers))
    print("\nAssumptions: " + " ".join(__doc__.split("Assumptions, printed with the table: ")[1].split()))


if __name__ == "__main__":
    main()
