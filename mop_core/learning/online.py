"""The online training loop (collect's TD3 behaviour policies, thesis 4.4.3), beside the offline one.

:func:`fit_online` is to :func:`~mop_core.learning.training.train_loop` what d3rlpy's ``fit_online``
is to its ``fit``: the same learner interface (``update``, ``updates``, ``state_dict``), the same
cadence (:meth:`~mop_core.learning.schedule.OnlineSchedule.evaluates_at`), the same resume file
(:func:`~mop_core.learning.resume.write_resume`: kind, fingerprint, the divergence check before it is
written) and the same losses kept on the device (:class:`~mop_core.learning.step_metrics.StepMetrics`).
What an online run adds is the environment: ``warmup_steps`` uniformly random actions, then one
exploring action, one stored transition and one update per step.

Resume files are written at episode ends only (the environment's random state is then the one of its
next reset), at the first one after every ``checkpoint_every`` updates; they hold the learner, every
generator, the replay, the caller's ``record`` and the losses of the evaluation window in progress,
so a resumed run ends with the same record, replay and weights as an uninterrupted one.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, Protocol, TypeVar

import numpy as np
import torch
from tqdm import tqdm

from mop_core.learning.resume import try_resume, write_resume
from mop_core.learning.schedule import OnlineSchedule
from mop_core.learning.step_metrics import StepMetrics

R = TypeVar("R")


class OnlineLearner(Protocol):
    updates: int  # gradient steps taken

    def act(self, obs: np.ndarray, noise: float = 0.0) -> np.ndarray: ...
    def update(self, batch: Any) -> dict: ...
    def state_dict(self) -> dict: ...
    def load_state_dict(self, state: dict) -> None: ...


def fit_online(agent: OnlineLearner, env: Any, buffer: Any, schedule: OnlineSchedule, *, act_dim: int, batch_size: int,
               exploration_noise: float, warmup_rng: np.random.Generator, sampler: torch.Generator,
               record: R, evaluate: Callable[[R, int, int, dict], tuple[float, bool]], resume: Path | None,
               fingerprint: str,
               desc: str, progress: bool, position: int = 0) -> tuple[R, float]:
    """Train ``agent`` online in ``env`` (a :class:`~mop_core.walker.envs.WalkerEnv`), storing every
    transition in ``buffer`` (a :class:`~mop_core.data.buffer.ReplayBuffer`) and updating on minibatches
    drawn with ``sampler``.

    After each update that :meth:`~OnlineSchedule.evaluates_at`, ``evaluate(record, update, env_steps,
    losses)`` adds a curve point to ``record`` (the caller's: its curve, snapshots) and returns the mean
    return shown on the progress bar and whether the run stops there (an early stop: collect's expert
    criterion met); ``losses``: the last value of each loss since the previous point.
    With ``resume``, a rerun continues from its resume file (see the module docstring).

    Returns the record (the resumed one, if the run resumed) and the seconds trained, resumed runs'
    earlier seconds included.
    """
    env_step, seconds_before, last_losses = 0, 0.0, {}
    state = try_resume(resume, fingerprint) if resume is not None else None
    if state is not None:
        agent.load_state_dict(state["agent"])
        sampler.set_state(state["sampler"])
        warmup_rng.bit_generator.state = state["rng"]
        env.set_random_state(state["env_random"])
        buffer.load_state_dict(state["buffer"])
        record, env_step, seconds_before, last_losses = state["record"], state["env_step"], state["seconds"], \
            state["losses"]
    obs = env.reset()
    started = time.perf_counter()
    saved_at = agent.updates
    metrics = StepMetrics(desc)
    bar = tqdm(total=schedule.updates, initial=agent.updates, desc=desc, position=position, disable=not progress,
               mininterval=2.0, unit="upd")
    for t in range(env_step, schedule.env_steps):
        if t < schedule.warmup_steps:
            action = warmup_rng.uniform(-1.0, 1.0, act_dim)
        else:
            action = agent.act(obs, exploration_noise)
        step = env.step(action)
        buffer.add(obs, action, step.reward, step.observation, False, step.timeout, step.physics, step.features)
        env_random = env.random_state() if step.timeout else None  # before the reset draws the next start
        obs = env.reset() if step.timeout else step.observation
        if t < schedule.warmup_steps:
            continue
        step_losses = agent.update(buffer.sample(batch_size, sampler))
        update = agent.updates
        metrics.add(update, step_losses)
        bar.update(1)
        if schedule.evaluates_at(update):
            last_losses |= metrics.take_last()
            shown, stop = evaluate(record, update, t + 1, last_losses)
            last_losses = {}
            bar.set_postfix(ret=f"{shown:.0f}")
            if stop:
                break
        if (resume is not None and step.timeout and update - saved_at >= schedule.checkpoint_every
                and t + 1 < schedule.env_steps):
            last_losses |= metrics.take_last()
            write_resume(resume, fingerprint, update, agent.state_dict(),
                         seconds_before + time.perf_counter() - started, desc, env_step=t + 1,
                         sampler=sampler.get_state(), rng=warmup_rng.bit_generator.state, env_random=env_random,
                         buffer=buffer.state_dict(), record=record, losses=last_losses)
            saved_at = update
    bar.close()
    return record, seconds_before + time.perf_counter() - started
