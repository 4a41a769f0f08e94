"""Composed datasets (thesis 5.2.4): offline datasets built from a teacher's own rollouts, with a
chosen share of episodes in which it acts perturbed, to give the student's data a known, graded
state distribution shift from the states the teacher visits.

Per task i and its teacher pi_i^T, a composition names the share of whole episodes the teacher
acts in (``teacher_share``) and how the rest act (``rest``):

- ``noise``: ``clip(pi_i^T(s) + N(0, sigma^2 I), -1, 1)`` (the thesis's Noise data, sigma = 1; DART's
  supervisor noise, Laskey et al. 2017);
- ``random``: ``U(-1, 1)^6``, the teacher not involved (Random90: 10% teacher, Random99: 1%).

The thesis's four: online (100% teacher: no shift), noise (10% / 90% noisy), random90 (10% / 90%
random), random99 (1% / 99% random). Every dataset has ``episodes`` episodes; a composition's teacher
episodes are ``round(teacher_share * episodes)``, at least one.

The episodes come from three pools per task, each rolled out once with its own seeds: the teacher's,
the noisy teacher's and the random policy's. A dataset takes the first episodes of each pool it
needs, so random90's random episodes are random99's first 90 and every dataset's teacher episodes are
the online dataset's first ones (common random numbers: the datasets differ only by composition).
A separate set of ``reference_episodes`` teacher episodes on other seeds is the teacher's state
distribution against which the state_shift stage measures each dataset (held out: the online
dataset is compared with teacher states it does not contain).

Each dataset also gets ``heldout_episodes`` held-out episodes of the same composition
(``<name>_heldout``: a train/validation split of whole episodes, as OGBench ships), from three more
pools on their own seeds: the student's action error on them is its error off its training states.
Their teacher episodes are ``round(teacher_share * heldout_episodes)``, which may be
0 (random99 at 10 held-out episodes: the expected 0.1 rounds to none).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from mop_core.config import from_mapping, keys_under, require
from mop_core.data import write_dataset
from mop_core.experiment.runs import TeacherRun
from mop_core.learning.runtime import derive_seeds
from mop_core.storage.layout import REFERENCE, composed_file, heldout_name
from mop_core.walker.rollout import Policy, collect_episodes

REST_POLICIES = ("noise", "random")
POOLS = ("teacher", *REST_POLICIES)
HELDOUT = "heldout_"  # the held-out pools' prefix: heldout_teacher, heldout_noise, heldout_random


@dataclass(frozen=True)
class Composition:
    """One composed dataset: the share of its episodes the teacher acts in, how the others act."""

    teacher_share: float
    rest: str = "noise"  # noise | random

    def __post_init__(self) -> None:
        require(0 < self.teacher_share <= 1, "teacher_share", "a share in (0, 1]", self.teacher_share)
        require(self.rest in REST_POLICIES, "rest", f"one of {', '.join(REST_POLICIES)}", self.rest)

    def teacher_episodes(self, episodes: int, at_least_one: bool = True) -> int:
        """Whole teacher episodes of a dataset of ``episodes``: the share rounded, at least one (a
        held-out set: ``at_least_one=False``, the share rounded)."""
        return min(episodes, max(int(at_least_one), int(round(self.teacher_share * episodes))))


THESIS_COMPOSITIONS = {"online": Composition(1.0), "noise": Composition(0.1, "noise"),
                       "random90": Composition(0.1, "random"), "random99": Composition(0.01, "random")}


@dataclass(frozen=True)
class ComposeConfig:
    """The composed datasets of a study (the ``state_shift`` section's data part)."""

    datasets: tuple[str, ...] = tuple(THESIS_COMPOSITIONS)
    compositions: Mapping[str, Composition] = field(default_factory=lambda: dict(THESIS_COMPOSITIONS))
    episodes: int = 100  # per composed dataset
    noise_std: float = 1.0  # sigma of the noisy teacher's Gaussian action noise
    reference_episodes: int = 20  # held-out teacher episodes: the teacher's state distribution
    heldout_episodes: int = 10  # per composed dataset: held-out episodes of its composition
    rollout_envs: int = 10

    def __post_init__(self) -> None:
        compositions = {}
        for name, value in dict(self.compositions).items():
            with keys_under(f"compositions.{name}"):
                compositions[name] = (value if isinstance(value, Composition)
                                      else from_mapping(Composition, value, f"compositions.{name}")
                                      if isinstance(value, Mapping) else value)
            require(isinstance(compositions[name], Composition), f"compositions.{name}",
                    "a mapping {teacher_share: <share>, rest: noise | random}", value)
        object.__setattr__(self, "compositions", compositions)
        for i, name in enumerate(self.datasets):
            require(name in compositions, f"datasets[{i}]", f"one of compositions {sorted(compositions)}", name)
            require(name != REFERENCE and "-" not in name and name.isidentifier()
                    and not name.endswith(heldout_name("")), f"datasets[{i}]", f"a name of letters, digits and "
                    f"'_' other than {REFERENCE!r}, not ending in {heldout_name('')!r}", name)
        require(len(set(self.datasets)) == len(self.datasets), "datasets", "a list without repeats",
                list(self.datasets))
        require(self.episodes >= 1, "episodes", "a positive integer", self.episodes)
        require(self.noise_std >= 0, "noise_std", "a non-negative number", self.noise_std)
        require(self.reference_episodes >= 2, "reference_episodes", "at least 2 (the shift's split-half null "
                "compares two halves)", self.reference_episodes)
        require(self.heldout_episodes >= 1, "heldout_episodes", "a positive integer (the students' held-out "
                "action error)", self.heldout_episodes)
        require(self.rollout_envs >= 1, "rollout_envs", "a positive integer", self.rollout_envs)

    def counts(self, name: str, heldout: bool = False) -> tuple[int, int]:
        """(teacher episodes, rest episodes) of dataset ``name`` or of its held-out set."""
        episodes = self.heldout_episodes if heldout else self.episodes
        teacher = self.compositions[name].teacher_episodes(episodes, at_least_one=not heldout)
        return teacher, episodes - teacher

    def pool_sizes(self, heldout: bool = False) -> dict[str, int]:
        """Episodes rolled out per pool (teacher, noise, random): what the datasets (or their held-out
        sets) need, at most."""
        sizes = dict.fromkeys(POOLS, 0)
        for name in self.datasets:
            teacher, rest = self.counts(name, heldout)
            sizes["teacher"] = max(sizes["teacher"], teacher)
            if rest:
                rest_pool = self.compositions[name].rest
                sizes[rest_pool] = max(sizes[rest_pool], rest)
        return sizes


def random_policy(rng: np.random.Generator) -> Policy:
    """Uniformly random torques in [-1, 1] for every walker of a batch."""
    return lambda obs: rng.uniform(-1.0, 1.0, size=(len(obs), 6))


def _episode_slice(arrays: Mapping[str, np.ndarray], count: int, episode_length: int) -> dict[str, np.ndarray]:
    return {key: value[:count * episode_length] for key, value in arrays.items()}


def concatenate(parts: Sequence[Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
    parts = [p for p in parts if len(p["rewards"])]
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


def pool_seeds(seed: int, task: str, level: str, pool: str, count: int) -> list[int]:
    """Episode seeds of one pool (teacher, noise, random, reference) of a task's composed data."""
    base = derive_seeds([seed, "compose", task, level, pool], ("episodes",))["episodes"] % (2 ** 31 - 100_000)
    return [base + j for j in range(count)]


def roll_pools(teacher: Policy, task: str, level: str, sizes: Mapping[str, int], noise_std: float, seed: int,
               episode_length: int, rollout_envs: int, prefix: str = "") -> dict[str, dict[str, np.ndarray]]:
    """The teacher, noisy-teacher and random pools of one task (``prefix``: the held-out pools, on
    their own seeds), each ``sizes[pool]`` episodes (none when 0)."""
    pools: dict[str, dict[str, np.ndarray]] = {}
    rng = {name: np.random.default_rng(derive_seeds([seed, "compose", task, level, prefix + name],
                                                    ("actions",))["actions"]) for name in REST_POLICIES}
    policies = {"teacher": (teacher, 0.0, None), "noise": (teacher, noise_std, rng["noise"]),
                "random": (random_policy(rng["random"]), 0.0, None)}
    for name, (policy, std, noise_rng) in policies.items():
        if sizes[name]:
            pools[name] = collect_episodes(policy, task, pool_seeds(seed, task, level, prefix + name, sizes[name]),
                                           episode_length, rollout_envs, std, noise_rng)
    return pools


def composed_arrays(pools: Mapping[str, Mapping[str, np.ndarray]], teacher_count: int, rest_count: int, rest: str,
                    episode_length: int) -> dict[str, np.ndarray]:
    """The first ``teacher_count`` episodes of the teacher pool, then the first ``rest_count`` of the
    ``rest`` pool."""
    parts = []
    if teacher_count:
        parts.append(_episode_slice(pools["teacher"], teacher_count, episode_length))
    if rest_count:
        parts.append(_episode_slice(pools[rest], rest_count, episode_length))
    return concatenate(parts)


def compose_task(teacher: Policy, task: str, level: str, config: ComposeConfig, seed: int, episode_length: int,
                 write: Callable[[str, dict[str, np.ndarray], dict[str, Any]], None]) -> dict[str, dict]:
    """Roll out the pools of one task and write each composed dataset, its held-out episodes and the
    reference episodes through ``write(name, arrays, attrs)``. Returns per dataset its composition and
    episode counts."""
    def roll(sizes: Mapping[str, int], prefix: str = "") -> dict[str, dict[str, np.ndarray]]:
        return roll_pools(teacher, task, level, sizes, config.noise_std, seed, episode_length, config.rollout_envs,
                          prefix)

    pools, heldout_pools = roll(config.pool_sizes()), roll(config.pool_sizes(heldout=True), HELDOUT)
    reference = collect_episodes(teacher, task, pool_seeds(seed, task, level, REFERENCE, config.reference_episodes),
                                 episode_length, config.rollout_envs)
    summary = {}
    for name in config.datasets:
        composition = config.compositions[name]
        for file_name, source, heldout in ((name, pools, False), (heldout_name(name), heldout_pools, True)):
            teacher_count, rest_count = config.counts(name, heldout)
            arrays = composed_arrays(source, teacher_count, rest_count, composition.rest, episode_length)
            write(file_name, arrays, {"composition": name, "teacher_episodes": teacher_count,
                                      "rest": composition.rest, "rest_episodes": rest_count,
                                      "noise_std": config.noise_std, "heldout": int(heldout)})
            returns = arrays["rewards"].reshape(-1, episode_length).sum(1)
            summary[file_name] = {"teacher_episodes": teacher_count,
                                  "rest": composition.rest if rest_count else None, "rest_episodes": rest_count,
                                  "transitions": len(arrays["rewards"]), "return_mean": float(returns.mean()),
                                  "return_std": float(returns.std())}
    write(REFERENCE, reference, {"composition": REFERENCE, "teacher_episodes": config.reference_episodes,
                                 "rest": "none", "rest_episodes": 0, "noise_std": 0.0, "heldout": 0})
    ref_returns = reference["rewards"].reshape(-1, episode_length).sum(1)
    summary[REFERENCE] = {"teacher_episodes": config.reference_episodes, "transitions": len(reference["rewards"]),
                          "return_mean": float(ref_returns.mean()), "return_std": float(ref_returns.std())}
    return summary


def dataset_writer(path_of: Callable[[str], Path], base_attrs: Mapping[str, Any]
                   ) -> Callable[[str, dict[str, np.ndarray], dict[str, Any]], None]:
    """A ``write`` for :func:`compose_task`: each dataset to ``path_of(name)`` (atomic, the dataset
    schema of mop_core.data) with ``base_attrs`` (task, level, seed, episode_length, behaviour_sha256)."""
    def write(name: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> None:
        write_dataset(path_of(name), arrays, dict(base_attrs) | attrs)
    return write


def compose_config(grid) -> ComposeConfig:
    """The composed-data settings of a :class:`mop_core.experiment.study.ShiftGrid` (errors name ``state_shift.<key>``);
    no ``compositions`` in the params: the thesis's four."""
    with keys_under("state_shift"):
        return ComposeConfig(datasets=tuple(grid.datasets), compositions=dict(grid.compositions or THESIS_COMPOSITIONS),
                             episodes=grid.episodes, noise_std=grid.noise_std,
                             reference_episodes=grid.reference_episodes, heldout_episodes=grid.heldout_episodes,
                             rollout_envs=grid.rollout_envs)


def compose_teacher_data(teacher_path: Path, task: str, level: str, config: ComposeConfig, seed: int,
                         episode_length: int, path_of: Callable[[str], Path]) -> dict:
    """The compose step of one task (a :func:`mop_core.learning.runtime.parallel_map` job): load the frozen
    deterministic teacher of ``teacher_path`` and write its composed datasets and reference episodes
    to ``path_of(name)``. Returns :func:`compose_task`'s summary with the seconds it took."""
    from mop_core.teacher_policies import load_teacher  # torch only in the compose workers

    started = time.perf_counter()
    teacher = load_teacher(teacher_path)
    if teacher.task != task or teacher.config.actor != "deterministic":
        raise ValueError(f"{teacher_path}: composing {task}'s data needs its deterministic teacher, got a "
                         f"{teacher.config.actor} one for {teacher.task!r}")
    attrs = {"task": task, "level": level, "seed": seed, "episode_length": episode_length,
             "behaviour_sha256": teacher.actor_sha256}
    summary = compose_task(teacher.act, task, level, config, seed, episode_length, dataset_writer(path_of, attrs))
    return {"datasets": summary, "teacher": str(teacher_path), "seconds": round(time.perf_counter() - started, 1)}


def compose_jobs(teachers: Sequence[TeacherRun], config: ComposeConfig, seed: int, episode_length: int) -> list[tuple]:
    """The :func:`compose_teacher_data` jobs of ``teachers`` (one per task), each writing its datasets to
    data/composed/<task>-<level>-<name>.hdf5 (mop_core.storage.layout.composed_file)."""
    return [(t.paths.checkpoint, t.task, t.level, config, seed, episode_length, partial(composed_file, t.task, t.level))
            for t in teachers]


def compose_metrics(teachers: Sequence[TeacherRun], summaries: Sequence[Mapping]) -> dict[str, Mapping]:
    """The compose stage's metrics (mop_core.storage.layout.COMPOSE_METRICS; the report's composed-data
    table reads them): per composing teacher, ``<task>-<level>`` -> its :func:`compose_teacher_data` summary
    without the seconds it took (those go to the timing record: an output holds only what the run computed,
    so a rerun, or a run on another machine, writes the same bytes)."""
    return {f"{t.task}-{t.level}": {k: v for k, v in summary.items() if k != "seconds"}
            for t, summary in zip(teachers, summaries, strict=True)}


def compose_seconds(teachers: Sequence[TeacherRun], summaries: Sequence[Mapping]) -> dict[str, float]:
    """``<task>-<level>`` -> the seconds its :func:`compose_teacher_data` took (the stage's timing record)."""
    return {f"{t.task}-{t.level}": summary["seconds"] for t, summary in zip(teachers, summaries, strict=True)}


def summary_lines(metrics: Mapping[str, Mapping], seconds: Mapping[str, float]) -> list[str]:
    """One line per composed task (``<task>-<level>``: :func:`compose_metrics`'s entry): each dataset's
    mean episode return and the seconds it took."""
    return [f"compose {key}: episode returns "
            + ", ".join(f"{name} {d['return_mean']:.0f}" for name, d in summary["datasets"].items())
            + f" ({seconds[key]:.0f} s)" for key, summary in metrics.items()]
