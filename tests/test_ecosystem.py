"""The study's data and envs as the field's libraries see them: the registered Gymnasium envs against
the study's own env, Minari exports read back, and a d3rlpy policy trained on a mop dataset and
evaluated in the registered env (minari and d3rlpy: the optional ``ecosystem`` dependencies, which
``.ci/run`` installs; without them those tests are skipped, saying so)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from mop_core.config import InputFileError
from mop_core.data import read_dataset, read_relabel
from mop_core.gym_envs import ENV_IDS, WalkerGymEnv, env_id
from mop_core.relabel import RelabelConfig, relabel_dataset
from mop_core.statistics import normalised_score
from mop_core.walker.envs import WalkerEnv
from mop_core.walker.rollout import episode_returns
from mop_core.walker.tasks import REWARD_FEATURES, TASKS

NORMALISATION = {"stand": {"random_return": 130.5, "expert_return": 986.8},
                 "walk": {"random_return": 32.6, "expert_return": 980.0}}
PERMALINK = "https://example.org/mop/tree/0123abc"


def test_every_task_of_the_registry_has_a_registered_env():
    assert ENV_IDS == [f"mop/walker-{name}-v0" for name in TASKS]
    for name in TASKS:
        spec = gym.spec(env_id(name))
        assert spec.entry_point == "mop_core.gym_envs:WalkerGymEnv" and spec.kwargs == {"task": name}
        assert spec.max_episode_steps == 1000
        assert json.loads(spec.to_json())["id"] == env_id(name)  # serialisable: Minari stores it


@pytest.mark.parametrize("task", ["stand", "walk", "stand_still"])
def test_the_registered_env_is_the_study_env_step_for_step(task):
    """Observations (the datasets' order, float32), rewards, reward features, physics and the 1000-step
    truncation equal the study's WalkerEnv on the same seeds and actions; reset() continues the stream."""
    env = gym.make(env_id(task))
    assert env.observation_space == gym.spaces.Box(-np.inf, np.inf, (24,), np.float32)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (6,), np.float32)
    study = WalkerEnv(task, 5)
    obs, info = env.reset(seed=5)
    assert obs.dtype == np.float32 and info == {}
    np.testing.assert_array_equal(obs, study.reset().astype(np.float32))
    actions = np.random.default_rng(0).uniform(-1, 1, size=(1000, 6)).astype(np.float32)
    for t, action in enumerate(actions):
        obs, reward, terminated, truncated, info = env.step(action)
        expected = study.step(action)
        np.testing.assert_array_equal(obs, expected.observation.astype(np.float32))
        assert reward == expected.reward and not terminated and truncated == (t == 999)
        assert [info[name] for name in REWARD_FEATURES] == expected.features.tolist()
        np.testing.assert_array_equal(info["physics"], expected.physics)
    np.testing.assert_array_equal(env.reset()[0], study.reset().astype(np.float32))  # the next episode of seed 5


def test_the_env_passes_gymnasiums_checker_and_refuses_misuse():
    from gymnasium.utils.env_checker import check_env

    check_env(WalkerGymEnv("walk", episode_length=20), skip_render_check=True)
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        WalkerGymEnv("walk").step(np.zeros(6))
    with pytest.raises(ValueError, match="episode_length"):
        WalkerGymEnv("walk", episode_length=0)
    with pytest.raises(ValueError, match="task"):
        WalkerGymEnv("fly")
    unseeded = WalkerGymEnv("stand")
    assert unseeded.observation_space.contains(unseeded.reset()[0])  # a seed from the env's own generator


@pytest.fixture(scope="module")
def run_root(tiny_collected, tmp_path_factory):
    """A run's files as the export reads them: stand's tiny datasets, the medium one relabelled to
    stand and walk, and the eval stage's normalisation."""
    collected, _ = tiny_collected
    root = tmp_path_factory.mktemp("run")
    (root / "data" / "datasets").mkdir(parents=True)
    for level in ("medium", "expert"):
        shutil.copy(collected / "datasets" / f"stand-{level}.hdf5", root / "data" / "datasets")
    data = root / "data"
    relabel_dataset(data / "datasets" / "stand-medium.hdf5", data / "relabelled" / "stand-medium.hdf5",
                    ["stand", "walk"], RelabelConfig(physics_check_transitions=0))
    (root / "results" / "eval").mkdir(parents=True)
    (root / "results" / "eval" / "metrics.json").write_text(json.dumps({"normalisation": NORMALISATION}))
    return root


def _load(out: Path, dataset_id: str):
    import minari

    from mop_core.minari_export import minari_root

    with minari_root(out):
        return minari.load_dataset(dataset_id)


def test_minari_exports_read_back_identical_with_scores_and_env(run_root, tmp_path):
    pytest.importorskip("minari", reason="minari is an optional dependency: pip install -e '.[ecosystem]'")
    import minari

    from mop_core.minari_export import episode_arrays, export_all

    out = tmp_path / "minari"
    ids = export_all(run_root, out, "mop tests", None, PERMALINK, progress=False)
    assert ids == ["mop/walker-stand/expert-v0", "mop/walker-stand/medium-v0", "mop/walker-walk/medium-from-stand-v0"]
    for dataset_id, level, reward_task in (("mop/walker-stand/medium-v0", "medium", "stand"),
                                           ("mop/walker-walk/medium-from-stand-v0", "medium", "walk")):
        source = read_dataset(run_root / "data" / "datasets" / f"stand-{level}.hdf5")
        loaded = _load(out, dataset_id)
        back = episode_arrays(loaded.iterate_episodes())
        expected = dict(source.arrays)
        if reward_task != "stand":
            expected["rewards"] = read_relabel(run_root / "data" / "relabelled" / "stand-medium.hdf5", source,
                                               reward_task)[reward_task]
        assert set(back) == set(expected)
        for name, array in expected.items():
            assert back[name].dtype == array.dtype, name
            np.testing.assert_array_equal(back[name], array, err_msg=name)
        assert loaded.total_episodes == int(source.arrays["timeouts"].sum())
        norm = NORMALISATION[reward_task]
        np.testing.assert_allclose(100 * minari.get_normalized_score(loaded, np.array([500.0])),
                                   normalised_score([500.0], norm["random_return"], norm["expert_return"]))
        assert loaded.storage.metadata["code_permalink"] == PERMALINK
        assert loaded.storage.metadata["author"] == {"mop tests"} or loaded.storage.metadata["author"] == "mop tests"
        env = loaded.recover_environment()  # the registered env of the reward task, at the data's episode length
        length = source.attrs["episode_length"]
        assert env.spec.id == env_id(reward_task) and env.spec.max_episode_steps == length
        np.testing.assert_array_equal(env.reset(seed=2)[0], WalkerEnv(reward_task, 2).reset().astype(np.float32))
        truncated = [env.step(np.zeros(6, dtype=np.float32))[3] for _ in range(length)]
        assert truncated == [False] * (length - 1) + [True]


def test_a_failed_export_leaves_the_previous_one_and_no_staging(run_root, tmp_path, monkeypatch):
    pytest.importorskip("minari", reason="minari is an optional dependency: pip install -e '.[ecosystem]'")
    from mop_core import minari_export

    out = tmp_path / "minari"
    minari_export.export_all(run_root, out, "mop tests", None, PERMALINK, progress=False)
    before = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    calls = []

    def failing(*args, **kwargs):
        calls.append(args[0].dataset_id)
        if len(calls) == 2:
            raise OSError("disk full")
        return original(*args, **kwargs)

    original = minari_export.write_export
    monkeypatch.setattr(minari_export, "write_export", failing)
    with pytest.raises(OSError, match="disk full"):
        minari_export.export_all(run_root, out, "mop tests", None, PERMALINK, progress=False)
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == before
    assert [p.name for p in tmp_path.iterdir()] == ["minari"]


def test_the_export_names_what_is_missing_before_writing(run_root, tmp_path):
    pytest.importorskip("minari", reason="minari is an optional dependency: pip install -e '.[ecosystem]'")
    from mop_core.minari_export import export_all, main

    bare = tmp_path / "bare"
    shutil.copytree(run_root / "data", bare / "data")
    (bare / "results" / "eval").mkdir(parents=True)
    only_stand = {"normalisation": {"stand": NORMALISATION["stand"]}}
    (bare / "results" / "eval" / "metrics.json").write_text(json.dumps(only_stand))
    with pytest.raises(InputFileError, match=r"metrics.json: no normalisation for task\(s\) walk"):
        export_all(bare, tmp_path / "out", "a", None, PERMALINK)
    (bare / "results" / "eval" / "metrics.json").write_text(json.dumps({"normalisation": NORMALISATION}))
    with pytest.raises(InputFileError, match="--code-permalink: .* not a git checkout"):
        export_all(bare, tmp_path / "out", "a", None, None)
    assert main(["--root", str(tmp_path / "nowhere")]) == 2
    assert not (tmp_path / "out").exists()


def test_a_d3rlpy_policy_trained_on_a_mop_dataset_evaluates_as_in_the_study(tiny_collected):
    """A d3rlpy MDPDataset from a mop dataset file trains TD3+BC; its policy's return in the registered
    env equals its return in the study's own rollout on the same episode seed."""
    d3rlpy = pytest.importorskip("d3rlpy", reason="d3rlpy is an optional dependency: pip install -e '.[ecosystem]'")
    collected, _ = tiny_collected
    data = read_dataset(collected / "datasets" / "stand-medium.hdf5")
    a = data.arrays
    dataset = d3rlpy.dataset.MDPDataset(a["observations"], a["actions"], a["rewards"], a["terminals"],
                                        a["timeouts"], action_space=d3rlpy.constants.ActionSpace.CONTINUOUS)
    episodes = int(a["timeouts"].sum())
    # d3rlpy keeps no next_observations: each episode's last step, whose next state it lacks, is no transition
    assert len(dataset.episodes) == episodes and dataset.transition_count == len(data) - episodes
    d3rlpy.seed(0)
    algo = d3rlpy.algos.TD3PlusBCConfig(batch_size=32).create(device="cpu:0")
    algo.fit(dataset, n_steps=300, n_steps_per_epoch=300, show_progress=False,
             logger_adapter=d3rlpy.logging.NoopAdapterFactory())

    def policy(obs: np.ndarray) -> np.ndarray:
        return algo.predict(obs.astype(np.float32))

    length = int(data.attrs["episode_length"])
    env = gym.make(env_id("stand"), episode_length=length)
    obs, _ = env.reset(seed=11)
    total, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, _ = env.step(policy(obs[None])[0])
        total += reward
        done = terminated or truncated
    study = episode_returns(policy, "stand", [11], length)[0]
    assert total == pytest.approx(study, abs=1e-9) and total > 0


def test_the_code_permalink_is_the_commit_on_origin(tmp_path):
    import subprocess

    from mop_core.minari_export import code_permalink

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                              check=True, capture_output=True, text=True).stdout.strip()

    git("init", "-q")
    git("commit", "-q", "--allow-empty", "-m", "x")
    commit = git("rev-parse", "HEAD")
    assert code_permalink(tmp_path) == f"git commit {commit} of {tmp_path.resolve()}"  # no origin: local, warned
    git("remote", "add", "origin", "git@github.com:someone/mop.git")
    assert code_permalink(tmp_path) == f"https://github.com/someone/mop/tree/{commit}"
    git("remote", "set-url", "origin", "https://github.com/someone/mop.git")
    assert code_permalink(tmp_path) == f"https://github.com/someone/mop/tree/{commit}"
