"""The training loop shared by every offline learner of the study (teachers, baseline, students).

``train_loop`` runs a learner's update to a fixed number of steps, evaluates it online every
``eval_every`` steps (the learning curve) and saves a resume checkpoint every ``checkpoint_every``
steps. A rerun whose resume file has the same fingerprint (configuration, seeds, data hashes)
continues from it; any other resume file is ignored with a warning and the run restarts at step 0.
Everything random draws from generators whose state is in the resume checkpoint, so a resumed run
ends with the same weights as an uninterrupted one.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from mop_core.learning.resume import check_finite, try_resume, write_resume
from mop_core.learning.schedule import TrainSchedule, due
from mop_core.learning.step_metrics import StepMetrics
from mop_core.storage.artifacts import save_checkpoint, write_curve
from mop_core.storage.files import write_json
from mop_core.storage.layout import RunPaths
from mop_core.storage.timings import per_second, write_timing


def train_loop(agent, update: Callable[[], dict], evaluate: Callable[[list[int]], dict[str, float]],
               schedule: TrainSchedule, seeds: dict[str, int], sampler: torch.Generator | None, resume: Path,
               fingerprint: str, desc: str, progress: bool, final_seeds: list[int] | None = None,
               ) -> tuple[list[dict], float, int]:
    """Run ``update`` to ``schedule.steps`` with periodic evaluation and resume checkpoints (``resume``).

    ``sampler``: a generator outside the agent whose state the resume file keeps (None: the agent's
    ``state_dict`` holds every generator it draws from). ``final_seeds``: the last curve point
    evaluates on these episodes instead of the curve's (the run's final evaluation, which the
    caller's ``evaluate`` can keep rather than roll out twice); None: on the curve's, like the others.

    Returns the learning curve rows, the training seconds and the step it resumed from (0 if none).
    A NaN or infinite loss or weight stops the run with :class:`TrainingDivergedError` naming
    ``desc`` and the step; the last good resume file is kept. Losses stay on the device until read
    (:class:`~mop_core.learning.step_metrics.StepMetrics`: every ``SYNC_EVERY`` steps, before an evaluation and
    before a resume file), weights are checked at every checkpoint.
    The resume file holds the losses of the evaluation window in progress, so a resumed run's
    curve equals an uninterrupted one's whatever ``checkpoint_every`` and ``eval_every`` are.
    """
    curve: list[dict] = []
    seconds_before = 0.0
    resumed_from = 0
    losses: dict[str, list[float]] = {}
    state = try_resume(resume, fingerprint)
    if state is not None:
        agent.load_state_dict(state["agent"])
        if sampler is not None:
            sampler.set_state(state["sampler"])
        curve, seconds_before, resumed_from = state["curve"], state["seconds"], state["step"]
        losses = state.get("losses", {})
    kept = f"; the resume file {resume} (if any) keeps the last good state"
    metrics = StepMetrics(desc, kept, losses)
    eval_seeds = [seeds["eval"] + i for i in range(schedule.eval_episodes)]
    started = time.perf_counter()
    bar = tqdm(total=schedule.steps, initial=resumed_from, desc=desc, disable=not progress, mininterval=2.0,
               unit="upd")
    for step in range(resumed_from + 1, schedule.steps + 1):
        metrics.add(step, update())
        bar.update(1)
        if schedule.evaluates_at(step):
            means = metrics.take()  # before the evaluation: a diverged run stops without evaluating
            episodes = final_seeds if step == schedule.steps and final_seeds is not None else eval_seeds
            row = {"step": step, **evaluate(episodes)} | means
            curve.append(row)
            bar.set_postfix(ret=f"{row['return_mean']:.0f}")
        if due(step, schedule.checkpoint_every, schedule.steps):
            metrics.sync()
            check_finite(agent.state_dict(), desc, step, kept)
        if step % schedule.checkpoint_every == 0 and step < schedule.steps:
            write_resume(resume, fingerprint, step, agent.state_dict(), seconds_before + time.perf_counter() - started,
                         desc, sampler=None if sampler is None else sampler.get_state(), curve=curve,
                         losses=metrics.values)
    bar.close()
    return curve, seconds_before + time.perf_counter() - started, resumed_from


def finish_run(paths: RunPaths, checkpoint: dict, curve: list[dict], metrics: dict, seconds: float, steps: int,
               resumed_from: int, device: torch.device | str) -> dict:
    """The end of every offline training run (teachers, the multi-task baseline, students): the final
    checkpoint, the learning curve, the metrics record, the timing record (``seconds`` for ``steps``
    updates, the step it resumed from, the machine: :mod:`mop_core.storage.timings`), and the resume file
    dropped last (a crash before this point resumes, after it the run is complete). Returns ``metrics``.

    The checkpoint, curve and metrics hold only what the run computed, never a time or a package
    version, so a rerun with the same weights writes the same bytes and leaves later stages clean."""
    save_checkpoint(paths.checkpoint, checkpoint)
    write_curve(paths.curve, curve)
    write_json(paths.metrics, metrics)
    if paths.timing is not None:
        write_timing(paths.timing, seconds, device, steps=steps, steps_per_second=per_second(steps, seconds),
                     resumed_from_step=resumed_from)
    paths.resume.unlink(missing_ok=True)
    return metrics


def returns_summary(returns: np.ndarray) -> dict[str, float]:
    return {"return_mean": float(returns.mean()), "return_std": float(returns.std())}
