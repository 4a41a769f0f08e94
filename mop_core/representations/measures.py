"""Similarity measures for shared computation (thesis 6.2): Kendall's tau (a and b) and linear CKA.

- :func:`kendall_tau` compares two activation vectors by the ranks of their neurons, batched over
  many vector pairs, and returns both variants from one pass over the neuron pairs:
  ``tau_a = (C - D) / n0`` (the thesis's formula 2(C - D) / (N(N - 1)) and the reference code's:
  ties count as neither concordant nor discordant but stay in the denominator) and
  ``tau_b = (C - D) / sqrt((n0 - n1)(n0 - n2))`` (ties removed from the denominator, scipy's
  default), with ``n0 = n(n-1)/2`` neuron pairs, ``C - D`` the concordant minus discordant pairs and
  ``n1``/``n2`` the pairs tied in x/y. ReLU outputs are often exactly zero, which makes many ties,
  so tau-a is smaller than tau-b; the report shows both so the thesis's numbers stay comparable.
  tau-b is undefined (NaN) when either vector is constant, as in ``scipy.stats.kendalltau``; tau-a
  is 0 there.
- :func:`linear_cka` (Kornblith et al. 2019, the thesis's suggested future work in 6.2.4) compares two
  activation matrices over the same inputs: ``||Y^T X||_F^2 / (||X^T X||_F ||Y^T Y||_F)`` after
  centring each column; invariant to orthogonal transforms and isotropic scaling.
- :func:`hidden_activations` records a student's post-ReLU activations of every hidden layer.
"""

from __future__ import annotations

from typing import Sequence

import torch

TAU_VARIANTS = ("a", "b")


@torch.no_grad()
def kendall_tau(x: torch.Tensor, y: torch.Tensor, chunk: int = 8) -> dict[str, torch.Tensor]:
    """Kendall's tau-a and tau-b between rows: ``x, y [S, n] -> {"a": [S], "b": [S]}`` (a single
    pair ``[n]`` -> scalars).

    With the boolean order matrices ``g_x[i, j] = x_i > x_j`` (and ``g_y``), over ordered pairs
    ``C = sum(g_x & g_y)``, ``D = sum(g_x & g_y^T)`` and the untied pairs of x are ``sum(g_x)``, so
    ``n0 - n1 = sum(g_x)``: four integer counts, exact. The ``[chunk, n, n]`` masks are one byte per
    pair, so small chunks stay in cache. O(n^2) per row but batched: on CPU 0.8-2.5x the speed of
    ``scipy.stats.kendalltau`` (O(n log n), C) called row by row (benchmarks/bench_structure.py);
    on a GPU it takes the thesis profile's millions of rows in seconds.
    """
    single = x.dim() == 1
    x, y = torch.atleast_2d(x), torch.atleast_2d(y)
    if x.shape != y.shape:
        raise ValueError(f"x, y: expected the same shape, got {tuple(x.shape)} and {tuple(y.shape)}")
    dtype = torch.float64 if torch.float64 in (x.dtype, y.dtype) else torch.float32
    x, y = x.to(dtype), y.to(dtype)
    n = x.shape[1]
    n0 = n * (n - 1) / 2
    tau_a, tau_b = [], []
    for xs, ys in zip(x.split(chunk), y.split(chunk)):
        gx = xs[:, :, None] > xs[:, None, :]  # [s, n, n]: ordered pairs, each untied pair once
        gy = ys[:, :, None] > ys[:, None, :]
        score = (gx & gy).sum((1, 2)).double() - (gx & gy.transpose(1, 2)).sum((1, 2)).double()  # C - D
        untied_x, untied_y = gx.sum((1, 2)).double(), gy.sum((1, 2)).double()  # n0 - n1, n0 - n2
        tau_a.append(score / n0)
        tau_b.append(score / torch.sqrt(untied_x * untied_y))  # 0/0 -> NaN for a constant vector
    out = {"a": torch.cat(tau_a), "b": torch.cat(tau_b)}
    return {k: v[0] for k, v in out.items()} if single else out


def kendall_tau_b(x: torch.Tensor, y: torch.Tensor, chunk: int = 8) -> torch.Tensor:
    """Kendall's tau-b between rows (:func:`kendall_tau`)."""
    return kendall_tau(x, y, chunk)["b"]


def kendall_tau_a(x: torch.Tensor, y: torch.Tensor, chunk: int = 8) -> torch.Tensor:
    """Kendall's tau-a between rows (:func:`kendall_tau`): ``(C - D) / (n (n - 1) / 2)``."""
    return kendall_tau(x, y, chunk)["a"]


@torch.no_grad()
def linear_cka(x: torch.Tensor, y: torch.Tensor, chunk: int = 65536) -> float:
    """Linear CKA between activation matrices ``x [N, p]`` and ``y [N, q]`` of the same N inputs.

    Accumulates the centred Gram products in float64 chunk by chunk
    (``X_c^T X_c = X^T X - N mu_x mu_x^T``), so a million states need O(p q) memory, not O(N p).
    """
    if x.shape[0] != y.shape[0]:
        raise ValueError(f"x, y: expected the same number of rows, got {x.shape[0]} and {y.shape[0]}")
    n = x.shape[0]
    xx = torch.zeros(x.shape[1], x.shape[1], dtype=torch.float64, device=x.device)
    yy = torch.zeros(y.shape[1], y.shape[1], dtype=torch.float64, device=x.device)
    yx = torch.zeros(y.shape[1], x.shape[1], dtype=torch.float64, device=x.device)
    for xs, ys in zip(x.split(chunk), y.split(chunk)):
        xs, ys = xs.double(), ys.double()
        xx += xs.T @ xs
        yy += ys.T @ ys
        yx += ys.T @ xs
    mx, my = x.mean(0, dtype=torch.float64), y.mean(0, dtype=torch.float64)
    xx -= n * torch.outer(mx, mx)
    yy -= n * torch.outer(my, my)
    yx -= n * torch.outer(my, mx)
    return float(yx.pow(2).sum() / (xx.norm() * yy.norm()))


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
def per_state_comparison(student, obs: torch.Tensor, own_task: int) -> list[dict[int, dict[str, torch.Tensor]]]:
    """Thesis 6.2, per state: for each visited state (``obs [N, o]``, visited while acting as
    ``own_task``), tau-a and tau-b between a layer's activations under the own task id and under every
    other task id. Returns per hidden layer ``{other task: {"a": tau [N], "b": tau [N]}}``."""
    own = hidden_activations(student, obs, own_task)
    result: list[dict[int, dict[str, torch.Tensor]]] = [{} for _ in own]
    for other in range(student.num_tasks):
        if other == own_task:
            continue
        for layer, acts in enumerate(hidden_activations(student, obs, other)):
            result[layer][other] = kendall_tau(own[layer], acts)
    return result


def per_state_tau_by_layer(student, probes: Sequence[torch.Tensor]) -> dict[str, list[float]]:
    """The per-state comparison reduced to one number per hidden layer and tau variant: the mean tau
    over every task's probe states (``probes[i]`` visited as task i) and every other task id,
    ``{"a": [per layer], "b": [per layer]}``. This is the quantity the thesis tracks during training
    (6.3.1, Figure 6.4b); NaN (constant activations) entries are left out of the mean."""
    per_layer: dict[str, list[list[torch.Tensor]]] = {v: [] for v in TAU_VARIANTS}
    for own, obs in enumerate(probes):
        for layer, by_other in enumerate(per_state_comparison(student, obs, own)):
            for variant in TAU_VARIANTS:
                if layer == len(per_layer[variant]):
                    per_layer[variant].append([])
                per_layer[variant][layer].extend(taus[variant] for taus in by_other.values())
    return {variant: [float(torch.nanmean(torch.cat(values))) if values else float("nan") for values in layers]
            for variant, layers in per_layer.items()}


def average_comparison(mean_activations: list[list[torch.Tensor]]) -> list[dict[str, torch.Tensor]]:
    """Thesis 6.2, on averages: ``mean_activations[task][layer]`` is the mean activation ``[width]`` of
    each neuron over that task's own visited states (under its own task id). Returns per layer the
    ``[m, m]`` matrices of tau-a and tau-b between every pair of tasks (1 on the diagonal)."""
    m = len(mean_activations)
    layers = len(mean_activations[0])
    out = []
    for layer in range(layers):
        tau = {variant: torch.ones(m, m, dtype=torch.float64) for variant in TAU_VARIANTS}
        for i in range(m):
            for j in range(i + 1, m):
                pair = kendall_tau(mean_activations[i][layer], mean_activations[j][layer])
                for variant in TAU_VARIANTS:
                    tau[variant][i, j] = tau[variant][j, i] = pair[variant]
        out.append(tau)
    return out
