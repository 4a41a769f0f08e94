"""The vectorised ensemble layer equals a loop of independent linear layers."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from mop_core.nn import EnsembleCritic, EnsembleLayerNorm, EnsembleLinear, mlp


def test_ensemble_linear_equals_loop_in_outputs_and_gradients():
    torch.manual_seed(0)
    E, B, i, o = 5, 7, 4, 3
    ens = EnsembleLinear(E, i, o)
    loop = [nn.Linear(i, o) for _ in range(E)]
    with torch.no_grad():
        for e, lin in enumerate(loop):
            lin.weight.copy_(ens.weight[e].T)
            lin.bias.copy_(ens.bias[e, 0])
    x = torch.randn(E, B, i)
    y_ens = ens(x)
    y_loop = torch.stack([lin(x[e]) for e, lin in enumerate(loop)])
    torch.testing.assert_close(y_ens, y_loop)
    target = torch.randn(E, B, o)
    (y_ens - target).pow(2).sum().backward()
    (y_loop - target).pow(2).sum().backward()
    for e, lin in enumerate(loop):
        torch.testing.assert_close(ens.weight.grad[e], lin.weight.grad.T)
        torch.testing.assert_close(ens.bias.grad[e, 0], lin.bias.grad)


def test_ensemble_members_are_independent():
    torch.manual_seed(1)
    net = mlp(5, [8, 8], 1, ensemble_size=3)
    x = torch.randn(3, 4, 5)
    net(x)[1].sum().backward()
    grads = [p.grad for p in net.parameters()]
    assert all(g[0].abs().sum() == 0 and g[2].abs().sum() == 0 and g[1].abs().sum() > 0 for g in grads)


def test_ensemble_layer_norm_equals_per_member_layer_norm():
    torch.manual_seed(2)
    ln = EnsembleLayerNorm(3, 6)
    with torch.no_grad():
        ln.weight.normal_(), ln.bias.normal_()
    x = torch.randn(3, 4, 6)
    for e in range(3):
        ref = nn.functional.layer_norm(x[e], (6,), ln.weight[e, 0], ln.bias[e, 0])
        torch.testing.assert_close(ln(x)[e], ref)


def test_critic_broadcasts_one_batch_to_all_members():
    critic = EnsembleCritic(24, 6, [16, 16], ensemble_size=4, layer_norm=True)
    q = critic(torch.randn(9, 24), torch.randn(9, 6))
    assert q.shape == (4, 9)
    assert not torch.allclose(q[0], q[1])  # members are initialised independently


@pytest.mark.parametrize("layer_norm", [False, True])
def test_member_by_member_path_equals_the_batched_path_in_outputs_and_gradients(layer_norm):
    torch.manual_seed(0)
    critic = EnsembleCritic(24, 6, [16, 16], ensemble_size=4, layer_norm=layer_norm)
    obs, act = torch.randn(50, 24), torch.randn(50, 6)
    critic.member_loop_rows = 10**9
    batched = critic(obs, act)
    batched.square().sum().backward()
    grads = {n: p.grad.clone() for n, p in critic.named_parameters()}
    critic.zero_grad()
    critic.member_loop_rows = 1
    looped = critic(obs, act)
    looped.square().sum().backward()
    torch.testing.assert_close(looped, batched)
    for n, p in critic.named_parameters():
        torch.testing.assert_close(p.grad, grads[n], msg=n)
