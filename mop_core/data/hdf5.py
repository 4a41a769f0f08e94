"""The offline dataset file: D4RL-compatible HDF5 schema, atomic writes and validated reads.

One file per (task, level). Keys (D4RL names, so d3rlpy/CORL/Minari users can read the file)::

    observations        [N, 24] float32     state s_t
    actions             [N, 6]  float32     a_t
    rewards             [N]     float32     dm_control's reward of the behaviour task for (s_t, a_t)
    next_observations   [N, 24] float32     s_{t+1}
    terminals           [N]     bool        true termination (never on walker)
    timeouts            [N]     bool        last transition of a stored trajectory
    infos/next_physics  [N, 18] float64     qpos+qvel of s_{t+1}: the state the reward is computed on
    infos/torso_height, infos/torso_upright, infos/horizontal_velocity   [N] float64  reward features

File attributes: task, level, seed, episode_length, behaviour_sha256 (the snapshot that acted),
content_sha256 (of all arrays; relabel files record it to detect stale pairs). The package versions
that wrote it are in the collect stage's timing record (results/timings/collect.json), not in the file.

The relabel file of a dataset holds ``rewards/<task>`` [N] float64 for every study task (the
rewards of D_{j->i} without a copy of the observations) and the dataset's content_sha256.
"""

from __future__ import annotations

import hashlib
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import h5py
import numpy as np

from mop_core.config import InputFileError
from mop_core.storage.files import atomic_path
from mop_core.walker.tasks import REWARD_FEATURES

FORMAT_VERSION = 1

# in-memory name -> (path in file, trailing shape, dtype)
DATASET_SCHEMA: dict[str, tuple[str, tuple[int, ...], np.dtype]] = {
    "observations": ("observations", (24,), np.dtype(np.float32)),
    "actions": ("actions", (6,), np.dtype(np.float32)),
    "rewards": ("rewards", (), np.dtype(np.float32)),
    "next_observations": ("next_observations", (24,), np.dtype(np.float32)),
    "terminals": ("terminals", (), np.dtype(bool)),
    "timeouts": ("timeouts", (), np.dtype(bool)),
    "next_physics": ("infos/next_physics", (18,), np.dtype(np.float64)),
}
FEATURE_PATHS = tuple(f"infos/{name}" for name in REWARD_FEATURES)
#: Dataset levels (thesis 4.4.3); the ``level`` attribute of every dataset file is one of them.
REQUIRED_ATTRS = ("task", "level", "seed", "episode_length", "behaviour_sha256", "content_sha256")


class DatasetError(InputFileError):
    """A dataset or relabel file is missing, unreadable or inconsistent; the message names the file."""


@dataclass
class Dataset:
    """A validated dataset in memory: numpy arrays under in-memory names, plus file attributes.

    ``arrays`` holds the :data:`DATASET_SCHEMA` keys and ``reward_features [N, 3]``.
    """

    path: Path
    arrays: dict[str, np.ndarray]
    attrs: dict[str, Any]

    def __len__(self) -> int:
        return len(self.arrays["observations"])


def content_sha256(arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 over every array's name, dtype, shape and bytes, in sorted name order."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{array.dtype.str}|{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def _write_array(h5: h5py.File, name: str, array: np.ndarray) -> None:
    h5.create_dataset(name, data=array, track_times=False)


def write_dataset(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> str:
    """Validate and atomically write a dataset; returns its content_sha256.

    ``arrays`` uses in-memory names (:data:`DATASET_SCHEMA` plus ``reward_features [N, 3]``);
    ``attrs`` must hold every :data:`REQUIRED_ATTRS` except content_sha256, which is computed.
    Identical inputs give byte-identical files (no timestamps are stored).
    """
    arrays = {name: np.asarray(arrays[name], dtype=DATASET_SCHEMA[name][2]) for name in DATASET_SCHEMA} | {
        "reward_features": np.asarray(arrays["reward_features"], dtype=np.float64)}
    attrs = dict(attrs)
    attrs["content_sha256"] = content_sha256(arrays)
    attrs.setdefault("format_version", FORMAT_VERSION)
    validate_arrays(arrays, attrs, str(path))
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w", track_order=False) as h5:
            for name, (file_path, _, _) in DATASET_SCHEMA.items():
                _write_array(h5, file_path, arrays[name])
            for column, file_path in enumerate(FEATURE_PATHS):
                _write_array(h5, file_path, arrays["reward_features"][:, column])
            for key in sorted(attrs):
                h5.attrs[key] = attrs[key]
    return attrs["content_sha256"]


def _open(path: Path) -> h5py.File:
    if not path.is_file():
        raise DatasetError(f"{path}: dataset file not found")
    try:
        return h5py.File(path, "r")
    except OSError as err:
        raise DatasetError(f"{path}: cannot be read as HDF5 (truncated or corrupt?): {err}") from None


def _attr(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value


def validate_arrays(arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any], where: str) -> None:
    """Check shapes, dtypes, finiteness and episode boundaries; raise :class:`DatasetError`."""
    missing = [a for a in REQUIRED_ATTRS if a not in attrs]
    if missing:
        raise DatasetError(f"{where}: missing attribute(s) {', '.join(missing)}")
    rows = {name: len(array) if np.ndim(array) else 0 for name, array in arrays.items()}
    n = Counter(rows.values()).most_common(1)[0][0]  # the arrays that agree name the odd one out
    odd = [name for name, count in rows.items() if count != n]
    if odd:
        raise DatasetError(f"{where}: '{odd[0]}' has {rows[odd[0]]} rows, the other arrays {n}")
    if n == 0:
        raise DatasetError(f"{where}: dataset is empty")
    shapes = {name: (tail, dtype) for name, (_, tail, dtype) in DATASET_SCHEMA.items()}
    shapes["reward_features"] = ((len(REWARD_FEATURES),), np.dtype(np.float64))
    for name, (tail, dtype) in shapes.items():
        array = arrays[name]
        if array.shape != (n, *tail):
            raise DatasetError(f"{where}: '{name}' has shape {array.shape}, expected {(n, *tail)}")
        if array.dtype != dtype:
            raise DatasetError(f"{where}: '{name}' has dtype {array.dtype}, expected {dtype}")
        if dtype.kind == "f" and not np.isfinite(array).all():
            bad = int(np.argwhere(~np.isfinite(array.reshape(n, -1)).all(axis=1))[0, 0])
            raise DatasetError(f"{where}: '{name}' has non-finite values (first at row {bad})")
    ends = arrays["timeouts"] | arrays["terminals"]
    if not ends[-1]:
        raise DatasetError(f"{where}: the last transition is neither a timeout nor a terminal (truncated episode?)")
    continuing = ~ends[:-1]
    broken = np.flatnonzero(continuing & np.any(arrays["next_observations"][:-1] != arrays["observations"][1:], axis=1))
    if broken.size:
        raise DatasetError(f"{where}: episode boundary broken at row {broken[0]}: next_observations[{broken[0]}] "
                           f"!= observations[{broken[0] + 1}] but timeouts/terminals[{broken[0]}] is false")


def read_dataset(path: str | os.PathLike, verify_checksum: bool = False, task: str | None = None,
                 level: str | None = None) -> Dataset:
    """Read and validate a dataset file (keys, shapes, dtypes, finiteness, episode boundaries).

    With ``verify_checksum`` the arrays' SHA-256 is recomputed and compared to the attribute (0.28 s
    per 100k transitions here, on top of 0.08 s to read them). ``task``/``level``: the file's
    attributes must name them (a dataset copied into another task's or level's slot is refused).
    """
    path = Path(path)
    with _open(path) as h5:
        required = [p for p, _, _ in DATASET_SCHEMA.values()] + list(FEATURE_PATHS)
        missing = [p for p in required if p not in h5]
        if missing:
            raise DatasetError(f"{path}: missing key(s) {', '.join(missing)}")
        try:
            arrays = {name: h5[file_path][()] for name, (file_path, _, _) in DATASET_SCHEMA.items()}
            columns = [h5[p][()] for p in FEATURE_PATHS]
        except OSError as err:
            raise DatasetError(f"{path}: cannot read array data (truncated file?): {err}") from None
        attrs = {k: _attr(v) for k, v in h5.attrs.items()}
    if len({c.shape for c in columns}) != 1 or columns[0].ndim != 1:
        raise DatasetError(f"{path}: reward features {', '.join(FEATURE_PATHS)} must be 1-D of equal length, "
                           f"got shapes {[c.shape for c in columns]}")
    arrays["reward_features"] = np.stack(columns, axis=1)
    validate_arrays(arrays, attrs, str(path))
    for name, expected in (("task", task), ("level", level)):
        if expected is not None and attrs[name] != expected:
            raise DatasetError(f"{path}: holds {attrs['task']}-{attrs['level']} data (file attributes), expected "
                               f"{name} {expected!r}; was another dataset copied here?")
    if verify_checksum and content_sha256(arrays) != attrs["content_sha256"]:
        raise DatasetError(f"{path}: content does not match its content_sha256 attribute (file modified?)")
    return Dataset(path, arrays, attrs)


def read_dataset_attrs(path: str | os.PathLike) -> dict[str, Any]:
    """A dataset file's attributes only (task, level, content_sha256...), without reading its arrays."""
    path = Path(path)
    with _open(path) as h5:
        return {k: _attr(v) for k, v in h5.attrs.items()}


def write_relabel(path: str | os.PathLike, rewards: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    """Atomically write a relabel file: ``rewards/<task> [N] float64`` for each task, plus attributes.

    ``attrs`` must carry ``dataset_content_sha256`` of the dataset the rewards belong to.
    """
    if "dataset_content_sha256" not in attrs:
        raise ValueError("attrs: expected 'dataset_content_sha256' of the source dataset")
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as h5:
            for task in sorted(rewards):
                _write_array(h5, f"rewards/{task}", np.asarray(rewards[task], dtype=np.float64))
            for key in sorted(attrs):
                h5.attrs[key] = attrs[key]


def read_relabel(path: str | os.PathLike, dataset: Dataset, task: str | None = None) -> dict[str, np.ndarray]:
    """Rewards of ``dataset``'s transitions under every task (or only ``task``) from its relabel file.

    Fails naming the file if it belongs to another dataset (content hash), lacks ``task``, has
    the wrong length or non-finite rewards.
    """
    path = Path(path)
    with _open(path) as h5:
        expected = dataset.attrs["content_sha256"]
        found = _attr(h5.attrs.get("dataset_content_sha256", ""))
        if found != expected:
            raise DatasetError(f"{path}: relabel file belongs to another dataset (content {found[:12]}..., "
                               f"expected {expected[:12]}... of {dataset.path}); rerun the relabel stage")
        if "rewards" not in h5:
            raise DatasetError(f"{path}: missing key 'rewards'")
        available = sorted(h5["rewards"])
        wanted = available if task is None else [task]
        for name in wanted:
            if name not in available:
                raise DatasetError(f"{path}: no rewards for task {name!r}; relabelled tasks: {', '.join(available)}")
        rewards = {name: h5[f"rewards/{name}"][()] for name in wanted}
    for name, values in rewards.items():
        if values.shape != (len(dataset),):
            raise DatasetError(f"{path}: 'rewards/{name}' has shape {values.shape}, expected ({len(dataset)},)")
        if not np.isfinite(values).all():
            raise DatasetError(f"{path}: 'rewards/{name}' has non-finite values")
    return rewards
