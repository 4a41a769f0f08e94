"""Side by side with the thesis's reference implementation: its own update functions against ours.

The reference is github.com/jaevanlith/mop at a pinned commit, loaded from a checkout given by
``--reference DIR`` or ``MOP_REFERENCE`` (benchmarks/reference.py says how to get it and the
little it changes to run on a CPU). Each row times blocks of updates of the reference code and of
ours on the same inputs in one process, alternating (reference, ours, reference, ...), so a busy
machine slows both alike. Printed per row: the median ms per update of each, and the median of
the per-block ratios reference/mop (>1: mop faster) with the smallest and largest block ratio.

Rows (2 torch threads unless ``--threads``):
- PBRL update at the thesis size (E=5 critics 256x256, batch 1024, 3 OOD actions at s and s'),
  at the quick size (params.yaml: E=5 128x128, batch 256, 1 OOD action), and at width 16 with batch
  32 (almost no arithmetic: the framework's own overhead). The reference hard-codes 256-wide
  networks; for the other sizes its actor and critics are rebuilt at the row's widths;
- PBRL sampler + update at the thesis size: the reference's replay loader (its
  ``OfflineReplayBuffer`` in a ``DataLoader``, over 50 episodes in its npz format) against our
  in-memory sampler, each feeding its own update;
- TD3 update at the thesis size (1024x1024 with LayerNorm, batch 1024) and the quick width (256x256,
  batch 128), both sides with the reference's architecture (LayerNorm + tanh trunk) and schedule (an
  actor step every critic step);
- student step, 2 tasks, one Adam step per task per update as the reference, MSE and Q losses, at
  the thesis size (batch 1024 per task, student 256x256, teachers 256x256, 5 critics) and the quick
  size (batch 256 per task, teachers 128x128). The reference re-runs the frozen teacher's actor on
  every MSE batch; ours reads the actions cached once per state (what the distill stage does).

Run: ``python benchmarks/bench_reference.py [--reference DIR] [--threads N] [--quick-only] [--blocks K]``.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import itertools
import statistics
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from bench_pbrl import pbrl_config, random_batch
from reference import HOW_TO_GET, REFERENCE_COMMIT, ReferenceError, load, on_cpu, reference_dir
from torch import nn

from mop_core.agents.pbrl import PBRL, PBRLConfig
from mop_core.agents.td3 import TD3, TD3Config
from mop_core.data import Batch
from mop_core.data.buffer import TransitionTensors
from mop_core.distill.config import DistillConfig
from mop_core.distill.distiller import Distiller
from mop_core.distill.states import task_states
from mop_core.distill.student import StudentConfig
from mop_core.learning.nn import DeterministicActor, EnsembleCritic
from mop_core.learning.runtime import configure_compute

ROOT = Path(__file__).resolve().parents[1]
OBS, ACT = 24, 6


@dataclass(frozen=True)
class Comparison:
    name: str
    reference_ms: float
    mop_ms: float
    ratio: float  # median over blocks of reference/mop
    ratio_min: float
    ratio_max: float


def compare(name: str, reference: Callable[[], None], mop: Callable[[], None], per_block: int,
            blocks: int) -> Comparison:
    """Alternate ``blocks`` timed blocks of ``per_block`` calls of each (after one warm-up block)."""
    def block(fn: Callable[[], None]) -> float:
        start = time.perf_counter()
        for _ in range(per_block):
            fn()
        return (time.perf_counter() - start) / per_block * 1000

    block(reference), block(mop)
    ref_ms, mop_ms = [], []
    for _ in range(blocks):
        ref_ms.append(block(reference))
        mop_ms.append(block(mop))
    ratios = [r / m for r, m in zip(ref_ms, mop_ms)]
    return Comparison(name, statistics.median(ref_ms), statistics.median(mop_ms), statistics.median(ratios),
                      min(ratios), max(ratios))


def as_reference_batch(batch: Batch, gamma: float = 0.99) -> tuple[np.ndarray, ...]:
    """(obs, action, reward [B,1], discount [B,1], next_obs, main-task flag): the reference loader's batch."""
    n = batch.observations.shape[0]
    return (batch.observations.numpy(), batch.actions.numpy(), batch.rewards[:, None].numpy(),
            np.full((n, 1), gamma, np.float32), batch.next_observations.numpy(), np.ones(n, bool))


# ---- PBRL -----------------------------------------------------------------------------------------
def reference_pbrl(ref, config: PBRLConfig):
    """The reference's PBRLAgent with this config's values; networks rebuilt if not 256 x 2 wide."""
    agent = ref.pbrl.PBRLAgent(
        name="pbrl", obs_shape=(OBS,), action_shape=(ACT,), device="cpu", lr=config.learning_rate, hidden_dim=256,
        critic_target_tau=config.critic_tau, actor_target_tau=config.actor_tau, policy_freq=config.policy_delay,
        policy_noise=config.target_noise, noise_clip=config.noise_clip, use_tb=False, batch_size=config.batch_size,
        num_expl_steps=0, num_random=config.ood_actions, ucb_ratio_in=config.beta_in,
        ucb_ratio_ood_init=config.beta_ood_init, ucb_ratio_ood_min=config.beta_ood_min,
        ood_decay_factor=config.beta_ood_decay, ensemble=config.ensemble_size, ood_noise=config.ood_noise,
        share_ratio=1.5, deterministic_actor=True)
    width = config.hidden_sizes[0]
    if tuple(config.hidden_sizes) != (256, 256):
        if len(set(config.hidden_sizes)) != 1 or len(config.hidden_sizes) != 2:
            raise ValueError(f"hidden_sizes: the reference's networks have two equal layers, got {config.hidden_sizes}")
        agent.actor = ref.pbrl.Actor(OBS, ACT, hidden_dim=width)
        agent.actor_target = copy.deepcopy(agent.actor)
        agent.actor_opt = torch.optim.Adam(agent.actor.parameters(), lr=config.learning_rate)
        for critic in agent.critic:
            critic.l1, critic.l2, critic.l3 = nn.Linear(OBS + ACT, width), nn.Linear(width, width), nn.Linear(width, 1)
        agent.critic_target = [copy.deepcopy(c) for c in agent.critic]
        agent.critic_opt = [torch.optim.Adam(c.parameters(), lr=config.learning_rate) for c in agent.critic]
    return agent


def pbrl_row(ref, name: str, config: PBRLConfig, per_block: int, blocks: int) -> Comparison:
    batch = random_batch(config.batch_size)
    theirs, ours = reference_pbrl(ref, config), PBRL(config, OBS, ACT, seed=0)
    stream = itertools.repeat(as_reference_batch(batch))
    step = itertools.count(1)
    return compare(name, lambda: theirs.update(stream, next(step), 1_000_000), lambda: ours.update(batch),
                   per_block, blocks)


def write_reference_episodes(directory: Path, episodes: int, length: int = 1000) -> None:
    """Episodes in the reference's npz format (a dummy first transition, then ``length`` steps)."""
    rng = np.random.default_rng(0)
    for i in range(episodes):
        episode = {"observation": rng.standard_normal((length + 1, OBS), dtype=np.float32),
                   "action": rng.uniform(-1, 1, (length + 1, ACT)).astype(np.float32),
                   "reward": rng.random((length + 1, 1), dtype=np.float32),
                   "discount": np.ones((length + 1, 1), np.float32)}
        np.savez_compressed(directory / f"episode_{i}_{length}.npz", **episode)


def sampler_row(ref, config: PBRLConfig, per_block: int, blocks: int, episodes: int = 50) -> Comparison:
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp) / "walk"
        directory.mkdir()
        write_reference_episodes(directory, episodes)
        loader = ref.replay_buffer.make_replay_loader(None, [directory], 10**7, config.batch_size, 1, 0.99, "walk",
                                                      ["walk"])
        stream = iter(loader)
        theirs, ours = reference_pbrl(ref, config), PBRL(config, OBS, ACT, seed=0)
        rng = np.random.default_rng(0)
        n = episodes * 1000
        data = TransitionTensors.from_arrays({
            "observations": rng.standard_normal((n, OBS), dtype=np.float32),
            "actions": rng.uniform(-1, 1, (n, ACT)), "rewards": rng.random(n),
            "next_observations": rng.standard_normal((n, OBS), dtype=np.float32),
            "terminals": np.zeros(n), "timeouts": np.zeros(n, bool)})
        sampler = torch.Generator().manual_seed(0)
        step = itertools.count(1)
        return compare("PBRL sampler + update, thesis size", lambda: theirs.update(stream, next(step), 1_000_000),
                       lambda: ours.update(data.sample(config.batch_size, sampler)), per_block, blocks)


# ---- TD3 ------------------------------------------------------------------------------------------
def td3_row(ref, name: str, width: int, batch_size: int, per_block: int, blocks: int) -> Comparison:
    config = TD3Config(hidden_sizes=(width, width), layer_norm=True, learning_rate=1e-4, batch_size=batch_size,
                       tau=0.01, target_noise=0.2, target_noise_clip=0.3, policy_delay=1)
    theirs = ref.td3.TD3Agent(name="td3", obs_shape=(OBS,), action_shape=(ACT,), device="cpu", lr=1e-4,
                              hidden_dim=width, critic_target_tau=0.01, stddev_schedule=0.2, num_expl_steps=0,
                              nstep=1, batch_size=batch_size, stddev_clip=0.3, use_tb=False)
    ours = TD3(config, OBS, ACT, seed=0)
    batch = random_batch(batch_size)
    stream = itertools.repeat(as_reference_batch(batch)[:5])
    step = itertools.count(1)
    return compare(name, lambda: theirs.update(stream, next(step)), lambda: ours.update(batch), per_block, blocks)


# ---- students -------------------------------------------------------------------------------------
def student_row(ref, name: str, loss: str, batch_size: int, teacher_width: int, per_block: int,
                blocks: int) -> Comparison:
    torch.manual_seed(0)
    tasks = 2
    teacher_config = replace(PBRLConfig(), hidden_sizes=(teacher_width, teacher_width), batch_size=batch_size)
    teachers = [reference_pbrl(ref, teacher_config) for _ in range(tasks)]
    for teacher in teachers:
        teacher.freeze_critics()  # the reference's train_mop.py does so for the Q loss
    theirs = ref.mop.MOP(OBS, ACT, hidden_dim=256, hidden_layers=1, device="cpu", lr=1e-4, ensemble=5,
                         deterministic_actor=True, ranking_loss=None)
    states = [np.random.default_rng(t).standard_normal((100_000, OBS), dtype=np.float32) for t in range(tasks)]
    streams = [itertools.repeat((s[:batch_size],)) for s in states]
    mode = "a2a" if loss == "mse" else "c2a"

    def reference_update() -> None:
        for t in range(tasks):
            theirs.update(t, teachers[t], None, streams[t], mode=mode)

    our_teachers = [DeterministicActor(OBS, ACT, (teacher_width, teacher_width)).requires_grad_(False)
                    for _ in range(tasks)]
    targets = [task_states(f"task{t}", s, a, {}) for t, (s, a) in enumerate(zip(states, our_teachers))]
    critics = [EnsembleCritic(OBS, ACT, (teacher_width, teacher_width), 5) for _ in range(tasks)]
    config = DistillConfig(loss=loss, student=StudentConfig(hidden_sizes=(256, 256)), learning_rate=1e-4,
                           batch_size=batch_size, step_per_task=True)
    ours = Distiller(config, [targets], OBS, ACT, [0], critics=critics if loss == "q" else None)
    return compare(name, reference_update, ours.update, per_block, blocks)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", help="checkout of the reference code (else $MOP_REFERENCE)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (the stages use 2)")
    parser.add_argument("--quick-only", action="store_true", help="skip the thesis-size rows")
    parser.add_argument("--blocks", type=int, default=7, help="timed blocks per implementation and row")
    args = parser.parse_args()
    root = reference_dir(args.reference)
    if root is None:
        sys.exit(f"--reference: no checkout of the reference code given; {HOW_TO_GET}")
    try:
        ref = load(root)
    except ReferenceError as err:
        sys.exit(str(err))
    configure_compute(args.threads)
    warnings.filterwarnings("ignore")  # the reference's DataLoader asks for pinned memory without a GPU
    thesis, quick = pbrl_config(ROOT / "profiles" / "thesis.yaml"), pbrl_config(ROOT / "params.yaml")
    k = args.blocks
    print(f"torch {torch.__version__}, {args.threads} thread(s); reference {REFERENCE_COMMIT[:12]}; "
          f"{k} alternating blocks per row; one process, configured as the stages configure theirs "
          f"(runtime.configure_compute: the reference runs with the same threads and memory allocator)")
    rows: list[Callable[[], Comparison]] = []
    if not args.quick_only:
        rows.append(lambda: pbrl_row(ref, "PBRL update, thesis size", thesis, 2, k))
    rows += [lambda: pbrl_row(ref, "PBRL update, quick size", quick, 10, k),
             lambda: pbrl_row(ref, "PBRL update, width 16, batch 32", replace(thesis, hidden_sizes=(16, 16),
                                                                              batch_size=32), 30, k)]
    if not args.quick_only:
        rows += [lambda: sampler_row(ref, thesis, 2, k),
                 lambda: td3_row(ref, "TD3 update, thesis size", 1024, 1024, 1, k)]
    rows.append(lambda: td3_row(ref, "TD3 update, quick width, batch 128", 256, 128, 10, k))
    if not args.quick_only:
        rows += [lambda: student_row(ref, "student step, MSE, thesis size", "mse", 1024, 256, 5, k),
                 lambda: student_row(ref, "student step, Q loss, thesis size", "q", 1024, 256, 3, k)]
    rows += [lambda: student_row(ref, "student step, MSE, quick size", "mse", 256, 128, 10, k),
             lambda: student_row(ref, "student step, Q loss, quick size", "q", 256, 128, 10, k)]
    print(f"{'what':38s} {'reference ms':>12s} {'mop ms':>8s}  ratio (>1: mop faster) [block min, max]")
    with on_cpu():
        for row in rows:
            with contextlib.redirect_stdout(io.StringIO()):  # the reference prints parameter counts and loader logs
                c = row()
            print(f"{c.name:38s} {c.reference_ms:12.2f} {c.mop_ms:8.2f}  {c.ratio:5.2f}x [{c.ratio_min:.2f}, "
                  f"{c.ratio_max:.2f}]", flush=True)


if __name__ == "__main__":
    main()
