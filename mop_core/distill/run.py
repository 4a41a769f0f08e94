"""One distillation run: teachers + states -> a trained multi-task student and its files.

The student for tasks (t_0, ..., t_{m-1}) learns from teacher i on task i's states (offline: the
dataset teacher i was trained on; online: states teacher i visits). The run evaluates the student
online on every task every ``eval_every`` steps (the learning curve), can be resumed like every
training run (:mod:`mop_core.learning.training`), and ends with a checkpoint (config, student weights, the
teachers it learned from) and a metrics record (return per task next to the teacher's).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from mop_core.config import require, to_dict
from mop_core.distill.checkpoint import STUDENT_KIND
from mop_core.distill.config import DistillConfig
from mop_core.distill.corrections import density_weights
from mop_core.distill.dagger import with_dagger
from mop_core.distill.distiller import Distiller
from mop_core.distill.evaluation import GroupEvaluation, final_returns_record, shift_record, tau_record
from mop_core.distill.losses import LOSSES
from mop_core.distill.states import (
    TaskStates,
    offline_split,
    offline_states,
    online_states,
    q_switch_states,
    task_states,
)
from mop_core.experiment.runs import StudentRun
from mop_core.experiment.variants import Q_SWITCH_JUDGES
from mop_core.learning.resume import run_fingerprint
from mop_core.learning.runtime import derive_seeds
from mop_core.learning.schedule import TrainSchedule
from mop_core.learning.step_metrics import run_key, split_runs
from mop_core.learning.training import RunPaths, finish_run, train_loop
from mop_core.storage.artifacts import read_curve, state_sha256, write_curve
from mop_core.storage.timings import per_second, write_timing
from mop_core.teacher_policies import Teacher, load_teacher
from mop_core.walker.envs import ACT_DIM, OBS_DIM
from mop_core.walker.tasks import check_task_list


@dataclass(frozen=True)
class StudentSources:
    """What one student learns from: per task (in task-id order) a teacher and its offline dataset.

    Data sharing (thesis 6.4): ``state_datasets`` set, every task's states are the union of these
    files (D = U_i D_i) and every task's teacher labels every state; ``candidates`` set (OQS), task
    i's label at s is the action of ``argmax_j Q_ij(s, pi_ij(s))`` over its candidate teachers
    (candidates[i][j] trained on D_{j->i}), Q_ij each candidate's own critics (``judge`` own, the
    thesis's rule) or task i's own teacher's (``judge`` target, QMP's)."""

    tasks: tuple[str, ...]
    teachers: tuple[Path, ...]  # teacher checkpoints (train_teachers), teachers[i] trained for tasks[i]
    datasets: tuple[Path, ...]  # offline datasets, datasets[i] the one teachers[i] was trained on
    state_datasets: tuple[Path, ...] = ()  # the union every task's states come from; () = datasets[i] each
    candidates: tuple[tuple[Path, ...], ...] = ()  # OQS: per task, a checkpoint per source task j
    judge: str = "own"  # OQS: own | target
    heldout: tuple[Path, ...] = ()  # per task, held-out episodes of its data (the action error off the training
    #                                 states); () = none (a dataset share's held-out states: the rest of the dataset)
    references: tuple[Path, ...] = ()  # reweighted distillation: per task, the teacher's visited states

    @classmethod
    def of(cls, run: StudentRun) -> "StudentSources":
        """What the catalogue's student ``run`` learns from (every seed of its entry learns from the same)."""
        return cls(run.tasks, tuple(t.paths.checkpoint for t in run.teachers), run.datasets, run.state_datasets,
                   tuple(tuple(t.paths.checkpoint for t in per_task) for per_task in run.candidates),
                   run.variant.judge if run.candidates else "own", run.heldout_datasets, run.reference_datasets)

    def __post_init__(self) -> None:
        check_task_list(self.tasks, "tasks")
        for name in ("teachers", "datasets"):
            if len(getattr(self, name)) != len(self.tasks):
                raise ValueError(f"{name}: expected one per task ({len(self.tasks)}), got {len(getattr(self, name))}")
        if self.candidates and len(self.candidates) != len(self.tasks):
            raise ValueError(f"candidates: expected one list per task ({len(self.tasks)}), got {len(self.candidates)}")
        for name in ("heldout", "references"):
            if getattr(self, name) and len(getattr(self, name)) != len(self.tasks):
                raise ValueError(f"{name}: expected one per task ({len(self.tasks)}) or none, got "
                                 f"{len(getattr(self, name))}")
        if self.judge not in Q_SWITCH_JUDGES:
            raise ValueError(f"judge: expected one of {Q_SWITCH_JUDGES}, got {self.judge!r}")


def load_teachers(sources: StudentSources, loss: str) -> list[Teacher]:
    """The frozen teachers, checked against their tasks and the loss (KL needs Gaussian teachers)."""
    teachers = []
    for task, path in zip(sources.tasks, sources.teachers):
        teacher = load_teacher(path)
        if teacher.task != task:
            raise ValueError(f"{path}: a teacher for task {teacher.task!r}, expected one for {task!r}")
        need = LOSSES[loss].teacher_actor
        if teacher.config.actor != need:
            raise ValueError(f"{path}: the {loss} loss needs a {need} teacher, this one is {teacher.config.actor}")
        teachers.append(teacher)
    return teachers


def load_candidates(sources: StudentSources) -> list[list[Teacher]]:
    """OQS: per task its candidate teachers (checked: each trained for that task, deterministic)."""
    out = []
    for task, paths in zip(sources.tasks, sources.candidates):
        teachers = [load_teacher(path) for path in paths]
        for path, teacher in zip(paths, teachers):
            if teacher.task != task or teacher.config.actor != "deterministic":
                raise ValueError(f"{path}: an OQS candidate must be a deterministic teacher for {task!r}, got a "
                                 f"{teacher.config.actor} one for {teacher.task!r}")
        out.append(teachers)
    return out


def union_states(datasets: Sequence[Path], num_states: int, rng: np.random.Generator) -> np.ndarray:
    """The states of every file of ``datasets``, in order (``num_states`` > 0: that many of the union,
    drawn without replacement)."""
    states = np.concatenate([offline_states(d, 0, rng) for d in datasets])
    if 0 < num_states < len(states):
        states = states[np.sort(rng.choice(len(states), size=num_states, replace=False))]
    return states


def build_states(sources: StudentSources, teachers: Sequence[Teacher], config: DistillConfig, episode_length: int,
                 seed: int, rollout_envs: int, device: torch.device,
                 candidates: Sequence[Sequence[Teacher]] = ()) -> list[TaskStates]:
    """Each task's distillation states (offline or online) with its teacher's outputs cached (OQS:
    the Q-switch's choice among ``candidates``)."""
    result = []
    shared = None
    if sources.state_datasets:  # data sharing: one union, the same states for every task
        require(config.state_source == "offline", "state_source", "offline for data-sharing students (they learn "
                "on the union of the offline datasets)", config.state_source)
        require(config.data_fraction == 1, "data_fraction", "1 for data-sharing students (they learn on the whole "
                "union)", config.data_fraction)
        shared = union_states(sources.state_datasets, config.num_states,
                              np.random.default_rng(derive_seeds([seed, "union"], ("subset",))["subset"]))
    require(config.correction != "reweight" or len(sources.references) == len(sources.tasks), "correction",
            "reweight only with the teachers' reference states (StudentSources.references)", config.correction)
    for i, (task, teacher, dataset) in enumerate(zip(sources.tasks, teachers, sources.datasets)):
        task_seeds = derive_seeds([seed, task], ("subset", "episodes", "reweight"))
        heldout = None
        if shared is not None:
            states = shared
            source = {"source": "offline_union", "datasets": [str(d) for d in sources.state_datasets],
                      "states": len(states)}
        elif config.state_source == "offline":
            states, heldout = offline_split(dataset, config.num_states, np.random.default_rng(task_seeds["subset"]),
                                            config.data_fraction)
            source = {"source": "offline", "dataset": str(dataset), "states": len(states)}
            if config.data_fraction < 1:
                source["data_fraction"] = config.data_fraction
        else:
            episodes = -(-config.num_states // episode_length)
            seeds = [task_seeds["episodes"] + j for j in range(episodes)]
            states = online_states(teacher.act, task, config.num_states, episode_length, seeds, rollout_envs)
            source = {"source": "online", "episodes": episodes, "first_seed": seeds[0], "states": len(states)}
        require(config.batch_size <= len(states), "batch_size",
                f"at most the {len(states)} states of {task} ({source.get('dataset', 'online')})", config.batch_size)
        weights = None
        if config.correction == "reweight":
            reference = offline_states(sources.references[i], 0, np.random.default_rng(0))
            weights, info = density_weights(states, reference, config.reweight, task_seeds["reweight"],
                                            episode_rows=episode_length)  # whole episodes, in dataset order
            source |= {"reference": str(sources.references[i])} | info
        if sources.heldout:
            heldout = offline_states(sources.heldout[i], 0, np.random.default_rng(0))
            source["heldout"] = str(sources.heldout[i])
        if candidates:
            judges = candidates[i] if sources.judge == "own" else [teacher] * len(candidates[i])
            states_i = q_switch_states(task, states, candidates[i], judges, config.q_reduction, source, device)
        else:
            states_i = task_states(task, states, teacher.actor, source, device)
        if weights is not None:
            states_i.weights = torch.as_tensor(weights, dtype=torch.float32, device=device)
        if heldout is not None and len(heldout):
            states_i.heldout = torch.as_tensor(heldout, device=device)
        result.append(states_i)
    return result


def group_states(sources: StudentSources, teachers: Sequence[Teacher], config: DistillConfig, episode_length: int,
                 seeds: Sequence[int], rollout_envs: int, device: torch.device,
                 candidates: Sequence[Sequence[Teacher]] = ()) -> list[list[TaskStates]]:
    """Each run's distillation states (:func:`build_states` with the run's seed); the whole offline
    dataset is the same for every seed: built once and shared."""
    first = build_states(sources, teachers, config, episode_length, seeds[0], rollout_envs, device, candidates)
    if config.state_source == "offline" and config.num_states == 0 and config.data_fraction == 1:
        return [first] * len(seeds)
    return [first] + [build_states(sources, teachers, config, episode_length, seed, rollout_envs, device, candidates)
                      for seed in seeds[1:]]


def offline_probes(sources: StudentSources, per_task: int, seed: int) -> list[torch.Tensor]:
    """``per_task`` states of each task's offline dataset (drawn without replacement with ``seed``), on
    which the per-state tau curve is measured during training (``probe_source: offline``). The seed
    depends on the study and the teachers' tasks and levels only, so every student of a pairing -
    whatever its loss, seed or distillation states - is measured on the same states."""
    return [torch.as_tensor(offline_states(dataset, per_task, np.random.default_rng([seed, i])))
            for i, dataset in enumerate(sources.datasets)]


def distill_student(sources: StudentSources, config: DistillConfig, schedule: TrainSchedule, episode_length: int,
                    seed: int, study_seed: int, paths: RunPaths, device: torch.device | str = "cpu",
                    progress: bool = False, name: str = "student") -> dict:
    """Distil the teachers of ``sources`` into one student (a group of one); write its files.

    Returns the metrics record (also written to ``paths.metrics``)."""
    return distill_students(sources, config, schedule, episode_length, [seed], study_seed, [paths], paths.resume,
                            paths.timing, device, progress, name)[0]


def q_switch_record(targets: Sequence[TaskStates]) -> dict:
    """OQS: per task, the share of its states whose label each candidate teacher gave ({} otherwise)."""
    if not any("q_switch" in t.source for t in targets):
        return {}
    return {"q_switch": {t.task: t.source["q_switch"] for t in targets}}


def conflict_rows(distiller: Distiller, seed: int) -> list[dict[str, float]]:
    """Each run's gradient-conflict columns now (none with one task), on states of a stream of their
    own per step: measuring changes no training draw, and a resumed run measures what an
    uninterrupted one does."""
    if len(distiller.tasks) < 2:
        return [{} for _ in range(distiller.runs)]
    return distiller.gradient_cosines(torch.Generator(distiller.device).manual_seed(seed + distiller.updates))


def distill_students(sources: StudentSources, config: DistillConfig, schedule: TrainSchedule, episode_length: int,
                     seeds: Sequence[int], study_seed: int, paths: Sequence[RunPaths], resume: Path,
                     timing: Path | None, device: torch.device | str = "cpu", progress: bool = False,
                     name: str = "students") -> list[dict]:
    """Distil the teachers of ``sources`` into one student per seed, all seeds trained together as one
    vectorised group (:class:`~mop_core.distill.distiller.Distiller`); write each run's checkpoint,
    curve and metrics (``paths[r]``), the group's resume file and its timing record.

    Each run's result is what the run alone would give (its own initialisation, states and index
    stream; tested to float rounding). Returns the metrics records, one per seed.
    """
    require(len(set(seeds)) == len(seeds) and len(seeds) == len(paths) and seeds, "seeds",
            f"distinct seeds, one per output path ({len(paths)})", list(seeds))
    device = torch.device(device)
    teachers = load_teachers(sources, config.loss)
    candidates = load_candidates(sources) if sources.candidates else []
    levels = [t.level for t in teachers]
    # What differs between students of a pairing (initialisation, distillation states) derives from the
    # student seed; what every student of the pairing must share (evaluation episodes, probe states)
    # does not depend on the loss or the seed.
    run_seeds = [derive_seeds([study_seed, "distill", *sources.tasks, *levels, seed], ("agent", "states"))
                 for seed in seeds]
    shared = derive_seeds([study_seed, "distill", *sources.tasks, *levels], ("eval", "final_eval", "probe",
                                                                           "conflict", "dagger"))
    targets = group_states(sources, teachers, config, episode_length, [s["states"] for s in run_seeds],
                           schedule.rollout_envs, device, candidates)
    critics = [t.critic for t in teachers] if LOSSES[config.loss].needs_critics else None
    distiller = Distiller(config, targets, OBS_DIM, ACT_DIM, [s["agent"] for s in run_seeds], critics, device,
                          schedule.steps)
    track_tau = config.probe_states > 0 and len(sources.tasks) > 1
    evaluation = GroupEvaluation(
        sources.tasks, episode_length, schedule.rollout_envs, device, track_tau, config.probe_states, shared["probe"],
        offline_probes(sources, config.probe_states, shared["probe"])
        if track_tau and config.probe_source == "offline" else [],
        [shared["final_eval"] + i for i in range(schedule.final_eval_episodes)])

    def evaluate(eval_seeds: list[int]) -> dict[str, float]:
        students = [distiller.student(r) for r in range(len(seeds))]
        rows = evaluation.rows(students, evaluation.per_task(students, eval_seeds))
        rows = [row | cosines for row, cosines in zip(rows, conflict_rows(distiller, shared["conflict"]))]
        group_row = {run_key(k, r): v for r, row in enumerate(rows) for k, v in row.items()}
        return group_row | {"return_mean": float(np.mean([row["return_mean"] for row in rows]))}

    tau_at_init: list[dict[str, float]] = [{} for _ in seeds]
    if track_tau:  # the untrained students, measured the way the curve is (visited: their own first episodes)
        first = [shared["eval"] + i for i in range(schedule.eval_episodes)]
        untrained = [distiller.student(r) for r in range(len(seeds))]
        tau_at_init = ([evaluation.probe_tau(student, []) for student in untrained] if evaluation.fixed_probes else
                       [{k: v for k, v in row.items() if k.startswith("per_state_tau_")}
                        for row in evaluation.rows(untrained, evaluation.per_task(untrained, first))])

    fingerprint = run_fingerprint({"tasks": sources.tasks, "config": to_dict(config), "schedule": to_dict(schedule),
                                   "seeds": list(seeds), "study_seed": study_seed,
                                   "teachers": [t.actor_sha256 for t in teachers],
                                   "candidates": [[c.actor_sha256 for c in per_task] for per_task in candidates],
                                   "judge": sources.judge if candidates else None,
                                   "states": [[t.source for t in run] for run in targets]})
    update = with_dagger(distiller, teachers, schedule.steps, shared["dagger"], evaluation.rollouts)
    group_curve, seconds, resumed_from = train_loop(distiller, update, evaluate, schedule, shared, None, resume,
                                                    fingerprint, f"distill {name}", progress, evaluation.final_seeds)
    curves = [[split_runs(row, len(seeds))[r] for row in group_curve] for r in range(len(seeds))]
    students = [distiller.student(r) for r in range(len(seeds))]
    final_rollouts = evaluation.final_rollouts(students)
    finals = [[returns for returns, _ in per_task] for per_task in final_rollouts]  # [task][run]
    visited = [[states for _, states in per_task] for per_task in final_rollouts]
    records = []
    for r, (seed, run_paths) in enumerate(zip(seeds, paths)):
        student, curve = students[r], curves[r]
        metrics: dict = {"tasks": list(sources.tasks), "loss": config.loss, "levels": levels, "seed": seed,
                         "gradient_steps": schedule.steps, "trained_with_seeds": list(seeds)}
        if track_tau:
            metrics["per_state_tau"] = tau_record(config, evaluation.fixed_probes, tau_at_init[r], curve[-1])
        metrics |= q_switch_record(targets[r])
        metrics |= final_returns_record(sources.tasks, teachers, [finals[i][r] for i in range(len(sources.tasks))])
        shift_record(metrics, distiller, r, student, teachers, [per_task[r] for per_task in visited], device)
        student_state = {k: v.cpu() for k, v in student.state_dict().items()}
        checkpoint = {
            "kind": STUDENT_KIND, "tasks": list(sources.tasks), "seed": seed, "study_seed": study_seed,
            "distill_config": to_dict(config), "schedule": to_dict(schedule), "episode_length": episode_length,
            "obs_dim": OBS_DIM, "act_dim": ACT_DIM, "student": student_state,
            "student_sha256": state_sha256(student_state),
            "teachers": [{"path": str(p), "task": t.task, "level": t.level, "seed": t.seed, "actor": t.config.actor,
                          "actor_sha256": t.actor_sha256} for p, t in zip(sources.teachers, teachers)],
            "states": [t.source for t in targets[r]], "metrics": metrics}
        records.append(finish_run(replace(run_paths, timing=None, resume=resume), checkpoint, curve, metrics,
                                  seconds, schedule.steps, resumed_from, device))
    if timing is not None:
        write_timing(timing, seconds, device, steps=schedule.steps, runs=len(seeds),
                     steps_per_second=per_second(schedule.steps, seconds), resumed_from_step=resumed_from)
    return records


def write_tau_curves(directory: Path, curve: list[dict]) -> None:
    """Each per-state tau the student logged (``per_state_tau_<a|b>_layer<k>`` columns of its learning
    curve) as its own two-column TSV (step, tau) in ``directory``: a stage-level ``dvc plots`` output
    draws one curve per file, whatever the number of layers. No column (probe_states = 0): an empty
    directory."""
    directory.mkdir(parents=True, exist_ok=True)
    for old in directory.glob("*.tsv"):
        old.unlink()
    keys = [key for key in (curve[0] if curve else {}) if key.startswith("per_state_tau_")]
    for key in keys:
        write_curve(directory / f"{key}.tsv", [{"step": row["step"], "tau": row[key]} for row in curve])


def finish_students(runs: Sequence[StudentRun], records: Sequence[dict]) -> None:
    """Per trained student: its per-state tau curves (:func:`write_tau_curves`) and a summary line."""
    for run, metrics in zip(runs, records):
        write_tau_curves(run.tau_dir, read_curve(run.paths.curve))
        print_summary(run.name, metrics)


def print_summary(name: str, metrics: dict) -> None:
    for task in metrics["tasks"]:
        m = metrics[task]
        print(f"student {name} on {task}: return {m['return_mean']:.1f} +- {m['return_std']:.1f} "
              f"(teacher {m['teacher_return_mean']:.1f}, ratio {m['student_to_teacher']:.2f})")
