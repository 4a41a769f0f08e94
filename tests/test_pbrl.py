"""PBRL: the vectorised ensemble vs a loop, target networks, the penalty formulas, the beta_ood
schedule, gradients of every loss, seeding, the Gaussian actor and the naive multi-task baseline."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from torch import nn

from mop_core.agents.pbrl import (
    PBRL,
    PBRLConfig,
    actor_objective,
    beta_ood,
    ensemble_std,
    in_distribution_target,
    noisy,
    ood_target,
)
from mop_core.agents.pbrl_multitask import MultiTaskPBRL
from mop_core.config import ConfigError
from mop_core.data import Batch
from mop_core.learning.nn import GaussianActor, bounded_log_std, with_task_id

CONFIG = PBRLConfig(hidden_sizes=(16, 16), ensemble_size=4, batch_size=8, ood_actions=2, policy_delay=2,
                    learning_rate=1e-3)


def _batch(seed: int = 0, n: int = 8, reward: float | None = None) -> Batch:
    g = torch.Generator().manual_seed(seed)
    rewards = torch.rand(n, generator=g) if reward is None else torch.full((n,), reward)
    return Batch(torch.randn(n, 24, generator=g), torch.rand(n, 6, generator=g) * 2 - 1, rewards,
                 torch.randn(n, 24, generator=g), torch.zeros(n))


def _params(module: nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def _changed(before: list[torch.Tensor], module: nn.Module) -> bool:
    return any(not torch.equal(b, p) for b, p in zip(before, module.parameters()))


# ---- formulas -------------------------------------------------------------------------------------
def test_in_distribution_target_hand_example():
    rewards, terminals = torch.tensor([1.0, 0.0]), torch.tensor([0.0, 1.0])
    next_q = torch.tensor([[10.0, 3.0], [12.0, 5.0], [14.0, 7.0]])  # [E=3, B=2]
    # column 0: std(10, 12, 14) = 2 -> y_e = 1 + 0.9 * (Q_e - 0.5 * 2) = [9.1, 10.9, 12.7]
    # column 1: terminal -> y_e = 0
    expected = torch.tensor([[9.1, 0.0], [10.9, 0.0], [12.7, 0.0]])
    torch.testing.assert_close(in_distribution_target(rewards, terminals, next_q, 0.9, 0.5), expected)


def test_ood_target_hand_example():
    q_ood = torch.tensor([[1.0, 4.0], [3.0, 4.0], [5.0, 4.0]], requires_grad=True)  # [E=3, M=2]
    # column 0: std(1, 3, 5) = 2 (unbiased); Q - 1.5 * 2 = [-2, 0, 2] -> max(., 0) = [0, 0, 2]
    # column 1: std = 0 -> targets equal Q = 4
    target = ood_target(q_ood, 1.5)
    torch.testing.assert_close(target, torch.tensor([[0.0, 4.0], [0.0, 4.0], [2.0, 4.0]]))
    assert not target.requires_grad


def test_beta_ood_decays_exponentially_to_its_floor():
    config = PBRLConfig(beta_ood_init=3.0, beta_ood_min=0.1, beta_ood_decay=0.999)
    assert beta_ood(0, config) == 3.0
    assert beta_ood(1000, config) == pytest.approx(3.0 * 0.999 ** 1000)
    assert beta_ood(10_000, config) == 0.1
    values = [beta_ood(t, config) for t in range(0, 5000, 100)]
    assert all(a >= b for a, b in zip(values, values[1:]))


def test_bad_config_names_the_parameter():
    with pytest.raises(ConfigError, match="ensemble_size"):
        PBRLConfig(ensemble_size=1)
    with pytest.raises(ConfigError, match="beta_ood_init"):
        PBRLConfig(beta_ood_init=0.05, beta_ood_min=0.1)
    with pytest.raises(ConfigError, match="actor"):
        PBRLConfig(actor="categorical")


# ---- the vectorised ensemble equals a loop of separate critics -------------------------------------------
class LoopCritic(nn.Module):
    """E separate critics (a list of Linear MLPs), as the reference code held them."""

    def __init__(self, ensemble):
        super().__init__()
        self.members = nn.ModuleList()
        linears = [m for m in ensemble.net if hasattr(m, "weight")]
        for e in range(ensemble.ensemble_size):
            layers = []
            for i, lin in enumerate(linears):
                layer = nn.Linear(lin.in_features, lin.out_features)
                with torch.no_grad():
                    layer.weight.copy_(lin.weight[e].T)
                    layer.bias.copy_(lin.bias[e, 0])
                layers += [layer] + ([nn.ReLU()] if i < len(linears) - 1 else [])
            self.members.append(nn.Sequential(*layers))

    def forward(self, obs, act):
        x = torch.cat([obs, act], -1)
        if x.dim() == 2:
            return torch.stack([m(x).squeeze(-1) for m in self.members])
        return torch.stack([m(x[e]).squeeze(-1) for e, m in enumerate(self.members)])


def test_vectorised_critic_loss_equals_a_loop_of_critics_in_value_and_gradient():
    torch.manual_seed(0)
    agent = PBRL(CONFIG, 24, 6, seed=0)
    critic = agent.critic
    loop = LoopCritic(critic.critic)
    loop_target = LoopCritic(critic.critic_target)
    batch = _batch()

    agent.generator.manual_seed(3)
    loss, _ = critic.loss(batch, agent.policy, agent.target_policy, 2.0, agent.generator)
    loss.backward()

    # the same loss computed member by member with separate modules and the same random draws
    agent.generator.manual_seed(3)
    with torch.no_grad():
        next_action = noisy(agent.target_policy(batch.next_observations), CONFIG.target_noise, CONFIG.noise_clip,
                            agent.generator)
        next_q = loop_target(batch.next_observations, next_action)
        target = in_distribution_target(batch.rewards, batch.terminals, next_q, CONFIG.gamma, CONFIG.beta_in)
        ood_states, ood_actions = critic.ood_inputs(batch, agent.policy, agent.generator)
    q = loop(batch.observations, batch.actions)
    q_ood = loop(ood_states, ood_actions)
    y_ood = ood_target(q_ood, 2.0)
    loop_loss = sum(((q[e] - target[e]) ** 2).mean() + ((q_ood[e] - y_ood[e]) ** 2).mean()
                    for e in range(CONFIG.ensemble_size))
    loop_loss.backward()
    torch.testing.assert_close(loss, loop_loss)

    linears = [m for m in critic.critic.net if hasattr(m, "weight")]
    for e, member in enumerate(loop.members):
        member_linears = [m for m in member if isinstance(m, nn.Linear)]
        for vec, lin in zip(linears, member_linears):
            torch.testing.assert_close(vec.weight.grad[e].T, lin.weight.grad)
            torch.testing.assert_close(vec.bias.grad[e, 0], lin.bias.grad)


# ---- target networks ------------------------------------------------------------------------------
def test_bootstrap_reads_the_target_critics_and_target_actor_only():
    agent = PBRL(CONFIG, 24, 6, seed=0)
    batch = _batch()
    agent.generator.manual_seed(5)
    before = agent.critic.compute_target(batch, agent.target_policy, agent.generator)
    with torch.no_grad():  # change only the online critics and the online actor
        for p in list(agent.critic.critic.parameters()) + list(agent.actor.parameters()):
            p.add_(1.0)
    agent.generator.manual_seed(5)
    torch.testing.assert_close(agent.critic.compute_target(batch, agent.target_policy, agent.generator), before)
    with torch.no_grad():  # change the target critics: the target moves
        for p in agent.critic.critic_target.parameters():
            p.add_(0.1)
    agent.generator.manual_seed(5)
    assert not torch.allclose(agent.critic.compute_target(batch, agent.target_policy, agent.generator), before)


def test_targets_follow_by_polyak_averaging_and_actor_updates_are_delayed():
    agent = PBRL(CONFIG, 24, 6, seed=0)
    actor_before = _params(agent.actor)
    target_before = _params(agent.critic.critic_target)
    agent.update(_batch(1))
    assert not _changed(actor_before, agent.actor)  # policy_delay = 2: no actor step yet
    assert _changed(target_before, agent.critic.critic_target)
    agent.update(_batch(2))
    assert _changed(actor_before, agent.actor)
    for t, s, b in zip(agent.critic.critic_target.parameters(), agent.critic.critic.parameters(), target_before):
        assert torch.all((t - b).abs() <= (s - b).abs() + 1e-7)  # targets lag the online critics


# ---- gradients ------------------------------------------------------------------------------------
@pytest.mark.parametrize("term", ["in", "ood"])
def test_each_critic_loss_term_gives_nonzero_gradients_to_every_parameter(term):
    config = PBRLConfig(**{**CONFIG.__dict__, "ood_actions": 2})
    agent = PBRL(config, 24, 6, seed=0)
    batch = _batch()
    if term == "in":
        target = agent.critic.compute_target(batch, agent.target_policy, agent.generator)
        loss = (agent.critic.critic(batch.observations, batch.actions) - target).pow(2).mean(1).sum()
    else:  # a large beta puts the OOD targets well below the current values
        states, actions = agent.critic.ood_inputs(batch, agent.policy, agent.generator)
        q_ood = agent.critic.critic(states, actions) + 1.0
        loss = (q_ood - ood_target(q_ood, 5.0)).pow(2).mean(1).sum()
    loss.backward()
    for name, p in agent.critic.critic.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_actor_objective_is_minus_the_ensemble_minimum_and_trains_every_actor_parameter(actor):
    config = PBRLConfig(**{**CONFIG.__dict__, "actor": actor, "entropy_weight": 0.1})
    agent = PBRL(config, 24, 6, seed=0)
    batch = _batch()
    agent.generator.manual_seed(0)
    loss, metrics, _ = actor_objective(agent.actor, batch.observations, batch.observations, agent.critic,
                                       config.entropy_weight, agent.generator)
    loss.backward()
    for name, p in agent.actor.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    assert all(p.grad is None for p in agent.critic.critic.parameters())  # the actor step leaves critics alone
    with torch.no_grad():
        agent.generator.manual_seed(0)
        if actor == "gaussian":
            actions, entropy = agent.actor.rsample(batch.observations, agent.generator)
        else:
            actions, entropy = agent.actor(batch.observations), torch.zeros(8)
        q_min = agent.critic.critic(batch.observations, actions).min(0).values
        torch.testing.assert_close(loss, -(q_min + config.entropy_weight * entropy).mean())


@pytest.mark.parametrize("target,direction", [(-25.0, -1), (5.0, 1)])
def test_entropy_temperature_moves_alpha_towards_the_target_entropy(target, direction):
    config = PBRLConfig(**{**CONFIG.__dict__, "actor": "gaussian", "entropy_weight": 0.5, "target_entropy": target})
    agent = PBRL(config, 24, 6, seed=0)
    assert agent.temperature.value == pytest.approx(0.5)
    for i in range(6):  # a fresh actor's entropy (~ -6.5 nats: log sigma mid-range) is above -25 and below 5
        agent.update(_batch(i))
    assert (agent.temperature.value - 0.5) * direction > 0
    fixed = PBRL(PBRLConfig(**{**CONFIG.__dict__, "actor": "gaussian", "entropy_weight": 0.5}), 24, 6, seed=0)
    for i in range(6):
        fixed.update(_batch(i))
    assert fixed.temperature.value == 0.5


def test_log_std_is_bounded_smoothly_and_keeps_its_gradient():
    raw = torch.linspace(-20, 20, 401, requires_grad=True)
    log_std = bounded_log_std(raw, -5.0, 0.0)
    assert torch.all((log_std >= -5.0) & (log_std <= 0.0))
    assert log_std[200].item() == pytest.approx(-2.5)  # raw 0: the middle of the range
    log_std[150:251].sum().backward()  # |raw| <= 5: well inside float precision
    assert torch.all(raw.grad[150:251] > 0)  # a clamp has gradient 0 for raw > 0 here


def test_entropy_ascent_cannot_pin_the_log_std_head():
    """Pure entropy ascent (the entropy bonus with no Q term) drives sigma towards its upper bound. With a
    hard clamp the head's gradient is exactly 0 once a raw output passes the bound (2/3 of them start there),
    and sigma stays pinned whatever alpha does; the smooth bound keeps a gradient, so alpha can pull it back.
    (Gradient descent, whose steps scale with the gradient, as an entropy term weighted by alpha.)"""
    torch.manual_seed(0)
    actor = GaussianActor(24, 6, (32, 32), log_std_min=-5.0, log_std_max=0.0)
    head = actor.net[-1]
    obs = torch.randn(256, 24)

    def entropy(seed: int) -> torch.Tensor:
        return actor.rsample(obs, torch.Generator().manual_seed(seed))[1].mean()

    entropy(0).backward()
    assert torch.all(head.bias.grad[6:] != 0)  # every log-std output, at initialisation
    optimizer = torch.optim.SGD(actor.parameters(), lr=0.05)
    for step in range(2000):
        optimizer.zero_grad()
        (-entropy(step)).backward()
        optimizer.step()
    optimizer.zero_grad()
    value = entropy(0)
    value.backward()
    assert torch.all(head.bias.grad[6:] != 0)
    assert value < 6 * 0.5 * math.log(2 * math.pi * math.e)  # below the entropy at the bound, not at it
    for step in range(50):  # and the other direction works: minimising the entropy lowers it
        optimizer.zero_grad()
        entropy(step).backward()
        optimizer.step()
    assert entropy(0) < value  # (a clamp past its bound: unchanged, the gradient is 0)


def test_gaussian_actor_samples_within_bounds_with_the_closed_form_entropy():
    actor = GaussianActor(24, 6, (16,), log_std_min=-3.0, log_std_max=0.0)
    obs = torch.randn(4096, 24)
    mean, std = actor.distribution(obs)
    assert torch.all(mean.abs() <= 1) and torch.all((std >= math.exp(-3) - 1e-6) & (std <= 1 + 1e-6))
    sample, entropy = actor.rsample(obs, torch.Generator().manual_seed(0))
    assert torch.all(sample.abs() <= 1)
    expected = torch.distributions.Normal(mean, std).entropy().sum(-1)
    torch.testing.assert_close(entropy, expected)
    torch.testing.assert_close(actor(obs), mean)


# ---- seeding --------------------------------------------------------------------------------------
@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_same_seed_same_weights_other_seed_other_weights(actor, device):
    """On the test device (MOP_TEST_DEVICE: CUDA in benchmarks/gpu_check.sh), with finite losses."""
    config = PBRLConfig(**{**CONFIG.__dict__, "actor": actor})

    def run(seed: int) -> list[torch.Tensor]:
        agent = PBRL(config, 24, 6, seed=seed, device=device)
        for i in range(4):
            metrics = agent.update(_batch(i))
            assert all(math.isfinite(float(v)) for v in metrics.values())
        return _params(agent.actor) + _params(agent.critic.critic)

    a, b, c = run(0), run(0), run(1)
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    assert not all(torch.equal(x, y) for x, y in zip(a, c))


@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_state_dict_round_trip_continues_identically(actor):
    config = PBRLConfig(**{**CONFIG.__dict__, "actor": actor, "target_entropy": -6.0})
    agent = PBRL(config, 24, 6, seed=0)
    for i in range(3):
        agent.update(_batch(i))
    clone = PBRL(config, 24, 6, seed=99)
    clone.load_state_dict(agent.state_dict())
    for i in range(3, 6):
        agent.update(_batch(i))
        clone.update(_batch(i))
    assert all(torch.equal(x, y) for x, y in zip(_params(agent.actor), _params(clone.actor)))
    assert all(torch.equal(x, y) for x, y in zip(_params(agent.critic.critic), _params(clone.critic.critic)))


# ---- naive multi-task baseline ---------------------------------------------------------------------
def test_one_hot_task_ids():
    obs = torch.zeros(2, 3)
    x = with_task_id(obs, 2, 3)
    torch.testing.assert_close(x[:, 3:], torch.tensor([[0.0, 0.0, 1.0]] * 2))
    x = with_task_id(obs, torch.tensor([0, 1]), 3)
    torch.testing.assert_close(x[:, 3:], torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    with pytest.raises(ValueError, match="task_index"):
        with_task_id(obs, 3, 3)


def test_multitask_trains_the_shared_actor_and_only_the_batch_tasks_critic():
    agent = MultiTaskPBRL(CONFIG, ["stand", "walk", "run"], 24, 6, seed=0)
    actor_before = _params(agent.actor)
    for step in range(6):  # each task twice: every task makes one actor step
        task = agent.next_task
        others = {i: _params(c.critic) for i, c in enumerate(agent.critics) if i != task}
        mine = _params(agent.critics[task].critic)
        agent.update(_batch(step), task)
        assert _changed(mine, agent.critics[task].critic)
        assert all(not _changed(before, agent.critics[i].critic) for i, before in others.items())
    assert _changed(actor_before, agent.actor)
    assert agent.critic_updates == [2, 2, 2]
    # the optimiser holds the live actor's parameters (the reference code's held a stale copy)
    held = {id(p) for group in agent.actor_optimizer.param_groups for p in group["params"]}
    assert held == {id(p) for p in agent.actor.parameters()}
    with pytest.raises(ValueError, match="tasks alternate"):
        agent.update(_batch(), (agent.next_task + 1) % 3)


def test_multitask_actor_reads_the_task_id():
    agent = MultiTaskPBRL(CONFIG, ["stand", "walk"], 24, 6, seed=0)
    for step in range(20):
        agent.update(_batch(step), agent.next_task)
    obs = torch.randn(5, 24).numpy()
    assert not torch.allclose(torch.as_tensor(agent.act(obs, 0)), torch.as_tensor(agent.act(obs, 1)))


@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_multitask_gradient_cosines_are_the_cosines_of_each_tasks_actor_gradient(actor):
    config = dataclasses.replace(CONFIG, actor=actor)
    agent = MultiTaskPBRL(config, ["stand", "walk", "run"], 24, 6, seed=0)
    for step in range(6):
        agent.update(_batch(step), agent.next_task)
    batches = [_batch(10 + t) for t in range(3)]
    before = _params(agent.actor)
    cosines = agent.gradient_cosines(batches, torch.Generator().manual_seed(5))
    assert not _changed(before, agent.actor)  # measuring takes no step
    draws = torch.Generator().manual_seed(5)  # the same Gaussian samples, task by task
    grads = []
    for t, batch in enumerate(batches):
        agent.actor.zero_grad()
        loss, _, _ = actor_objective(agent.actor, batch.observations, with_task_id(batch.observations, t, 3),
                                     agent.critics[t], agent.temperature.value, draws)
        loss.backward()
        grads.append(torch.cat([p.grad.flatten() for p in agent.actor.parameters()]))
    for (i, a), (k, b) in [((0, "stand"), (1, "walk")), ((0, "stand"), (2, "run")), ((1, "walk"), (2, "run"))]:
        expected = float(torch.nn.functional.cosine_similarity(grads[i], grads[k], dim=0))
        assert cosines[f"grad_cosine_{a}-{b}"] == pytest.approx(expected, abs=1e-5)
    assert cosines["grad_cosine"] == pytest.approx(sum(v for k, v in cosines.items() if k != "grad_cosine") / 3)


# ---- what the fast paths must equal -------------------------------------------------------------
def test_ensemble_std_equals_torch_std():
    q = torch.randn(5, 300) * 10 + 3
    torch.testing.assert_close(ensemble_std(q), q.std(dim=0))


@pytest.mark.parametrize("actor", ["deterministic", "gaussian"])
def test_ood_actions_equal_the_policy_run_on_every_repeated_state(actor):
    config = PBRLConfig(**{**CONFIG.__dict__, "actor": actor, "ood_actions": 3})
    agent = PBRL(config, 24, 6, seed=0)
    batch = _batch()
    agent.generator.manual_seed(4)
    states, actions = agent.critic.ood_inputs(batch, agent.policy, agent.generator)
    # the straightforward computation: repeat the states, then run the policy on every copy
    agent.generator.manual_seed(4)
    repeated = torch.cat([batch.observations, batch.next_observations]).repeat_interleave(3, dim=0)
    with torch.no_grad():
        expected = noisy(agent.policy(repeated), config.ood_noise, config.noise_clip, agent.generator)
    torch.testing.assert_close(states, repeated)
    torch.testing.assert_close(actions, expected)
    if actor == "gaussian":  # the copies of a state are independent samples, not one sample repeated
        assert not torch.allclose(actions[0], actions[1], atol=1e-3)


def test_critic_step_reports_its_metrics_as_tensors_without_reading_them():
    agent = PBRL(CONFIG, 24, 6, seed=0)
    metrics = agent.update(_batch())
    assert {"critic_loss_in", "critic_loss_ood", "q_mean", "target_mean", "q_std", "q_ood_std"} <= set(metrics)
    assert all(isinstance(metrics[k], torch.Tensor) and metrics[k].dim() == 0 for k in metrics if k != "beta_ood")
    assert all(math.isfinite(float(v)) for v in metrics.values())
