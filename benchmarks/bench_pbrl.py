"""Speed of a PBRL update and of the choices inside it, measured in one run on this machine.

Prints:
- the machine's ceiling: GFLOP/s of one 2048x2048 float32 matrix product on the same threads;
- updates/s of our PBRL update at the quick (params.yaml) and thesis (profiles/thesis.yaml) sizes,
  and the GFLOP/s it achieves (matrix FLOPs counted analytically);
- the critic ensemble's forward + backward member by member (plain GEMMs, the hand-written
  backward of ``nn._EnsembleReLUMLP``) against one batched ``bmm`` per layer, at the shapes the
  study uses: the evidence for ``EnsembleCritic.member_loop_work``;
- the thesis-size update with glibc's default allocator against ``runtime.keep_freed_memory``
  (each in its own process, alternating, 3 processes each);
- one Adam step, fused kernel (``nn.adam``) against PyTorch's default, for 5 critics of the
  thesis size;
- a group of R = 1, 2, 4, 8 PBRL teachers trained as one vectorised model (``agents.pbrl_group``, the
  train_teachers stage's runs of one level and actor type): time per update of the group over one
  run's (a group of one), and the group of one against the plain single-run ``PBRL`` update.
The side-by-side with the thesis's reference code is benchmarks/bench_reference.py.

Run: ``python benchmarks/bench_pbrl.py [--threads N] [--quick-only]``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import torch
import yaml
from timing import rate

from mop_core.agents.pbrl import PBRL, PBRLConfig
from mop_core.agents.pbrl_group import PBRLGroup, stack_batches
from mop_core.config import from_mapping
from mop_core.float_path import random_batch
from mop_core.learning.nn import EnsembleCritic, adam, per_member_forward
from mop_core.learning.runtime import configure_compute, set_threads

ROOT = Path(__file__).resolve().parents[1]


def pbrl_config(profile: Path) -> PBRLConfig:
    raw = dict(yaml.safe_load(profile.read_text())["train_teachers"]["pbrl"])
    return from_mapping(PBRLConfig, raw, "train_teachers.pbrl")


def update_flops(c: PBRLConfig) -> float:
    """Matmul FLOPs of one averaged PBRL update (2 per multiply-add; a trained pass is 3x a forward)."""
    def mlp(rows: int, i: int, o: int) -> float:
        sizes = [i, *c.hidden_sizes, o]
        return 2.0 * rows * sum(a * b for a, b in zip(sizes[:-1], sizes[1:]))

    b, e, n = c.batch_size, c.ensemble_size, c.ood_actions
    flops = 3 * e * mlp(b * (1 + 2 * n), 30, 1)  # in-distribution + OOD rows, forward and backward
    flops += e * mlp(b, 30, 1) + mlp(b, 24, 6)  # target critics and target actor (no grad)
    flops += mlp(2 * b, 24, 6)  # current actor at s and s' for the OOD actions (no grad)
    flops += (3 * mlp(b, 24, 6) + 2 * e * mlp(b, 30, 1)) / c.policy_delay  # actor step: dQ/da through the critics
    return flops


def matmul_gflops(n: int = 2048) -> float:
    a, b = torch.randn(n, n), torch.randn(n, n)
    return rate(lambda: a @ b, 2.0 * n ** 3 / 1e9, repeats=5)


def update_rate(config: PBRLConfig, updates: int) -> float:
    batch = random_batch(config.batch_size)
    agent = PBRL(config, 24, 6, seed=0)
    return rate(lambda: [agent.update(batch) for _ in range(updates)], updates, repeats=5)


def measure_update(name: str, config: PBRLConfig, updates: int) -> None:
    gflops = update_flops(config) / 1e9
    per_second = update_rate(config, updates)
    print(f"{name}: E={config.ensemble_size} {'x'.join(map(str, config.hidden_sizes))} batch {config.batch_size} "
          f"OOD {config.ood_actions} ({gflops:.2f} GFLOP/update): {per_second:.1f} updates/s, "
          f"{per_second * gflops:.1f} GFLOP/s achieved")


def group_rates(name: str, config: PBRLConfig, updates: int, runs: tuple[int, ...] = (1, 2, 4, 8),
                rounds: int = 3) -> None:
    """Seconds per update of a group of R teachers (each run its own seed, generator and minibatch)
    over seconds per update of a group of one: the cost of R runs trained as one model, relative to one.
    The group sizes are measured in turn, ``rounds`` times, and each keeps its fastest round's median:
    a burst of other load on the machine then skews no ratio."""
    groups = {r: (PBRLGroup(config, 24, 6, list(range(r))),
                  stack_batches([random_batch(config.batch_size, seed) for seed in range(r)])) for r in runs}
    seconds = {r: float("inf") for r in runs}
    for _ in range(rounds):
        for r, (group, batch) in groups.items():
            per_update = 1.0 / rate(lambda: [group.update(batch) for _ in range(updates)], updates, repeats=3)
            seconds[r] = min(seconds[r], per_update)
    single = 1.0 / update_rate(config, updates)
    cells = ", ".join(f"R={r}: {seconds[r] / seconds[1]:.2f}x ({seconds[1] * r / seconds[r]:.2f}x per run)"
                      for r in runs)
    print(f"{name}: PBRL teacher group ({config.actor}, E={config.ensemble_size}, "
          f"{'x'.join(map(str, config.hidden_sizes))}, batch {config.batch_size}) time per update / one run's: "
          f"{cells}; one run {1e3 * seconds[1]:.2f} ms as a group of one, {1e3 * single:.2f} ms as plain PBRL "
          f"(fastest of {rounds} interleaved rounds)")


def critic_paths(members: int, width: int, rows: int) -> None:
    torch.manual_seed(0)
    critic = EnsembleCritic(24, 6, (width, width), members)
    x = torch.randn(rows, 30)

    def looped() -> None:
        per_member_forward(critic.net, x).square().sum().backward()

    def batched() -> None:
        critic.net(x.unsqueeze(0).expand(members, -1, -1)).square().sum().backward()

    loop_rate, bmm_rate = rate(looped, 1, repeats=7), rate(batched, 1, repeats=7)
    chosen = "member loop" if critic.member_by_member(rows, x.device) else "batched"
    print(f"  E={members} {width}x{width}, {rows:5d} rows: member loop {1000 / loop_rate:6.2f} ms, batched "
          f"{1000 / bmm_rate:6.2f} ms, loop/batched speed {loop_rate / bmm_rate:4.2f}x; the critic picks: {chosen}")


def adam_step() -> None:
    critic = EnsembleCritic(24, 6, (256, 256), 5)
    for p in critic.parameters():
        p.grad = torch.randn_like(p)
    fused, default = adam(critic.parameters(), 1e-4), torch.optim.Adam(critic.parameters(), lr=1e-4)
    fused_rate, default_rate = rate(fused.step, 1, repeats=50), rate(default.step, 1, repeats=50)
    print(f"Adam step, 5 critics 256x256: fused {1e6 / fused_rate:.0f} us, default {1e6 / default_rate:.0f} us, "
          f"ratio {fused_rate / default_rate:.2f}x")


def allocator_comparison(threads: int, rounds: int = 3) -> None:
    """Alternate child processes with and without keep_freed_memory (it cannot be undone in one process)."""
    rates: dict[str, list[float]] = {"default": [], "kept": []}
    for _ in range(rounds):
        for mode in rates:
            out = subprocess.run([sys.executable, __file__, "--threads", str(threads), "--allocator-child", mode],
                                 capture_output=True, text=True, check=True).stdout
            rates[mode].append(float(out.split()[-1]))
    default, kept = statistics.median(rates["default"]), statistics.median(rates["kept"])
    print(f"thesis-size update, glibc default allocator {default:.2f} updates/s, freed memory kept "
          f"(runtime.keep_freed_memory) {kept:.2f} updates/s: {kept / default:.2f}x ({rounds} processes each)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2, help="torch threads (the stage's train_teachers.threads)")
    parser.add_argument("--quick-only", action="store_true", help="skip the (slow) thesis-size measurements")
    parser.add_argument("--allocator-child", choices=["default", "kept"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    thesis = pbrl_config(ROOT / "profiles" / "thesis.yaml")
    if args.allocator_child:  # one measurement for allocator_comparison, in a fresh process
        (configure_compute if args.allocator_child == "kept" else set_threads)(args.threads)
        print(update_rate(thesis, 3))
        return
    configure_compute(args.threads)
    print(f"torch {torch.__version__}, {args.threads} thread(s)")
    print(f"ceiling: 2048x2048 float32 matmul {matmul_gflops():.1f} GFLOP/s")
    measure_update("quick (params.yaml)", pbrl_config(ROOT / "params.yaml"), updates=20)
    if not args.quick_only:
        measure_update("thesis (profiles/thesis.yaml)", thesis, updates=3)
    print("critic ensemble forward + backward (the study's shapes):")
    shapes = [(5, 128, 256), (5, 128, 768), (2, 256, 128), (5, 256, 512), (5, 256, 1024)]
    if not args.quick_only:
        shapes += [(5, 256, 7168), (2, 1024, 1024)]
    for members, width, rows in shapes:
        critic_paths(members, width, rows)
    adam_step()
    quick = pbrl_config(ROOT / "params.yaml")
    for actor in ("deterministic", "gaussian"):  # the study's two teacher groups per level
        group_rates(f"quick {actor}", replace(quick, actor=actor), updates=10)
    if not args.quick_only:
        group_rates("thesis deterministic", thesis, updates=2, runs=(1, 2, 4))
        allocator_comparison(args.threads)


if __name__ == "__main__":
    main()
