"""Training PBRL teachers (thesis 5.1.1) and the naive multi-task baseline (5.1.2) on offline data.

A teacher for task i and level l learns from D_{i->i}: dataset (i, l) with the relabel stage's
rewards for i. The training loop evaluates online every ``eval_every`` steps (the learning curve),
saves a resume checkpoint every ``checkpoint_every`` steps, and at the end writes the final
checkpoint (config, actor, critics) and a metrics record. Everything random draws from generators
whose state is in the resume checkpoint, so an interrupted run resumed from it ends with the same
weights as an uninterrupted one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch

from mop_core.agents.pbrl import PBRL, PBRLConfig, make_actor
from mop_core.agents.pbrl_multitask import MultiTaskPBRL
from mop_core.artifacts import load_checkpoint, state_sha256
from mop_core.config import InputFileError, from_mapping, require, to_dict
from mop_core.data import TransitionTensors, read_dataset, read_relabel
from mop_core.envs import ACT_DIM, OBS_DIM
from mop_core.nn import EnsembleCritic, numpy_policy
from mop_core.rollout import episode_returns, trajectory_returns
from mop_core.runtime import derive_seeds
from mop_core.schedule import TrainSchedule
from mop_core.study import StudyConfig, teacher_grid
from mop_core.tasks import check_task_list
from mop_core.training import (
    RunPaths,
    finish_run,
    returns_summary,
    run_fingerprint,
    train_loop,
)

TEACHER_KIND = "pbrl_teacher"
MULTITASK_KIND = "pbrl_multitask"


@dataclass(frozen=True)
class TeacherConfig:
    """One PBRL run: algorithm, schedule and the episode length of its evaluations."""

    pbrl: PBRLConfig
    schedule: TrainSchedule
    episode_length: int = 1000



def teacher_config(params: Mapping[str, Any], study: StudyConfig, actor: str = "deterministic") -> TeacherConfig:
    """How one teacher of the params' train_teachers section trains (and the multi-task baseline, with
    the same settings, as the thesis does)."""
    grid = teacher_grid(params)
    pbrl = from_mapping(PBRLConfig, dict(grid.pbrl) | {"actor": actor}, "train_teachers.pbrl")
    return TeacherConfig(pbrl=pbrl, schedule=grid.schedule, episode_length=study.episode_length)


@dataclass(frozen=True)
class DataSource:
    """One dataset file with its relabel file, read with ``reward_task``'s rewards: D_{j->i}."""

    dataset: Path
    relabel: Path
    reward_task: str
    source_task: str | None = None  # the task whose behaviour policy collected the file (checked if set)
    level: str | None = None  # the file's dataset level (checked if set)


def load_source(source: DataSource, episode_length: int, device: torch.device | str = "cpu"
                ) -> tuple[TransitionTensors, dict]:
    """The transitions as tensors and a summary (content hash, level, mean episode return)."""
    dataset = read_dataset(source.dataset, verify_checksum=True, task=source.source_task, level=source.level)
    rewards = read_relabel(source.relabel, dataset, source.reward_task)[source.reward_task]
    returns = trajectory_returns(rewards, dataset.arrays["timeouts"] | dataset.arrays["terminals"], episode_length)
    summary = {"dataset": str(source.dataset), "source_task": str(dataset.attrs["task"]),
               "level": str(dataset.attrs["level"]), "reward_task": source.reward_task,
               "content_sha256": str(dataset.attrs["content_sha256"]), "transitions": len(dataset),
               "return_mean": float(returns.mean()) if len(returns) else float("nan"),
               "return_std": float(returns.std()) if len(returns) else float("nan"),
               "complete_episodes": int(len(returns))}
    return TransitionTensors.from_arrays(dataset.arrays, rewards, device), summary


def check_batch_fits(config: TeacherConfig, summary: dict) -> None:
    """A PBRL batch (drawn with replacement) larger than its dataset is a typo, not an experiment."""
    require(config.pbrl.batch_size <= summary["transitions"], "pbrl.batch_size",
            f"at most the {summary['transitions']} transitions of {summary['dataset']}", config.pbrl.batch_size)


def run_seeds(study_seed: int, name: Sequence[str], seed: int) -> dict[str, int]:
    """Seeds of one run, a function of (study seed, what it trains on, run seed) only."""
    return derive_seeds([study_seed, *name, seed], ("agent", "sampler", "eval", "final_eval"))


def train_teacher(task: str, source: DataSource, config: TeacherConfig, seed: int, study_seed: int,
                  paths: RunPaths, device: torch.device | str = "cpu", progress: bool = False) -> dict:
    """Train one PBRL teacher for ``task`` on ``source`` (its own dataset: D_{i->i}); write its files.

    Returns the metrics record (also written to ``paths.metrics``).
    """
    check_task_list([task], "task")
    device = torch.device(device)
    data, summary = load_source(source, config.episode_length, device)  # in memory on the learner's device
    check_batch_fits(config, summary)
    level = summary["level"]
    seeds = run_seeds(study_seed, [task, summary["source_task"], level], seed)
    agent = PBRL(config.pbrl, OBS_DIM, ACT_DIM, seeds["agent"], device)
    sampler = torch.Generator(device).manual_seed(seeds["sampler"])  # indices drawn where the data lies
    batch_size = config.pbrl.batch_size
    policy = numpy_policy(agent.actor, device)
    sched = config.schedule

    def evaluate(eval_seeds: list[int]) -> dict[str, float]:
        return returns_summary(episode_returns(policy, task, eval_seeds, config.episode_length, sched.rollout_envs))

    fingerprint = run_fingerprint({"task": task, "config": to_dict(config), "seed": seed, "study_seed": study_seed,
                                "data": summary["content_sha256"], "reward_task": source.reward_task})
    curve, seconds, resumed_from = train_loop(
        agent, lambda: agent.update(data.sample(batch_size, sampler)), evaluate, sched, seeds, sampler, paths.resume,
        fingerprint, f"teacher {task}-{level}-{seed}", progress)
    final = episode_returns(policy, task, [seeds["final_eval"] + i for i in range(sched.final_eval_episodes)],
                            config.episode_length, sched.rollout_envs)
    metrics = {"task": task, "level": level, "seed": seed, "return_mean": float(final.mean()),
               "return_std": float(final.std()), "eval_episodes": len(final),
               "dataset_return_mean": summary["return_mean"],
               "return_ratio": float(final.mean() / summary["return_mean"]), "gradient_steps": sched.steps}
    actor_state = {k: v.cpu() for k, v in agent.actor.state_dict().items()}
    return finish_run(paths, {
        "kind": TEACHER_KIND, "task": task, "level": level, "seed": seed, "study_seed": study_seed,
        "pbrl_config": to_dict(config.pbrl), "episode_length": config.episode_length,
        "obs_dim": OBS_DIM, "act_dim": ACT_DIM, "actor": actor_state,
        "critic": {k: v.cpu() for k, v in agent.critic.critic.state_dict().items()},
        "actor_sha256": state_sha256(actor_state), "dataset": summary, "metrics": metrics}, curve, metrics,
        seconds, sched.steps, resumed_from, device)


def train_multitask(tasks: Sequence[str], sources: Sequence[DataSource], config: TeacherConfig, seed: int,
                    study_seed: int, paths: RunPaths, device: torch.device | str = "cpu",
                    progress: bool = False) -> dict:
    """Train the naive multi-task PBRL baseline: one shared actor, a critic per task, tasks alternating.

    ``sources[i]`` is task i's dataset read with task i's rewards. ``schedule`` counts steps *per
    task*: one step of the loop is one PBRL update of every task in turn (the agent alternates tasks),
    so each critic trains as long as a single-task teacher's and the learning curve's ``step`` column
    is on the teachers' axis (thesis Figure 5.3 draws both against per-task steps).
    """
    tasks = check_task_list(tasks, "tasks")
    if len(sources) != len(tasks):
        raise ValueError(f"sources: expected one per task ({len(tasks)}), got {len(sources)}")
    device = torch.device(device)
    loaded = [load_source(source, config.episode_length, device) for source in sources]
    for _, summary in loaded:
        check_batch_fits(config, summary)
    level = "+".join(summary["level"] for _, summary in loaded)
    seeds = run_seeds(study_seed, ["multitask", *tasks, level], seed)
    agent = MultiTaskPBRL(config.pbrl, tasks, OBS_DIM, ACT_DIM, seeds["agent"], device)
    sampler = torch.Generator(device).manual_seed(seeds["sampler"])
    sched = config.schedule
    policies = [numpy_policy(agent.actor, device, i, len(tasks)) for i in range(len(tasks))]

    def update() -> dict:
        metrics = {}
        for _ in tasks:  # one update per task, in the agent's alternating order
            task_index = agent.next_task
            step = agent.update(loaded[task_index][0].sample(config.pbrl.batch_size, sampler), task_index)
            metrics |= {f"{key}_{tasks[task_index]}": value for key, value in step.items()}
        return metrics

    def evaluate(eval_seeds: list[int]) -> dict[str, float]:
        row = {}
        for i, task in enumerate(tasks):
            stats = returns_summary(episode_returns(policies[i], task, eval_seeds, config.episode_length,
                                                     sched.rollout_envs))
            row |= {f"{key}_{task}": value for key, value in stats.items()}
        row["return_mean"] = float(np.mean([row[f"return_mean_{task}"] for task in tasks]))
        return row

    fingerprint = run_fingerprint({"tasks": tasks, "config": to_dict(config), "seed": seed, "study_seed": study_seed,
                                "data": [s["content_sha256"] for _, s in loaded]})
    curve, seconds, resumed_from = train_loop(agent, update, evaluate, sched, seeds, sampler, paths.resume, fingerprint,
                                              f"multitask {level}-{seed}", progress)
    final_seeds = [seeds["final_eval"] + i for i in range(sched.final_eval_episodes)]
    metrics: dict = {"tasks": list(tasks), "level": level, "seed": seed, "gradient_steps_per_task": sched.steps}
    for i, (task, (_, summary)) in enumerate(zip(tasks, loaded)):
        final = episode_returns(policies[i], task, final_seeds, config.episode_length, sched.rollout_envs)
        metrics[task] = {"return_mean": float(final.mean()), "return_std": float(final.std()),
                         "eval_episodes": len(final), "dataset_return_mean": summary["return_mean"]}
    actor_state = {k: v.cpu() for k, v in agent.actor.state_dict().items()}
    return finish_run(paths, {
        "kind": MULTITASK_KIND, "tasks": list(tasks), "level": level, "seed": seed, "study_seed": study_seed,
        "pbrl_config": to_dict(config.pbrl), "episode_length": config.episode_length, "obs_dim": OBS_DIM,
        "act_dim": ACT_DIM, "actor": actor_state,
        "critics": [{k: v.cpu() for k, v in c.critic.state_dict().items()} for c in agent.critics],
        "actor_sha256": state_sha256(actor_state), "datasets": [s for _, s in loaded], "metrics": metrics},
        curve, metrics, seconds, sched.steps, resumed_from, device)


@dataclass
class Teacher:
    """A frozen teacher rebuilt from its checkpoint: actor (deterministic or Gaussian) and critics."""

    task: str
    level: str
    seed: int
    config: PBRLConfig
    actor: torch.nn.Module
    critic: EnsembleCritic
    actor_sha256: str = ""
    metrics: dict = field(default_factory=dict)  # the training run's metrics (final return, dataset return)

    def act(self, observations: np.ndarray) -> np.ndarray:
        return numpy_policy(self.actor)(observations)


def load_teacher(path: str | Path) -> Teacher:
    """Rebuild a teacher from a ``train_teacher`` checkpoint (no params.yaml needed)."""
    return teacher_from_checkpoint(load_checkpoint(path, TEACHER_KIND))


def teacher_from_checkpoint(payload: dict) -> Teacher:
    config = from_mapping(PBRLConfig, payload["pbrl_config"], "pbrl_config")
    actor = make_actor(config, payload["obs_dim"], payload["act_dim"])
    actor.load_state_dict(payload["actor"])
    critic = EnsembleCritic(payload["obs_dim"], payload["act_dim"], config.hidden_sizes, config.ensemble_size,
                            config.layer_norm)
    critic.load_state_dict(payload["critic"])
    return Teacher(payload["task"], payload["level"], payload["seed"], config, actor.eval().requires_grad_(False),
                   critic.eval().requires_grad_(False), payload["actor_sha256"], dict(payload["metrics"]))


def check_teacher_checkpoint(path: str | Path, task: str, level: str, seed: int, study_seed: int,
                             config: TeacherConfig, dataset_sha256: str) -> None:
    """Refuse a teacher checkpoint that was not trained as the study now says: another task, level,
    seed, study seed, PBRL setting, number of steps, episode length or dataset content. Raises
    InputFileError naming the file and the first difference (a stale or copied checkpoint would
    otherwise be distilled without a word)."""
    payload = load_checkpoint(path, TEACHER_KIND)
    stored_config = payload.get("pbrl_config", {})
    expected = {"task": task, "level": level, "seed": seed, "study_seed": study_seed,
                "episode_length": config.episode_length}
    found = {key: payload.get(key) for key in expected}
    expected |= {f"pbrl.{key}": value for key, value in to_dict(config.pbrl).items()}
    found |= {f"pbrl.{key}": stored_config.get(key) for key in to_dict(config.pbrl)}
    expected["schedule.steps"] = config.schedule.steps
    found["schedule.steps"] = payload.get("metrics", {}).get("gradient_steps")
    expected["dataset content_sha256"] = dataset_sha256
    found["dataset content_sha256"] = payload.get("dataset", {}).get("content_sha256")
    for key, value in expected.items():
        if found[key] != value:
            raise InputFileError(f"{path}: teacher trained with {key}={found[key]!r}, the study expects {value!r}; "
                                 "rerun `dvc repro train_teachers`")


@dataclass
class MultiTaskPolicy:
    """The naive multi-task baseline's shared actor rebuilt from its checkpoint."""

    tasks: list[str]
    level: str
    seed: int
    actor: torch.nn.Module

    def policy(self, task: str) -> Callable[[np.ndarray], np.ndarray]:
        if task not in self.tasks:
            raise ValueError(f"task: expected one of the baseline's tasks {self.tasks}, got {task!r}")
        return numpy_policy(self.actor, torch.device("cpu"), self.tasks.index(task), len(self.tasks))


def load_multitask(path: str | Path) -> MultiTaskPolicy:
    """Rebuild the baseline's actor from a ``train_multitask`` checkpoint."""
    return multitask_from_checkpoint(load_checkpoint(path, MULTITASK_KIND))


def multitask_from_checkpoint(payload: dict) -> MultiTaskPolicy:
    config = from_mapping(PBRLConfig, payload["pbrl_config"], "pbrl_config")
    actor = make_actor(config, payload["obs_dim"] + len(payload["tasks"]), payload["act_dim"])
    actor.load_state_dict(payload["actor"])
    return MultiTaskPolicy(list(payload["tasks"]), payload["level"], payload["seed"],
                           actor.eval().requires_grad_(False))
