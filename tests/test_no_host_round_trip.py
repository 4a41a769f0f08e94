"""Issue 39, part 1: a training update makes no host round trip (a PBRL group's: its replayed CUDA graphs).
Minibatch indices come from generators
on the data's device and metrics stay tensors, so on CUDA a step of the PBRL teacher group (the
train_teachers stage's learner, sampling included), of a student group (MSE and Q losses) and of TD3
runs under ``torch.cuda.set_sync_debug_mode("error")``, which raises on any synchronising call
(``.item()``, a device-to-host copy, a data-dependent shape). On the CPU the same updates run without
that check: the code path is the one the GPU test sees."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
import torch
from conftest import TEST_DEVICE

from mop_core.agents.pbrl import PBRLConfig
from mop_core.agents.pbrl_group import PBRLGroup
from mop_core.agents.td3 import TD3, TD3Config
from mop_core.data.buffer import Batch, TransitionTensors
from mop_core.distill.config import DistillConfig
from mop_core.distill.distiller import Distiller
from mop_core.distill.states import TaskStates
from mop_core.distill.student import StudentConfig
from mop_core.learning.nn import EnsembleCritic
from mop_core.teachers import GroupLearner

STEPS = 3
CAPTURED = 6  # calls before the checked ones: on CUDA a PBRL group's both variants warm up and are captured


def _dataset(rows: int, seed: int, device: torch.device) -> TransitionTensors:
    rng = np.random.default_rng(seed)
    arrays = {"observations": rng.normal(size=(rows, 24)), "actions": rng.uniform(-1, 1, size=(rows, 6)),
              "rewards": rng.uniform(size=rows), "next_observations": rng.normal(size=(rows, 24)),
              "terminals": np.zeros(rows), "timeouts": np.zeros(rows, dtype=bool)}
    return TransitionTensors.from_arrays(arrays, device=device)


def _learners(device: torch.device) -> dict:
    """Each learner's update, built (and warmed up: first calls allocate) on ``device``."""
    learners = {}
    for actor, graphs, name in (("deterministic", None, ""), ("gaussian", None, ""),
                                ("deterministic", False, "-eager")):
        config = PBRLConfig(actor=actor, hidden_sizes=(32, 32), batch_size=64, ood_actions=2, layer_norm=True,
                            target_entropy=-6.0)
        group = PBRLGroup(config, 24, 6, [0, 1], device, cuda_graphs=graphs)
        learner = GroupLearner(group, [_dataset(500, 0, device), _dataset(500, 1, device)],
                                [torch.Generator(device).manual_seed(s) for s in (0, 1)], 64, CAPTURED + STEPS)
        learners[f"pbrl-{actor}{name}"] = learner.update
        for _ in range(CAPTURED - 1):  # the checked steps replay the graphs (eager on the CPU)
            learner.update()
    g = torch.Generator().manual_seed(0)
    tasks = [TaskStates(f"task{i}", torch.randn(300, 24, generator=g).to(device),
                        (torch.rand(300, 6, generator=g) * 2 - 1).to(device), None, {}) for i in range(2)]
    critics = [EnsembleCritic(24, 6, (32, 32), 3) for _ in range(2)]
    for loss in ("mse", "q"):
        config = DistillConfig(loss=loss, student=StudentConfig(hidden_sizes=(32, 32)), batch_size=32)
        learners[f"student-{loss}"] = Distiller(config, [tasks] * 2, 24, 6, [0, 1], critics if loss == "q" else None,
                                                device, total_steps=CAPTURED + STEPS).update
    td3 = TD3(TD3Config(hidden_sizes=(32, 32), batch_size=64), 24, 6, 0, device)
    batch = _dataset(64, 2, device)
    fixed = Batch(batch.observations, batch.actions, batch.rewards, batch.next_observations, batch.terminals)
    learners["td3"] = lambda: td3.update(fixed)
    for name, update in learners.items():
        for _ in range(1 if name.startswith("pbrl") else CAPTURED):  # students: warmed up and captured too
            update()
    return learners


def _no_sync(device: torch.device):
    if device.type != "cuda":
        return contextlib.nullcontext()
    torch.cuda.synchronize(device)
    return _sync_debug_error()


@contextlib.contextmanager
def _sync_debug_error():
    torch.cuda.set_sync_debug_mode("error")
    try:
        yield
    finally:
        torch.cuda.set_sync_debug_mode("default")


@pytest.mark.parametrize("name", ["pbrl-deterministic", "pbrl-gaussian", "pbrl-deterministic-eager", "student-mse",
                                  "student-q", "td3"])
def test_an_update_makes_no_host_round_trip(name):
    device = torch.device(TEST_DEVICE)
    update = _learners(device)[name]
    with _no_sync(device):
        for _ in range(STEPS):
            metrics = update()
    tensors = [v for v in metrics.values() if isinstance(v, torch.Tensor)]
    assert tensors and all(t.device.type == device.type for t in tensors)  # metrics stay where they were made
