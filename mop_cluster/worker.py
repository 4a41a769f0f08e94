"""One stage entry run by a worker: a throw-away clone at the coordinator's commit, sharing its DVC cache.

The worker runs ``dvc repro <entry>``: the upstream entries, already run by other workers, are restored
from the shared run cache, and the entry itself runs (or is restored, if any clone ran it before). DVC
saves an entry's outputs to the cache and its record to the run cache only after its command succeeds,
and the clone is deleted afterwards, so a killed worker leaves nothing half-written behind. ``dvc repro``
runs under ``mop_cluster.reaper``, which kills it and the stage's processes when this worker dies.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import yaml

GPU_SHARE_ENV = "MOP_GPU_SHARE"  # read by mop_core.learning.group_memory (mop_cluster imports no torch)

RAN = "Running stage '"
# fault injection for the tests: the first attempt at this entry dies as a killed node would
KILL_ONCE = "MOP_CLUSTER_KILL_ONCE"


@dataclass(frozen=True)
class Sharing:
    """How a worker's clone reaches the study. One filesystem: ``source`` is the workspace's path and
    ``cache_dir`` its DVC cache, which every clone uses. Across machines: ``source`` is a git URL every node
    can reach (HEAD pushed there) and ``remote`` the DVC remote outputs and run-cache records travel through
    (the workspace's default remote): each clone pulls what it reads and pushes what it ran."""

    source: str
    cache_dir: str | None = None
    remote: str | None = None

    def __post_init__(self):
        if (self.cache_dir is None) == (self.remote is None):
            raise ValueError("Sharing: exactly one of cache_dir (one filesystem) and remote (across machines)")


@dataclass(frozen=True)
class EntryResult:
    entry: str
    ran: bool            # False: restored from the run cache (another clone had run it)
    seconds: float       # the whole task: clone, dvc repro, clean-up
    dvc_seconds: float   # dvc repro alone
    node: str


def stages_ran(log: str) -> list[str]:
    """The stages a ``dvc repro`` / ``dvc exp run`` log says it executed (not those it restored)."""
    return [line.split("'")[1] for line in log.splitlines() if line.startswith(RAN)]


class EntryFailed(RuntimeError):
    """An entry's command failed: its name and the last lines of its log (one message: picklable)."""


def _failed(entry: str, log: str, command: str = "dvc repro") -> EntryFailed:
    tail = "\n".join(log.strip().splitlines()[-20:])
    return EntryFailed(f"{entry}: {command} failed; last lines of its log:\n{tail}")


def _git(args: list[str], cwd: Path) -> None:
    subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True)


def _maybe_die(entry: str, scratch: Path, proc: subprocess.Popen) -> None:
    if os.environ.get(KILL_ONCE) != entry:
        return
    marker = scratch / f"killed-{entry.replace('@', '_')}"
    if marker.exists():
        return
    marker.touch()
    time.sleep(1.0)  # mid-entry
    os.killpg(proc.pid, signal.SIGKILL)  # dvc and the stage's command, as a node's loss takes them
    os._exit(137)


def _clone(sharing: Sharing, commit: str, clone: Path) -> None:
    local = Path(sharing.source).is_dir()  # a path: objects shared, not copied
    _git(["clone", "-q", *(["--shared"] if local else []), "--no-checkout", sharing.source, str(clone)], clone.parent)
    if subprocess.run(["git", "cat-file", "-e", f"{commit}^{{commit}}"], cwd=clone).returncode != 0:
        _git(["fetch", "-q", "origin", commit], clone)  # an experiment's commit: a ref clone does not fetch
    _git(["checkout", "-q", commit], clone)
    if sharing.cache_dir is not None:
        subprocess.run(["dvc", "cache", "dir", "--local", sharing.cache_dir], cwd=clone, check=True,
                       capture_output=True)
    else:  # dvc repro --pull reads the default remote
        subprocess.run(["dvc", "remote", "default", "--local", sharing.remote], cwd=clone, check=True,
                       capture_output=True)


def drop_lock_entries(lock: Path, stages: Iterable[str]) -> None:
    """Remove ``stages``' entries from the dvc.lock at ``lock`` (atomically; no file: nothing to do).

    A lock entry whose dependencies match makes DVC trust its output hashes and never ask the run cache
    (dvc/stage/cache.py, ``restore``): when those outputs are not in this cache (a record made on another
    machine, timings that differ from run to run) DVC runs the stage again. The entries this cluster run
    executes are stale by construction; without them DVC restores each from the run cache."""
    if not lock.exists():
        return
    data = yaml.safe_load(lock.read_text()) or {}
    entries = data.get("stages") or {}
    stale = [stage for stage in dict.fromkeys(stages) if stage in entries]
    if not stale:
        return
    for stage in stale:
        del entries[stage]
    write_atomic(lock, yaml.safe_dump(data, sort_keys=False).encode())


def write_atomic(path: Path, content: bytes) -> None:
    """``content`` to ``path`` through a temporary file beside it: a reader sees the old file or the new."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(content)
    tmp.replace(path)


def _dvc(args: list[str], clone: Path, env: dict, entry: str, scratch: Path, may_die: bool = False) -> str:
    """``dvc args`` under the reaper (it dies with this process); the log, or EntryFailed with its tail."""
    reaper = [sys.executable, "-m", "mop_cluster.reaper", str(os.getpid())]
    proc = subprocess.Popen([*reaper, "dvc", *args], cwd=clone, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    if may_die:
        _maybe_die(entry, scratch, proc)
    log, _ = proc.communicate()
    if proc.returncode != 0:
        raise _failed(entry, log, f"dvc {args[0]}")
    return log


def run_entry(sharing: Sharing, commit: str, entry: str, scratch: str, cpus: int = 1,
              stale: tuple[str, ...] = (), gpus: float = 0.0) -> EntryResult:
    """``dvc repro entry`` in a fresh clone of ``sharing.source`` at ``commit``, told the ``cpus`` Ray gave it
    (``MOP_THREADS``: what a ``threads: auto`` param resolves to there) and its share ``gpus`` of a GPU
    (``MOP_GPU_SHARE``: the memory a vectorised group sizes its waves by, mop_core.learning.group_memory).
    Through a remote, the clone pulls what it reads (``dvc repro --pull``) and pushes the entry's outputs
    and the run-cache records. The clone's dvc.lock loses the ``stale`` entries (the run's), so that its
    upstream entries, which other clones ran, are restored from the run cache instead of run again
    (:func:`drop_lock_entries`)."""
    start = time.perf_counter()
    Path(scratch).mkdir(parents=True, exist_ok=True)
    clone = Path(tempfile.mkdtemp(prefix=f"{entry.replace('@', '_')}-", dir=scratch))
    try:
        _clone(sharing, commit, clone)
        drop_lock_entries(clone / "dvc.lock", stale)
        env = os.environ | {"MOP_PROGRESS": "0", "MOP_THREADS": str(cpus)} | (
            {GPU_SHARE_ENV: str(gpus)} if 0.0 < gpus < 1.0 else {})
        dvc_start = time.perf_counter()
        pull = ["--pull"] if sharing.remote else []
        log = _dvc(["repro", *pull, entry], clone, env, entry, Path(scratch), may_die=True)
        dvc_seconds = time.perf_counter() - dvc_start
        if sharing.remote:
            _dvc(["push", "--run-cache", entry], clone, env, entry, Path(scratch))
        ran = f"{RAN}{entry}'" in log
        return EntryResult(entry, ran, time.perf_counter() - start, dvc_seconds, socket.gethostname())
    finally:
        shutil.rmtree(clone, ignore_errors=True)


def run_after(sharing: Sharing, commit: str, entry: str, scratch: str, cpus: int, stale: tuple[str, ...],
              gpus: float, *upstream: EntryResult) -> EntryResult:
    """The Ray task: ``upstream`` are the results of the entries ``entry`` reads from (Ray passes them
    once they exist, so an entry starts only after its inputs are in the run cache)."""
    return run_entry(sharing, commit, entry, scratch, cpus, stale, gpus)
