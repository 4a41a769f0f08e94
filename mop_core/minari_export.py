"""Minari datasets of a run's offline data: every (task, level) dataset and every relabelled D_{j->i}.

    python -m mop_core.minari_export [--root .] [--out data/minari] [--code-permalink URL]

Each dataset becomes one Minari dataset (``minari`` is an optional dependency: ``pip install -e
'.[ecosystem]'``), with the Gymnasium env of its reward task (:mod:`mop_core.gym_envs`, an env spec
with a string entry point, so ``recover_environment()`` rebuilds it) and the reference scores of
the study's normalised score, ``ref_min_score`` = R_random and ``ref_max_score`` = R_expert of the
reward task (the eval stage's ``normalisation`` block: ``get_normalized_score`` is the report's
normalised score divided by 100). Ids:

- ``mop/walker-<task>/<level>-v0``: the collect stage's dataset of ``task`` at ``level``;
- ``mop/walker-<i>/<level>-from-<j>-v0``: D_{j->i}, task j's dataset with task i's rewards (the
  relabel stage's, float64).

Episodes are the HDF5 file's, split at its time-outs and terminals, array for array: Minari's
``observations`` are the episode's T observations followed by its last ``next_observations`` row
(T + 1, Minari's convention), ``actions``, ``rewards``, ``terminations`` (``terminals``) and
``truncations`` (``timeouts``) its T rows, and ``infos`` the file's ``infos/*`` after each step (T
rows each: ``next_physics`` and the reward features; the reset state's are not in the file, so
unlike an env-collected Minari dataset there is no leading reset row). Tested: every array read back
equal. The export is all or nothing: the datasets are written under a temporary folder that replaces
``--out`` only when every one is written.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from mop_core.config import ConfigError, InputFileError
from mop_core.data.hdf5 import Dataset, read_dataset, read_relabel
from mop_core.storage.files import read_json
from mop_core.storage.layout import DATA, EVAL_METRICS, relabel_file
from mop_core.walker.tasks import REWARD_FEATURES

NAMESPACE = "mop"
DEFAULT_OUT = DATA / "minari"
REQUIREMENTS = ["dm-control==1.0.50", "mujoco==3.17.0"]  # what recovering the env needs beside this package


def minari_id(reward_task: str, level: str, source_task: str | None = None) -> str:
    """The Minari id of task ``source_task``'s ``level`` data with ``reward_task``'s rewards."""
    name = level if source_task in (None, reward_task) else f"{level}-from-{source_task}"
    return f"{NAMESPACE}/walker-{reward_task}/{name}-v0"


@dataclass(frozen=True)
class Export:
    """One Minari dataset to write: ``dataset_path``'s transitions with ``reward_task``'s rewards."""

    dataset_id: str
    dataset_path: Path
    source_task: str
    level: str
    reward_task: str
    relabel_path: Path | None  # None: the dataset's own rewards


def plan_exports(root: Path) -> list[Export]:
    """Every dataset under ``root/data/datasets`` and, from its relabel file, every other task's D_{j->i}."""
    files = sorted((root / DATA / "datasets").glob("*.hdf5"))
    if not files:
        raise InputFileError(f"{root / DATA / 'datasets'}: no dataset files (*.hdf5); run `dvc repro relabel` first")
    exports = []
    for path in files:
        dataset = read_dataset(path)
        task, level = dataset.attrs["task"], dataset.attrs["level"]
        exports.append(Export(minari_id(task, level), path, task, level, task, None))
        relabel = root / relabel_file(task, level)
        if relabel.is_file():
            for other in sorted(read_relabel(relabel, dataset)):
                if other != task:
                    exports.append(Export(minari_id(other, level, task), path, task, level, other, relabel))
    return exports


def reference_scores(root: Path, tasks: set[str]) -> dict[str, tuple[float, float]]:
    """Per task (R_random, R_expert): the eval stage's normalisation of the normalised score."""
    path = root / EVAL_METRICS
    norms = read_json(path).get("normalisation", {})
    missing = sorted(tasks - set(norms))
    if missing:
        raise InputFileError(f"{path}: no normalisation for task(s) {', '.join(missing)} (R_random, R_expert); "
                             "run `dvc repro eval` with them in the study")
    return {task: (float(norms[task]["random_return"]), float(norms[task]["expert_return"])) for task in tasks}


def code_permalink(root: Path) -> str:
    """Where the code of this export is: the checked-out commit's URL on the ``origin`` remote (an https
    or ssh GitHub-style remote: ``https://<host>/<owner>/<repo>/tree/<commit>``), else the commit in
    the local repository (with a warning: pass ``--code-permalink`` before publishing the datasets)."""
    def git(*args: str) -> str:
        done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True)
        return done.stdout.strip() if done.returncode == 0 else ""

    url, commit = git("remote", "get-url", "origin"), git("rev-parse", "HEAD")
    if not commit:
        raise InputFileError(f"--code-permalink: {root} is not a git checkout with a commit to name; pass the URL "
                             "of the code that produced the datasets")
    match = re.fullmatch(r"(?:https://|git@)([^/:]+)[/:](.+?)(?:\.git)?/?", url)
    if match:
        return f"https://{match.group(1)}/{match.group(2)}/tree/{commit}"
    print(f"warning: {root} has no https or ssh remote 'origin' (origin: {url or 'none'}); the datasets name the "
          "local commit: pass --code-permalink before publishing them", file=sys.stderr)
    return f"git commit {commit} of {url or root.resolve()}"


def episode_buffers(dataset: Dataset, rewards: np.ndarray) -> list:
    """The dataset's episodes as Minari episode buffers (module docstring), ``rewards`` as given."""
    from minari.data_collector import EpisodeBuffer

    arrays = dataset.arrays
    ends = np.flatnonzero(arrays["timeouts"] | arrays["terminals"])
    starts = np.concatenate([[0], ends[:-1] + 1])
    buffers = []
    for k, (s, e) in enumerate(zip(starts, ends + 1)):
        infos = {"next_physics": arrays["next_physics"][s:e]} | {
            name: arrays["reward_features"][s:e, column] for column, name in enumerate(REWARD_FEATURES)}
        buffers.append(EpisodeBuffer(
            id=k, observations=np.concatenate([arrays["observations"][s:e], arrays["next_observations"][e - 1:e]]),
            actions=arrays["actions"][s:e], rewards=rewards[s:e], terminations=arrays["terminals"][s:e],
            truncations=arrays["timeouts"][s:e], infos=infos))
    return buffers


def episode_arrays(episodes) -> dict[str, np.ndarray]:
    """Minari episodes (``iterate_episodes()``) joined back into the HDF5 file's arrays."""
    episodes = list(episodes)
    out = {"observations": np.concatenate([ep.observations[:-1] for ep in episodes]),
           "next_observations": np.concatenate([ep.observations[1:] for ep in episodes]),
           "actions": np.concatenate([ep.actions for ep in episodes]),
           "rewards": np.concatenate([ep.rewards for ep in episodes]),
           "terminals": np.concatenate([ep.terminations for ep in episodes]),
           "timeouts": np.concatenate([ep.truncations for ep in episodes]),
           "next_physics": np.concatenate([ep.infos["next_physics"] for ep in episodes])}
    out["reward_features"] = np.stack([np.concatenate([ep.infos[name] for ep in episodes])
                                       for name in REWARD_FEATURES], axis=1)
    return out


@contextlib.contextmanager
def minari_root(path: Path) -> Iterator[None]:
    """Minari reads its datasets folder from ``MINARI_DATASETS_PATH``: ``path`` inside the block."""
    before = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = before


def write_export(export: Export, scores: tuple[float, float], author: str, author_email: str | None,
                 permalink: str):
    """Write one Minari dataset (into the current ``MINARI_DATASETS_PATH``); returns it."""
    import gymnasium as gym
    import minari

    from mop_core.gym_envs import env_id

    dataset = read_dataset(export.dataset_path, verify_checksum=True)
    rewards = (dataset.arrays["rewards"] if export.relabel_path is None
               else read_relabel(export.relabel_path, dataset, export.reward_task)[export.reward_task])
    length = int(dataset.attrs["episode_length"])  # the env's time limit is the data's (the tiny profile: 50)
    registered = gym.spec(env_id(export.reward_task))
    spec = dataclasses.replace(registered, kwargs=registered.kwargs | {"episode_length": length},
                               max_episode_steps=length)
    origin = ("its behaviour policy's own rewards" if export.relabel_path is None
              else f"rewards relabelled to {export.reward_task} (D_{{{export.source_task}->{export.reward_task}}})")
    return minari.create_dataset_from_buffers(
        export.dataset_id, episode_buffers(dataset, rewards), env=spec, eval_env=spec,
        algorithm_name=f"TD3 behaviour policy of {export.source_task} ({export.level} level, mop collect stage)",
        author=author, author_email=author_email, code_permalink=permalink,
        ref_min_score=scores[0], ref_max_score=scores[1],
        description=(f"DeepMind Control walker, {export.source_task} behaviour data at the {export.level} level with "
                     f"{origin}; from {export.dataset_path.name} (content_sha256 {dataset.attrs['content_sha256']})."),
        requirements=REQUIREMENTS)


def export_all(root: Path, out: Path, author: str, author_email: str | None, permalink: str | None,
               progress: bool = True) -> list[str]:
    """Export every dataset of the run at ``root`` into the Minari folder ``out``; returns the ids.
    Every input is checked before anything is written; ``out`` is replaced only once all are written."""
    root, out = root.resolve(), out.resolve()  # Minari lists its files relative to an absolute folder
    exports = plan_exports(root)
    scores = reference_scores(root, {e.reward_task for e in exports})
    permalink = permalink or code_permalink(root)
    staging = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        with minari_root(staging):
            for export in exports:
                write_export(export, scores[export.reward_task], author, author_email, permalink)
                if progress:
                    print(f"wrote {export.dataset_id}", file=sys.stderr)
        old = out.with_name(f".{out.name}.old-{os.getpid()}")
        if out.exists():
            out.rename(old)
        staging.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [e.dataset_id for e in exports]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Export a run's datasets as Minari datasets.")
    parser.add_argument("--root", type=Path, default=Path("."), help="the run's repository (default: .)")
    parser.add_argument("--out", type=Path, default=None,
                        help=f"the Minari datasets folder (default: <root>/{DEFAULT_OUT})")
    parser.add_argument("--author", default="mop study", help="the datasets' author field")
    parser.add_argument("--author-email", default=None, help="the datasets' author_email field")
    parser.add_argument("--code-permalink", default=None,
                        help="URL of the code at this commit (default: from the git remote 'origin')")
    args = parser.parse_args(argv)
    try:
        import minari  # noqa: F401
    except ImportError:
        print("error: minari: not installed; pip install -e '.[ecosystem]'", file=sys.stderr)
        return 2
    try:
        ids = export_all(args.root, args.out or args.root / DEFAULT_OUT, args.author, args.author_email,
                         args.code_permalink)
    except (ConfigError, InputFileError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    out = args.out or args.root / DEFAULT_OUT
    print(f"{len(ids)} Minari datasets in {out}: MINARI_DATASETS_PATH={out} python -c "
          f"\"import minari; print(minari.load_dataset('{ids[0]}'))\"")
    return 0


if __name__ == "__main__":
    sys.exit(main())
