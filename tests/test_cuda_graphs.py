"""Issue 39, part 2: PBRL groups', the multi-task baseline's (alone and as a group of seeds), student groups'
and TD3's updates replayed as CUDA graphs equal eager ones.

On CUDA (MOP_TEST_DEVICE=cuda, benchmarks/gpu_check.sh) a captured group and an eager one of the same
seeds take the same minibatches under a cosine learning rate; after the warm-up, both variants' capture
and many replays, their networks, targets, optimiser states, metrics and generators agree to float
tolerance, and a captured group resumed from a state dict continues as the uninterrupted one. A student
group (MSE, Q, KL losses; one step over all tasks or one per task; its state draws inside the graph)
equals its eager twin, also across a DAgger
aggregation, which replaces the states the graph read. On the CPU
the capture is off (eager is the CPU path) and the pieces that need no GPU are tested: the switch, the
in-place learning rate a replayed step reads, the static-input checks.
"""

from __future__ import annotations

import pytest
import torch
from conftest import TEST_DEVICE

from mop_core.agents.pbrl import PBRLConfig
from mop_core.agents.pbrl_group import PBRLGroup, stack_batches
from mop_core.agents.pbrl_multitask import MultiTaskPBRL
from mop_core.agents.pbrl_multitask_group import MultiTaskPBRLGroup
from mop_core.agents.td3 import TD3, TD3Config
from mop_core.data.buffer import Batch
from mop_core.distill.config import DistillConfig
from mop_core.distill.distiller import Distiller
from mop_core.distill.states import TaskStates
from mop_core.distill.student import StudentConfig
from mop_core.learning.graphs import GraphedStep, graphs_enabled
from mop_core.learning.nn import EnsembleCritic
from mop_core.learning.schedule import scheduled_rate, set_learning_rate

OBS, ACT, SEEDS, STEPS = 24, 6, [0, 1, 2], 14  # 14 updates: 4 eager, 2 captures, 8 replays
cuda = pytest.mark.skipif(TEST_DEVICE != "cuda" or not torch.cuda.is_available(), reason="needs MOP_TEST_DEVICE=cuda")


def _config(actor: str) -> PBRLConfig:
    return PBRLConfig(actor=actor, hidden_sizes=(64, 64), ensemble_size=5, batch_size=32, ood_actions=2,
                      layer_norm=True, beta_ood_decay=0.9, target_entropy=-6.0 if actor == "gaussian" else None)


def _batches(device: torch.device, count: int) -> list[Batch]:
    g = torch.Generator().manual_seed(5)
    out = []
    for _ in range(count):
        runs = [Batch(torch.randn(32, OBS, generator=g), torch.rand(32, ACT, generator=g) * 2 - 1,
                      torch.randn(32, generator=g), torch.randn(32, OBS, generator=g),
                      (torch.rand(32, generator=g) < 0.1).float()) for _ in SEEDS]
        out.append(stack_batches(runs).to(device))
    return out


def _train(group: PBRLGroup, batches: list[Batch], start: int = 0) -> dict:
    metrics = {}
    for step, batch in enumerate(batches, start):
        set_learning_rate(group.optimizers(), scheduled_rate(group.config.learning_rate, "cosine", step, STEPS))
        metrics = group.update(batch)
    return metrics


def _assert_same(captured: PBRLGroup, eager: PBRLGroup, metrics: tuple[dict, dict]) -> None:
    a, b = captured.state_dict(), eager.state_dict()
    for part in ("actor", "actor_target", "critic", "critic_target"):
        for key, value in b[part].items():
            torch.testing.assert_close(a[part][key], value, atol=2e-5, rtol=1e-4,
                                       msg=lambda m, k=key, p=part: f"{p} {k}: {m}")
    for part in ("actor_optimizer", "critic_optimizer"):
        for index, state in b[part]["state"].items():
            for key, value in state.items():
                torch.testing.assert_close(a[part]["state"][index][key].float(), value.float(), atol=2e-5, rtol=1e-4)
    torch.testing.assert_close(a["log_alpha"], b["log_alpha"], atol=2e-5, rtol=1e-4)
    for ga, gb in zip(a["generators"], b["generators"], strict=True):  # each run's draws advanced alike
        assert torch.equal(ga, gb)
    found, expected = metrics
    assert found.keys() == expected.keys()
    for key, value in expected.items():
        torch.testing.assert_close(torch.as_tensor(found[key]).float().cpu(), torch.as_tensor(value).float().cpu(),
                                   atol=1e-4, rtol=1e-4, msg=lambda m, k=key: f"metric {k}: {m}")


@cuda
@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_a_captured_group_equals_the_eager_group(actor):
    device = torch.device("cuda")
    batches = _batches(device, STEPS)
    captured = PBRLGroup(_config(actor), OBS, ACT, SEEDS, device, cuda_graphs=True)
    eager = PBRLGroup(_config(actor), OBS, ACT, SEEDS, device, cuda_graphs=False)
    metrics = (_train(captured, batches), _train(eager, batches))
    assert captured.graphed is not None and len(captured.graphed.graphs) == 2  # both variants replayed
    _assert_same(captured, eager, metrics)


@cuda
def test_a_resumed_captured_group_continues_as_the_uninterrupted_one():
    device = torch.device("cuda")
    batches = _batches(device, STEPS)
    whole = PBRLGroup(_config("gaussian"), OBS, ACT, SEEDS, device, cuda_graphs=True)
    first = PBRLGroup(_config("gaussian"), OBS, ACT, SEEDS, device, cuda_graphs=True)
    _train(first, batches[:8])
    resumed = PBRLGroup(_config("gaussian"), OBS, ACT, SEEDS, device, cuda_graphs=True)
    resumed.load_state_dict(first.state_dict())
    metrics = (_train(resumed, batches[8:], start=8), _train(whole, batches))
    _assert_same(resumed, whole, metrics)


@cuda
@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_a_captured_multitask_baseline_equals_the_eager_one(actor):
    device = torch.device("cuda")
    tasks = ("stand", "walk", "run")
    captured = MultiTaskPBRL(_config(actor), tasks, OBS, ACT, 0, device, cuda_graphs=True)
    eager = MultiTaskPBRL(_config(actor), tasks, OBS, ACT, 0, device, cuda_graphs=False)
    g = torch.Generator().manual_seed(3)
    for step in range(30):  # 3 tasks x 2 variants: 12 eager, 6 captures, 12 replays
        batch = Batch(torch.randn(32, OBS, generator=g), torch.rand(32, ACT, generator=g) * 2 - 1,
                      torch.randn(32, generator=g), torch.randn(32, OBS, generator=g), torch.zeros(32)).to(device)
        for agent in (captured, eager):
            set_learning_rate(agent.optimizers(), scheduled_rate(1e-3, "cosine", step, 30))
        found, expected = captured.update(batch, step % 3), eager.update(batch, step % 3)
    assert len(captured.graphed.graphs) == 6
    a, b = captured.state_dict(), eager.state_dict()
    for part in ("actor", "actor_target"):
        for key, value in b[part].items():
            torch.testing.assert_close(a[part][key], value, atol=2e-5, rtol=1e-4, msg=lambda m, k=key: f"{k}: {m}")
    for ca, cb in zip(a["critics"], b["critics"], strict=True):
        for key, value in cb["critic"].items():
            torch.testing.assert_close(ca["critic"][key], value, atol=2e-5, rtol=1e-4)
    assert torch.equal(a["generator"], b["generator"])
    for key, value in expected.items():
        torch.testing.assert_close(torch.as_tensor(found[key]).float().cpu(), torch.as_tensor(value).float().cpu(),
                                   atol=1e-4, rtol=1e-4, msg=lambda m, k=key: f"metric {k}: {m}")


@cuda
def test_a_captured_multitask_group_equals_the_eager_one():
    device = torch.device("cuda")
    tasks = ("stand", "walk", "run")
    batches = _batches(device, 30)
    captured = MultiTaskPBRLGroup(_config("gaussian"), tasks, OBS, ACT, SEEDS, device, cuda_graphs=True)
    eager = MultiTaskPBRLGroup(_config("gaussian"), tasks, OBS, ACT, SEEDS, device, cuda_graphs=False)
    for step, batch in enumerate(batches):  # 3 tasks x 2 variants: 12 eager, 6 captures, 12 replays
        for agent in (captured, eager):
            set_learning_rate(agent.optimizers(), scheduled_rate(1e-3, "cosine", step, 30))
        found, expected = captured.update(batch, step % 3), eager.update(batch, step % 3)
    assert len(captured.graphed.graphs) == 6
    _assert_nested_close(captured.state_dict(), eager.state_dict(), "state")  # every weight, Adam moment, generator
    assert found.keys() == expected.keys()
    for key, value in expected.items():
        torch.testing.assert_close(torch.as_tensor(found[key]).float().cpu(), torch.as_tensor(value).float().cpu(),
                                   atol=1e-4, rtol=1e-4, msg=lambda m, k=key: f"metric {k}: {m}")


def _assert_nested_close(a, b, where: str) -> None:
    """Two state dicts alike: floats to tolerance, generator states and counts exactly, dicts and lists
    entry by entry."""
    if isinstance(b, dict):
        assert a.keys() == b.keys(), where
        for key in b:
            _assert_nested_close(a[key], b[key], f"{where}.{key}")
    elif isinstance(b, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_nested_close(x, y, f"{where}[{i}]")
    elif isinstance(b, torch.Tensor) and b.is_floating_point():
        torch.testing.assert_close(a.float(), b.float(), atol=2e-5, rtol=1e-4, msg=lambda m: f"{where}: {m}")
    elif isinstance(b, torch.Tensor):
        assert torch.equal(a.cpu(), b.cpu()), where
    else:
        assert a == b, where


@cuda
def test_a_captured_td3_equals_the_eager_one_with_exploration_draws_between_updates():
    device = torch.device("cuda")
    config = TD3Config(hidden_sizes=(64, 64), batch_size=32, layer_norm=True)
    captured, eager = TD3(config, OBS, ACT, 0, device, cuda_graphs=True), TD3(config, OBS, ACT, 0, device,
                                                                               cuda_graphs=False)
    g = torch.Generator().manual_seed(4)
    for _ in range(STEPS):  # collect's order: act with exploration noise (the same generator), then update
        states = torch.randn(3, OBS, generator=g).numpy()
        torch.testing.assert_close(captured.act(states, 0.1), eager.act(states, 0.1), atol=1e-5, rtol=1e-4)
        batch = Batch(torch.randn(32, OBS, generator=g), torch.rand(32, ACT, generator=g) * 2 - 1,
                      torch.randn(32, generator=g), torch.randn(32, OBS, generator=g), torch.zeros(32)).to(device)
        found, expected = captured.update(batch), eager.update(batch)
    assert len(captured.graphed.graphs) == 2
    a, b = captured.state_dict(), eager.state_dict()
    for part in ("actor", "critic", "actor_target", "critic_target"):
        for key, value in b[part].items():
            torch.testing.assert_close(a[part][key], value, atol=2e-5, rtol=1e-4,
                                       msg=lambda m, k=key, p=part: f"{p} {k}: {m}")
    assert torch.equal(a["generator"], b["generator"])
    for key, value in expected.items():
        torch.testing.assert_close(found[key].float().cpu(), value.float().cpu(), atol=1e-4, rtol=1e-4)


def _students(loss: str, device: torch.device, cuda_graphs: bool, step_per_task: bool = False) -> Distiller:
    g = torch.Generator().manual_seed(0)
    gaussian = loss == "kl"
    tasks = [TaskStates(f"task{i}", torch.randn(400, OBS, generator=g).to(device),
                        (torch.rand(400, ACT, generator=g) * 2 - 1).to(device),
                        (torch.rand(400, ACT, generator=g) * 0.5 + 0.1).to(device) if gaussian else None, {})
             for i in range(2)]
    torch.manual_seed(1)
    critics = [EnsembleCritic(OBS, ACT, (32, 32), 3) for _ in range(2)] if loss == "q" else None
    config = DistillConfig(loss=loss, student=StudentConfig(hidden_sizes=(64, 64)), batch_size=32,
                           lr_schedule="cosine", step_per_task=step_per_task)
    return Distiller(config, [tasks] * 3, OBS, ACT, SEEDS, critics, device, total_steps=STEPS,
                     cuda_graphs=cuda_graphs)


@cuda
@pytest.mark.parametrize("loss,step_per_task", [("mse", False), ("q", False), ("kl", False), ("mse", True),
                                                ("q", True)])
def test_a_captured_student_group_equals_the_eager_group_across_an_aggregation(loss, step_per_task):
    device = torch.device("cuda")
    captured, eager = _students(loss, device, True, step_per_task), _students(loss, device, False, step_per_task)
    g = torch.Generator().manual_seed(9)
    extra = [torch.randn(50, OBS, generator=g).to(device), (torch.rand(50, ACT, generator=g) * 2 - 1).to(device),
             (torch.rand(50, ACT, generator=g) * 0.5 + 0.1).to(device) if loss == "kl" else None]
    for step in range(STEPS):
        if step == STEPS // 2:  # a DAgger round: run 0's task 0 grows
            for group in (captured, eager):
                group.aggregate(0, 0, *extra)
        found, expected = captured.update(), eager.update()
    assert captured.graphed is not None and captured.graphed.graphs
    a, b = captured.state_dict(), eager.state_dict()
    for key, value in b["group"].items():
        torch.testing.assert_close(a["group"][key], value, atol=2e-5, rtol=1e-4, msg=lambda m, k=key: f"{k}: {m}")
    for ga, gb in zip(a["generators"], b["generators"], strict=True):
        assert torch.equal(ga, gb)
    for key, value in expected.items():
        torch.testing.assert_close(torch.as_tensor(found[key]).float().cpu(), torch.as_tensor(value).float().cpu(),
                                   atol=1e-4, rtol=1e-4, msg=lambda m, k=key: f"metric {k}: {m}")


def test_capture_is_a_cuda_path_and_can_be_turned_off(monkeypatch):
    assert not graphs_enabled("cpu") and not graphs_enabled("cpu", True)
    monkeypatch.setenv("MOP_CUDA_GRAPHS", "0")
    assert not graphs_enabled("cuda") and graphs_enabled("cuda", True)
    monkeypatch.setenv("MOP_CUDA_GRAPHS", "1")
    assert graphs_enabled("cuda") and not graphs_enabled("cuda", False)
    assert PBRLGroup(_config("deterministic"), OBS, ACT, [0], "cpu", cuda_graphs=True).graphed is None  # eager on CPU


def test_a_tensor_learning_rate_is_set_in_place_for_the_replayed_step():
    weight = torch.nn.Parameter(torch.zeros(3))
    tensor_rate = torch.optim.Adam([weight], lr=torch.tensor(1e-3))
    float_rate = torch.optim.Adam([torch.nn.Parameter(torch.zeros(3))], lr=1e-3)
    held = tensor_rate.param_groups[0]["lr"]
    set_learning_rate([tensor_rate, float_rate], 2.5e-4)
    assert tensor_rate.param_groups[0]["lr"] is held and float(held) == pytest.approx(2.5e-4)  # the graph's tensor
    assert float_rate.param_groups[0]["lr"] == 2.5e-4


def test_a_captured_step_takes_one_shape_per_input():
    step = GraphedStep(lambda variant: (lambda: {}))
    step._fill({"observations": torch.zeros(2, 4)})
    step._fill({"observations": torch.ones(2, 4)})
    assert torch.equal(step.buffers["observations"], torch.ones(2, 4))  # copied into the static buffer
    with pytest.raises(ValueError, match=r"inputs\['observations'\].*\(2, 4\).*\(3, 4\)"):
        step._fill({"observations": torch.zeros(3, 4)})
    with pytest.raises(ValueError, match="warmup"):
        GraphedStep(lambda variant: (lambda: {}), warmup=0)


def test_a_resume_file_of_a_captured_run_continues_eagerly_on_a_cpu():
    """A captured run's optimiser groups (capturable, a tensor learning rate) resumed by an eager CPU group:
    the groups become what the CPU group built (a CPU Adam refuses capturable) and it continues as the
    uninterrupted run (issue 39: runs restored across machines)."""
    batches = _batches(torch.device("cpu"), 10)
    whole, first = (PBRLGroup(_config("gaussian"), OBS, ACT, SEEDS, "cpu") for _ in range(2))
    _train(first, batches[:5])
    state = first.state_dict()
    for part in ("actor_optimizer", "critic_optimizer", "alpha_optimizer"):  # as a captured run writes them
        for group in state[part]["param_groups"]:
            group["capturable"], group["lr"] = True, torch.tensor(group["lr"])
    resumed = PBRLGroup(_config("gaussian"), OBS, ACT, SEEDS, "cpu")
    resumed.load_state_dict(state)
    assert all(not g["capturable"] and isinstance(g["lr"], float) for o in resumed.optimizers() for g in o.param_groups)
    _assert_same(resumed, whole, (_train(resumed, batches[5:], start=5), _train(whole, batches)))


def test_a_batch_round_trips_through_a_captured_steps_buffers():
    batch = Batch(*(torch.randn(4, 2) for _ in range(5)))
    buffers = batch.as_dict() | {"beta_ood": torch.zeros(())}  # the learners' extra input is ignored
    assert list(batch.as_dict()) == ["observations", "actions", "rewards", "next_observations", "terminals"]
    assert all(torch.equal(a, b) for a, b in zip(Batch.from_dict(buffers).as_dict().values(),
                                                  batch.as_dict().values()))
