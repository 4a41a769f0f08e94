"""This machine's float path: short hashes of fixed computations, one per library that rounds.

The quick study is bit-reproducible on one machine, but not across every machine sold as the same
CPU: the same commit has trained the same TD3 seed to other weights on two machines that both
reported "AMD EPYC", 2 cores and the same wheels (docs/timings.md, "float paths"), and every later
output then differs. On this kind of machine the usual switches do not move it: on the path-A machine
of 2026-12-05 (AVX512), ``ATEN_CPU_CAPABILITY=avx2``, ``MKL_ENABLE_INSTRUCTIONS=AVX2``,
``ONEDNN_MAX_CPU_ISA=AVX2``, ``NPY_DISABLE_CPU_FEATURES`` and ``OPENBLAS_CORETYPE=Haswell`` left
5,000 TD3 updates of the study's walk run bit-identical.

Each entry hashes what one library computed, so two machines' probes say *where* their paths part:

- ``torch_updates``: the speed probe's TD3 learner (256 x 2, LayerNorm, fused Adam) after 200 updates
  on fixed batches, 1 thread, subnormals flushed (as collect runs it): the bytes of every weight;
- ``torch_acting``: that actor's actions for 1 and for 10 observations (collect acts on one walker and
  evaluates a batch of them; MKL rounds such small matrices on paths of their own);
- ``mujoco``: 300 control steps of the walk walker under fixed random actions: the physics state,
  observation and reward (dm_control's numpy reward) of every step.

Equal hashes mean the same rounding in these computations, not a proof that the whole study
matches; a different hash means the study's numbers may differ from the other machine's (the quick
profile's did: docs/timings.md). Every hash is of CPU work at these sizes: where collect trains on a
GPU (its timing record's ``device``) the card rounds the TD3 updates, and other network sizes (the
thesis profile's) may take other kernels.

Run: ``python -m mop_core.float_path`` (about a second). The collect stage's timing record and every
speed probe (benchmarks/speed_probe.py) carry it.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys

import numpy as np
import torch

from mop_core.agents.td3 import TD3, TD3Config
from mop_core.config import from_mapping
from mop_core.data.buffer import Batch
from mop_core.learning.runtime import configure_compute
from mop_core.walker.envs import WalkerEnv

# frozen: every record's fingerprint hashes the same work
TD3_NET = {"hidden_sizes": [256, 256], "layer_norm": True, "learning_rate": 1.0e-3, "batch_size": 128}
TD3_UPDATES, BATCHES = 200, 4
ACTING_ROWS = (1, 10)  # observations per forward pass of the trained actor (MKL's small-matrix paths)
WALKER_STEPS = 300
DIGITS = 12  # hex digits of each hash


def _digest(arrays) -> str:
    h = hashlib.sha256()
    for array in arrays:
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()[:DIGITS]


def random_batch(rows: int, seed: int = 0) -> Batch:
    """A fixed random minibatch (24-d observations, 6-d actions, as the walker's): the fingerprint's and
    the benchmarks' (benchmarks/bench_pbrl.py, speed_probe.py)."""
    g = torch.Generator().manual_seed(seed)
    return Batch(torch.randn(rows, 24, generator=g), torch.rand(rows, 6, generator=g) * 2 - 1,
                 torch.rand(rows, generator=g), torch.randn(rows, 24, generator=g), torch.zeros(rows))


def torch_hashes() -> dict[str, str]:
    """``torch_updates``: the TD3 learner's weights after ``TD3_UPDATES`` updates on ``BATCHES`` fixed
    batches; ``torch_acting``: its actor's actions for each of ``ACTING_ROWS`` observations."""
    configure_compute(1)
    agent = TD3(from_mapping(TD3Config, TD3_NET, "float path"), 24, 6, 0, torch.device("cpu"))
    batches = [random_batch(TD3_NET["batch_size"], seed) for seed in range(BATCHES)]
    for step in range(TD3_UPDATES):
        agent.update(batches[step % BATCHES])
    state = agent.state_dict()
    observations = np.random.default_rng(1).standard_normal((ACTING_ROWS[-1], 24)).astype(np.float32)
    return {"torch_updates": _digest(t.numpy() for part in ("actor", "critic") for t in state[part].values()),
            "torch_acting": _digest(agent.act(observations[:rows]) for rows in ACTING_ROWS)}


def mujoco_hash() -> str:
    """Physics state, observation and reward of ``WALKER_STEPS`` walk steps under seeded random actions."""
    env, actions = WalkerEnv("walk", 0, WALKER_STEPS), np.random.default_rng(0).uniform(-1, 1, (WALKER_STEPS, 6))
    arrays = [env.reset()]
    for action in actions:
        step = env.step(action)
        arrays += [step.physics, step.observation, np.float64(step.reward)]
    return _digest(arrays)


def measure() -> dict[str, str]:
    """The fingerprint computed in this process, which it leaves configured as a collect worker
    (:func:`~mop_core.learning.runtime.configure_compute` with 1 thread: the thread variables,
    subnormals flushed) with torch's global seed reset: :func:`float_path` runs it in a fresh one."""
    return torch_hashes() | {"mujoco": mujoco_hash()}


def float_path() -> dict[str, str]:
    """``{"torch_updates": hash, "torch_acting": hash, "mujoco": hash}`` of this machine (the module's
    docstring), measured in a fresh Python process (``python -m mop_core.float_path``, ~3 s with its
    imports) started like a collect worker, so the caller's settings and random state are untouched."""
    result = subprocess.run([sys.executable, "-m", "mop_core.float_path"], capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"python -m mop_core.float_path failed ({result.returncode}):\n{result.stderr}")
    return json.loads(result.stdout)


def differs(ours: dict[str, str], theirs: dict[str, str] | None) -> list[str]:
    """The entries (computations) whose hash differs between two fingerprints (none when either is missing)."""
    if not theirs:
        return []
    return [name for name in sorted(ours) if name in theirs and ours[name] != theirs[name]]


if __name__ == "__main__":
    print(json.dumps(measure()))
