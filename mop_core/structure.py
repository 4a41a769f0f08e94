"""Similarity measures for shared computation (thesis 6.2): Kendall's tau-b and linear CKA.

- :func:`kendall_tau_b` compares two activation vectors by the ranks of their neurons, batched over
  many vector pairs. ReLU outputs are often exactly zero, which makes ties; tau-b corrects for them:
  ``tau_b = (C - D) / sqrt((n0 - n1)(n0 - n2))`` with ``n0 = n(n-1)/2`` neuron pairs, ``C - D`` the
  concordant minus discordant pairs, ``n1``/``n2`` the pairs tied in x/y. Undefined (NaN) when either
  vector is constant, as in ``scipy.stats.kendalltau``.
- :func:`linear_cka` (Kornblith et al. 2019, the thesis's suggested future work in 6.2.4) compares two
  activation matrices over the same inputs: ``||Y^T X||_F^2 / (||X^T X||_F ||Y^T Y||_F)`` after
  centring each column; invariant to orthogonal transforms and isotropic scaling.
- :func:`hidden_activations` records a student's post-ReLU activations of every hidden layer.
"""

from __future__ import annotations

import torch


@torch.no_grad()
def kendall_tau_b(x: torch.Tensor, y: torch.Tensor, chunk: int = 256) -> torch.Tensor:
    """Kendall's tau-b between rows: ``x, y [S, n] -> [S]`` (a single pair ``[n]`` -> scalar)."""
    single = x.dim() == 1
    x, y = torch.atleast_2d(x).double(), torch.atleast_2d(y).double()
    if x.shape != y.shape:
        raise ValueError(f"x, y: expected the same shape, got {tuple(x.shape)} and {tuple(y.shape)}")
    n = x.shape[1]
    upper = torch.triu(torch.ones(n, n, dtype=torch.bool, device=x.device), diagonal=1)
    n0 = n * (n - 1) / 2
    out = []
    for xs, ys in zip(x.split(chunk), y.split(chunk)):
        sx = torch.sign(xs[:, :, None] - xs[:, None, :])[:, upper]  # [s, n0] over pairs i < j
        sy = torch.sign(ys[:, :, None] - ys[:, None, :])[:, upper]
        score = (sx * sy).sum(1)
        ties_x, ties_y = (sx == 0).sum(1), (sy == 0).sum(1)
        out.append(score / torch.sqrt((n0 - ties_x) * (n0 - ties_y)))  # 0/0 -> NaN for a constant vector
    tau = torch.cat(out)
    return tau[0] if single else tau


def linear_cka(x: torch.Tensor, y: torch.Tensor) -> float:
    """Linear CKA between activation matrices ``x [N, p]`` and ``y [N, q]`` of the same N inputs."""
    if x.shape[0] != y.shape[0]:
        raise ValueError(f"x, y: expected the same number of rows, got {x.shape[0]} and {y.shape[0]}")
    x = x.double() - x.double().mean(0)
    y = y.double() - y.double().mean(0)
    cross = (y.T @ x).pow(2).sum()
    return float(cross / ((x.T @ x).norm() * (y.T @ y).norm()))


@torch.no_grad()
def hidden_activations(student, obs: torch.Tensor, task: int | torch.Tensor) -> list[torch.Tensor]:
    """The post-ReLU activations ``[B, width]`` of every hidden layer of a student, in layer order."""
    captured: list[torch.Tensor] = []
    hooks = [layer.register_forward_hook(lambda _m, _i, out: captured.append(out.detach()))
             for layer in student.hidden_layers()]
    try:
        student(obs, task)
    finally:
        for hook in hooks:
            hook.remove()
    return captured


@torch.no_grad()
def per_state_comparison(student, obs: torch.Tensor, own_task: int) -> list[dict[int, torch.Tensor]]:
    """Thesis 6.2, per state: for each visited state (``obs [N, o]``, visited while acting as
    ``own_task``), tau-b between a layer's activations under the own task id and under every other
    task id. Returns per hidden layer ``{other task: tau [N]}``."""
    own = hidden_activations(student, obs, own_task)
    result: list[dict[int, torch.Tensor]] = [{} for _ in own]
    for other in range(student.num_tasks):
        if other == own_task:
            continue
        for layer, acts in enumerate(hidden_activations(student, obs, other)):
            result[layer][other] = kendall_tau_b(own[layer], acts)
    return result


def average_comparison(mean_activations: list[list[torch.Tensor]]) -> list[torch.Tensor]:
    """Thesis 6.2, on averages: ``mean_activations[task][layer]`` is the mean activation ``[width]`` of
    each neuron over that task's own visited states (under its own task id). Returns per layer the
    ``[m, m]`` matrix of tau-b between every pair of tasks (1 on the diagonal)."""
    m = len(mean_activations)
    layers = len(mean_activations[0])
    out = []
    for layer in range(layers):
        tau = torch.ones(m, m, dtype=torch.float64)
        for i in range(m):
            for j in range(i + 1, m):
                tau[i, j] = tau[j, i] = kendall_tau_b(mean_activations[i][layer], mean_activations[j][layer])
        out.append(tau)
    return out
