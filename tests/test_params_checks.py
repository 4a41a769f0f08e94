"""The whole params file is checked before any compute (mop_core/study_params.py): every bad value
below was once accepted silently; each now fails with one line naming its key."""

from __future__ import annotations

import copy
import re

import pytest
from conftest import ROOT

from mop_core.config import ConfigError
from mop_core.study_params import check_params


def _set(params: dict, key: str, value) -> dict:
    params = copy.deepcopy(params)
    *path, last = key.split(".")
    node = params
    for part in path:
        node = node.setdefault(part, {})
    node[last] = value
    return params


def test_the_profiles_pass(tiny_params):
    check_params(tiny_params)
    import yaml
    for path in (ROOT / "params.yaml", ROOT / "profiles" / "thesis.yaml"):
        check_params(yaml.safe_load(path.read_text()))


NON_FINITE = [
    ("train_teachers.pbrl.learning_rate", float("inf")),
    ("collect.td3.learning_rate", float("inf")),
    ("distill.learning_rate", float("inf")),
    ("train_teachers.pbrl.target_entropy", float("nan")),
    ("collect.schedule.medium_target_return", float("nan")),
    ("collect.datasets.action_noise", float("inf")),
    ("relabel.tolerance", float("inf")),
    ("train_teachers.pbrl.log_std_max", float("inf")),
    ("distill.student.log_std_min", float("-inf")),
    ("train_teachers.pbrl.gamma", "nan"),  # a quoted 'nan': YAML gives the string
]


@pytest.mark.parametrize("key,value", NON_FINITE)
def test_non_finite_numbers_are_rejected(tiny_params, key, value):
    with pytest.raises(ConfigError, match=rf"^{key}: expected a finite number"):
        check_params(_set(tiny_params, key, value))


UNKNOWN = [
    ("train_teachers.pbr", {"batch_size": 64}, "train_teachers.pbr: unknown parameter"),
    ("train_teachers.thread", 2, "train_teachers.thread: unknown parameter"),
    ("train_multitask.level", ["medium"], "train_multitask.level: unknown parameter"),
    ("distill.step_per_tasks", True, "distill.step_per_tasks: unknown parameter"),
    ("shared_computation.episode", 3, "shared_computation.episode: unknown parameter"),
    ("distil", {"seeds": [0]}, "distil: unknown section in params.yaml"),
]


@pytest.mark.parametrize("key,value,message", UNKNOWN)
def test_unknown_keys_and_sections_are_rejected(tiny_params, key, value, message):
    with pytest.raises(ConfigError, match="^" + re.escape(message)):
        check_params(_set(tiny_params, key, value))


REPEATED = [
    ("distill.seeds", [0, 0], "distill.seeds: expected a list without repeats"),
    ("distill.losses", ["mse", "mse"], "distill.losses: expected a list without repeats"),
    ("distill.pairings", ["medium", "medium+medium"], "distill.pairings: expected distinct pairings"),
    ("train_teachers.seeds", [0, 1, 0], "train_teachers.seeds: expected a list without repeats"),
    ("train_teachers.actors", ["gaussian", "deterministic", "gaussian"],
     "train_teachers.actors: expected a list without repeats"),
    ("train_multitask.levels", ["medium", "medium"], "train_multitask.levels: expected a list without repeats"),
    ("train_multitask.seeds", [1, 1], "train_multitask.seeds: expected a list without repeats"),
    ("train_multitask.levels", ["expert"], "train_multitask.levels[0]: expected one of study.levels"),
    ("eval.transfer_tasks", ["stand_still", "stand_still"], "eval.transfer_tasks: tasks must not repeat"),
    ("data_sharing.levels", ["expert"], "data_sharing.levels[0]: expected one of study.levels"),
    ("data_sharing.teachers", ["ds"], "data_sharing.students[1]: expected its oqs teachers in teachers"),
    ("data_sharing.teachers", ["ds", "cds"], "data_sharing.teachers[1]: expected one of ds, oqs"),
    ("data_sharing.students", ["ds", "ds"], "data_sharing.students: expected a list without repeats"),
    ("eval.transfer_tasks", ["walk"], "eval.transfer_tasks[0]: expected a task outside study.tasks"),
    ("eval.transfer_tasks", ["sit"], "eval.transfer_tasks[0]: unknown task 'sit'"),
]


@pytest.mark.parametrize("key,value,message", REPEATED)
def test_repeated_or_unstudied_grid_entries_are_rejected(tiny_params, key, value, message):
    with pytest.raises(ConfigError, match="^" + re.escape(message)):
        check_params(_set(tiny_params, key, value))


def test_sizes_are_bounded_by_the_data_the_study_will_have(tiny_params):
    # the tiny medium datasets hold 3 episodes of 50 steps
    with pytest.raises(ConfigError, match=r"^train_teachers.pbrl.batch_size: expected at most the 150 transitions"):
        check_params(_set(tiny_params, "train_teachers.pbrl.batch_size", 10**9))
    with pytest.raises(ConfigError, match=r"^distill.batch_size: expected at most the 150 states"):
        check_params(_set(tiny_params, "distill.batch_size", 151))
    with pytest.raises(ConfigError, match=r"^distill.batch_size: expected at most the 40 states"):
        check_params(_set(_set(tiny_params, "distill.num_states", 40), "distill.batch_size", 41))
    with pytest.raises(ConfigError, match=r"^collect.td3.batch_size: expected at most the 400 transitions"):
        check_params(_set(tiny_params, "collect.td3.batch_size", 10**9))
    no_shift = _set(_set(_set(_set(tiny_params, "state_shift.datasets", []), "state_shift.widths", []),
                         "state_shift.data_percents", []), "state_shift.correction_datasets", ["offline"])
    check_params(_set(no_shift, "distill.batch_size", 150))  # the bound itself is allowed


def test_shift_students_batches_are_bounded_by_their_data(tiny_params):
    # tiny: composed datasets of 2 episodes x 50 steps; 50% of the 3 medium episodes is 2 episodes
    with pytest.raises(ConfigError, match=r"^distill.batch_size: expected at most the 100 states of a composed"):
        check_params(_set(tiny_params, "distill.batch_size", 101))
    only_sizes = _set(_set(_set(tiny_params, "state_shift.datasets", []), "state_shift.widths", []),
                      "state_shift.correction_datasets", ["offline"])
    with pytest.raises(ConfigError, match=r"^distill.batch_size: expected at most the 100 states of 50% of the "):
        check_params(_set(only_sizes, "distill.batch_size", 101))
    check_params(_set(tiny_params, "distill.batch_size", 100))


SHIFT_ERRORS = [
    ("state_shift.datasets", ["random99", "nosie"], "state_shift.datasets[1]: expected one of compositions"),
    ("state_shift.datasets", ["online", "online"], "state_shift.datasets: expected a list without repeats"),
    ("state_shift.compositions.noise.rest", "uniform", "state_shift.compositions.noise.rest: expected one of noise"),
    ("state_shift.compositions.noise.teacher_share", 0.0, "state_shift.compositions.noise.teacher_share: expected"),
    ("state_shift.widths", [16, 0], "state_shift.widths: expected a list of positive integers"),
    ("state_shift.data_percents", [100], "state_shift.data_percents: expected a list of whole percentages"),
    ("state_shift.pairing", "expert", "state_shift.pairing: expected levels among study.levels"),
    ("state_shift.reference_episodes", 1, "state_shift.reference_episodes: expected at least 2"),
    ("state_shift.measure.k", 60, "state_shift.measure.k: expected in [1, states / 2)"),
    ("state_shift.measure.statez", 60, "state_shift.measure.statez: unknown parameter"),
    ("state_shift.heldout_episodes", 0, "state_shift.heldout_episodes: expected a positive integer"),
    ("state_shift.corrections", ["reweight", "dagger", "reweigh"], "state_shift.corrections: expected a list of"),
    ("state_shift.correction_datasets", ["noise"], "state_shift.correction_datasets[0]: expected 'offline' (the "),
    ("state_shift.correction_widths", [], "state_shift.corrections: expected [] unless correction_datasets and"),
    ("distill.reweight.clip", 0.5, "distill.reweight.clip: expected a number >= 1"),
    ("distill.dagger.rounds", 0, "distill.dagger.rounds: expected a positive integer"),
    ("distill.correction", "dagger", "distill.correction: set the state_shift corrections instead"),
]


@pytest.mark.parametrize("key,value,message", SHIFT_ERRORS)
def test_state_shift_errors_name_their_key(tiny_params, key, value, message):
    with pytest.raises(ConfigError, match="^" + re.escape(message)):
        check_params(_set(tiny_params, key, value))


def test_library_errors_are_reported_under_their_section(tiny_collected, tmp_path):
    """A size checked only against the data (inside mop_core, keys relative to the config) still names
    the params key the user edits."""
    from mop_core.agents.pbrl import PBRLConfig
    from mop_core.config import keys_under
    from mop_core.learning.schedule import TrainSchedule
    from mop_core.learning.training import RunPaths
    from mop_core.relabel import RelabelConfig, relabel_dataset
    from mop_core.teachers import DataSource, TeacherConfig, train_teacher

    root, _ = tiny_collected
    dataset, relabel = root / "datasets" / "stand-medium.hdf5", tmp_path / "relabel.hdf5"
    relabel_dataset(dataset, relabel, ["stand"], RelabelConfig(physics_check_transitions=0))
    config = TeacherConfig(PBRLConfig(hidden_sizes=(8,), batch_size=10**6), TrainSchedule(steps=2, rollout_envs=1), 50)
    paths = RunPaths(*(tmp_path / name for name in ("t.pt", "m.json", "c.tsv", "r.pt")))
    with pytest.raises(ConfigError, match=rf"^train_teachers.pbrl.batch_size: expected at most the 150 transitions of "
                                          rf"{dataset}, got 1000000"):
        with keys_under("train_teachers"):
            train_teacher("stand", DataSource(dataset, relabel, "stand"), config, 0, 0, paths)
