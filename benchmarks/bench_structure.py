"""Speed of the shared-computation measures, measured in one run on this machine.

Prints
- Kendall tau-b rows/s on 256-neuron ReLU activations: ``mop_core.representations.measures.kendall_tau_b``
  (one-byte order masks, small chunks) vs the upper-triangle float64 version it replaced vs a
  ``scipy.stats.kendalltau`` loop, and the ratios;
- the cost of the per-state tau curve during distillation (thesis Figure 6.4b): seconds per
  measurement on ``probe_states`` states per task against the seconds of the ``eval_every``
  gradient steps between two measurements, at the quick and thesis profiles' sizes (target: < 10%).

Run: ``python benchmarks/bench_structure.py [--threads N]``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
import yaml
from bench_distill import profile
from scipy import stats
from timing import rate

from mop_core.distill.distiller import Distiller
from mop_core.distill.states import task_states
from mop_core.learning.nn import DeterministicActor
from mop_core.learning.runtime import configure_compute
from mop_core.representations.measures import kendall_tau_b, per_state_tau_by_layer

ROOT = Path(__file__).resolve().parents[1]


def upper_triangle_tau_b(x: torch.Tensor, y: torch.Tensor, chunk: int = 256) -> torch.Tensor:
    """The first implementation: float64, gathering the n(n-1)/2 pairs of the upper triangle."""
    x, y = x.double(), y.double()
    n = x.shape[1]
    upper = torch.triu(torch.ones(n, n, dtype=torch.bool), diagonal=1)
    n0 = n * (n - 1) / 2
    out = []
    for xs, ys in zip(x.split(chunk), y.split(chunk)):
        sx = torch.sign(xs[:, :, None] - xs[:, None, :])[:, upper]
        sy = torch.sign(ys[:, :, None] - ys[:, None, :])[:, upper]
        out.append((sx * sy).sum(1) / torch.sqrt((n0 - (sx == 0).sum(1)) * (n0 - (sy == 0).sum(1))))
    return torch.cat(out)


def tau_rates(rows: int = 2000, width: int = 256) -> None:
    gen = torch.Generator().manual_seed(0)
    x = torch.relu(torch.randn(rows, width, generator=gen))
    y = torch.relu(x + 0.5 * torch.randn(rows, width, generator=gen))
    ours = rate(lambda: kendall_tau_b(x, y), rows)
    old = rate(lambda: upper_triangle_tau_b(x, y), rows)
    xs, ys = x[:200].numpy(), y[:200].numpy()
    scipy_rate = rate(lambda: [stats.kendalltau(a, b).statistic for a, b in zip(xs, ys)], len(xs))
    diff = float((kendall_tau_b(x, y) - upper_triangle_tau_b(x, y)).abs().max())
    print(f"tau-b rows/s ({width} neurons): ours {ours:.0f}, upper-triangle float64 {old:.0f}, scipy loop "
          f"{scipy_rate:.0f}; ours / upper-triangle {ours / old:.1f}x, ours / scipy {ours / scipy_rate:.1f}x "
          f"(max |difference| {diff:.1e})")


def probe_overhead(name: str, path: Path, states: int = 100_000) -> None:
    config, _, _ = profile(path)
    eval_every = yaml.safe_load(path.read_text())["distill"]["schedule"]["eval_every"]
    torch.manual_seed(0)
    teachers = [DeterministicActor(24, 6, (64, 64)).requires_grad_(False) for _ in range(2)]
    targets = [task_states(f"task{i}", torch.randn(states, 24).numpy(), t, {}) for i, t in enumerate(teachers)]
    distiller = Distiller(config, [targets], 24, 6, [0])
    steps = 50
    step_rate = rate(lambda: [distiller.update() for _ in range(steps)], steps)
    probes = [t.states[: config.probe_states] for t in targets]
    started = time.perf_counter()
    repeats = 5
    for _ in range(repeats):
        per_state_tau_by_layer(distiller.student(0), probes)
    probe_seconds = (time.perf_counter() - started) / repeats
    between = eval_every / step_rate
    print(f"{name}: per-state tau on {config.probe_states} states/task x 2 tasks (student "
          f"{list(config.student.hidden_sizes)}): {probe_seconds * 1e3:.0f} ms per measurement, every {eval_every} "
          f"steps = {between:.1f} s of training ({step_rate:.0f} steps/s): overhead "
          f"{100 * probe_seconds / between:.2f}%")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    args = parser.parse_args()
    configure_compute(args.threads)
    print(f"torch {torch.__version__}, numpy {np.__version__}, {args.threads} thread(s)")
    tau_rates()
    probe_overhead("quick", ROOT / "params.yaml")
    probe_overhead("thesis", ROOT / "profiles" / "thesis.yaml")


if __name__ == "__main__":
    main()
