"""A group of R naive multi-task baselines equals the R baselines trained alone."""

from __future__ import annotations

import pytest
import torch
from test_pbrl_group import ACT, OBS, assert_states_close, batch, config

from mop_core.agents.pbrl_group import stack_batches
from mop_core.agents.pbrl_multitask import MultiTaskPBRL
from mop_core.agents.pbrl_multitask_group import MultiTaskPBRLGroup

SEEDS = [3, 7]
TASKS = ("stand", "walk", "run")


def close(found, expected, what: str) -> None:
    torch.testing.assert_close(torch.as_tensor(found).float().cpu(), torch.as_tensor(expected).float().cpu(),
                               atol=1e-4, rtol=1e-4, msg=lambda m: f"{what}: {m}")


@pytest.mark.parametrize("actor,overrides", [("deterministic", {}), ("gaussian", {}),
                                             ("deterministic", {"layer_norm": True, "ood_actions": 0})])
def test_multitask_group_equals_runs_trained_alone(actor, overrides, device):
    cfg = config(actor, **overrides)
    alone = [MultiTaskPBRL(cfg, TASKS, OBS, ACT, seed, device) for seed in SEEDS]
    group = MultiTaskPBRLGroup(cfg, TASKS, OBS, ACT, SEEDS, device)
    data = torch.Generator().manual_seed(0)
    for step in range(2 * len(TASKS) * cfg.policy_delay):  # every task's critic and two actor steps of each
        task = group.next_task
        batches = [batch(data) for _ in SEEDS]
        expected = [run.update(b, task) for run, b in zip(alone, batches)]
        found = group.update(stack_batches(batches), task)
        assert found["beta_ood"] == expected[0]["beta_ood"]
        for r, metrics in enumerate(expected):
            assert {k for k in found if k.endswith(f"@{r}")} == {f"{k}@{r}" for k in metrics if k != "beta_ood"}
            for key, value in metrics.items():
                if key != "beta_ood":
                    close(found[f"{key}@{r}"], value, f"step {step} run {r} {key}")
    for r, run in enumerate(alone):
        assert_states_close(group.member_actor(r).state_dict(), run.actor.state_dict(), f"run {r} actor")
        for i, critic in enumerate(run.critics):
            assert_states_close(group.member_critic_state(r, i), critic.critic.state_dict(), f"run {r} task {i}")
        close(group.log_alpha[r].detach(), run.temperature.log_alpha.detach(), f"run {r} alpha")
        assert group.generators[r].get_state().equal(run.generator.get_state())  # the same draws, in order
    obs = torch.randn(4, OBS).numpy()
    close(group.act(1, obs, task=2), alone[1].act(obs, 2), "act")
    # the gradient conflict of each run as the run alone measures it
    draws = torch.Generator().manual_seed(5)
    batches = [[batch(draws) for _ in TASKS] for _ in SEEDS]
    generators = [torch.Generator(device).manual_seed(9 + r) for r in range(len(SEEDS))]
    found = group.gradient_cosines([stack_batches([b[i] for b in batches]) for i in range(len(TASKS))], generators)
    for r, run in enumerate(alone):
        expected = run.gradient_cosines(batches[r], torch.Generator(device).manual_seed(9 + r))
        assert found[r].keys() == expected.keys() and len(expected) == 4
        for key in expected:
            assert found[r][key] == pytest.approx(expected[key], abs=1e-4), f"run {r} {key}"


def test_multitask_group_resumes_bit_for_bit_and_refuses_out_of_turn_tasks(device):
    cfg = config("gaussian")
    data = [batch(torch.Generator().manual_seed(i)) for i in range(7)]
    straight = MultiTaskPBRLGroup(cfg, TASKS, OBS, ACT, SEEDS, device)
    for b in data:
        straight.update(stack_batches([b, b]), straight.next_task)
    interrupted = MultiTaskPBRLGroup(cfg, TASKS, OBS, ACT, SEEDS, device)
    for b in data[:4]:
        interrupted.update(stack_batches([b, b]), interrupted.next_task)
    resumed = MultiTaskPBRLGroup(cfg, TASKS, OBS, ACT, [5, 6], device)  # other seeds: all comes from the state
    resumed.load_state_dict(interrupted.state_dict())
    for b in data[4:]:
        resumed.update(stack_batches([b, b]), resumed.next_task)
    for r in range(2):
        assert_states_close(resumed.member_actor(r).state_dict(), straight.member_actor(r).state_dict(), "actor",
                            atol=0)
        for i in range(len(TASKS)):
            assert_states_close(resumed.member_critic_state(r, i), straight.member_critic_state(r, i), "critic", atol=0)
    with pytest.raises(ValueError, match="task: expected 1"):
        resumed.update(stack_batches([data[0], data[0]]), 2)
    with pytest.raises(ValueError, match="seeds"):
        MultiTaskPBRLGroup(cfg, TASKS, OBS, ACT, [1, 1])
