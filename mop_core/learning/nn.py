"""Networks: MLPs, the vectorised ensemble linear layer, actors and ensemble critics.

:class:`EnsembleLinear` holds E independent linear layers as one weight ``[E, in, out]`` and one
bias ``[E, 1, out]``; ``y_e = x_e W_e + b_e`` for every member in one batched matmul, so an
ensemble of critics is one module with one loss, one backward and one optimiser step (as in
CORL's ``VectorizedLinear``). TD3's twin critics are an ensemble of two; PBRL's critics an ensemble
of E. Each member is initialised like ``torch.nn.Linear``.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F


class EnsembleLinear(nn.Module):
    """E independent affine maps applied to inputs ``[E, B, in]`` -> ``[E, B, out]``."""

    def __init__(self, ensemble_size: int, in_features: int, out_features: int):
        super().__init__()
        self.ensemble_size, self.in_features, self.out_features = ensemble_size, in_features, out_features
        self.weight = nn.Parameter(torch.empty(ensemble_size, in_features, out_features))
        self.bias = nn.Parameter(torch.empty(ensemble_size, 1, out_features))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        # torch.nn.Linear's init per member: U(-1/sqrt(in), 1/sqrt(in)) for weight and bias.
        bound = 1.0 / math.sqrt(self.in_features)
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.baddbmm(self.bias, x, self.weight)

    def extra_repr(self) -> str:
        return f"ensemble_size={self.ensemble_size}, in_features={self.in_features}, out_features={self.out_features}"


class EnsembleLayerNorm(nn.Module):
    """LayerNorm over the last dimension with a separate affine transform per ensemble member."""

    def __init__(self, ensemble_size: int, features: int, eps: float = 1e-5):
        super().__init__()
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(ensemble_size, 1, features))
        self.bias = nn.Parameter(torch.zeros(ensemble_size, 1, features))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.layer_norm(x, x.shape[-1:], eps=self.eps) * self.weight + self.bias


ACTOR_TYPES = ("deterministic", "gaussian")  # a policy network's head: an action, or a Gaussian over actions


def mlp(in_features: int, hidden_sizes: Sequence[int], out_features: int, layer_norm: bool = False,
        ensemble_size: int | None = None) -> nn.Sequential:
    """Fully connected ReLU network; optionally an ensemble of E such networks.

    With ``layer_norm`` the first hidden layer is Linear -> LayerNorm -> tanh (the trunk of the
    reference TD3/DrQ-v2 code), the remaining hidden layers Linear -> ReLU.
    """
    if not hidden_sizes:
        raise ValueError("hidden_sizes: expected at least one hidden layer")

    def linear(i: int, o: int) -> nn.Module:
        return nn.Linear(i, o) if ensemble_size is None else EnsembleLinear(ensemble_size, i, o)

    layers: list[nn.Module] = []
    sizes = [in_features, *hidden_sizes]
    for index, (i, o) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(linear(i, o))
        if index == 0 and layer_norm:
            layers.append(nn.LayerNorm(o) if ensemble_size is None else EnsembleLayerNorm(ensemble_size, o))
            layers.append(nn.Tanh())
        else:
            layers.append(nn.ReLU())
    layers.append(linear(sizes[-1], out_features))
    return nn.Sequential(*layers)


def stack_networks(nets: Sequence[nn.Sequential]) -> nn.Sequential:
    """R plain networks of one :func:`mlp` architecture as one ensemble network with R members: member r
    computes exactly what ``nets[r]`` computes (``nn.Linear`` weight ``[out, in]`` -> row r of an
    :class:`EnsembleLinear` ``[R, in, out]``; ``nn.LayerNorm`` -> :class:`EnsembleLayerNorm`). Runs of a
    group (:class:`mop_core.distill.student.StudentGroup`, :class:`mop_core.agents.pbrl_group.PBRLGroup`)
    train as one model this way."""
    if not nets:
        raise ValueError("nets: a group needs at least one network")
    kinds = [type(layer) for layer in nets[0]]
    if any([type(layer) for layer in net] != kinds for net in nets):
        raise ValueError("nets: every network of a group must have the same layers")
    linears = [layer for layer in nets[0] if isinstance(layer, nn.Linear)]
    sizes = [layer.in_features for layer in linears] + [linears[-1].out_features]
    layer_norm = any(k is nn.LayerNorm for k in kinds)
    group = mlp(sizes[0], sizes[1:-1], sizes[-1], layer_norm, ensemble_size=len(nets)).to(linears[0].weight.device)
    if [type(layer) for layer in group] != [{nn.Linear: EnsembleLinear, nn.LayerNorm: EnsembleLayerNorm}.get(k, k)
                                            for k in kinds]:
        raise ValueError("nets: expected networks built by mop_core.learning.nn.mlp")
    with torch.no_grad():
        for index, layer in enumerate(group):
            if isinstance(layer, EnsembleLinear):
                layer.weight.copy_(torch.stack([net[index].weight.t() for net in nets]))
                layer.bias.copy_(torch.stack([net[index].bias.unsqueeze(0) for net in nets]))
            elif isinstance(layer, EnsembleLayerNorm):
                layer.weight.copy_(torch.stack([net[index].weight.unsqueeze(0) for net in nets]))
                layer.bias.copy_(torch.stack([net[index].bias.unsqueeze(0) for net in nets]))
    return group


@torch.no_grad()
def copy_member(group: nn.Sequential, member: int, net: nn.Sequential) -> nn.Sequential:
    """Write member ``member`` of an ensemble network into the plain network ``net`` (the inverse of
    :func:`stack_networks`); returns ``net``."""
    for layer, plain in zip(group, net, strict=True):
        if isinstance(layer, EnsembleLinear):
            plain.weight.copy_(layer.weight[member].t())
            plain.bias.copy_(layer.bias[member, 0])
        elif isinstance(layer, EnsembleLayerNorm):
            plain.weight.copy_(layer.weight[member, 0])
            plain.bias.copy_(layer.bias[member, 0])
    return net


class DeterministicActor(nn.Module):
    """a = tanh(f(s)): a deterministic policy with actions in [-1, 1]."""

    def __init__(self, obs_dim: int, act_dim: int, hidden_sizes: Sequence[int], layer_norm: bool = False):
        super().__init__()
        self.net = mlp(obs_dim, hidden_sizes, act_dim, layer_norm)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.net(obs))


def bounded_log_std(raw: torch.Tensor, low: float, high: float) -> torch.Tensor:
    """``low + (high - low) (tanh(raw) + 1) / 2``: log sigma in (low, high) with a non-zero gradient
    everywhere (``d/draw = (high - low) (1 - tanh(raw)^2) / 2``), unlike ``raw.clamp(low, high)``."""
    return low + 0.5 * (high - low) * (torch.tanh(raw) + 1.0)


class GaussianActor(nn.Module):
    """A diagonal Gaussian policy N(mu(s), diag(sigma(s)^2)) over actions (thesis 5.1.3).

    ``mu = tanh(f_mu(s))`` stays in [-1, 1]; ``log sigma`` is a second head bounded *smoothly*,
    ``log sigma = min + (max - min) (tanh(x) + 1) / 2`` (:func:`bounded_log_std`, as CleanRL's SAC
    and the thesis's reference code do). A hard clamp has zero gradient outside its range: with an
    entropy bonus the raw output drifts past the upper bound and sigma stays pinned there (measured:
    entropy 8.51 nats, sigma = 1 on every dimension, for half of a teacher's training).
    ``forward`` returns the mean (the deterministic action);
    :meth:`rsample` a reparameterised sample ``clip(mu + sigma * eps, -1, 1)`` and the entropy
    ``H = sum_k 0.5 * log(2 pi e sigma_k^2)`` of the (unclipped) Gaussian.
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden_sizes: Sequence[int], layer_norm: bool = False,
                 log_std_min: float = -5.0, log_std_max: float = 0.0):
        super().__init__()
        self.act_dim, self.log_std_min, self.log_std_max = act_dim, log_std_min, log_std_max
        self.net = mlp(obs_dim, hidden_sizes, 2 * act_dim, layer_norm)

    def distribution(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mu, sigma), each ``[B, act]``."""
        mean, raw_log_std = self.net(obs).split(self.act_dim, dim=-1)
        return torch.tanh(mean), bounded_log_std(raw_log_std, self.log_std_min, self.log_std_max).exp()

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.distribution(obs)[0]

    def rsample(self, obs: torch.Tensor, generator: torch.Generator | None = None, repeats: int = 1
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """``repeats`` independent samples per state, rows in ``repeat_interleave`` order, with the
        network run once per state: the same draws as sampling ``obs.repeat_interleave(repeats, 0)``
        (tested). The entropy is per state, ``[B]``."""
        mean, std = self.distribution(obs)
        entropy = (0.5 * math.log(2 * math.pi * math.e) + std.log()).sum(-1)
        if repeats > 1:
            mean, std = mean.repeat_interleave(repeats, dim=0), std.repeat_interleave(repeats, dim=0)
        eps = torch.randn(mean.shape, generator=generator, device=mean.device)
        return (mean + std * eps).clamp(-1.0, 1.0), entropy


def with_task_id(obs: torch.Tensor, task_index: int | torch.Tensor, num_tasks: int) -> torch.Tensor:
    """``[B, obs] -> [B, obs + num_tasks]``: the state with a one-hot task id appended.

    ``task_index`` is one task for the whole batch (int) or one per row (long tensor ``[B]``).
    One-hot, not a scalar id: a scalar orders the tasks and only separates two of them.
    """
    if isinstance(task_index, int):
        if not 0 <= task_index < num_tasks:
            raise ValueError(f"task_index: expected 0 <= index < {num_tasks}, got {task_index}")
        task_index = torch.full(obs.shape[:-1], task_index, dtype=torch.long, device=obs.device)
    return torch.cat([obs, F.one_hot(task_index, num_tasks).to(obs.dtype)], dim=-1)


class _EnsembleReLUMLP(torch.autograd.Function):
    """E ReLU networks on one shared input ``x [B, in]`` (or one input per member, ``x [E, B, in]``),
    member by member, with a hand-written backward.

    Forward: for each member e, ``h_0 = x`` (or ``x[e]``), ``h_k = relu(h_{k-1} W_k[e] + b_k[e])`` (the ReLU in
    place on the product), output ``h_{L-1} W_L[e] + b_L[e]``. Backward, from ``g = dL/dout[e]``,
    for k = L..1: ``dW_k[e] = h_{k-1}^T g``, ``db_k[e] = sum_rows g``, then ``g <- g W_k[e]^T``
    masked to zero where ``h_{k-1} = 0`` (the ReLU's derivative), the mask applied in place on ``g``.

    The same values and gradients as autograd through plain layers (tested, and with
    ``torch.autograd.gradcheck``), but each activation gradient is one buffer written once, where
    autograd allocates a second buffer for every ReLU's backward, and the members' weight gradients
    are written straight into one ``[E, in, out]`` buffer. First-order gradients only.
    """

    @staticmethod
    def forward(ctx, x: torch.Tensor, *params: torch.Tensor) -> torch.Tensor:
        layers = len(params) // 2
        weights, biases = params[:layers], params[layers:]
        outputs, saved = [], []
        for e in range(weights[0].shape[0]):
            h = x if x.dim() == 2 else x[e]
            for k in range(layers):
                h = torch.addmm(biases[k][e], h, weights[k][e])
                if k < layers - 1:
                    h = h.relu_()
                    saved.append(h)
            outputs.append(h)
        ctx.layers = layers
        ctx.save_for_backward(x, *weights, *saved)
        return torch.stack(outputs)

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        x, *rest = ctx.saved_tensors
        layers = ctx.layers
        weights, saved = rest[:layers], rest[layers:]
        members = weights[0].shape[0]
        need_x = ctx.needs_input_grad[0]
        need_w = ctx.needs_input_grad[1]  # weights and biases are trained (or frozen) together
        grad_w = [torch.empty_like(w) for w in weights] if need_w else None
        grad_b = [w.new_empty(members, 1, w.shape[-1]) for w in weights] if need_w else None
        grad_x = torch.zeros_like(x) if need_x else None
        for e in range(members):
            hidden = saved[e * (layers - 1):(e + 1) * (layers - 1)]
            x_e = x if x.dim() == 2 else x[e]
            grad_x_e = grad_x if grad_x is None or x.dim() == 2 else grad_x[e]
            g = grad_out[e]
            rows = _rows_with_gradient(g)
            if rows is not None:
                g = g.index_select(0, rows)
            for k in range(layers - 1, -1, -1):
                below = hidden[k - 1] if k > 0 else x_e
                if rows is not None:
                    below = below.index_select(0, rows)
                if need_w:
                    torch.mm(below.t(), g, out=grad_w[k][e])
                    torch.sum(g, dim=0, keepdim=True, out=grad_b[k][e])
                if k > 0:
                    g = torch.mm(g, weights[k][e].t())
                    torch.ops.aten.threshold_backward.grad_input(g, below, 0.0, grad_input=g)
                elif need_x and rows is None:
                    grad_x_e.addmm_(g, weights[0][e].t())
                elif need_x:
                    grad_x_e.index_add_(0, rows, torch.mm(g, weights[0][e].t()))
        return (grad_x, *(grad_w if need_w else [None] * layers), *(grad_b if need_w else [None] * layers))


class _BatchedReLUMLP(torch.autograd.Function):
    """The batched twin of :class:`_EnsembleReLUMLP`: E ReLU networks as one ``baddbmm`` per layer on
    ``x [B, in]`` (shared) or ``x [E, B, in]``, with the same hand-written backward (each ReLU in place
    on its product, each activation gradient masked in place, no weight gradients when the weights
    are frozen). Autograd through ``nn.Sequential`` allocates a new buffer for every ReLU and every
    ReLU backward: at the PBRL groups' sizes (20 critics x 768 rows x 128) those element-wise passes
    cost as much as the matrix products (benchmarks/bench_pbrl.py)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, *params: torch.Tensor) -> torch.Tensor:
        layers = len(params) // 2
        weights, biases = params[:layers], params[layers:]
        h = x if x.dim() == 3 else x.unsqueeze(0).expand(weights[0].shape[0], -1, -1)
        saved = []
        for k in range(layers):
            h = torch.baddbmm(biases[k], h, weights[k])
            if k < layers - 1:
                h = h.relu_()
                saved.append(h)
        ctx.layers = layers
        ctx.save_for_backward(x, *weights, *saved)
        return h

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        x, *rest = ctx.saved_tensors
        layers = ctx.layers
        weights, saved = rest[:layers], rest[layers:]
        need_x, need_w = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        grad_w: list = [None] * layers
        grad_b: list = [None] * layers
        grad_x = None
        g = grad_out
        for k in range(layers - 1, -1, -1):
            below = saved[k - 1] if k > 0 else (x if x.dim() == 3 else x.unsqueeze(0).expand(g.shape[0], -1, -1))
            if need_w:
                grad_w[k] = torch.bmm(below.transpose(1, 2), g)
                grad_b[k] = g.sum(dim=1, keepdim=True)
            if k > 0:
                g = torch.bmm(g, weights[k].transpose(1, 2))
                torch.ops.aten.threshold_backward.grad_input(g, below, 0.0, grad_input=g)
            elif need_x:
                grad_x = torch.bmm(g, weights[0].transpose(1, 2))
                if x.dim() == 2:
                    grad_x = grad_x.sum(dim=0)
        return (grad_x, *grad_w, *grad_b)


def ensemble_forward(net: nn.Sequential, x: torch.Tensor, member_by_member: bool) -> torch.Tensor:
    """An ensemble network on ``x [B, in]`` (shared by every member) or ``[E, B, in]`` (one batch per
    member) -> ``[E, B, out]``: member by member (:func:`per_member_forward`), or batched: a plain
    ReLU network through :class:`_BatchedReLUMLP`, any other through autograd."""
    if member_by_member:
        return per_member_forward(net, x)
    if _plain_relu_mlp(net):
        linears = list(net)[0::2]
        return _BatchedReLUMLP.apply(x, *[lin.weight for lin in linears], *[lin.bias for lin in linears])
    if x.dim() == 2:
        x = x.unsqueeze(0).expand(net[0].ensemble_size, -1, -1)
    return net(x)


def _rows_with_gradient(grad: torch.Tensor) -> torch.Tensor | None:
    """The rows of ``grad [R, out]`` that hold a non-zero value, when at most half do (on a CPU), else None.

    A row whose output gradient is zero contributes exactly zero to every gradient below it, so the
    backward may skip it. Under a minimum over the ensemble (PBRL's actor objective, the Q
    distillation loss) or when only member 0 is read (TD3's actor), each member receives the
    gradient of the rows where it is the minimum, ~1/E of them, and the rest of its backward is
    work on zeros. On a GPU the count would cost a device sync, so every row is kept there."""
    if grad.device.type != "cpu":
        return None
    nonzero = grad.ne(0).any(dim=1)
    if int(nonzero.sum()) * 2 > grad.shape[0]:
        return None
    return nonzero.nonzero().squeeze(1)


def _plain_relu_mlp(net: nn.Sequential) -> bool:
    """EnsembleLinear layers with a ReLU between each pair and nothing else (no LayerNorm, no tanh)."""
    kinds = [type(layer) for layer in net]
    return (len(kinds) % 2 == 1 and all(k is EnsembleLinear for k in kinds[0::2])
            and all(k is nn.ReLU for k in kinds[1::2]))


def per_member_forward(net: nn.Sequential, x: torch.Tensor, members: int | None = None) -> torch.Tensor:
    """``net(x expanded to [E, B, in])`` computed one member at a time with plain matrix products;
    with ``members=m`` only the first m members, ``[m, B, out]``. ``x`` may also hold one batch per
    member, ``[E, B, in]`` (runs of a group with their own data: :class:`mop_core.distill.student.StudentGroup`).

    Same result and gradients as the batched path (tested). On CPU, E plain GEMMs over a large
    batch beat one batched GEMM (``bmm``) (benchmarks/bench_pbrl.py). A plain ReLU network runs
    through :class:`_EnsembleReLUMLP` (hand-written backward); other networks (LayerNorm + tanh
    trunks) through autograd, each weight unbound once (a slice ``w[e]`` per use would allocate a
    full-size gradient buffer each time) and each ReLU in place on the product before it (autograd
    keeps the ReLU's result, not the product's). Small batches are faster batched.
    """
    count = net[0].ensemble_size if members is None else members
    if _plain_relu_mlp(net):
        linears = list(net)[0::2]
        subset = count < net[0].ensemble_size  # slice only when needed: a slice's backward writes a full-size buffer
        return _EnsembleReLUMLP.apply(x, *[lin.weight[:count] if subset else lin.weight for lin in linears],
                                      *[lin.bias[:count] if subset else lin.bias for lin in linears])
    unbound = [(layer.weight.unbind(0), layer.bias.unbind(0))
               if isinstance(layer, (EnsembleLinear, EnsembleLayerNorm)) else None for layer in net]
    outputs = []
    for e in range(count):
        h = x if x.dim() == 2 else x[e]
        for index, (layer, params) in enumerate(zip(net, unbound)):
            if isinstance(layer, EnsembleLinear):
                h = torch.addmm(params[1][e], h, params[0][e])
            elif isinstance(layer, nn.ReLU) and index > 0 and isinstance(net[index - 1], EnsembleLinear):
                h = h.relu_()  # in place on the product just computed
            elif isinstance(layer, EnsembleLayerNorm):
                h = F.layer_norm(h, h.shape[-1:], eps=layer.eps) * params[0][e] + params[1][e]
            else:
                h = layer(h)
        outputs.append(h)
    return torch.stack(outputs)


MEMBER_LOOP_WORK = 2 ** 25  # rows * widest_hidden^2 from which a member loop beats bmm on a CPU (bench_pbrl)


def member_loop_pays(rows: int, widest: int, device: torch.device, work: int = MEMBER_LOOP_WORK) -> bool:
    """Whether an ensemble over ``rows`` rows per member runs faster as E plain GEMMs per layer
    (:func:`per_member_forward`) than as one batched GEMM: on a CPU from ``rows * widest^2 >= work``."""
    return device.type == "cpu" and rows * widest ** 2 >= work


class EnsembleCritic(nn.Module):
    """E Q-functions Q_e(s, a) evaluated together: ``(obs [B, o], act [B, a]) -> [E, B]``.

    Inputs may also carry a leading ensemble dimension (``[E, B, o]``) when each member should see
    a different batch (e.g. per-member actions). On the CPU a shared batch whose work
    ``rows * widest_hidden^2`` reaches ``member_loop_work`` runs member by member
    (:func:`per_member_forward`: plain GEMMs), a smaller one as one batched matmul per layer (fewer
    operator calls); both are one module with one set of ``[E, in, out]`` weights.
    """

    # measured on 2 CPU cores, forward + backward (benchmarks/bench_pbrl.py): 5 members x 256 wide
    # run 1.08x faster member by member at 512 rows, 1.15x at 1024, 1.44x at 7168; 5 x 128 at 768
    # rows and 2 x 256 at 128 rows run faster batched (0.86x, 0.62x); 2 x 1024 at 1024 rows is even.
    member_loop_work = MEMBER_LOOP_WORK

    def __init__(self, obs_dim: int, act_dim: int, hidden_sizes: Sequence[int], ensemble_size: int,
                 layer_norm: bool = False):
        super().__init__()
        self.ensemble_size = ensemble_size
        self.widest = max(hidden_sizes)
        self.net = mlp(obs_dim + act_dim, hidden_sizes, 1, layer_norm, ensemble_size=ensemble_size)

    def member_by_member(self, rows: int, device: torch.device) -> bool:
        """Whether a shared batch of ``rows`` rows runs as E plain GEMMs per layer (else one ``bmm``)."""
        return member_loop_pays(rows, self.widest, device, self.member_loop_work)

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        x = torch.cat([obs, act], dim=-1)
        per_member = x.dim() == 2 and self.member_by_member(x.shape[0], x.device)
        return ensemble_forward(self.net, x, per_member).squeeze(-1)

    def first(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        """Q_1(s, a) alone, ``[B]`` (TD3's actor objective): one member's work, not E members'."""
        return per_member_forward(self.net, torch.cat([obs, act], dim=-1), members=1)[0].squeeze(-1)


def adam(params, lr: float) -> torch.optim.Adam:
    """Adam (default betas and eps) with PyTorch's fused kernel: the same update to float rounding
    (tested), ~2.5-3x faster per optimiser step than the default multi-tensor path on 2 CPU cores
    (0.46 -> 0.18 ms for a 256 x 2 actor, 1.0 -> 0.36 ms for 5 critics of 256 x 2)."""
    return torch.optim.Adam(params, lr=lr, fused=True)


@torch.no_grad()
def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """Polyak averaging: theta_target <- (1 - tau) * theta_target + tau * theta_source."""
    for t, s in zip(target.parameters(), source.parameters()):
        t.lerp_(s, tau)


def smoothed_target_action(target_action: torch.Tensor, noise: torch.Tensor, noise_clip: float) -> torch.Tensor:
    """Target policy smoothing (TD3; PBRL's OOD actions): a' = clip(pi_targ(s') + clip(noise, -c, c), -1, 1)."""
    return (target_action + noise.clamp(-noise_clip, noise_clip)).clamp(-1.0, 1.0)


NumpyPolicy = Callable[[np.ndarray], np.ndarray]


def numpy_policy(actor: Callable[[torch.Tensor], torch.Tensor], device: torch.device | str = "cpu",
                 task_index: int | None = None, num_tasks: int = 0) -> NumpyPolicy:
    """The one adapter from a network to an environment policy: float64 actions ``[K, act]`` for
    observations ``[K, obs]``, without gradients; with ``task_index`` the one-hot task id of
    ``num_tasks`` is appended to every observation (:func:`with_task_id`)."""
    @torch.no_grad()
    def policy(obs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(np.asarray(obs, dtype=np.float32), device=device)
        if task_index is not None:
            x = with_task_id(x, task_index, num_tasks)
        return actor(x).cpu().numpy().astype(np.float64)
    return policy
