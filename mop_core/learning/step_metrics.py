"""Per-update metrics read from the device in batches, not one ``.item()`` per value per update.

A learner's ``update()`` returns its metrics as 0-d tensors (or plain numbers). Reading a tensor's
value forces the device to finish all queued work: on a GPU, ``.item()`` after every update
serialises the host and the device once per metric per update. :class:`StepMetrics` keeps the
tensors of the updates since the last read and reads them all with one ``torch.stack`` and one
``tolist`` per metric when :meth:`StepMetrics.sync` is called (every ``SYNC_EVERY`` updates and
whenever a caller needs the values: an evaluation row, a resume file). Each read also checks that
every value is finite and names the *first* non-finite one exactly (its metric and update step),
as a per-update check would.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
import torch

from mop_core.learning.runtime import TrainingDivergedError

SYNC_EVERY = 1000  # updates between reads when nothing else asks for the values

Value = torch.Tensor | float | int


def as_floats(values: list[Value]) -> list[float]:
    """Plain floats of a list of 0-d tensors and numbers, with one device read for all the tensors."""
    tensors = [v for v in values if isinstance(v, torch.Tensor)]
    if not tensors:
        return [float(v) for v in values]
    read = iter(torch.stack([t.detach().to(torch.float64) for t in tensors]).tolist())  # exact for float32
    return [next(read) if isinstance(v, torch.Tensor) else float(v) for v in values]


class StepMetrics:
    """The metrics of consecutive update steps: ``add`` each step's, ``sync`` to read them.

    ``values[key]`` holds the floats of every synced step since the last :meth:`take` (steps where
    an update did not report ``key``, e.g. the delayed actor step, hold nothing for it);
    ``last[key]`` the most recent synced value of ``key``.
    """

    def __init__(self, run: str, kept: str = "", values: Mapping[str, list[float]] | None = None):
        self.run, self.kept = run, kept
        self.values: dict[str, list[float]] = {k: list(v) for k, v in (values or {}).items()}
        self.last: dict[str, float] = {k: v[-1] for k, v in self.values.items() if v}
        self._pending: dict[str, list[tuple[int, Value]]] = {}
        self._count = 0

    def add(self, step: int, metrics: Mapping[str, Value]) -> None:
        """Record update ``step``'s metrics; reads them all every ``SYNC_EVERY`` calls."""
        for key, value in metrics.items():
            self._pending.setdefault(key, []).append((step, value))
        self._count += 1
        if self._count % SYNC_EVERY == 0:
            self.sync()

    def sync(self) -> None:
        """Read every pending value; raise :class:`TrainingDivergedError` at the first non-finite one."""
        pending, self._pending = self._pending, {}
        read = {key: ([s for s, _ in items], as_floats([v for _, v in items])) for key, items in pending.items()}
        bad = [(steps[i], key, value) for key, (steps, floats) in read.items()
               for i, value in enumerate(floats) if not math.isfinite(value)]
        if bad:
            step, key, value = min(bad, key=lambda b: b[0])
            raise TrainingDivergedError(f"{self.run}: {key} = {value} at step {step}; stopped{self.kept}. Lower the "
                                        "learning rate or check the data")
        for key, (_, floats) in read.items():
            self.values.setdefault(key, []).extend(floats)
            if floats:
                self.last[key] = floats[-1]

    def take(self) -> dict[str, float]:
        """The mean of each metric since the last ``take`` (after a sync), and start a new window."""
        self.sync()
        means = {key: float(np.mean(v)) for key, v in sorted(self.values.items()) if v}
        self.values = {}
        return means

    def take_last(self) -> dict[str, float]:
        """The most recent value of each metric since the last ``take`` (after a sync), and start a new window."""
        self.sync()
        last = {key: v[-1] for key, v in self.values.items() if v}
        self.values = {}
        return last


def run_key(key: str, run: int) -> str:
    """The metric or curve column ``key`` of run ``run`` of a group: ``key@run``."""
    return f"{key}@{run}"


def split_runs(row: Mapping[str, Any], runs: int) -> list[dict]:
    """A group's row (``key@r`` columns per run, plain columns shared) -> one row per run, the columns in
    the order they first appear (a run alone writes the same header); a run's own value of a column
    wins over the group's (e.g. ``return_mean``: the run's, not the group's mean)."""
    out: list[dict] = [{} for _ in range(runs)]
    for key, value in row.items():
        name, _, run = key.rpartition("@") if "@" in key else (key, "", "")
        for target in ([out[int(run)]] if run else out):
            if run or name not in target:
                target[name] = value
    return out
