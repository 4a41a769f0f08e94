"""Datasets: HDF5 round trip, validation errors naming file and defect, atomic writes."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from mop_core.data import DatasetError, read_dataset, write_dataset
from mop_core.data.hdf5 import content_sha256


def _arrays(n_episodes: int = 2, length: int = 5, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = n_episodes * length
    states = rng.normal(size=(n_episodes, length + 1, 24)).astype(np.float32)
    timeouts = np.zeros((n_episodes, length), dtype=bool)
    timeouts[:, -1] = True
    return {
        "observations": states[:, :-1].reshape(n, 24), "next_observations": states[:, 1:].reshape(n, 24),
        "actions": rng.uniform(-1, 1, (n, 6)).astype(np.float32), "rewards": rng.uniform(0, 1, n).astype(np.float32),
        "terminals": np.zeros(n, dtype=bool), "timeouts": timeouts.reshape(n),
        "next_physics": rng.normal(size=(n, 18)), "reward_features": rng.normal(size=(n, 3)),
    }


ATTRS = {"task": "walk", "level": "medium", "seed": 0, "episode_length": 5, "behaviour_sha256": "ab" * 32}


def test_round_trip(tmp_path):
    arrays = _arrays()
    path = tmp_path / "d.hdf5"
    sha = write_dataset(path, arrays, ATTRS)
    ds = read_dataset(path, verify_checksum=True)
    for key, value in arrays.items():
        np.testing.assert_array_equal(ds.arrays[key], value)
    assert ds.attrs["task"] == "walk" and ds.attrs["content_sha256"] == sha == content_sha256(ds.arrays)
    with h5py.File(path) as h5:  # D4RL key names for other libraries
        assert {"observations", "actions", "rewards", "next_observations", "terminals", "timeouts"} <= set(h5)
        assert set(h5["infos"]) == {"next_physics", "torso_height", "torso_upright", "horizontal_velocity"}


def test_identical_inputs_give_identical_bytes(tmp_path):
    write_dataset(tmp_path / "a.hdf5", _arrays(), ATTRS)
    write_dataset(tmp_path / "b.hdf5", _arrays(), ATTRS)
    assert (tmp_path / "a.hdf5").read_bytes() == (tmp_path / "b.hdf5").read_bytes()


def test_truncated_file(tmp_path):
    path = tmp_path / "d.hdf5"
    write_dataset(path, _arrays(), ATTRS)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match=str(path)):
        read_dataset(path)


def test_missing_key(tmp_path):
    path = tmp_path / "d.hdf5"
    write_dataset(path, _arrays(), ATTRS)
    with h5py.File(path, "a") as h5:
        del h5["actions"]
    with pytest.raises(DatasetError, match=rf"{path}: missing key\(s\) actions"):
        read_dataset(path)


def test_nan_values(tmp_path):
    path = tmp_path / "d.hdf5"
    write_dataset(path, _arrays(), ATTRS)
    with h5py.File(path, "a") as h5:
        h5["next_observations"][3, 2] = np.nan
    with pytest.raises(DatasetError, match=r"'next_observations' has non-finite values \(first at row 3\)"):
        read_dataset(path)


def test_broken_episode_boundary_and_wrong_dtype(tmp_path):
    path = tmp_path / "d.hdf5"
    write_dataset(path, _arrays(), ATTRS)
    shutil.copy(path, tmp_path / "e.hdf5")
    with h5py.File(path, "a") as h5:
        h5["observations"][2, 0] += 1.0
    with pytest.raises(DatasetError, match="episode boundary broken at row 1"):
        read_dataset(path)
    with h5py.File(tmp_path / "e.hdf5", "a") as h5:
        rewards = h5["rewards"][()]
        del h5["rewards"]
        h5["rewards"] = rewards.astype(np.float64)
    with pytest.raises(DatasetError, match="'rewards' has dtype float64, expected float32"):
        read_dataset(tmp_path / "e.hdf5")


def test_last_transition_must_end_an_episode(tmp_path):
    arrays = _arrays()
    arrays["timeouts"][-1] = False
    with pytest.raises(DatasetError, match="last transition"):
        write_dataset(tmp_path / "d.hdf5", arrays, ATTRS)
    assert not list(tmp_path.iterdir())  # nothing written, not even a temporary file


def test_checksum_detects_modification(tmp_path):
    path = tmp_path / "d.hdf5"
    write_dataset(path, _arrays(), ATTRS)
    with h5py.File(path, "a") as h5:
        h5["rewards"][0] = 0.123
    read_dataset(path)  # still a valid dataset...
    with pytest.raises(DatasetError, match="content does not match"):
        read_dataset(path, verify_checksum=True)  # ...but not the one that was written


def test_failed_write_keeps_existing_file(tmp_path):
    path = tmp_path / "d.hdf5"
    write_dataset(path, _arrays(seed=1), ATTRS)
    before = path.read_bytes()
    bad = _arrays(seed=2)
    bad["actions"] = bad["actions"][:, :5]
    with pytest.raises(DatasetError):
        write_dataset(path, bad, ATTRS)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.hdf5"]
