"""Training the naive multi-task PBRL baseline (thesis 5.1.2) on offline data: one task-conditioned actor
for every study task, a critic ensemble per task, updates alternating between the tasks' datasets; a
level's seeds train as one vectorised group (:class:`~mop_core.agents.pbrl_multitask_group.MultiTaskPBRLGroup`)
in the teachers' wave loop (:func:`mop_core.teachers.train_in_waves`), its runs drawn as they would be alone.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from mop_core.agents.pbrl_group import stack_batches
from mop_core.agents.pbrl_multitask_group import MultiTaskPBRLGroup, probe_multitask_group
from mop_core.config import require, to_dict
from mop_core.data.buffer import TransitionTensors
from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.runs import MultitaskRun
from mop_core.learning.nn import numpy_policy
from mop_core.learning.resume import run_fingerprint, write_resume
from mop_core.learning.step_metrics import run_key, split_runs
from mop_core.learning.training import RunPaths, finish_run, returns_summary, train_loop
from mop_core.storage.artifacts import state_sha256
from mop_core.teacher_policies import MULTITASK_KIND
from mop_core.teachers import (
    DataSource,
    GroupLearner,
    TeacherConfig,
    anneal,
    check_batch_fits,
    load_source,
    run_seeds,
    train_in_waves,
)
from mop_core.walker.envs import ACT_DIM, OBS_DIM
from mop_core.walker.rollout import episode_returns
from mop_core.walker.tasks import check_task_list


class _MultitaskLearner(GroupLearner):
    """A :class:`MultiTaskPBRLGroup` with each task's data (``data[i]``) and each run's index generator: one
    ``update()`` is one PBRL step of every task in turn, run r's batch drawn with run r's generator (as the
    run alone draws it); curve columns ``<key>_<task>``."""

    def update(self) -> dict:
        agent, tasks, metrics = self.agent, self.agent.tasks, {}
        anneal(agent, agent.updates // len(tasks), self.steps)  # the schedule counts steps per task
        for _ in tasks:  # one update per task, in the agent's alternating order
            i = agent.next_task
            step = agent.update(stack_batches([self.data[i].sample(self.batch_size, g) for g in self.samplers]), i)
            metrics |= {_per_task(key, tasks[i]): value for key, value in step.items()}
        return metrics


def _per_task(key: str, task: str) -> str:
    """A step metric of task ``task``'s update as a curve column: ``q_mean@0`` -> ``q_mean_<task>@0``."""
    name, at, run = key.partition("@")
    return f"{name}_{task}{at}{run}"


def train_multitask(tasks: Sequence[str], sources: Sequence[DataSource], config: TeacherConfig, seeds: Sequence[int],
                    study_seed: int, paths: Sequence[RunPaths], resume: Path, timing: Path | None,
                    device: torch.device | str = "cpu", progress: bool = False, name: str = "multitask",
                    max_group: int | None = None) -> list[dict]:
    """Train the naive multi-task PBRL baseline once per seed of ``seeds``: one shared actor, a critic per
    task, tasks alternating; the seeds as one vectorised group
    (:class:`~mop_core.agents.pbrl_multitask_group.MultiTaskPBRLGroup`), in waves where the device has no
    room for all (:func:`train_in_waves`). Writes run r's checkpoint, curve and metrics (``paths[r]``), the
    group's resume file and timing record; returns the metrics records, one per seed.

    ``sources[i]`` is task i's dataset read with task i's rewards. ``schedule`` counts steps *per
    task*: one step of the loop is one PBRL update of every task in turn (the agent alternates tasks),
    so each critic trains as long as a single-task teacher's and the learning curve's ``step`` column
    is on the teachers' axis (thesis Figure 5.3 draws both against per-task steps). Run r draws what it
    would draw alone (seeds from (study seed, tasks, level, its seed)): a group equals its runs trained
    alone to float rounding (tested).
    """
    tasks = check_task_list(tasks, "tasks")
    require(len(sources) == len(tasks), "sources", f"one per task ({len(tasks)})", len(sources))
    require(len(seeds) > 0 and len(paths) == len(seeds), "paths", f"one per seed of {list(seeds)}", len(paths))
    device = torch.device(device)
    loaded = [load_source(source, config.episode_length, device) for source in sources]
    for _, summary in loaded:
        check_batch_fits(config, summary)
    pbrl, data = config.pbrl, [tensors for tensors, _ in loaded]
    sampler = torch.Generator(device).manual_seed(0)
    probe = probe_multitask_group(pbrl, tasks, OBS_DIM, ACT_DIM, lambda runs: stack_batches(
        [data[0].sample(pbrl.batch_size, sampler) for _ in range(runs)]), device)

    def train_wave(wave: list[int], wave_resume: Path, wave_name: str, keep: bool) -> tuple[list[dict], float, int]:
        return _train_multitask_wave(tasks, loaded, config, [seeds[r] for r in wave], study_seed,
                                     [paths[r] for r in wave], wave_resume, device, progress, wave_name, keep)
    return train_in_waves(len(seeds), probe, device, f"a multi-task baseline of {name}", max_group, resume, timing,
                          config.schedule.steps, name, train_wave)


def _train_multitask_wave(tasks: tuple[str, ...], loaded: Sequence[tuple[TransitionTensors, dict]],
                          config: TeacherConfig, wave_seeds: Sequence[int], study_seed: int, paths: Sequence[RunPaths],
                          resume: Path, device: torch.device, progress: bool, name: str, keep: bool
                          ) -> tuple[list[dict], float, int]:
    """One group of :func:`train_multitask` (``keep``: its resume file kept at the last step, as a teachers'
    wave's in :func:`mop_core.teachers.train_teacher_group`)."""
    level = "+".join(summary["level"] for _, summary in loaded)
    seeds = [run_seeds(study_seed, ["multitask", *tasks, level], seed) for seed in wave_seeds]
    agent = MultiTaskPBRLGroup(config.pbrl, tasks, OBS_DIM, ACT_DIM, [s["agent"] for s in seeds], device)
    samplers = [torch.Generator(device).manual_seed(s["sampler"]) for s in seeds]
    sched, runs = config.schedule, len(seeds)
    learner = _MultitaskLearner(agent, [tensors for tensors, _ in loaded], samplers, config.pbrl.batch_size,
                                sched.steps)

    def episodes(run: int, task: int, key: str, count: int) -> np.ndarray:
        policy = numpy_policy(agent.member_actor(run), device, task, len(tasks))
        return episode_returns(policy, tasks[task], [seeds[run][key] + j for j in range(count)], config.episode_length,
                               sched.rollout_envs)

    def evaluate(_: list[int]) -> dict[str, float]:  # each run on every task with its own episode seeds
        rows = [{f"{key}_{task}": value for i, task in enumerate(tasks)
                 for key, value in returns_summary(episodes(r, i, "eval", sched.eval_episodes)).items()}
                for r in range(runs)]
        for row in rows:
            row["return_mean"] = float(np.mean([row[f"return_mean_{task}"] for task in tasks]))
        if len(tasks) > 1:  # the shared actor's gradient conflict, on batches of a stream of their own per step
            draws = [torch.Generator(device).manual_seed(s["conflict"] + agent.updates) for s in seeds]
            batches = [[data.sample(config.pbrl.batch_size, g) for data, _ in loaded] for g in draws]
            cosines = agent.gradient_cosines([stack_batches([b[i] for b in batches]) for i in range(len(tasks))],
                                             draws)
            rows = [row | cosine for row, cosine in zip(rows, cosines)]
        group_row = {run_key(k, r): v for r, row in enumerate(rows) for k, v in row.items()}
        return group_row | {"return_mean": float(np.mean([row["return_mean"] for row in rows]))}

    fingerprint = run_fingerprint({"tasks": tasks, "config": to_dict(config), "seeds": list(wave_seeds),
                                   "study_seed": study_seed, "data": [s["content_sha256"] for _, s in loaded]})
    group_curve, seconds, resumed_from = train_loop(learner, learner.update, evaluate, sched, seeds[0], None, resume,
                                                    fingerprint, f"multitask {name}", progress)
    curves = list(zip(*(split_runs(row, runs) for row in group_curve))) or [[] for _ in seeds]
    records = []
    for r, seed in enumerate(wave_seeds):
        metrics: dict = {"tasks": list(tasks), "level": level, "seed": seed, "gradient_steps_per_task": sched.steps}
        for i, (task, (_, summary)) in enumerate(zip(tasks, loaded)):
            final = episodes(r, i, "final_eval", sched.final_eval_episodes)
            metrics[task] = {"return_mean": float(final.mean()), "return_std": float(final.std()),
                             "eval_episodes": len(final), "dataset_return_mean": summary["return_mean"]}
        actor_state = {k: v.cpu() for k, v in agent.member_actor(r).state_dict().items()}
        checkpoint = {
            "kind": MULTITASK_KIND, "tasks": list(tasks), "level": level, "seed": seed, "study_seed": study_seed,
            "pbrl_config": to_dict(config.pbrl), "episode_length": config.episode_length, "obs_dim": OBS_DIM,
            "act_dim": ACT_DIM, "actor": actor_state,
            "critics": [{k: v.cpu() for k, v in agent.member_critic_state(r, i).items()} for i in range(len(tasks))],
            "actor_sha256": state_sha256(actor_state), "datasets": [s for _, s in loaded], "metrics": metrics}
        records.append(finish_run(replace(paths[r], timing=None, resume=resume), checkpoint, list(curves[r]), metrics,
                                  seconds, sched.steps, resumed_from, device))
    if keep:
        write_resume(resume, fingerprint, sched.steps, learner.state_dict(), seconds, f"multitask {name}",
                     sampler=None, curve=list(group_curve), losses={})
    return records, seconds, resumed_from


def multitask_runs(params: Mapping[str, Any], level: str, seeds: Sequence[int] | None = None) -> list[MultitaskRun]:
    """The multi-task baselines of train_multitask entry ``level`` (every seed of that level) among ``seeds``
    (None: all), in the entry's order; a level or seed the study does not have is refused, naming its flag."""
    entry = [run for run in build_catalogue(params).multitask if run.level == level]
    require(bool(entry), "--level", "a level of train_multitask.levels", level)
    for seed in seeds or ():
        require(seed in [run.seed for run in entry], "--seeds", f"a subset of {[run.seed for run in entry]}", seed)
    return [run for run in entry if seeds is None or run.seed in seeds]
