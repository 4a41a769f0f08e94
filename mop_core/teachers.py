"""Training PBRL teachers (thesis 5.1.1) on offline data, as vectorised groups trained in waves (the naive
multi-task baseline, 5.1.2, reuses the group loop: :mod:`mop_core.multitask`).

A teacher for task i and level l learns from D_{i->i}: dataset (i, l) with the relabel stage's
rewards for i. The training loop evaluates online every ``eval_every`` steps (the learning curve),
saves a resume checkpoint every ``checkpoint_every`` steps, and at the end writes the final
checkpoint (config, actor, critics) and a metrics record. Everything random draws from generators
whose state is in the resume checkpoint, so an interrupted run resumed from it ends with the same
weights as an uninterrupted one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch

from mop_core.agents.pbrl import PBRLConfig
from mop_core.agents.pbrl_group import PBRLGroup, probe_group, stack_batches
from mop_core.agents.pbrl_multitask import MultiTaskPBRL
from mop_core.config import ConfigError, InputFileError, from_mapping, keys_under, require, to_dict
from mop_core.data.buffer import TransitionTensors
from mop_core.data.hdf5 import read_dataset, read_relabel
from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.runs import TeacherRun, sharing_teacher_entry, teacher_entry
from mop_core.experiment.study import StudyConfig, teacher_grid
from mop_core.learning.group_memory import device_room, measure_footprint, split_waves, wave_sizes
from mop_core.learning.nn import numpy_policy
from mop_core.learning.resume import run_fingerprint, write_resume
from mop_core.learning.runtime import derive_seeds
from mop_core.learning.schedule import TrainSchedule, scheduled_rate, set_learning_rate
from mop_core.learning.step_metrics import run_key, split_runs
from mop_core.learning.training import (
    RunPaths,
    finish_run,
    returns_summary,
    train_loop,
)
from mop_core.storage.artifacts import load_checkpoint, state_sha256
from mop_core.storage.files import read_json
from mop_core.storage.timings import per_second, write_timing
from mop_core.teacher_policies import TEACHER_KIND
from mop_core.walker.envs import ACT_DIM, OBS_DIM
from mop_core.walker.rollout import episode_returns, trajectory_returns
from mop_core.walker.tasks import check_task_list


@dataclass(frozen=True)
class TeacherConfig:
    """One PBRL run: algorithm, schedule and the episode length of its evaluations."""

    pbrl: PBRLConfig
    schedule: TrainSchedule
    episode_length: int = 1000


def teacher_config(params: Mapping[str, Any], study: StudyConfig, actor: str, level: str) -> TeacherConfig:
    """How one teacher of dataset ``level`` trains by the params' train_teachers section (and the multi-task
    baseline, with the same settings, as the thesis does)."""
    grid = teacher_grid(params)
    pbrl = from_mapping(PBRLConfig, dict(grid.pbrl) | {"actor": actor}, "train_teachers.pbrl")
    with keys_under("train_teachers"):
        schedule = grid.schedule_for(level)
    return TeacherConfig(pbrl=pbrl, schedule=schedule, episode_length=study.episode_length)


@dataclass(frozen=True)
class DataSource:
    """One dataset file with its relabel file, read with ``reward_task``'s rewards: D_{j->i}."""

    dataset: Path
    relabel: Path
    reward_task: str
    source_task: str | None = None  # the task whose behaviour policy collected the file (checked if set)
    level: str | None = None  # the file's dataset level (checked if set)


def _read_source(source: DataSource, episode_length: int) -> tuple[dict, np.ndarray, np.ndarray, dict]:
    dataset = read_dataset(source.dataset, verify_checksum=True, task=source.source_task, level=source.level)
    rewards = read_relabel(source.relabel, dataset, source.reward_task)[source.reward_task]
    returns = trajectory_returns(rewards, dataset.arrays["timeouts"] | dataset.arrays["terminals"], episode_length)
    return dataset.arrays, rewards, returns, dict(dataset.attrs)


def _summary(sources: Sequence[DataSource], attrs: Sequence[dict], transitions: int, returns: np.ndarray) -> dict:
    return {"dataset": " + ".join(str(s.dataset) for s in sources),
            "source_task": "+".join(str(a["task"]) for a in attrs),
            "level": "+".join(dict.fromkeys(str(a["level"]) for a in attrs)),
            "reward_task": sources[0].reward_task,
            "content_sha256": "+".join(str(a["content_sha256"]) for a in attrs), "transitions": transitions,
            "return_mean": float(returns.mean()) if len(returns) else float("nan"),
            "return_std": float(returns.std()) if len(returns) else float("nan"),
            "complete_episodes": int(len(returns))}


def load_source(source: DataSource, episode_length: int, device: torch.device | str = "cpu"
                ) -> tuple[TransitionTensors, dict]:
    """The transitions as tensors and a summary (content hash, level, mean episode return)."""
    arrays, rewards, returns, attrs = _read_source(source, episode_length)
    return TransitionTensors.from_arrays(arrays, rewards, device), _summary([source], [attrs], len(rewards), returns)


def load_sources(sources: Sequence[DataSource], episode_length: int, device: torch.device | str = "cpu"
                 ) -> tuple[TransitionTensors, dict]:
    """The union of several D_{j->i} (one reward task) as one set of tensors, in the order given
    (thesis 6.4.2's U_j D_{j->i}: each file's transitions with the reward task's relabelled rewards);
    the summary joins the files' names, tasks and content hashes with '+' and gives the episode
    returns over all of them. One source: :func:`load_source`."""
    if len(sources) == 1:
        return load_source(sources[0], episode_length, device)
    require(len({s.reward_task for s in sources}) == 1, "sources", "one reward task for every file of a union",
            [s.reward_task for s in sources])
    read = [_read_source(source, episode_length) for source in sources]
    keys = ("observations", "actions", "next_observations", "terminals", "timeouts")
    arrays = {key: np.concatenate([r[0][key] for r in read]) for key in keys}
    rewards, returns = np.concatenate([r[1] for r in read]), np.concatenate([r[2] for r in read])
    return (TransitionTensors.from_arrays(arrays, rewards, device),
            _summary(sources, [r[3] for r in read], len(rewards), returns))


def check_batch_fits(config: TeacherConfig, summary: dict) -> None:
    """A PBRL batch (drawn with replacement) larger than its dataset is a typo, not an experiment."""
    require(config.pbrl.batch_size <= summary["transitions"], "pbrl.batch_size",
            f"at most the {summary['transitions']} transitions of {summary['dataset']}", config.pbrl.batch_size)


def run_seeds(study_seed: int, name: Sequence[str], seed: int) -> dict[str, int]:
    """Seeds of one run, a function of (study seed, what it trains on, run seed) only."""
    return derive_seeds([study_seed, *name, seed], ("agent", "sampler", "eval", "final_eval", "conflict"))


@dataclass(frozen=True)
class TeacherJob:
    """One run of a teacher group: the task it learns, its data (D_{i->i}; with ``extra_sources`` the
    union of D_{j->i}, thesis 6.4.2), its seed and its files."""

    task: str
    source: DataSource
    seed: int
    paths: RunPaths
    extra_sources: tuple[DataSource, ...] = ()

    @property
    def sources(self) -> tuple[DataSource, ...]:
        return (self.source, *self.extra_sources)

    @classmethod
    def of(cls, run: TeacherRun) -> TeacherJob:
        """The job of a catalogue teacher run: D_{j->task} for each of its data tasks j (its own first)."""
        sources = [DataSource(dataset, relabel, run.task, source, run.level)
                   for dataset, relabel, source in zip(run.datasets, run.relabels, run.data_tasks)]
        return cls(run.task, sources[0], run.seed, run.paths, tuple(sources[1:]))


def anneal(agent: PBRLGroup | MultiTaskPBRL, step: int, steps: int) -> None:
    """Set the learning rate of step ``step`` of ``steps`` on every optimiser of ``agent``
    (``pbrl.lr_schedule``; a constant schedule leaves the optimisers untouched)."""
    pbrl = agent.config
    if pbrl.lr_schedule != "constant":
        set_learning_rate(agent.optimizers(), scheduled_rate(pbrl.learning_rate, pbrl.lr_schedule, step, steps))


class GroupLearner:
    """A :class:`PBRLGroup` with each run's dataset and index generator: ``update()`` draws run r's
    minibatch from run r's data with run r's generator (as :func:`train_teacher` alone would) and
    takes one step of every run; the generators' states are part of the resume state."""

    def __init__(self, agent: PBRLGroup, data: Sequence[TransitionTensors], samplers: Sequence[torch.Generator],
                 batch_size: int, steps: int):
        self.agent, self.data, self.samplers, self.batch_size = agent, list(data), list(samplers), batch_size
        self.steps = steps

    def update(self) -> dict:
        anneal(self.agent, self.agent.updates, self.steps)
        return self.agent.update(stack_batches([d.sample(self.batch_size, g) for d, g in zip(self.data,
                                                                                             self.samplers)]))

    def state_dict(self) -> dict:
        return {"agent": self.agent.state_dict(), "samplers": [g.get_state() for g in self.samplers]}

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["agent"])
        for generator, saved in zip(self.samplers, state["samplers"], strict=True):
            generator.set_state(saved)


def train_teacher(task: str, source: DataSource, config: TeacherConfig, seed: int, study_seed: int,
                  paths: RunPaths, device: torch.device | str = "cpu", progress: bool = False) -> dict:
    """Train one PBRL teacher for ``task`` on ``source`` (its own dataset: D_{i->i}), a group of one;
    write its files. Returns the metrics record (also written to ``paths.metrics``)."""
    return train_teacher_group([TeacherJob(task, source, seed, paths)], config, study_seed, paths.resume,
                               paths.timing, device, progress, f"{task}-{seed}")[0]


def train_teacher_group(jobs: Sequence[TeacherJob], config: TeacherConfig, study_seed: int, resume: Path,
                        timing: Path | None, device: torch.device | str = "cpu", progress: bool = False,
                        name: str = "teachers", max_group: int | None = None) -> list[dict]:
    """Train the teachers of ``jobs`` (one configuration: tasks and seeds of one level and actor type)
    as one vectorised PBRL group (:class:`~mop_core.agents.pbrl_group.PBRLGroup`); write each run's
    checkpoint, curve and metrics (``jobs[r].paths``), the group's resume file and its timing record.

    Each run draws what it would draw alone: its initialisation, its generator and its minibatch
    indices derive from (study seed, its task, data and seed), and it is evaluated on its own task
    with its own episode seeds; a group equals its runs trained alone to float rounding (tested).
    Where the device has no room for the whole group (measured: :mod:`mop_core.learning.group_memory`),
    or ``max_group`` caps it, the runs train in waves of as many as fit, one after another, each wave
    with its own resume file (``<resume>-wave<k>``). Returns the metrics records, one per job.
    """
    require(len(jobs) > 0, "jobs", "at least one teacher run", len(jobs))
    for job in jobs:
        check_task_list([job.task], "task")
    device = torch.device(device)
    loaded: dict[tuple[DataSource, ...], tuple[TransitionTensors, dict]] = {}
    for job in jobs:  # the seeds of one task share one copy of its data
        if job.sources not in loaded:  # in memory on the learner's device
            loaded[job.sources] = load_sources(job.sources, config.episode_length, device)
            check_batch_fits(config, loaded[job.sources][1])
    data = [loaded[j.sources] for j in jobs]
    probe = teacher_probe(config, data[0][0], device)

    def train_wave(wave: list[int], wave_resume: Path, wave_name: str, keep: bool) -> tuple[list[dict], float, int]:
        return _train_wave([jobs[r] for r in wave], [data[r] for r in wave], config, study_seed, wave_resume, device,
                           progress, wave_name, keep)
    return train_in_waves(len(jobs), probe, device, f"a teacher of {name}", max_group, resume, timing,
                          config.schedule.steps, name, train_wave)


def train_in_waves(runs: int, probe: Callable[[int], None], device: torch.device, what: str, max_group: int | None,
                   resume: Path, timing: Path | None, steps: int, name: str,
                   train_wave: Callable[[list[int], Path, str, bool], tuple[list[dict], float, int]]) -> list[dict]:
    """Train ``runs`` runs of one entry as one vectorised group, or in waves where the device has no room for
    all (``probe(R)`` steps a throwaway group of R: :mod:`mop_core.learning.group_memory`) or ``max_group``
    caps them. ``train_wave(runs, resume, name, keep)`` trains the runs given and returns their records,
    its seconds and the step it resumed from; a wave's resume file is ``<resume>-wave<k>``, kept (``keep``)
    until every wave is done. Writes the entry's timing record (``steps`` per wave); returns the records."""
    sizes = wave_sizes(runs, measure_footprint(probe, device), device_room(device), what, max_group)
    records, seconds, resumed = [], 0.0, []
    for k, wave in enumerate(split_waves(list(range(runs)), sizes)):
        wave_resume = resume if len(sizes) == 1 else _wave_file(resume, k)
        wave_records, wave_seconds, resumed_from = train_wave(
            wave, wave_resume, name if len(sizes) == 1 else f"{name} wave {k + 1}/{len(sizes)}", k + 1 < len(sizes))
        records += wave_records
        seconds += wave_seconds
        resumed.append(resumed_from)
    for kept in resume.parent.glob(_wave_file(resume, "*").name):  # every run done: the finished
        kept.unlink(missing_ok=True)  # waves' files go, and those of an earlier split (another device's room)
    if timing is not None:
        steps *= len(sizes)  # group steps: every wave's
        waves = {} if len(sizes) == 1 else {"waves": sizes}  # a whole group writes what it always wrote
        write_timing(timing, seconds, device, steps=steps, runs=runs, **waves,
                     steps_per_second=per_second(steps, seconds),
                     resumed_from_step=resumed[0] if len(resumed) == 1 else resumed)
    return records


def _wave_file(resume: Path, wave: int | str) -> Path:
    """Wave ``wave``'s resume file beside the entry's ``resume``: ``<stem>-wave<k><suffix>``."""
    return resume.with_name(f"{resume.stem}-wave{wave}{resume.suffix}")


def teacher_probe(config: TeacherConfig, data: TransitionTensors, device: torch.device) -> Callable[[int], None]:
    """:func:`~mop_core.agents.pbrl_group.probe_group` on minibatches of ``data``: what the footprint is measured on."""
    pbrl = config.pbrl
    sampler = torch.Generator(device).manual_seed(0)
    return probe_group(pbrl, OBS_DIM, ACT_DIM, lambda runs: stack_batches(
        [data.sample(pbrl.batch_size, sampler) for _ in range(runs)]), device)


def _train_wave(jobs: Sequence[TeacherJob], data: Sequence[tuple[TransitionTensors, dict]], config: TeacherConfig,
                study_seed: int, resume: Path, device: torch.device, progress: bool, name: str,
                keep: bool = False) -> tuple[list[dict], float, int]:
    """One group of :func:`train_teacher_group`: its records, seconds and the step it resumed from. With
    ``keep`` (waves follow it) its resume file is written again at the last step once its files are, so
    a rerun after a later wave's interruption restores this wave instead of training it again."""
    seeds = [run_seeds(study_seed, [job.task, summary["source_task"], summary["level"]], job.seed)
             for job, (_, summary) in zip(jobs, data)]
    agent = PBRLGroup(config.pbrl, OBS_DIM, ACT_DIM, [s["agent"] for s in seeds], device)
    samplers = [torch.Generator(device).manual_seed(s["sampler"]) for s in seeds]  # indices drawn where the data lies
    sched = config.schedule
    learner = GroupLearner(agent, [tensors for tensors, _ in data], samplers, config.pbrl.batch_size, sched.steps)

    def episodes(run: int, key: str, count: int) -> np.ndarray:
        return episode_returns(numpy_policy(agent.member_actor(run), device), jobs[run].task,
                               [seeds[run][key] + i for i in range(count)], config.episode_length, sched.rollout_envs)

    def evaluate(_: list[int]) -> dict[str, float]:  # each run on its own task with its own episode seeds
        rows = [returns_summary(episodes(r, "eval", sched.eval_episodes)) for r in range(len(jobs))]
        group_row = {run_key(k, r): v for r, row in enumerate(rows) for k, v in row.items()}
        return group_row | {"return_mean": float(np.mean([row["return_mean"] for row in rows]))}

    fingerprint = run_fingerprint({"runs": [{"task": j.task, "seed": j.seed, "data": s["content_sha256"],
                                             "reward_task": j.source.reward_task} for j, (_, s) in zip(jobs, data)],
                                   "config": to_dict(config), "study_seed": study_seed})
    group_curve, seconds, resumed_from = train_loop(learner, learner.update, evaluate, sched, seeds[0], None, resume,
                                                    fingerprint, f"teachers {name}", progress)
    curves = list(zip(*(split_runs(row, len(jobs)) for row in group_curve))) or [[] for _ in jobs]
    records = []
    for r, (job, (_, summary)) in enumerate(zip(jobs, data)):
        level = summary["level"]
        final = episodes(r, "final_eval", sched.final_eval_episodes)
        metrics = {"task": job.task, "level": level, "seed": job.seed, "return_mean": float(final.mean()),
                   "return_std": float(final.std()), "eval_episodes": len(final),
                   "dataset_return_mean": summary["return_mean"],
                   "return_ratio": float(final.mean() / summary["return_mean"]), "gradient_steps": sched.steps}
        actor_state = {k: v.cpu() for k, v in agent.member_actor(r).state_dict().items()}
        checkpoint = {
            "kind": TEACHER_KIND, "task": job.task, "level": level, "seed": job.seed, "study_seed": study_seed,
            "pbrl_config": to_dict(config.pbrl), "episode_length": config.episode_length,
            "obs_dim": OBS_DIM, "act_dim": ACT_DIM, "actor": actor_state,
            "critic": {k: v.cpu() for k, v in agent.member_critic_state(r).items()},
            "actor_sha256": state_sha256(actor_state), "dataset": summary, "metrics": metrics}
        records.append(finish_run(replace(job.paths, timing=None, resume=resume), checkpoint, list(curves[r]), metrics,
                                  seconds, sched.steps, resumed_from, device))
    if keep:
        write_resume(resume, fingerprint, sched.steps, learner.state_dict(), seconds, f"teachers {name}",
                     sampler=None, curve=list(group_curve), losses={})
    return records, seconds, resumed_from


def check_teacher_checkpoint(path: str | Path, task: str, level: str, seed: int, study_seed: int,
                             config: TeacherConfig, dataset_sha256: str | None) -> None:
    """Refuse a teacher checkpoint that was not trained as the study now says: another task, level,
    seed, study seed, PBRL setting, number of steps, episode length or dataset content (``dataset_sha256``
    None: a reader without the datasets among its inputs, which checks everything else). Raises
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
    if dataset_sha256 is not None:
        expected["dataset content_sha256"] = dataset_sha256
        found["dataset content_sha256"] = payload.get("dataset", {}).get("content_sha256")
    for key, value in expected.items():
        if found[key] != value:
            raise InputFileError(f"{path}: teacher trained with {key}={found[key]!r}, the study expects {value!r}; "
                                 "rerun `dvc repro train_teachers`")


# ---- the teacher stages' runs ------------------------------------------------------------------------
def entry_runs(params: Mapping[str, Any], level: str, actor: str, sharing: str | None = None,
               tasks: Sequence[str] | None = None, seeds: Sequence[int] | None = None) -> list[TeacherRun]:
    """The teachers of one entry (the catalogue's teacher_entries: of ``level`` and ``actor``; with the sharing
    kind ``sharing`` if set) among ``tasks`` and ``seeds`` (None: all of the entry's), in the entry's order:
    a subset retrains alone (a group of one: one teacher). An entry, task or seed the study does not
    have is refused, naming its command-line flag."""
    catalogue = build_catalogue(params)
    entries = catalogue.relabelled_teacher_entries() if sharing else catalogue.teacher_entries()
    entry = sharing_teacher_entry(sharing, level, actor) if sharing else teacher_entry(level, actor)
    if entry not in entries:
        flags = "--level/--sharing/--actor" if sharing else "--level/--actor"
        raise ConfigError(f"{flags}: expected an entry of this study, one of {list(entries)}, got {entry!r}")
    runs = entries[entry]
    for flag, asked, known in (("--tasks", tasks, [r.task for r in runs]), ("--seeds", seeds, [r.seed for r in runs])):
        for value in asked or ():
            require(value in known, flag, f"a subset of the {flag[2:]} of entry {entry}, {list(dict.fromkeys(known))}",
                    value)
    return [run for run in runs if (tasks is None or run.task in tasks) and (seeds is None or run.seed in seeds)]


def group_lines(runs: Sequence[TeacherRun], records: Sequence[Mapping]) -> list[str]:
    """What a trained group prints: each teacher's final return, then the group's seconds and update rate
    (its timing record)."""
    timing = read_json(runs[0].paths.timing)
    return [f"{run.name}: return {m['return_mean']:.1f} +- {m['return_std']:.1f} (dataset "
            f"{m['dataset_return_mean']:.1f}, ratio {m['return_ratio']:.2f})" for run, m in zip(runs, records)] + [
        f"{runs[0].entry}: {len(runs)} teachers in {timing['seconds']:.0f} s, {timing['steps_per_second']:.0f} group "
        "updates/s"]
