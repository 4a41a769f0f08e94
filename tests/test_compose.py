"""mop_core/shift/compose.py: composed datasets (thesis 5.2.4) from a policy's rollouts, by whole episodes,
with shared episode pools, and the teachers that compose them; and the dataset-share subset of
mop_core/distill/states.py."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from mop_core.config import ConfigError
from mop_core.data import read_dataset
from mop_core.distill.states import episode_rows, offline_states
from mop_core.experiment.catalogue import build_catalogue
from mop_core.experiment.study import shift_grid, study_config
from mop_core.shift.compose import (
    REFERENCE,
    THESIS_COMPOSITIONS,
    ComposeConfig,
    Composition,
    compose_config,
    compose_jobs,
    compose_metrics,
    compose_seconds,
    compose_task,
    dataset_writer,
    random_policy,
    summary_lines,
)
from mop_core.storage.layout import composed_file

T = 20  # control steps per episode in these tests


def constant_policy(obs: np.ndarray) -> np.ndarray:
    """A deterministic 'teacher': the same mid-range torques everywhere (so noise and clipping show)."""
    return np.full((len(obs), 6), 0.5)


def _compose(config: ComposeConfig, seed: int = 0) -> tuple[dict, dict]:
    written: dict[str, tuple[dict, dict]] = {}
    summary = compose_task(constant_policy, "stand", "medium", config, seed, T,
                           lambda name, arrays, attrs: written.__setitem__(name, (arrays, attrs)))
    return written, summary


@pytest.fixture(scope="module")
def composed():
    config = ComposeConfig(episodes=4, noise_std=1.0, reference_episodes=2, heldout_episodes=4, rollout_envs=4,
                           compositions={"online": Composition(1.0), "noise": Composition(0.25, "noise"),
                                         "random90": Composition(0.25, "random"),
                                         "random99": Composition(0.01, "random")},
                           datasets=("online", "noise", "random90", "random99"))
    return config, *_compose(config)


def test_every_dataset_has_its_share_of_teacher_episodes_then_the_rest(composed):
    config, written, summary = composed
    for name in config.datasets:
        arrays, attrs = written[name]
        assert len(arrays["rewards"]) == 4 * T and arrays["timeouts"].sum() == 4
        teacher = {"online": 4, "noise": 1, "random90": 1, "random99": 1}[name]  # 1% of 4 rounds up to one
        assert attrs["teacher_episodes"] == summary[name]["teacher_episodes"] == teacher
        actions = arrays["actions"].reshape(4, T, 6)
        assert (actions[:teacher] == 0.5).all()  # the teacher's own actions
        if teacher < 4:
            rest = actions[teacher:]
            assert (np.abs(rest) <= 1).all() and not (rest == 0.5).all()
    noisy = written["noise"][0]["actions"][T:]
    assert np.isclose(noisy, 1.0).mean() > 0.2  # N(0, 1) around 0.5, clipped to the action bounds


def test_the_pools_are_shared_so_datasets_differ_only_by_composition(composed):
    _, written, _ = composed
    online = written["online"][0]["observations"]
    for name in ("noise", "random90", "random99"):
        assert (written[name][0]["observations"][:T] == online[:T]).all()  # the same first teacher episode
    # random90's random episodes are random99's first ones
    assert (written["random90"][0]["actions"][T:] == written["random99"][0]["actions"][T:4 * T]).all()


def test_the_reference_episodes_are_the_teachers_on_other_seeds(composed):
    config, written, summary = composed
    reference, attrs = written[REFERENCE]
    assert len(reference["rewards"]) == config.reference_episodes * T and attrs["rest_episodes"] == 0
    assert (reference["actions"] == 0.5).all()
    assert not (reference["observations"][:T] == written["online"][0]["observations"][:T]).all()
    assert summary[REFERENCE]["teacher_episodes"] == 2


def test_each_dataset_has_held_out_episodes_of_its_composition_on_other_seeds(composed):
    config, written, summary = composed
    for name in config.datasets:
        arrays, attrs = written[f"{name}_heldout"]
        teacher = {"online": 4, "noise": 1, "random90": 1, "random99": 0}[name]  # 1% of 4: none (no floor of one)
        assert len(arrays["rewards"]) == 4 * T and attrs["heldout"] == 1 and attrs["teacher_episodes"] == teacher
        assert summary[f"{name}_heldout"]["rest_episodes"] == 4 - teacher
        actions = arrays["actions"].reshape(4, T, 6)
        assert (actions[:teacher] == 0.5).all() and not (actions[teacher:] == 0.5).any()
        train = written[name][0]["observations"]  # not a single state in common with its training episodes
        assert not (arrays["observations"][:, None, :] == train[None, :, :]).all(-1).any()
    assert written["online"][1]["heldout"] == 0


def test_composing_is_repeatable_and_seeded(composed):
    config, written, _ = composed
    again, _ = _compose(config)
    other, _ = _compose(config, seed=1)
    for name in config.datasets:
        assert all((again[name][0][k] == written[name][0][k]).all() for k in written[name][0])
    assert not (other["random99"][0]["actions"] == written["random99"][0]["actions"]).all()


def test_written_datasets_read_back_with_their_composition(tmp_path):
    config = ComposeConfig(episodes=2, reference_episodes=2, heldout_episodes=1, rollout_envs=2,
                           datasets=("online", "random99"))
    attrs = {"task": "stand", "level": "medium", "seed": 0, "episode_length": T, "behaviour_sha256": "x"}
    compose_task(constant_policy, "stand", "medium", config, 0, T,
                 dataset_writer(lambda name: tmp_path / f"{name}.hdf5", attrs))
    data = read_dataset(tmp_path / "random99.hdf5", verify_checksum=True, task="stand", level="medium")
    assert data.attrs["composition"] == "random99" and data.attrs["teacher_episodes"] == 1
    assert read_dataset(tmp_path / f"{REFERENCE}.hdf5").attrs["composition"] == REFERENCE


def test_the_composing_teachers_are_the_ones_the_shift_students_learn_from(tiny_params):
    teachers = build_catalogue(tiny_params).composing_teachers
    assert [(t.task, t.level, t.actor) for t in teachers] == [("stand", "medium", "deterministic"),
                                                              ("walk", "medium", "deterministic")]
    assert all(run.teachers == teachers for run in build_catalogue(tiny_params).shift_students)
    config = compose_config(shift_grid(tiny_params, study_config(tiny_params)))
    jobs = compose_jobs(teachers, config, 7, 50)
    assert [job[:6] for job in jobs] == [(t.paths.checkpoint, t.task, t.level, config, 7, 50) for t in teachers]
    assert jobs[1][6]("online") == composed_file("walk", "medium", "online")
    params = copy.deepcopy(tiny_params)
    params["state_shift"].update(datasets=[], widths=[], correction_datasets=["offline"])
    assert build_catalogue(params).composing_teachers == ()
    summary = {"datasets": {"online": {"return_mean": 812.4}, "noise": {"return_mean": 300.6}}, "seconds": 12.3}
    metrics = compose_metrics(teachers[:1], [summary])
    assert metrics == {"stand-medium": {"datasets": summary["datasets"]}}  # no wall-clock time in an output
    assert summary_lines(metrics, compose_seconds(teachers[:1], [summary])) == [
        "compose stand-medium: episode returns online 812, noise 301 (12 s)"]


def test_the_thesis_compositions_and_pool_sizes():
    config = ComposeConfig()
    assert config.datasets == ("online", "noise", "random90", "random99")
    assert [THESIS_COMPOSITIONS[d].teacher_episodes(100) for d in config.datasets] == [100, 10, 10, 1]
    assert config.pool_sizes() == {"teacher": 100, "noise": 90, "random": 99}


@pytest.mark.parametrize("kwargs,message", [
    ({"datasets": ("online", "nosie")}, "datasets[1]: expected one of compositions"),
    ({"datasets": ("reference",), "compositions": {"reference": Composition(1.0)}}, "datasets[0]: expected a name"),
    ({"compositions": {"online": {"teacher_share": 1.5}}}, "compositions.online.teacher_share: expected a share"),
    ({"compositions": {"online": {"teacher_share": 0.5, "rest": "zero"}}}, "compositions.online.rest: expected one of"),
    ({"reference_episodes": 1}, "reference_episodes: expected at least 2"),
    ({"episodes": 0}, "episodes: expected a positive integer"),
    ({"heldout_episodes": 0}, "heldout_episodes: expected a positive integer"),
    ({"datasets": ("x_heldout",), "compositions": {"x_heldout": Composition(1.0)}}, "datasets[0]: expected a name"),
])
def test_bad_composition_settings_name_their_key(kwargs, message):
    if "compositions" in kwargs and "datasets" not in kwargs:
        kwargs = {"datasets": ("online",), **kwargs}
    with pytest.raises(ConfigError, match="^" + message.replace("[", r"\[").replace("]", r"\]")):
        ComposeConfig(**kwargs)


def test_random_policy_is_uniform_in_the_action_box():
    actions = random_policy(np.random.default_rng(0))(np.zeros((5000, 24)))
    assert actions.shape == (5000, 6) and actions.min() >= -1 and actions.max() <= 1
    assert abs(actions.mean()) < 0.02 and abs(actions.var() - 1 / 3) < 0.02


def test_a_dataset_share_keeps_whole_episodes_drawn_by_the_seed(tiny_collected):
    ends = np.zeros(100, dtype=bool)
    ends[9::10] = True  # 10 episodes of 10 rows
    rows = episode_rows(ends, 0.3, np.random.default_rng(0))
    episodes = np.unique(rows // 10)
    assert len(rows) == 30 and len(episodes) == 3 and set(rows) == {e * 10 + t for e in episodes for t in range(10)}
    assert (episode_rows(ends, 0.3, np.random.default_rng(0)) == rows).all()
    assert len(episode_rows(ends, 0.01, np.random.default_rng(0))) == 10  # at least one episode
    root, _ = tiny_collected
    dataset = root / "datasets" / "stand-medium.hdf5"
    whole = offline_states(dataset, 0, np.random.default_rng(0))
    part = offline_states(dataset, 0, np.random.default_rng(0), fraction=0.5)
    assert len(part) < len(whole) and len(part) % 50 == 0
    assert {row.tobytes() for row in part} <= {row.tobytes() for row in whole}
