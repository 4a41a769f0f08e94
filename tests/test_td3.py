"""TD3: the target formula, target networks, delayed actor updates, gradients and seeding."""

from __future__ import annotations

import torch

from mop_core.agents.td3 import TD3, TD3Config, td3_target
from mop_core.data import Batch
from mop_core.learning.nn import smoothed_target_action

CONFIG = TD3Config(hidden_sizes=(16, 16), batch_size=8, policy_delay=2)


def _batch(seed: int = 0, n: int = 8) -> Batch:
    g = torch.Generator().manual_seed(seed)
    return Batch(torch.randn(n, 24, generator=g), torch.rand(n, 6, generator=g) * 2 - 1,
                 torch.rand(n, generator=g), torch.randn(n, 24, generator=g), torch.zeros(n))


def test_target_formula_hand_example():
    rewards = torch.tensor([1.0, 0.5])
    terminals = torch.tensor([0.0, 1.0])
    next_q = torch.tensor([[10.0, 4.0], [8.0, 6.0]])  # [critic, batch]
    # y0 = 1 + 0.9 * min(10, 8) = 8.2 ; y1 = 0.5 (terminal: no bootstrap)
    torch.testing.assert_close(td3_target(rewards, terminals, next_q, 0.9), torch.tensor([8.2, 0.5]))


def test_smoothed_target_action_clips_noise_then_action():
    action = torch.tensor([0.9, -0.2, 0.0])
    noise = torch.tensor([0.4, -0.9, 0.1])
    # noise clipped to +-0.5: [0.4, -0.5, 0.1]; sums [1.3, -0.7, 0.1]; action clip -> [1.0, -0.7, 0.1]
    torch.testing.assert_close(smoothed_target_action(action, noise, 0.5), torch.tensor([1.0, -0.7, 0.1]))


def test_target_reads_target_networks_only():
    agent = TD3(CONFIG, 24, 6, seed=0)
    batch = _batch()
    agent.generator.manual_seed(5)
    before = agent.compute_target(batch)
    with torch.no_grad():  # change only the online networks
        for p in list(agent.critic.parameters()) + list(agent.actor.parameters()):
            p.add_(1.0)
    agent.generator.manual_seed(5)
    torch.testing.assert_close(agent.compute_target(batch), before)
    with torch.no_grad():  # changing the target critic changes the target
        for p in agent.critic_target.parameters():
            p.add_(0.1)
    agent.generator.manual_seed(5)
    assert not torch.allclose(agent.compute_target(batch), before)


def test_actor_and_targets_update_every_policy_delay_steps():
    agent = TD3(CONFIG, 24, 6, seed=0)
    actor0 = [p.clone() for p in agent.actor.parameters()]
    target0 = [p.clone() for p in agent.critic_target.parameters()]
    first = agent.update(_batch(1))
    assert "actor_loss" not in first
    assert all(torch.equal(a, b) for a, b in zip(actor0, agent.actor.parameters()))
    assert all(torch.equal(a, b) for a, b in zip(target0, agent.critic_target.parameters()))
    second = agent.update(_batch(2))
    assert "actor_loss" in second
    assert not all(torch.equal(a, b) for a, b in zip(actor0, agent.actor.parameters()))
    assert not all(torch.equal(a, b) for a, b in zip(target0, agent.critic_target.parameters()))


def test_losses_give_nonzero_gradients_to_every_parameter():
    agent = TD3(TD3Config(hidden_sizes=(16, 16), layer_norm=True), 24, 6, seed=0)
    batch = _batch(3)
    target = agent.compute_target(batch)
    critic_loss = (agent.critic(batch.observations, batch.actions) - target).pow(2).mean(1).sum()
    critic_loss.backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in agent.critic.parameters())
    actor_loss = -agent.critic(batch.observations, agent.actor(batch.observations))[0].mean()
    actor_loss.backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in agent.actor.parameters())


def test_same_seed_same_learning(device):
    """On the test device (MOP_TEST_DEVICE: CUDA in benchmarks/gpu_check.sh)."""
    runs = []
    for _ in range(2):
        agent = TD3(CONFIG, 24, 6, seed=11, device=device)
        for i in range(4):
            agent.update(_batch(i))
        runs.append(torch.cat([p.flatten() for p in agent.actor.parameters()]))
    torch.testing.assert_close(runs[0], runs[1], rtol=0, atol=0)
    other = TD3(CONFIG, 24, 6, seed=12, device=device)
    assert not torch.equal(runs[0][:10], torch.cat([p.flatten() for p in other.actor.parameters()])[:10])
