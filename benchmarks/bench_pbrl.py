"""Speed of a PBRL update, measured in one run on this machine.

Prints, at the quick (params.yaml) and thesis (profiles/thesis.yaml) sizes:
- updates/s of our update (one vectorised ensemble module ``[E, in, out]``, one forward over the
  in-distribution and OOD rows, one loss, one backward, one optimiser) and of the reference-style
  update (a Python list of E critic modules with E optimisers, separate forwards for the
  in-distribution, target and each OOD set, E backward passes, one per critic), same
  maths, same sizes; and the ratio;
- the achieved GFLOP/s of our update (matmul FLOPs counted analytically) next to the GFLOP/s of
  one large float32 matrix product on the same threads (the machine's practical ceiling).

Run: ``python benchmarks/bench_pbrl.py [--threads N] [--quick-only]``.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import torch
import yaml
from timing import rate
from torch import nn

from mop_core.agents.pbrl import PBRL, PBRLConfig, beta_ood, noisy
from mop_core.config import from_mapping
from mop_core.data import Batch
from mop_core.nn import soft_update
from mop_core.runtime import set_threads

ROOT = Path(__file__).resolve().parents[1]


def pbrl_config(profile: Path) -> PBRLConfig:
    raw = dict(yaml.safe_load(profile.read_text())["train_teachers"]["pbrl"])
    return from_mapping(PBRLConfig, raw, "train_teachers.pbrl")


def random_batch(n: int, seed: int = 0) -> Batch:
    g = torch.Generator().manual_seed(seed)
    return Batch(torch.randn(n, 24, generator=g), torch.rand(n, 6, generator=g) * 2 - 1, torch.rand(n, generator=g),
                 torch.randn(n, 24, generator=g), torch.zeros(n))


class LoopPBRL:
    """The reference code's structure: E separate critics and optimisers, a forward per input set."""

    def __init__(self, config: PBRLConfig):
        torch.manual_seed(0)
        self.c = config

        def net(i, o):
            sizes = [i, *config.hidden_sizes]
            layers = []
            for a, b in zip(sizes[:-1], sizes[1:]):
                layers += [nn.Linear(a, b), nn.ReLU()]
            return nn.Sequential(*layers, nn.Linear(sizes[-1], o))

        self.actor = nn.Sequential(net(24, 6), nn.Tanh())
        self.actor_target = copy.deepcopy(self.actor)
        self.critics = [net(30, 1) for _ in range(config.ensemble_size)]
        self.targets = [copy.deepcopy(c) for c in self.critics]
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.learning_rate)
        self.critic_opts = [torch.optim.Adam(c.parameters(), lr=config.learning_rate) for c in self.critics]
        self.g = torch.Generator().manual_seed(0)
        self.updates = 0

    def _q(self, critics, obs, act):
        return torch.stack([c(torch.cat([obs, act], -1)).squeeze(-1) for c in critics])

    def update(self, b: Batch) -> None:
        c, n = self.c, self.c.ood_actions
        with torch.no_grad():
            next_a = noisy(self.actor_target(b.next_observations), c.target_noise, c.noise_clip, self.g)
            a_s = noisy(self.actor(b.observations).repeat_interleave(n, 0), c.ood_noise, c.noise_clip, self.g)
            a_n = noisy(self.actor(b.next_observations).repeat_interleave(n, 0), c.ood_noise, c.noise_clip, self.g)
            next_q = self._q(self.targets, b.next_observations, next_a)
            y = b.rewards + c.gamma * (next_q - c.beta_in * next_q.std(0))
        # one graph per critic (a stacked tensor would route every backward through all critics)
        q = [cr(torch.cat([b.observations, b.actions], -1)).squeeze(-1) for cr in self.critics]
        obs_s, obs_n = b.observations.repeat_interleave(n, 0), b.next_observations.repeat_interleave(n, 0)
        q_s = [cr(torch.cat([obs_s, a_s], -1)).squeeze(-1) for cr in self.critics]
        q_n = [cr(torch.cat([obs_n, a_n], -1)).squeeze(-1) for cr in self.critics]
        beta = beta_ood(self.updates, c)
        with torch.no_grad():
            qs, qn = torch.stack(q_s), torch.stack(q_n)
            y_s = (qs - beta * qs.std(0)).clamp(min=0)
            y_n = (qn - beta * qn.std(0)).clamp(min=0)
        for e in range(c.ensemble_size):
            q_ood, y_ood = torch.cat([q_s[e], q_n[e]]), torch.cat([y_s[e], y_n[e]])
            loss = ((q[e] - y[e]) ** 2).mean() + ((q_ood - y_ood) ** 2).mean()
            self.critic_opts[e].zero_grad()
            loss.backward()
            self.critic_opts[e].step()
        self.updates += 1
        if self.updates % c.policy_delay == 0:
            pi = self.actor(b.observations)
            actor_loss = -self._q(self.critics, b.observations, pi).min(0).values.mean()
            self.actor_opt.zero_grad()
            actor_loss.backward()
            self.actor_opt.step()
        soft_update(self.actor_target, self.actor, c.actor_tau)
        for t, s in zip(self.targets, self.critics):
            soft_update(t, s, c.critic_tau)


def update_flops(c: PBRLConfig) -> float:
    """Matmul FLOPs of one averaged PBRL update (2 per multiply-add; a trained pass is 3x a forward)."""
    def mlp(rows: int, i: int, o: int) -> float:
        sizes = [i, *c.hidden_sizes, o]
        return 2.0 * rows * sum(a * b for a, b in zip(sizes[:-1], sizes[1:]))

    b, e, n = c.batch_size, c.ensemble_size, c.ood_actions
    critic_rows = b * (1 + 2 * n)
    flops = 3 * e * mlp(critic_rows, 30, 1)  # in-distribution + OOD rows, forward and backward
    flops += e * mlp(b, 30, 1) + mlp(b, 24, 6)  # target critics and target actor (no grad)
    flops += mlp(2 * b, 24, 6)  # current actor at s and s' for the OOD actions (no grad)
    flops += (3 * mlp(b, 24, 6) + 2 * e * mlp(b, 30, 1)) / c.policy_delay  # actor step: dQ/da through the critics
    return flops


def matmul_gflops(n: int = 2048) -> float:
    a, b = torch.randn(n, n), torch.randn(n, n)
    return rate(lambda: a @ b, 2.0 * n ** 3 / 1e9, repeats=5)


def measure(name: str, config: PBRLConfig, updates: int) -> None:
    batch = random_batch(config.batch_size)
    ours = PBRL(config, 24, 6, seed=0)
    loop = LoopPBRL(config)

    def run(agent):
        def go():
            for _ in range(updates):
                agent.update(batch)
        return go

    ours_rate = rate(run(ours), updates)
    loop_rate = rate(run(loop), updates)
    gflops = update_flops(config) / 1e9
    print(f"{name}: E={config.ensemble_size} {'x'.join(map(str, config.hidden_sizes))} batch {config.batch_size} "
          f"OOD {config.ood_actions}  ({gflops:.2f} GFLOP/update)")
    print(f"  vectorised ensemble   {ours_rate:8.1f} updates/s  ({ours_rate * gflops:6.1f} GFLOP/s achieved)")
    print(f"  loop of E critics     {loop_rate:8.1f} updates/s  ({loop_rate * gflops:6.1f} GFLOP/s)")
    print(f"  ratio                 {ours_rate / loop_rate:8.2f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch threads (the stage's train_teachers.threads)")
    parser.add_argument("--quick-only", action="store_true", help="skip the (slow) thesis-size update")
    args = parser.parse_args()
    set_threads(args.threads)
    print(f"torch {torch.__version__}, {args.threads} thread(s)")
    ceiling = matmul_gflops()
    print(f"ceiling: 2048x2048 float32 matmul {ceiling:.1f} GFLOP/s")
    measure("quick (params.yaml)", pbrl_config(ROOT / "params.yaml"), updates=20)
    if not args.quick_only:
        measure("thesis (profiles/thesis.yaml)", pbrl_config(ROOT / "profiles" / "thesis.yaml"), updates=3)


if __name__ == "__main__":
    main()
