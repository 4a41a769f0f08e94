"""The vectorised ensemble layer equals a loop of independent linear layers."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from mop_core.learning.nn import (
    EnsembleCritic,
    EnsembleLayerNorm,
    EnsembleLinear,
    _BatchedReLUMLP,
    _EnsembleReLUMLP,
    adam,
    copy_member,
    ensemble_forward,
    mlp,
    per_member_forward,
    stack_networks,
)


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
    critic.member_loop_work = 10**18
    batched = critic(obs, act)
    batched.square().sum().backward()
    grads = {n: p.grad.clone() for n, p in critic.named_parameters()}
    critic.zero_grad()
    critic.member_loop_work = 1
    looped = critic(obs, act)
    looped.square().sum().backward()
    torch.testing.assert_close(looped, batched)
    for n, p in critic.named_parameters():
        torch.testing.assert_close(p.grad, grads[n], msg=n)


# ---- the hand-written member-by-member pass and the fused optimiser ----------------------------
def _relu_ensemble(width: int = 6, members: int = 3, depth: int = 2, dtype=torch.float64) -> nn.Sequential:
    torch.manual_seed(1)
    return mlp(5, [width] * depth, 2, ensemble_size=members).to(dtype)


@pytest.mark.parametrize("depth", [1, 2, 3])
def test_hand_written_member_pass_passes_gradcheck_in_weights_and_inputs(depth):
    net = _relu_ensemble(depth=depth)
    linears = [m for m in net if isinstance(m, EnsembleLinear)]
    x = torch.randn(11, 5, dtype=torch.float64, requires_grad=True)
    params = [lin.weight for lin in linears] + [lin.bias for lin in linears]
    assert torch.autograd.gradcheck(lambda x_, *p: _EnsembleReLUMLP.apply(x_, *p), (x, *params))


@pytest.mark.parametrize("depth", [1, 2])
def test_hand_written_member_pass_with_one_input_per_member_passes_gradcheck(depth):
    """A group of runs: member e reads its own batch x[e] (mop_core.distill.student.StudentGroup)."""
    net = _relu_ensemble(depth=depth)
    linears = [m for m in net if isinstance(m, EnsembleLinear)]
    x = torch.randn(3, 7, 5, dtype=torch.float64, requires_grad=True)
    params = [lin.weight for lin in linears] + [lin.bias for lin in linears]
    assert torch.autograd.gradcheck(lambda x_, *p: _EnsembleReLUMLP.apply(x_, *p), (x, *params))
    torch.testing.assert_close(per_member_forward(net, x), net(x))


def test_hand_written_member_pass_equals_autograd_through_plain_layers():
    net = _relu_ensemble(width=32, members=4, dtype=torch.float32)
    x = torch.randn(300, 5, requires_grad=True)
    fast = per_member_forward(net, x)
    assert fast.grad_fn.name() == "_EnsembleReLUMLPBackward"
    weight = torch.randn_like(fast)
    (fast * weight).sum().backward()
    fast_grads = [p.grad.clone() for p in net.parameters()] + [x.grad.clone()]
    net.zero_grad()
    x.grad = None
    plain = net(x.unsqueeze(0).expand(4, -1, -1))  # autograd through EnsembleLinear and nn.ReLU
    torch.testing.assert_close(fast, plain)
    (plain * weight).sum().backward()
    for got, expected in zip(fast_grads, [p.grad for p in net.parameters()] + [x.grad]):
        torch.testing.assert_close(got, expected)


def test_hand_written_member_pass_gives_input_gradients_through_frozen_weights():
    net = _relu_ensemble(dtype=torch.float32).requires_grad_(False)
    x = torch.randn(20, 5, requires_grad=True)
    per_member_forward(net, x).sum().backward()
    x_fast = x.grad.clone()
    x.grad = None
    net(x.unsqueeze(0).expand(3, -1, -1)).sum().backward()
    torch.testing.assert_close(x_fast, x.grad)
    assert all(p.grad is None for p in net.parameters())


@pytest.mark.parametrize("shared", [True, False])
def test_batched_hand_written_pass_passes_gradcheck(shared):
    net = _relu_ensemble(depth=2)
    linears = [m for m in net if isinstance(m, EnsembleLinear)]
    x = torch.randn(*(() if shared else (3,)), 7, 5, dtype=torch.float64, requires_grad=True)
    params = [lin.weight for lin in linears] + [lin.bias for lin in linears]
    assert torch.autograd.gradcheck(lambda x_, *p: _BatchedReLUMLP.apply(x_, *p), (x, *params))


@pytest.mark.parametrize("frozen", [False, True])
def test_batched_hand_written_pass_equals_autograd_through_plain_layers(frozen):
    net = _relu_ensemble(width=32, members=4, dtype=torch.float32).requires_grad_(not frozen)
    x = torch.randn(4, 300, 5, requires_grad=True)
    fast = ensemble_forward(net, x, member_by_member=False)
    assert fast.grad_fn.name() == "_BatchedReLUMLPBackward"
    weight = torch.randn_like(fast)
    (fast * weight).sum().backward()
    fast_grads = [] if frozen else [p.grad.clone() for p in net.parameters()]
    fast_x = x.grad.clone()
    net.zero_grad()
    x.grad = None
    plain = net(x)  # autograd through EnsembleLinear and nn.ReLU
    torch.testing.assert_close(fast, plain)
    (plain * weight).sum().backward()
    torch.testing.assert_close(fast_x, x.grad)
    for got, expected in zip(fast_grads, [p.grad for p in net.parameters()]):
        torch.testing.assert_close(got, expected)
    if frozen:
        assert all(p.grad is None for p in net.parameters())


@pytest.mark.parametrize("layer_norm", [False, True])
def test_stacked_networks_compute_what_each_network_computes(layer_norm):
    nets = []
    for seed in range(3):
        torch.manual_seed(seed)
        nets.append(mlp(5, [8, 8], 2, layer_norm))
    group = stack_networks(nets)
    x = torch.randn(3, 10, 5)
    out = ensemble_forward(group, x, member_by_member=False)
    for r, net in enumerate(nets):
        torch.testing.assert_close(out[r], net(x[r]))
        back = copy_member(group, r, mlp(5, [8, 8], 2, layer_norm))
        for got, expected in zip(back.state_dict().values(), net.state_dict().values(), strict=True):
            torch.testing.assert_close(got, expected)


def test_layer_norm_ensembles_take_the_generic_member_loop():
    torch.manual_seed(0)
    critic = EnsembleCritic(24, 6, [16, 16], ensemble_size=2, layer_norm=True)
    assert per_member_forward(critic.net, torch.randn(3, 30)).grad_fn.name() != "_EnsembleReLUMLPBackward"


def test_work_decides_between_the_member_loop_and_one_batched_matmul():
    critic = EnsembleCritic(24, 6, [256, 256], ensemble_size=5)
    cpu = torch.device("cpu")
    assert critic.member_by_member(1024, cpu) and not critic.member_by_member(256, cpu)
    assert not critic.member_by_member(10**6, torch.device("meta"))  # other devices: always batched


def test_fused_adam_takes_the_same_steps_as_the_default_adam():
    torch.manual_seed(0)
    a = mlp(8, [32, 32], 3)
    b = mlp(8, [32, 32], 3)
    b.load_state_dict(a.state_dict())
    fused, default = adam(a.parameters(), 1e-3), torch.optim.Adam(b.parameters(), lr=1e-3)
    for step in range(50):
        x = torch.randn(16, 8, generator=torch.Generator().manual_seed(step))
        for net, opt in ((a, fused), (b, default)):
            opt.zero_grad()
            net(x).pow(2).mean().backward()
            opt.step()
    for p, q in zip(a.parameters(), b.parameters()):
        torch.testing.assert_close(p, q, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("layer_norm", [False, True])
def test_first_member_alone_equals_the_first_row_of_the_ensemble(layer_norm):
    torch.manual_seed(0)
    critic = EnsembleCritic(24, 6, [16, 16], ensemble_size=3, layer_norm=layer_norm)
    obs, act = torch.randn(40, 24), torch.randn(40, 6, requires_grad=True)
    alone = critic.first(obs, act)
    alone.sum().backward()
    grads = [act.grad.clone()] + [p.grad.clone() for p in critic.parameters()]
    act.grad = None
    critic.zero_grad()
    full = critic(obs, act)[0]
    full.sum().backward()
    torch.testing.assert_close(alone, full)
    for got, expected in zip(grads, [act.grad] + [p.grad for p in critic.parameters()]):
        torch.testing.assert_close(got, expected)
