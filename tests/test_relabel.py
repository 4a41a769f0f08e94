"""Relabelling: vectorised == physics replay == the env's own reward; D_{j->i} loading and export."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from mop_core.data import DatasetError, read_dataset, read_relabel
from mop_core.relabel import RelabelConfig, export_d4rl, load_transitions, relabel_dataset, relabel_rewards
from mop_core.walker.envs import WalkerEnv

TASKS = ("stand", "walk", "run")


@pytest.fixture(scope="module")
def relabelled(tiny_collected, tmp_path_factory):
    root, _ = tiny_collected
    out = tmp_path_factory.mktemp("relabel") / "stand-medium_replay.hdf5"
    dataset_path = root / "datasets" / "stand-medium_replay.hdf5"
    metrics = relabel_dataset(dataset_path, out, TASKS, RelabelConfig(physics_check_transitions=50))
    return dataset_path, out, metrics


def test_vectorised_equals_physics_replay_equals_env_reward(relabelled):
    dataset_path, _, _ = relabelled
    ds = read_dataset(dataset_path)
    vec = relabel_rewards(ds, TASKS, "vectorised")
    phys = relabel_rewards(ds, TASKS, "physics")
    for task in TASKS:
        assert np.abs(vec[task] - phys[task]).max() <= 1e-6
    # the env's own reward, recorded while collecting the stand data
    assert np.abs(vec["stand"] - ds.arrays["rewards"]).max() <= 1e-6
    # and each other task's env, stepped from the same physics states, agrees too
    for task in ("walk", "run"):
        env = WalkerEnv(task, 0)
        own = []
        for state in ds.arrays["next_physics"][:100]:
            env.physics.set_state(state)
            env.physics.forward()
            own.append(env.dm_env.task.get_reward(env.physics))
        assert np.abs(vec[task][:100] - np.array(own)).max() <= 1e-6


def test_relabel_metrics_report_the_checks(relabelled):
    _, _, metrics = relabelled
    assert metrics["max_abs_diff_vs_stored"] <= 1e-6
    assert metrics["max_abs_diff_vectorised_vs_physics"] <= 1e-6


def test_load_transitions_gives_d_j_to_i(relabelled):
    dataset_path, relabel_path, _ = relabelled
    ds = read_dataset(dataset_path)
    d_walk = load_transitions(dataset_path, relabel_path, "walk")
    expected = relabel_rewards(ds, ["walk"])["walk"].astype(np.float32)
    np.testing.assert_array_equal(d_walk.rewards.numpy(), expected)
    np.testing.assert_array_equal(d_walk.observations.numpy(), ds.arrays["observations"])
    own = load_transitions(dataset_path)
    np.testing.assert_array_equal(own.rewards.numpy(), ds.arrays["rewards"])
    import torch
    batch = d_walk.sample(16, torch.Generator().manual_seed(0))
    assert batch.observations.shape == (16, 24) and batch.rewards.shape == (16,)


def test_export_d4rl_round_trip(relabelled, tmp_path):
    """D_{stand->run} as its own file: D4RL keys for any reader, and mop's read_dataset reads it back
    (every array but the rewards equal to the source dataset's, as a dataset of the reward task)."""
    dataset_path, relabel_path, _ = relabelled
    out = export_d4rl(dataset_path, relabel_path, "run", tmp_path / "stand_to_run.hdf5")
    ds = read_dataset(dataset_path)
    with h5py.File(out) as h5:
        assert h5.attrs["reward_task"] == "run" and h5.attrs["source_task"] == "stand"
        np.testing.assert_array_equal(h5["observations"][()], ds.arrays["observations"])
        np.testing.assert_allclose(h5["rewards"][()], relabel_rewards(ds, ["run"])["run"], atol=1e-6)
        assert h5["rewards"].dtype == np.float32
    back = read_dataset(out, verify_checksum=True, task="run", level=ds.attrs["level"])
    for name, array in ds.arrays.items():
        if name != "rewards":
            np.testing.assert_array_equal(back.arrays[name], array)
    np.testing.assert_array_equal(back.arrays["rewards"], relabel_rewards(ds, ["run"])["run"].astype(np.float32))
    assert back.attrs["dataset_content_sha256"] == ds.attrs["content_sha256"] != back.attrs["content_sha256"]


def test_stale_or_incomplete_relabel_file_is_rejected(relabelled, tiny_collected):
    _, relabel_path, _ = relabelled
    root, _ = tiny_collected
    other = read_dataset(root / "datasets" / "stand-expert.hdf5")
    with pytest.raises(DatasetError, match="belongs to another dataset"):
        read_relabel(relabel_path, other)
    ds = read_dataset(root / "datasets" / "stand-medium_replay.hdf5")
    with pytest.raises(DatasetError, match="no rewards for task 'fly'"):
        read_relabel(relabel_path, ds, "fly")


def test_relabel_config_errors():
    from mop_core.config import ConfigError, from_mapping
    with pytest.raises(ConfigError, match="relabel.method: expected one of vectorised, physics"):
        from_mapping(RelabelConfig, {"method": "magic"}, "relabel")
