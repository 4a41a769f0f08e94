"""A group of R PBRL runs equals the R runs trained alone."""

from __future__ import annotations

import pytest
import torch

import mop_core.agents.pbrl_group as pbrl_group
from mop_core.agents.pbrl import PBRL, PBRLConfig
from mop_core.agents.pbrl_group import PBRLGroup, stack_batches
from mop_core.data.buffer import Batch
from mop_core.learning.nn import stack_networks

OBS, ACT = 7, 3
SEEDS = [3, 7, 11]


def config(actor: str, **overrides) -> PBRLConfig:
    values = dict(actor=actor, hidden_sizes=(32, 32), ensemble_size=3, learning_rate=3e-3, batch_size=16,
                  critic_tau=0.1, actor_tau=0.1, ood_actions=2, beta_ood_decay=0.9,
                  target_entropy=-float(ACT) if actor == "gaussian" else None)
    return PBRLConfig(**(values | overrides))


def batch(generator: torch.Generator, size: int = 16) -> Batch:
    return Batch(torch.randn(size, OBS, generator=generator), torch.rand(size, ACT, generator=generator) * 2 - 1,
                 torch.randn(size, generator=generator),
                 torch.randn(size, OBS, generator=generator), (torch.rand(size, generator=generator) < 0.1).float())


def assert_states_close(found: dict, expected: dict, what: str, atol: float = 2e-5) -> None:
    assert found.keys() == expected.keys(), what
    for key in expected:
        torch.testing.assert_close(found[key], expected[key].to(found[key].dtype), atol=atol, rtol=1e-4,
                                   msg=lambda m, k=key: f"{what} {k}: {m}")


@pytest.mark.parametrize("path", ["batched", "member_loop"])
@pytest.mark.parametrize("actor,overrides", [("deterministic", {}), ("gaussian", {}),
                                             ("deterministic", {"layer_norm": True}),
                                             ("gaussian", {"target_entropy": None}),
                                             ("deterministic", {"ood_actions": 0})])
def test_group_equals_runs_trained_alone(actor, overrides, path, monkeypatch, device):
    if path == "member_loop":  # the CPU path of large batches, forced at this size
        monkeypatch.setattr(pbrl_group, "member_loop_pays", lambda *args, **kwargs: True)
    cfg = config(actor, **overrides)
    alone = [PBRL(cfg, OBS, ACT, seed, device) for seed in SEEDS]
    group = PBRLGroup(cfg, OBS, ACT, SEEDS, device)
    data = torch.Generator().manual_seed(0)
    for step in range(5):  # two actor steps (policy_delay 2) and beta_ood decaying
        batches = [batch(data) for _ in SEEDS]
        expected = [run.update(b) for run, b in zip(alone, batches)]
        found = group.update(stack_batches(batches))
        for r, metrics in enumerate(expected):
            for key, value in metrics.items():
                if key == "beta_ood":
                    assert found[key] == value
                    continue
                torch.testing.assert_close(torch.as_tensor(found[f"{key}@{r}"]).float().cpu(),
                                           torch.as_tensor(value).float().cpu(), atol=1e-4, rtol=1e-4,
                                           msg=lambda m, k=key: f"step {step} run {r} {k}: {m}")
            assert not any(key.endswith(f"@{r}") and key[:-2] not in metrics for key in found)
    for r, run in enumerate(alone):
        assert_states_close(group.member_actor(r).state_dict(), run.actor.state_dict(), f"run {r} actor")
        assert_states_close(group.member_critic_state(r), run.critic.critic.state_dict(), f"run {r} critics")
        target = {key: value[r * cfg.ensemble_size:(r + 1) * cfg.ensemble_size]
                  for key, value in group.critic_target.state_dict().items()}
        assert_states_close(target, run.critic.critic_target.state_dict(), f"run {r} target critics")
        torch.testing.assert_close(group.log_alpha[r].detach(), run.temperature.log_alpha.detach())
        assert group.generators[r].get_state().equal(run.generator.get_state())  # the same draws, in order
    obs = torch.randn(4, OBS).numpy()
    torch.testing.assert_close(torch.as_tensor(group.act(1, obs)), torch.as_tensor(alone[1].act(obs)),
                               atol=2e-5, rtol=1e-4)


def test_every_run_gets_gradient_from_its_own_loss_only(device):
    """Run 1's batch changes nothing in run 0's step: the group's loss is a sum of per-run losses."""
    cfg = config("deterministic")
    first, second = PBRLGroup(cfg, OBS, ACT, SEEDS[:2], device), PBRLGroup(cfg, OBS, ACT, SEEDS[:2], device)
    data = torch.Generator().manual_seed(1)
    shared = batch(data)
    for _ in range(2):
        first.update(stack_batches([shared, batch(data)]))
        second.update(stack_batches([shared, batch(data)]))
    assert_states_close(first.member_actor(0).state_dict(), second.member_actor(0).state_dict(), "run 0", atol=0)
    assert not torch.equal(first.member_actor(1).net[0].weight, second.member_actor(1).net[0].weight)


def test_resumed_group_continues_bit_for_bit(device):
    cfg = config("gaussian")
    data = [batch(torch.Generator().manual_seed(i)) for i in range(6)]
    straight = PBRLGroup(cfg, OBS, ACT, SEEDS[:2], device)
    for b in data:
        straight.update(stack_batches([b, b]))
    interrupted = PBRLGroup(cfg, OBS, ACT, SEEDS[:2], device)
    for b in data[:3]:
        interrupted.update(stack_batches([b, b]))
    resumed = PBRLGroup(cfg, OBS, ACT, [5, 6], device)  # other seeds: everything comes from the state
    resumed.load_state_dict(interrupted.state_dict())
    for b in data[3:]:
        resumed.update(stack_batches([b, b]))
    for r in range(2):
        assert_states_close(resumed.member_actor(r).state_dict(), straight.member_actor(r).state_dict(), "actor",
                            atol=0)


def test_group_rejects_mixed_or_repeated_runs():
    with pytest.raises(ValueError, match="seeds"):
        PBRLGroup(config("deterministic"), OBS, ACT, [1, 1])
    with pytest.raises(ValueError, match="same layers"):
        stack_networks([torch.nn.Sequential(torch.nn.Linear(2, 3)), torch.nn.Sequential(torch.nn.Linear(2, 3),
                                                                                        torch.nn.ReLU())])


@pytest.mark.parametrize("schedule", ["constant", "cosine"])
def test_a_teacher_learning_rate_schedule_reaches_every_optimiser(schedule):
    # train_teachers.pbrl.lr_schedule: the group's actors, critics and entropy temperature (and the
    # multi-task baseline's shared actor, per-task critics, temperature) all follow it; constant
    # leaves Adam's rate as configured
    from mop_core.agents.pbrl_multitask import MultiTaskPBRL
    from mop_core.learning.schedule import scheduled_rate
    from mop_core.teachers import anneal

    cfg = config("gaussian", lr_schedule=schedule)
    agents = [PBRLGroup(cfg, OBS, ACT, SEEDS), MultiTaskPBRL(cfg, ["stand", "walk"], OBS, ACT, seed=0)]
    assert [len(a.optimizers()) for a in agents] == [3, 4]
    for step, steps in ((0, 10), (5, 10), (9, 10)):
        expected = cfg.learning_rate if schedule == "constant" else scheduled_rate(cfg.learning_rate, schedule,
                                                                                   step, steps)
        for agent in agents:
            anneal(agent, step, steps)
            assert [g["lr"] for o in agent.optimizers() for g in o.param_groups] == \
                pytest.approx([expected] * len(agent.optimizers()))
    if schedule == "cosine":  # half the rate at mid-run, ~0 at the end
        assert scheduled_rate(1.0, schedule, 5, 10) == pytest.approx(0.5) and scheduled_rate(1.0, schedule, 10, 10) == 0
