"""How many runs of a vectorised group a device holds, from measured memory.

A stage trains its entry's runs (a teacher entry's tasks and seeds, a student entry's seeds) as one
group. On a GPU the group's memory grows with its runs: each adds its parameters, Adam state and the
activations of its share of every minibatch. Where the whole group does not fit, the runs train in
*waves*, groups one after another, each a group of as many runs as fit; a run's result does not
depend on its wave (a group equals its runs trained alone to float rounding).

The footprint is measured, not modelled: a probe steps a throwaway group of one run and of two runs
the way the learner will (captured as CUDA graphs or eager) and reads the device's peak allocation,

    peak(R) = fixed + R * per_run,    per_run = peak(2) - peak(1),    fixed = peak(1) - per_run,

and the room is what the device has free, capped at ``MOP_GPU_SHARE`` of its memory where a
scheduler gave this process a share of the card (mop-cluster's ``--gpus-per-run``). A CPU has no
room limit here: the whole group is one wave.
"""

from __future__ import annotations

import gc
import math
import os
from dataclasses import dataclass
from typing import Callable, Sequence, TypeVar

import torch

GPU_SHARE_ENV = "MOP_GPU_SHARE"  # the share of one GPU this process may use (a mop-cluster worker sets it)
HEADROOM = 0.85  # of the room, what the waves plan to fill (the allocator's fragmentation, evaluation rollouts)

T = TypeVar("T")


@dataclass(frozen=True)
class GroupFootprint:
    """Device bytes of a group of R runs: ``fixed + R * per_run`` (measured by :func:`measure_footprint`)."""

    fixed: int
    per_run: int

    def bytes(self, runs: int) -> int:
        return self.fixed + runs * self.per_run


def gpu_share() -> float:
    """``MOP_GPU_SHARE`` as a fraction in (0, 1]; 1 where it is unset."""
    value = os.environ.get(GPU_SHARE_ENV, "").strip()
    if not value:
        return 1.0
    try:
        share = float(value)
    except ValueError:
        share = math.nan
    if not 0.0 < share <= 1.0:
        raise ValueError(f"{GPU_SHARE_ENV}: expected the share of one GPU this process may use, in (0, 1], "
                         f"got {value!r}")
    return share


def device_room(device: torch.device | str) -> int | None:
    """Bytes a new group may take on ``device``: on CUDA the free memory, capped at ``MOP_GPU_SHARE`` of
    the card less what this process holds already; ``None`` (no limit) elsewhere."""
    device = torch.device(device)
    if device.type != "cuda":
        return None
    free, total = torch.cuda.mem_get_info(device)
    return max(0, min(free, int(gpu_share() * total) - torch.cuda.memory_reserved(device)))


def measure_footprint(step_group: Callable[[int], None], device: torch.device | str) -> GroupFootprint | None:
    """The footprint of a group, from ``step_group(R)`` (build a throwaway group of R runs and step it as
    training will, every captured variant included) for R = 1 and 2 on ``device``; ``None`` off CUDA."""
    device = torch.device(device)
    if device.type != "cuda":
        return None
    peaks = []
    for runs in (1, 2):
        torch.cuda.synchronize(device)
        torch.cuda.empty_cache()
        base = torch.cuda.memory_allocated(device)
        torch.cuda.reset_peak_memory_stats(device)
        step_group(runs)
        torch.cuda.synchronize(device)
        peaks.append(torch.cuda.max_memory_allocated(device) - base)
        gc.collect()  # a captured group is a reference cycle (its graphs' steps are its bound methods)
        torch.cuda.empty_cache()
    per_run = max(peaks[1] - peaks[0], 1)
    return GroupFootprint(fixed=max(peaks[0] - per_run, 0), per_run=per_run)


def wave_sizes(runs: int, footprint: GroupFootprint | None, room: int | None, what: str = "a run",
               max_group: int | None = None) -> list[int]:
    """The group sizes, in order, that train ``runs`` runs: one group where the room holds it, else
    near-equal waves of at most what fits in ``HEADROOM`` of ``room`` (and at most ``max_group``).
    Raises ``MemoryError`` naming the need where not even one run fits."""
    if runs < 1:
        raise ValueError(f"runs: expected at least one run, got {runs}")
    if max_group is not None and max_group < 1:
        raise ValueError(f"max_group: expected a positive group size, got {max_group}")
    fit = runs if max_group is None else min(runs, max_group)
    if footprint is not None and room is not None:
        usable = int(room * HEADROOM) - footprint.fixed
        if usable < footprint.per_run:
            gib = 2.0 ** 30
            raise MemoryError(f"{what} needs {footprint.bytes(1) / gib:.2f} GiB on the device "
                              f"({footprint.fixed / gib:.2f} GiB fixed + {footprint.per_run / gib:.2f} GiB per run), "
                              f"{HEADROOM:.0%} of its room is {room * HEADROOM / gib:.2f} GiB "
                              f"(free memory, {GPU_SHARE_ENV}={gpu_share():g} of the card)")
        fit = min(fit, usable // footprint.per_run)
    waves = math.ceil(runs / fit)
    return [runs // waves + (1 if i < runs % waves else 0) for i in range(waves)]


def split_waves(items: Sequence[T], sizes: Sequence[int]) -> list[list[T]]:
    """``items`` cut into consecutive waves of ``sizes``."""
    if sum(sizes) != len(items):
        raise ValueError(f"sizes: expected waves covering {len(items)} items, got {list(sizes)}")
    waves, start = [], 0
    for size in sizes:
        waves.append(list(items[start:start + size]))
        start += size
    return waves
