"""mop_core/experiment/study.py: the study grid as typed configs; every bad value raises a ConfigError naming its
key."""

from __future__ import annotations

import copy
import re

import pytest

from mop_core.config import ConfigError
from mop_core.experiment.catalogue import LOSS_ACTORS
from mop_core.experiment.study import (
    SECTIONS,
    DistillGrid,
    MultitaskGrid,
    StudyConfig,
    TeacherGrid,
    check_sections,
    distill_grid,
    multitask_grid,
    pairing_levels,
    positive_threads,
    section,
    study_config,
    teacher_grid,
    typed_section,
)
from mop_core.learning.schedule import TrainSchedule


def _set(params: dict, key: str, value) -> dict:
    params = copy.deepcopy(params)
    *path, last = key.split(".")
    node = params
    for part in path:
        node = node[part]
    node[last] = value
    return params


def _raises(message: str):
    return pytest.raises(ConfigError, match="^" + re.escape(message))


STUDY = StudyConfig(tasks=("stand", "walk"), levels=("expert", "medium"))


def test_pairing_levels_gives_one_level_per_study_task():
    assert pairing_levels("medium", STUDY) == ("medium", "medium")
    assert pairing_levels("expert+medium", STUDY) == ("expert", "medium")
    assert pairing_levels("medium+expert", STUDY) == ("medium", "expert")
    assert pairing_levels("expert", StudyConfig(tasks=("run",), levels=("expert",))) == ("expert",)
    three = StudyConfig(tasks=("stand", "walk", "run"), levels=("medium",))
    assert pairing_levels("medium", three) == ("medium",) * 3


def test_a_bad_pairing_names_its_key():
    with _raises("distill.pairings: expected one level or one per study task (2) joined by '+', "
                 "got 'expert+medium+expert'"):
        pairing_levels("expert+medium+expert", STUDY)
    with _raises("distill.pairings: expected levels among study.levels ['expert', 'medium'], got 'medium_replay'"):
        pairing_levels("medium_replay", STUDY, "distill.pairings")
    with _raises("distill.pairings: expected levels among study.levels ['expert', 'medium'], got 'expert+random'"):
        pairing_levels("expert+random", STUDY)
    with _raises("distill.pairings: expected one level or one per study task (3) joined by '+', got 'expert+medium'"):
        pairing_levels("expert+medium", StudyConfig(tasks=("stand", "walk", "run")))
    with _raises("distill.pairings: expected levels among study.levels ['expert', 'medium'], got 'expert+'"):
        pairing_levels("expert+", STUDY)  # an empty level


def test_the_tiny_profiles_grid(tiny_params):
    study = study_config(tiny_params)
    assert study == StudyConfig(tasks=("stand", "walk"), levels=("medium",), seed=0, episode_length=50, device="cpu",
                                progress=False)
    teachers = teacher_grid(tiny_params)
    assert teachers.actors == ("deterministic", "gaussian") and teachers.seeds == (0,) and teachers.threads == 1
    assert teachers.schedule_for("medium") == TrainSchedule(steps=40, eval_every=20, eval_episodes=2,
                                                            final_eval_episodes=2, checkpoint_every=20, rollout_envs=2)
    assert teachers.pbrl["batch_size"] == 32 and "actor" not in teachers.pbrl
    assert multitask_grid(tiny_params, study) == MultitaskGrid(levels=("medium",), seeds=(0,))
    assert distill_grid(tiny_params, study, LOSS_ACTORS) == DistillGrid(
        losses=("mse", "q", "kl"), pairings=("medium",), seeds=(0,), teacher_seed=0, threads=1,
        schedule=TrainSchedule(steps=20, eval_every=10, eval_episodes=1, final_eval_episodes=1, checkpoint_every=10,
                               rollout_envs=1))


THREADS_EXPECTED = "expected a positive integer or 'auto' (the cores this process may use)"


@pytest.mark.parametrize("key,value,message", [
    ("study.tasks", [], "study.tasks: expected at least one task"),
    ("study.tasks", ["stand", "hop"], "study.tasks[1]: unknown task 'hop'"),
    ("study.tasks", ["walk", "walk"], "study.tasks: tasks must not repeat"),
    ("study.levels", ["medium", "random"], "study.levels[1]: expected one of expert, medium, medium_replay, "
                                           "got 'random'"),
    ("study.levels", ["medium", "medium"], "study.levels: expected a non-empty list without repeats"),
    ("study.levels", [], "study.levels: expected a non-empty list without repeats, got []"),
    ("study.seed", -1, "study.seed: expected a non-negative integer, got -1"),
    ("study.episode_length", 0, "study.episode_length: expected a positive integer, got 0"),
    ("study.device", 0, "study.device: expected a string, got 0"),
    ("study.cuda_matmul", "bf16", "study.cuda_matmul: expected one of fp32, tf32, got 'bf16'"),
])
def test_study_config_checks(tiny_params, key, value, message):
    with _raises(message):
        study_config(_set(tiny_params, key, value))


@pytest.mark.parametrize("key,value,message", [
    ("train_teachers.actors", [], "train_teachers.actors: expected a non-empty list, got []"),
    ("train_teachers.actors", ["gaussian", "beta"], "train_teachers.actors[1]: expected one of deterministic, "
                                                    "gaussian, got 'beta'"),
    ("train_teachers.actors", ["gaussian", "gaussian"], "train_teachers.actors: expected a list without repeats"),
    ("train_teachers.seeds", [], "train_teachers.seeds: expected a non-empty list of non-negative integers"),
    ("train_teachers.seeds", [0, -2], "train_teachers.seeds: expected a non-empty list of non-negative integers"),
    ("train_teachers.seeds", [3, 3], "train_teachers.seeds: expected a list without repeats, got [3, 3] (3 twice)"),
    ("train_teachers.threads", 0, "train_teachers.threads: expected a positive integer or 'auto' (the cores "
                                    "this process may use), got 0"),
    ("train_teachers.pbrl", {"actor": "gaussian"}, "train_teachers.pbrl.actor: set the actor types in "
                                                   "train_teachers.actors instead"),
    ("train_teachers.schedule", {"steps": 0}, "train_teachers.schedule.steps: expected a positive integer, got 0"),
    ("train_teachers.schedule", {"eval_every": 5}, "train_teachers.schedule.steps: missing required parameter"),
])
def test_teacher_grid_checks(tiny_params, key, value, message):
    with _raises(message):
        teacher_grid(_set(tiny_params, key, value))


def test_teacher_steps_may_be_one_per_level_and_every_study_level_needs_one(tiny_params):
    """Expert data needs longer than medium at this budget (docs/teachers.md): steps per dataset level."""
    schedule = dict(tiny_params["train_teachers"]["schedule"], steps={"expert": 80, "medium": 40})
    grid = teacher_grid(_set(tiny_params, "train_teachers.schedule", schedule))
    assert grid.schedule_for("expert").steps == 80 and grid.schedule_for("medium").steps == 40
    for steps, message in (({"expert": 0}, "train_teachers.schedule.steps.expert: expected a positive integer"),
                           ({"hard": 5}, "train_teachers.schedule.steps.hard: expected one of expert, medium"),
                           ({}, "train_teachers.schedule.steps: expected a number of steps, or one per dataset level")):
        with _raises(message):
            teacher_grid(_set(tiny_params, "train_teachers.schedule", dict(schedule, steps=steps)))
    from mop_core.teachers import teacher_config

    params = _set(tiny_params, "train_teachers.schedule", dict(schedule, steps={"expert": 80}))
    with _raises("train_teachers.schedule.steps: expected a number of steps for level 'medium' (every study level)"):
        teacher_config(params, study_config(params), "deterministic", "medium")


@pytest.mark.parametrize("key,value,message", [
    ("train_multitask.levels", ["medium", "medium"], "train_multitask.levels: expected a list without repeats"),
    ("train_multitask.levels", ["expert"], "train_multitask.levels[0]: expected one of study.levels ['medium'], "
                                           "got 'expert'"),
    ("train_multitask.seeds", [-1], "train_multitask.seeds: expected non-negative integers, got [-1]"),
    ("train_multitask.seeds", [2, 2], "train_multitask.seeds: expected a list without repeats"),
])
def test_multitask_grid_checks(tiny_params, key, value, message):
    with _raises(message):
        multitask_grid(_set(tiny_params, key, value), study_config(tiny_params))


def test_no_multitask_baseline_is_an_empty_grid(tiny_params):
    params = _set(_set(tiny_params, "train_multitask.levels", []), "train_multitask.seeds", [])
    assert multitask_grid(params, study_config(params)) == MultitaskGrid((), ())


@pytest.mark.parametrize("key,value,message", [
    ("distill.losses", [], "distill.losses: expected a non-empty list, got []"),
    ("distill.losses", "mse", "distill.losses: expected a non-empty list, got 'mse'"),
    ("distill.losses", ["mse", "l1"], "distill.losses: expected entries among ('mse', 'q', 'kl'), got ['mse', 'l1']"),
    ("distill.losses", ["q", "q"], "distill.losses: expected a list without repeats"),
    ("distill.pairings", None, "distill.pairings: expected a non-empty list, got None"),
    ("distill.pairings", ["expert"], "distill.pairings: expected levels among study.levels ['medium']"),
    ("distill.pairings", ["medium+medium+medium"], "distill.pairings: expected one level or one per study task (2)"),
    ("distill.pairings", ["medium", "medium+medium"], "distill.pairings: expected distinct pairings ('medium' and "
                                                      "'medium+medium' both pair the tasks with medium+medium)"),
    ("distill.seeds", [0, -1], "distill.seeds: expected non-negative integers, got [0, -1]"),
    ("distill.seeds", [True], "distill.seeds: expected non-negative integers, got [True]"),
    ("distill.seeds", [1, 1], "distill.seeds: expected a list without repeats"),
    ("distill.teacher_seed", 1, "distill.teacher_seed: expected one of train_teachers.seeds [0], got 1"),
    ("distill.threads", 0, f"distill.threads: {THREADS_EXPECTED}, got 0"),
    ("distill.threads", 1.0, f"distill.threads: {THREADS_EXPECTED}, got 1.0"),
    ("distill.schedule", {"steps": 5, "eval_evry": 1}, "distill.schedule.eval_evry: unknown parameter"),
])
def test_distill_grid_checks(tiny_params, key, value, message):
    with _raises(message):
        distill_grid(_set(tiny_params, key, value), study_config(tiny_params), LOSS_ACTORS)


def test_a_loss_needs_teachers_of_its_actor_type(tiny_params):
    params = _set(tiny_params, "train_teachers.actors", ["deterministic"])
    with _raises("distill.losses: expected gaussian teachers for the kl loss: add gaussian to train_teachers.actors"):
        distill_grid(params, study_config(params), LOSS_ACTORS)
    params = _set(params, "distill.losses", ["mse", "q"])
    assert distill_grid(params, study_config(params), LOSS_ACTORS).losses == ("mse", "q")


def test_distill_grid_defaults_threads_to_one(tiny_params):
    params = copy.deepcopy(tiny_params)
    del params["distill"]["threads"]
    assert distill_grid(params, study_config(params), LOSS_ACTORS).threads == 1


def test_typed_section_and_section_name_the_section(tiny_params):
    assert typed_section(tiny_params, "study", StudyConfig) == study_config(tiny_params)
    assert section(tiny_params, "eval") is tiny_params["eval"]
    with _raises("train_teachers: missing section in params.yaml"):
        typed_section({"study": tiny_params["study"]}, "train_teachers", TeacherGrid)
    with _raises("study.task: unknown parameter; known: "):
        typed_section({"study": {"task": ["stand"]}}, "study", StudyConfig)
    with _raises("study: expected a mapping, got ['stand']"):
        typed_section({"study": ["stand"]}, "study", StudyConfig)


def test_check_sections_refuses_a_section_no_stage_reads(tiny_params):
    assert set(tiny_params) == set(SECTIONS)
    check_sections(tiny_params)
    check_sections({})
    with _raises(f"distil: unknown section in params.yaml; known: {', '.join(SECTIONS)}"):
        check_sections(tiny_params | {"distil": {}})
    with _raises("aaa: unknown section in profiles/x.yaml"):  # the first unknown one, sorted
        check_sections({"zzz": 1, "aaa": 2, "study": {}}, "profiles/x.yaml")


def test_positive_threads():
    assert positive_threads(3, "eval.workers") == 3
    for value in (0, -1, True, 2.0, "2", None):
        with _raises("eval.workers: expected a positive integer"):
            positive_threads(value, "eval.workers")


@pytest.mark.parametrize("value", [0.0, False])
def test_the_teacher_seed_must_be_an_integer(tiny_params, value):
    with pytest.raises(ConfigError, match=r"^distill.teacher_seed: "):
        distill_grid(_set(tiny_params, "distill.teacher_seed", value), study_config(tiny_params), LOSS_ACTORS)


def test_the_data_sharing_names_the_params_check_knows_are_the_runs_own():
    """study.py checks data_sharing without importing the run kinds (collect reads study.py): its name
    lists must stay equal to mop_core.experiment.runs'."""
    from mop_core.experiment.runs import SHARING_KINDS
    from mop_core.experiment.study import SHARING_STUDENTS, SHARING_TEACHERS
    from mop_core.experiment.variants import SHARING_VARIANTS

    assert SHARING_TEACHERS == SHARING_KINDS
    assert SHARING_STUDENTS == {name: v.kind for name, v in SHARING_VARIANTS.items() if v.pooled_states}


def test_every_rollout_workers_key_takes_auto_as_the_cores_this_process_may_use(tiny_params, monkeypatch):
    from mop_core.collect import collect_configs
    from mop_core.experiment.study import EvalConfig, shift_grid, typed_section
    from mop_core.learning.runtime import THREADS_ENV
    from mop_core.shared_computation import shared_computation_config
    from mop_core.study_params import check_params

    monkeypatch.setenv(THREADS_ENV, "7")
    params = tiny_params
    for key in ("collect.parallel.workers", "state_shift.workers", "eval.workers", "shared_computation.workers"):
        params = _set(params, key, "auto")
    check_params(params, "params.yaml")
    study = study_config(params)
    assert collect_configs(params, study)[0].workers == 7
    assert shift_grid(params, study).workers == 7
    assert typed_section(params, "eval", EvalConfig).workers == 7
    assert shared_computation_config(params)[1].workers == 7
    with _raises("shared_computation.workers: expected a positive integer or 'auto'"):
        shared_computation_config(_set(params, "shared_computation.workers", "all"))
