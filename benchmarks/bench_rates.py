"""Training rates at a profile's network sizes on one device: what ``python -m mop_core.plan`` turns
into the profile's cost.

Measures in one process (after a warm-up; on CUDA every timed block ends with a synchronize):
- TD3 updates/s at ``collect.td3`` (the collect stage's learner; its 1:1 env/update schedule adds env steps);
- PBRL updates/s per actor type at ``train_teachers.pbrl`` (a teacher), the naive multi-task baseline's
  updates/s (one task's step each), and the group updates/s of R = 1 and R = 8 teachers trained as one
  vectorised model (the train_teachers stage trains every task and seed of a (level, actor) as one);
- on CUDA these learners replay their updates as CUDA graphs (mop_core.learning.graphs); TD3, the
  baseline and the R = 8 groups are also timed eager, and the ratios printed;
- student updates/s for a group of R = 1 and R = 8 students (the distill stage trains every seed of a
  (loss, pairing) as one group) at ``distill``, MSE and Q losses, 2 tasks: the group's updates/s, so
  R runs of 8 cost R / (8 * rate_8) seconds per step each;
- control steps/s of ``eval.rollout_envs`` walkers stepped together under a batched student policy;
- the same over every core: jobs of ``eval.rollout_envs`` walkers in as many single-threaded processes as
  this process may use (what the eval and shared-computation stages do with ``workers: auto``), with the
  one-process rate's ratio.

Writes the numbers as JSON (``--out``) with the device's name; ``mop_core.plan`` reads that file.

Run: ``python benchmarks/bench_rates.py --profile profiles/thesis.yaml --device cuda --out rates.json``
(``--quick`` times fewer updates: a smoke test).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import torch
import yaml
from bench_distill import profile as distill_profile
from bench_pbrl import pbrl_config, random_batch

from mop_core.agents.pbrl import PBRL
from mop_core.agents.pbrl_group import PBRLGroup, probe_group, stack_batches
from mop_core.agents.pbrl_multitask_group import MultiTaskPBRLGroup
from mop_core.agents.td3 import TD3, TD3Config
from mop_core.config import from_mapping
from mop_core.distill.checkpoint import student_policy
from mop_core.distill.distiller import Distiller
from mop_core.distill.states import TaskStates
from mop_core.distill.student import Student
from mop_core.learning.group_memory import device_room, measure_footprint, wave_sizes
from mop_core.learning.nn import EnsembleCritic
from mop_core.learning.runtime import available_cores, configure_compute, parallel_map, resolve_device, set_cuda_matmul
from mop_core.storage.timings import machine_facts
from mop_core.walker.rollout import episode_returns

ROOT = Path(__file__).resolve().parents[1]
GROUP_SIZES = (1, 8)


def profile_group_sizes(params: dict) -> tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
    """The group sizes to measure for a profile: teachers at 1, 8, its entry's runs (tasks x seeds) and
    twice that (would a larger group, e.g. both actor types of a level, pay?); students at 1, 8, an
    entry's seeds and a loss's every pairing and seed (would one group per loss of the distill stage
    pay?); multi-task baselines at 1 and an entry's seeds. The plan interpolates between measured sizes,
    so the profile's own are measured."""
    entry = len(params["study"]["tasks"]) * len(params["train_teachers"]["seeds"])
    seeds = len(params["distill"]["seeds"])
    return (tuple(sorted({*GROUP_SIZES, entry, 2 * entry})),
            tuple(sorted({*GROUP_SIZES, seeds, seeds * len(params["distill"]["pairings"])})),
            tuple(sorted({1, len(params.get("train_multitask", {}).get("seeds") or [0])})))


def pbrl_group_footprint(profile: Path, params: dict, device: torch.device) -> dict | None:
    """On CUDA: a deterministic teacher group's measured device memory (fixed and per run, bytes; captured as
    training captures it) and the waves the profile's teacher entry trains in on this card
    (:mod:`mop_core.learning.group_memory`); None elsewhere."""
    config = replace(pbrl_config(profile), actor="deterministic")

    footprint = measure_footprint(probe_group(config, 24, 6, lambda runs: stack_batches(
        [random_batch(config.batch_size, seed) for seed in range(runs)]).to(device), device), device)
    if footprint is None:
        return None
    entry = profile_group_sizes(params)[0][-1] // 2
    room = device_room(device)
    return {"fixed_bytes": footprint.fixed, "per_run_bytes": footprint.per_run, "room_bytes": room,
            "entry_runs": entry, "entry_waves": wave_sizes(entry, footprint, room, "a teacher")}


def per_second(step, count: int, device: torch.device, repeats: int = 3) -> float:
    """Median calls/s of ``step`` over ``repeats`` blocks of ``count`` calls (one warm-up block)."""
    def block() -> float:
        start = time.perf_counter()
        for _ in range(count):
            step()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return time.perf_counter() - start

    block()
    times = sorted(block() for _ in range(repeats))
    return count / times[len(times) // 2]


def td3_rate(params: dict, device: torch.device, count: int, cuda_graphs: bool | None = None) -> float:
    config = from_mapping(TD3Config, params["collect"]["td3"], "collect.td3")
    agent = TD3(config, 24, 6, 0, device, cuda_graphs)
    batch = random_batch(config.batch_size).to(device)
    return per_second(lambda: agent.update(batch), count, device)


def pbrl_rates(profile: Path, device: torch.device, count: int) -> dict[str, float]:
    base = pbrl_config(profile)
    rates = {}
    for actor in ("deterministic", "gaussian"):
        config = replace(base, actor=actor)
        agent = PBRL(config, 24, 6, 0, device)
        batch = random_batch(config.batch_size).to(device)
        rates[actor] = per_second(lambda: agent.update(batch), count, device)
    return rates


def pbrl_group_rates(profile: Path, device: torch.device, count: int, sizes=GROUP_SIZES,
                     cuda_graphs: bool | None = None) -> dict[str, dict[str, float]]:
    """Group updates/s per actor type and group size (on CUDA: replayed CUDA graphs unless ``cuda_graphs``
    is False; the warm-up block holds the capture)."""
    base = pbrl_config(profile)
    rates: dict[str, dict[str, float]] = {}
    for actor in ("deterministic", "gaussian"):
        config = replace(base, actor=actor)
        rates[actor] = {}
        for runs in sizes:
            group = PBRLGroup(config, 24, 6, list(range(runs)), device, cuda_graphs)
            batch = stack_batches([random_batch(config.batch_size, seed) for seed in range(runs)]).to(device)
            rates[actor][str(runs)] = per_second(lambda: group.update(batch), count, device)
    return rates


def multitask_rates(profile: Path, params: dict, device: torch.device, count: int, sizes: tuple[int, ...] = (1,),
                    cuda_graphs: bool | None = None) -> dict[str, float]:
    """Group updates/s of the naive multi-task baseline per group size (its seeds as one
    :class:`MultiTaskPBRLGroup`; one task's PBRL step per update, the profile's tasks alternating): on CUDA
    replayed CUDA graphs unless ``cuda_graphs`` is False."""
    config, tasks = pbrl_config(profile), tuple(params["study"]["tasks"])
    rates = {}
    for runs in sizes:
        group = MultiTaskPBRLGroup(config, tasks, 24, 6, list(range(runs)), device, cuda_graphs)
        batch = stack_batches([random_batch(config.batch_size, seed) for seed in range(runs)]).to(device)
        rates[str(runs)] = per_second(lambda: group.update(batch, group.next_task), count, device)
    return rates


def student_rates(profile: Path, params: dict, device: torch.device, count: int, sizes=GROUP_SIZES,
                  cuda_graphs: bool | None = None) -> dict[str, dict[str, float]]:
    config, teacher_sizes, _ = distill_profile(profile)
    states = 100_000
    g = torch.Generator().manual_seed(0)
    targets = [TaskStates(f"task{i}", torch.randn(states, 24, generator=g).to(device),
                          (torch.rand(states, 6, generator=g) * 2 - 1).to(device), None, {}) for i in range(2)]
    critics = [EnsembleCritic(24, 6, teacher_sizes, params["train_teachers"]["pbrl"]["ensemble_size"])
               for _ in range(2)]
    rates: dict[str, dict[str, float]] = {}
    for loss in ("mse", "q"):
        loss_config = replace(config, loss=loss)
        rates[loss] = {}
        for runs in sizes:
            group = Distiller(loss_config, [targets] * runs, 24, 6, list(range(runs)),
                              critics if loss == "q" else None, device, cuda_graphs=cuda_graphs)
            rates[loss][str(runs)] = per_second(group.update, count, device)
    return rates


def rollout_rate(profile: Path, device: torch.device, envs: int | None = None) -> float:
    """Control steps/s of ``envs`` walkers (default ``eval.rollout_envs``) stepped together under one
    batched student policy (200-step episodes)."""
    config, _, profile_envs = distill_profile(profile)
    envs = profile_envs if envs is None else envs
    student = Student(config.student, 24, 6, 2).to(device).eval()
    policy = student_policy(student, 0, device)
    length = 200
    episode_returns(policy, "walk", list(range(envs)), length, envs)  # warm-up
    start = time.perf_counter()
    episode_returns(policy, "walk", list(range(envs)), length, envs)
    return envs * length / (time.perf_counter() - start)


def _rollout_job(student_config, envs: int, length: int, seed: int) -> int:
    """One eval-style job in a worker process: ``envs`` walkers under a CPU student for ``length`` steps."""
    student = Student(student_config, 24, 6, 2).eval()
    episode_returns(student_policy(student, 0, torch.device("cpu")), "walk", list(range(seed, seed + envs)),
                    length, envs)
    return envs * length


def parallel_rollout_rate(profile: Path, workers: int) -> float:
    """Control steps/s of 2 x ``workers`` jobs of ``eval.rollout_envs`` walkers (200-step episodes) over
    ``workers`` single-threaded processes, the pool's start included (what eval pays)."""
    config, _, envs = distill_profile(profile)
    args = [(config.student, envs, 200, 1000 * j) for j in range(2 * workers)]
    parallel_map(_rollout_job, args[:workers], workers, "warm-up")
    start = time.perf_counter()
    steps = sum(parallel_map(_rollout_job, args, workers, "rollouts"))
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default=str(ROOT / "profiles" / "thesis.yaml"))
    parser.add_argument("--device", default="auto", help="auto | cpu | cuda[:N]")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--quick", action="store_true", help="a few updates per measure (a smoke test)")
    parser.add_argument("--out", help="write the rates as JSON here")
    parser.add_argument("--tf32", action="store_true",
                        help="CUDA matmuls in TF32 (what a profile's study.cuda_matmul: tf32 runs; every profile "
                             "runs fp32 until benchmarks/tf32_check.py passes)")
    args = parser.parse_args()
    configure_compute(args.threads)
    set_cuda_matmul("tf32" if args.tf32 else "fp32")
    device = resolve_device(args.device, "--device")
    profile = Path(args.profile)
    params = yaml.safe_load(profile.read_text())
    count = 3 if args.quick else 50
    teacher_sizes, student_sizes, multitask_sizes = profile_group_sizes(params)
    multitask = multitask_rates(profile, params, device, count, multitask_sizes)
    result = {"profile": profile.name, "device": str(device), "threads": args.threads, "tf32": args.tf32,
              "machine": machine_facts(device),
              "td3_updates_per_second": td3_rate(params, device, count),
              "pbrl_updates_per_second": pbrl_rates(profile, device, count),
              "pbrl_group_updates_per_second": pbrl_group_rates(profile, device, count, teacher_sizes),
              "pbrl_multitask_updates_per_second": multitask["1"],  # one baseline: a group of one
              "pbrl_multitask_group_updates_per_second": multitask,
              "student_group_updates_per_second": student_rates(profile, params, device, count, student_sizes),
              "rollout_control_steps_per_second": rollout_rate(profile, device),
              "single_env_control_steps_per_second": rollout_rate(profile, device, envs=1),
              "parallel_rollout_workers": available_cores(),
              "parallel_rollout_control_steps_per_second": parallel_rollout_rate(profile, available_cores())}
    if device.type == "cuda":  # what the captured updates buy: the same groups eager (R = 8)
        result["pbrl_group_memory"] = pbrl_group_footprint(profile, params, device)
        result["pbrl_group_eager_updates_per_second"] = pbrl_group_rates(profile, device, count, (8,), False)
        result["student_group_eager_updates_per_second"] = student_rates(profile, params, device, count, (8,), False)
        result["pbrl_multitask_eager_updates_per_second"] = multitask_rates(profile, params, device, count, (1,),
                                                                            False)["1"]
        result["td3_eager_updates_per_second"] = td3_rate(params, device, count, False)
    print(json.dumps(result, indent=1))
    for name in ("pbrl_group", "student_group"):
        for kind, eager in result.get(f"{name}_eager_updates_per_second", {}).items():
            captured = result[f"{name}_updates_per_second"][kind]["8"]
            print(f"{name} {kind} R = 8: CUDA graphs {captured:.0f} updates/s, eager {eager['8']:.0f}: "
                  f"{captured / eager['8']:.2f}x")
    for key, name in (("pbrl_multitask", "multi-task baseline"), ("td3", "TD3")):
        if f"{key}_eager_updates_per_second" in result:
            captured, eager = result[f"{key}_updates_per_second"], result[f"{key}_eager_updates_per_second"]
            print(f"{name}: CUDA graphs {captured:.0f} updates/s, eager {eager:.0f}: {captured / eager:.2f}x")
    ratio = result["parallel_rollout_control_steps_per_second"] / result["rollout_control_steps_per_second"]
    print(f"rollouts over {result['parallel_rollout_workers']} processes: {ratio:.2f}x one process's batched rate")
    groups = (("pbrl_group", "teacher"), ("student_group", "student"), ("pbrl_multitask_group", "multi-task"))
    for name, unit in groups:  # does a larger group pay?
        measured = result[f"{name}_updates_per_second"]
        for kind, by_r in (measured if name != "pbrl_multitask_group" else {"deterministic": measured}).items():
            runs = ", ".join(f"R = {r}: {rate * int(r):.0f}" for r, rate in by_r.items())
            print(f"{name} {kind}: {unit} updates/s summed over the group's runs, {runs}")
    memory = result.get("pbrl_group_memory")
    if memory:
        print(f"teacher group memory: {memory['fixed_bytes'] / 2**30:.2f} GiB fixed + "
              f"{memory['per_run_bytes'] / 2**30:.2f} GiB per run; the profile's entry of {memory['entry_runs']} "
              f"runs trains in waves {memory['entry_waves']} on this card")
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
