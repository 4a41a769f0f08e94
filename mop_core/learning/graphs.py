"""Training steps replayed as CUDA graphs (issue 39, part 2): one launch per update instead of hundreds.

A vectorised update (a PBRL group's critic and actor steps, Adam and Polyak averaging included) is a
few hundred small kernels. On a GPU each launch costs microseconds of host time, so a small update is
bound by the launches, not the card (190 thesis-size PBRL updates/s on an H200, a few percent of it).
:class:`GraphedStep` records the update once as a CUDA graph and then replays it: the same kernels on
the same memory, launched by one call.

What a captured step needs, and how the learners provide it:

- *Static inputs.* The graph reads fixed addresses, so each call copies its inputs (the minibatch,
  ``beta_ood``) into buffers the graph was captured with (:meth:`GraphedStep.__call__`'s ``inputs``).
- *No host round trip.* Nothing in the step may read a value on the host (tested under
  ``torch.cuda.set_sync_debug_mode("error")``, tests/test_no_host_round_trip.py).
- *Graph-safe randomness.* Each run's generator is registered with every graph
  (``CUDAGraph.register_generator_state``), so a replay draws fresh numbers and advances the generator
  as an eager step would.
- *Optimisers that can be captured.* Adam with ``capturable=True`` and its learning rate a device
  tensor (:func:`capturable_adam`), changed in place by :func:`mop_core.learning.schedule.set_learning_rate`,
  so a cosine schedule reaches the replayed step.
- *Outputs that survive the next replay.* A replay overwrites the step's outputs: the metrics come back
  as one stacked tensor, cloned once per call (metrics that are plain numbers, e.g. a fixed entropy
  weight, are the capture's constants).

The first ``warmup`` calls run eagerly on a side stream (they are real updates: they allocate the
optimiser state and the gradients' memory, as capture requires); the next call captures its variant
of the step and replays it, and every later call replays. A learner with several variants (PBRL's
critic-only step and its critic + delayed actor step) keeps one graph per variant.

Eager stays the CPU path: :func:`graphs_enabled` is false off CUDA, and where ``MOP_CUDA_GRAPHS=0``.
"""

from __future__ import annotations

import os
from typing import Callable, Hashable, Iterable, Sequence

import torch

from mop_core.learning.nn import adam

Step = Callable[[], dict[str, torch.Tensor]]


def graphs_enabled(device: torch.device | str, requested: bool | None = None) -> bool:
    """Whether updates on ``device`` are captured: only on CUDA; ``requested`` (a learner's own
    choice) wins, else ``MOP_CUDA_GRAPHS`` (``0`` turns capture off; default on)."""
    if torch.device(device).type != "cuda":
        return False
    if requested is not None:
        return requested
    return os.environ.get("MOP_CUDA_GRAPHS", "1") != "0"


def capturable_adam(params: Iterable[torch.nn.Parameter], lr: float, device: torch.device) -> torch.optim.Adam:
    """Adam that a CUDA graph can capture: fused, ``capturable``, its learning rate a device tensor
    (filled in place by :func:`~mop_core.learning.schedule.set_learning_rate`). The same update as
    :func:`~mop_core.learning.nn.adam` to float rounding."""
    return torch.optim.Adam(params, lr=torch.tensor(lr, dtype=torch.float32, device=device), fused=True,
                            capturable=True)


def learner_adam(params: Iterable[torch.nn.Parameter], lr: float, device: torch.device,
                 captured: bool) -> torch.optim.Adam:
    """A learner's Adam: :func:`capturable_adam` where its updates are captured, else
    :func:`~mop_core.learning.nn.adam`."""
    return capturable_adam(params, lr, device) if captured else adam(params, lr)


def match_loaded(optimizer: torch.optim.Optimizer, captured: bool, device: torch.device) -> None:
    """After ``optimizer.load_state_dict`` of a resume file that a captured or an eager run wrote (on this
    machine or another): its groups as this learner built them. Captured: capturable, the learning rate a
    device tensor of the loaded value; eager: not capturable (a CPU Adam refuses it), a plain float rate."""
    for group in optimizer.param_groups:
        rate = float(group["lr"])
        group["capturable"] = captured
        group["lr"] = torch.tensor(rate, dtype=torch.float32, device=device) if captured else rate


class GraphedStep:
    """Steps ``step_for(variant)()`` run eagerly ``warmup`` times, then captured and replayed, per variant.

    ``__call__(variant, inputs)`` copies each ``inputs[name]`` into the static buffer ``buffers[name]``
    (created from the first call's tensors) and runs the variant's step, which must read its inputs
    from ``buffers``; it returns the step's metrics, cloned (a replay overwrites the graph's outputs).
    """

    def __init__(self, step_for: Callable[[Hashable], Step], generators: Sequence[torch.Generator] = (),
                 warmup: int = 2):
        if warmup < 1:
            raise ValueError(f"warmup: expected at least one eager call before capture, got {warmup}")
        self.step_for, self.generators, self.warmup = step_for, list(generators), warmup
        self.buffers: dict[str, torch.Tensor] = {}
        self.graphs: dict[Hashable, tuple[torch.cuda.CUDAGraph, list[str], torch.Tensor, dict]] = {}
        self.eager_calls: dict[Hashable, int] = {}

    def _fill(self, inputs: dict[str, torch.Tensor]) -> None:
        for name, value in inputs.items():
            buffer = self.buffers.get(name)
            if buffer is None:
                self.buffers[name] = value.detach().clone()
            elif buffer.shape != value.shape or buffer.dtype != value.dtype:
                raise ValueError(f"inputs[{name!r}]: a captured step takes one shape per input, "
                                 f"{tuple(buffer.shape)} {buffer.dtype}, got {tuple(value.shape)} {value.dtype}")
            else:
                buffer.copy_(value, non_blocking=True)

    def __call__(self, variant: Hashable, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        self._fill(inputs)
        if variant in self.graphs:
            graph, keys, out, constants = self.graphs[variant]
            graph.replay()
            return dict(zip(keys, out.clone().unbind(0))) | constants
        step = self.step_for(variant)
        if self.eager_calls.get(variant, 0) < self.warmup:
            self.eager_calls[variant] = self.eager_calls.get(variant, 0) + 1
            side = torch.cuda.Stream()
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                metrics = step()
            torch.cuda.current_stream().wait_stream(side)
            return metrics
        graph = torch.cuda.CUDAGraph()
        for generator in self.generators:
            graph.register_generator_state(generator)
        with torch.cuda.graph(graph):
            metrics = step()
            keys = [k for k, v in metrics.items() if isinstance(v, torch.Tensor)]
            out = torch.stack([metrics[k].detach().to(torch.float32) for k in keys])
        constants = {k: v for k, v in metrics.items() if not isinstance(v, torch.Tensor)}  # e.g. a fixed alpha
        self.graphs[variant] = (graph, keys, out, constants)
        graph.replay()
        return dict(zip(keys, out.clone().unbind(0))) | constants

    def reset(self) -> None:
        """Forget the graphs (after the learner's state was replaced, e.g. on resume): the next calls
        warm up and capture again."""
        self.graphs.clear()
        self.eager_calls.clear()
