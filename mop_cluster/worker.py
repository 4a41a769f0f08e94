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
from dataclasses import dataclass
from pathlib import Path

RAN = "Running stage '"
# fault injection for the tests: the first attempt at this entry dies as a killed node would
KILL_ONCE = "MOP_CLUSTER_KILL_ONCE"


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


def _failed(entry: str, log: str) -> EntryFailed:
    tail = "\n".join(log.strip().splitlines()[-20:])
    return EntryFailed(f"{entry}: dvc repro failed; last lines of its log:\n{tail}")


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


def run_entry(root: str, commit: str, entry: str, cache_dir: str, scratch: str, cpus: int = 1) -> EntryResult:
    """``dvc repro entry`` in a fresh clone of ``root`` at ``commit`` whose cache is ``cache_dir``, told the
    ``cpus`` Ray gave it (``MOP_THREADS``: what a ``threads: auto`` param resolves to there)."""
    start = time.perf_counter()
    Path(scratch).mkdir(parents=True, exist_ok=True)
    clone = Path(tempfile.mkdtemp(prefix=f"{entry.replace('@', '_')}-", dir=scratch))
    try:
        _git(["clone", "-q", "--shared", "--no-checkout", root, str(clone)], Path(scratch))
        _git(["checkout", "-q", commit], clone)
        subprocess.run(["dvc", "cache", "dir", "--local", cache_dir], cwd=clone, check=True, capture_output=True)
        env = os.environ | {"MOP_PROGRESS": "0", "MOP_THREADS": str(cpus)}
        dvc_start = time.perf_counter()
        reaper = [sys.executable, "-m", "mop_cluster.reaper", str(os.getpid())]  # dies with this process
        proc = subprocess.Popen([*reaper, "dvc", "repro", entry], cwd=clone, env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
        _maybe_die(entry, Path(scratch), proc)
        log, _ = proc.communicate()
        dvc_seconds = time.perf_counter() - dvc_start
        if proc.returncode != 0:
            raise _failed(entry, log)
        ran = f"{RAN}{entry}'" in log
        return EntryResult(entry, ran, time.perf_counter() - start, dvc_seconds, socket.gethostname())
    finally:
        shutil.rmtree(clone, ignore_errors=True)


def run_after(root: str, commit: str, entry: str, cache_dir: str, scratch: str, cpus: int,
              *upstream: EntryResult) -> EntryResult:
    """The Ray task: ``upstream`` are the results of the entries ``entry`` reads from (Ray passes them
    once they exist, so an entry starts only after its inputs are in the run cache)."""
    return run_entry(root, commit, entry, cache_dir, scratch, cpus)
