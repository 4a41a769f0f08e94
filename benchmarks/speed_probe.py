"""The machine's speed today: a fixed ~20-second measurement printed with every record.

This machine's speed varies 1.3-2.7x from day to day (another tenant's load), so a study's seconds
mean little without the speed of the day they were measured on. The probe times the study's three
kinds of work at fixed sizes that never follow a profile (so probes of different records compare):

- ``td3_updates_per_second``: behaviour TD3 updates (256 x 2, LayerNorm, batch 128) on 1 torch thread,
  as each collect worker runs them (env steps not included);
- ``pbrl_group_updates_per_second``: a vectorised group of 2 deterministic PBRL teachers (128 x 2,
  ensemble 5, batch 256, 1 OOD action) on 2 threads, as a quick teacher stage runs them;
- ``rollout_control_steps_per_second``: 10 walkers stepped together under one batched policy, 1 thread.

Each rate is the median of 3 timed blocks after a warm-up block (bench_rates.per_second). Beside the
rates, ``float_path`` holds the machine's float-path fingerprint (mop_core/float_path.py): two
machines whose fingerprints differ round otherwise, so the same study may give other results on them.
``scripts/record.py`` runs it after a study and stores it beside the record (``speed_probe.json``);
the README's time table quotes it.

Run: ``python benchmarks/speed_probe.py [--out probe.json]``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_pbrl import random_batch  # noqa: E402
from bench_rates import per_second  # noqa: E402

from mop_core.agents.pbrl import PBRLConfig  # noqa: E402
from mop_core.agents.pbrl_group import PBRLGroup, stack_batches  # noqa: E402
from mop_core.agents.td3 import TD3, TD3Config  # noqa: E402
from mop_core.config import from_mapping  # noqa: E402
from mop_core.distill.checkpoint import student_policy  # noqa: E402
from mop_core.distill.student import Student, StudentConfig  # noqa: E402
from mop_core.float_path import float_path  # noqa: E402
from mop_core.learning.runtime import configure_compute  # noqa: E402
from mop_core.storage.timings import machine_facts  # noqa: E402
from mop_core.walker.rollout import episode_returns  # noqa: E402

# the probe's sizes: frozen, so that every record's probe measures the same work
TD3_PROBE = {"hidden_sizes": [256, 256], "layer_norm": True, "learning_rate": 1.0e-3, "batch_size": 128}
PBRL_PROBE = {"hidden_sizes": [128, 128], "ensemble_size": 5, "batch_size": 256, "ood_actions": 1,
              "learning_rate": 1.0e-3, "actor": "deterministic"}
PBRL_GROUP = 2
ROLLOUT_ENVS, ROLLOUT_STEPS = 10, 200
CPU = torch.device("cpu")


def td3_rate(count: int) -> float:
    configure_compute(1)
    agent = TD3(from_mapping(TD3Config, TD3_PROBE, "td3 probe"), 24, 6, 0, CPU)
    batch = random_batch(TD3_PROBE["batch_size"])
    return per_second(lambda: agent.update(batch), count, CPU)


def pbrl_group_rate(count: int) -> float:
    configure_compute(2)
    config = from_mapping(PBRLConfig, PBRL_PROBE, "pbrl probe")
    group = PBRLGroup(config, 24, 6, list(range(PBRL_GROUP)), CPU)
    batch = stack_batches([random_batch(config.batch_size, seed) for seed in range(PBRL_GROUP)])
    return per_second(lambda: group.update(batch), count, CPU)


def rollout_rate() -> float:
    configure_compute(1)
    policy = student_policy(Student(StudentConfig(), 24, 6, 2).eval(), 0, CPU)
    return per_second(lambda: episode_returns(policy, "walk", list(range(ROLLOUT_ENVS)), ROLLOUT_STEPS,
                                              ROLLOUT_ENVS), 1, CPU) * ROLLOUT_ENVS * ROLLOUT_STEPS


def probe(quick: bool = False) -> dict:
    """The three rates (``quick``: a few calls each, a smoke test whose numbers mean little)."""
    start = time.perf_counter()
    result = {"td3_updates_per_second": td3_rate(5 if quick else 300),
              "pbrl_group_updates_per_second": pbrl_group_rate(3 if quick else 100),
              "rollout_control_steps_per_second": rollout_rate(),
              "machine": machine_facts(CPU),
              "float_path": float_path(),
              "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    result["seconds"] = round(time.perf_counter() - start, 1)
    return result


def summary(result: dict) -> str:
    """One line for a record: the three rates."""
    return (f"TD3 {result['td3_updates_per_second']:.0f} updates/s (1 thread), PBRL group of {PBRL_GROUP} "
            f"{result['pbrl_group_updates_per_second']:.1f} updates/s (2 threads), rollouts "
            f"{result['rollout_control_steps_per_second']:.0f} control steps/s (10 walkers, 1 thread)"
            + (f"; {result['machine']['cpu']}" if result.get("machine", {}).get("cpu") else "")
            + (f"; float path {_path_text(result['float_path'])}" if result.get("float_path") else ""))


def _path_text(path: dict[str, str]) -> str:
    return ", ".join(f"{name} {digest}" for name, digest in path.items())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="write the probe as JSON here")
    parser.add_argument("--quick", action="store_true", help="a few calls per rate (a smoke test)")
    args = parser.parse_args(argv)
    result = probe(args.quick)
    print(f"speed probe ({result['when']}, {result['seconds']} s): {summary(result)}")
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
