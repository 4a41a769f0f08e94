"""The coordinator: stale entries as Ray tasks in DAG order, then one ``dvc repro`` that restores them."""

from __future__ import annotations

import os
import subprocess
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from .dag import stage_graph, stale_entries
from .resources import entry_resources
from .worker import EntryResult, Sharing, drop_lock_entries, run_after, stages_ran

LOCK = Path(".dvc/tmp/mop-cluster.pid")
SCRATCH = Path(".dvc/tmp/mop-cluster")  # the workers' clones


class ClusterError(RuntimeError):
    """A refusal before any compute, or an entry that failed: one line for the user."""


@dataclass
class ClusterRun:
    entries: list[str]
    results: list[EntryResult] = field(default_factory=list)
    final_ran: list[str] = field(default_factory=list)  # stages the workspace's dvc repro executed
    seconds: float = 0.0


@contextmanager
def coordinator_lock(root: Path):
    """One coordinator per workspace: a second is refused, naming the first (its pid)."""
    path = root / LOCK
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        pid = path.read_text().strip() or "?"
        alive = pid.isdigit() and Path(f"/proc/{pid}").exists()
        if alive:
            raise ClusterError(f"{path}: another mop-cluster (pid {pid}) coordinates this workspace") from None
        path.unlink(missing_ok=True)  # left by a coordinator that died
        fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    try:
        yield
    finally:
        path.unlink(missing_ok=True)


def _git(args: list[str], root: Path) -> str:
    return subprocess.run(["git", *args], cwd=root, check=True, capture_output=True, text=True).stdout.strip()


def _check_committed(root: Path) -> str:
    """Workers clone HEAD, so every tracked file but dvc.lock must be as committed. Returns HEAD."""
    status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, check=True,
                            capture_output=True, text=True).stdout
    dirty = [line[3:] for line in status.splitlines() if line[3:] != "dvc.lock"]
    if dirty:
        raise ClusterError(f"{', '.join(dirty)}: uncommitted changes; commit them first (workers clone HEAD)")
    return _git(["rev-parse", "HEAD"], root)


def _dvc_out(args: list[str], root: Path) -> str:
    return subprocess.run(["dvc", *args], cwd=root, check=True, capture_output=True, text=True).stdout.strip()


def sharing(root: Path, commit: str, git_url: str | None = None, dvc_remote: bool = False) -> Sharing:
    """How the workers reach the study, checked before any compute: the workspace and its DVC cache on
    one filesystem (default), or ``git_url`` (where HEAD must be a branch or tag tip) and, with
    ``dvc_remote``, the workspace's default DVC remote, defined in the committed .dvc/config."""
    if git_url is not None:
        listed = subprocess.run(["git", "ls-remote", git_url], cwd=root, capture_output=True, text=True)
        if listed.returncode != 0:
            why = (listed.stderr.strip().splitlines() or ["git ls-remote failed"])[-1]
            raise ClusterError(f"--git-url {git_url}: not a git repository this machine can read ({why})")
        if commit not in {line.split()[0] for line in listed.stdout.splitlines() if line.strip()}:
            raise ClusterError(f"--git-url {git_url}: HEAD ({commit[:12]}) is no branch or tag tip there; "
                               "git push it first (workers clone it)")
    source = git_url or str(root)
    if not dvc_remote:
        return Sharing(source, cache_dir=_dvc_out(["cache", "dir"], root))
    name = _dvc_out(["remote", "default"], root)
    settings = _dvc_out(["config", "--project", "--list"], root).splitlines()  # remote.NAME.url=...
    committed = {line.split(".")[1] for line in settings if line.startswith("remote.")}
    if not name or name not in committed:
        raise ClusterError("--dvc-remote: the workspace's default DVC remote must be defined in the committed "
                           ".dvc/config, so that every clone has it (dvc remote add -d NAME URL; git commit); "
                           f"default: {name or 'none'}, committed: {', '.join(sorted(committed)) or 'none'}")
    return Sharing(source, remote=name)


def repro(root: Path, address: str | None = None, workers: int | None = None, gpus_per_run: float = 0.0,
          retries: int = 2, scratch: Path | None = None, log=print, auto_cpus: int = 2,
          git_url: str | None = None, dvc_remote: bool = False, targets: tuple[str, ...] = ()) -> ClusterRun:
    """Run ``root``'s stale entries on a Ray cluster, then ``dvc repro`` in ``root`` (restoring them).
    With ``targets`` (stages or entries, as ``dvc repro`` takes them) only what they read from runs.
    With ``dvc_remote`` the workers share no filesystem with ``root``: the workspace first pushes what it
    has, each worker pulls and pushes through the remote, and the closing ``dvc repro --pull`` fetches."""
    import ray

    root = root.resolve()
    start = time.perf_counter()
    with coordinator_lock(root):
        commit = _check_committed(root)
        shared = sharing(root, commit, git_url, dvc_remote)
        graph = stage_graph(root)
        entries = stale_entries(root, graph, targets)
        sized = entry_resources(entries, root / "params.yaml", gpus_per_run, auto_cpus=auto_cpus)
        run = ClusterRun(entries)
        if entries:
            if shared.remote:  # the up-to-date entries' outputs, which the workers' entries read
                subprocess.run(["dvc", "push", "-q"], cwd=root, capture_output=True, text=True)
            jobs = [Job(entry, commit, entry, tuple(u for u in graph.upstream[entry] if u in entries),
                        tuple(entries)) for entry in entries]
            run.results = run_on_ray(ray, root, jobs, sized, address, workers, gpus_per_run, retries,
                                     scratch or root / SCRATCH, log, shared)
            drop_lock_entries(root / "dvc.lock", entries)  # stale: the closing repro restores each from the run cache
        final = subprocess.run(["dvc", "repro", *(["--pull"] if shared.remote else []), *targets], cwd=root,
                               capture_output=True, text=True)
        if final.returncode != 0:
            raise ClusterError(f"dvc repro in {root} failed:\n{final.stdout[-2000:]}{final.stderr[-2000:]}")
        run.final_ran = stages_ran(final.stdout)
        run.seconds = time.perf_counter() - start
        return run


@dataclass(frozen=True)
class Job:
    """One Ray task: ``entry`` in a clone at ``commit``, after the jobs keyed ``upstream``."""

    key: str  # unique among a run's jobs (an entry name; with experiments, prefixed by its combination)
    commit: str
    entry: str
    upstream: tuple[str, ...] = ()
    stale: tuple[str, ...] = ()  # the entries this run executes: dropped from the clone's dvc.lock


def run_on_ray(ray, root: Path, jobs: list[Job], sized: dict, address: str | None, workers: int | None,
               gpus_per_run: float, retries: int, scratch: Path, log,
               shared: Sharing | None = None) -> list[EntryResult]:
    """Every job as a Ray task in the given (DAG) order, sized by ``sized[job.key]``; stops them all on
    the first failure or Ctrl-C."""
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(num_cpus=workers or os.cpu_count(), num_gpus=None if gpus_per_run else 0, log_to_driver=False)
    try:
        largest = max((node["Resources"].get("CPU", 0) for node in ray.nodes() if node["Alive"]), default=0)
        for job in jobs:
            if sized[job.key].cpus > largest:
                raise ClusterError(f"{job.entry}: asks for {sized[job.key].cpus} CPUs (its params' threads) but "
                                   f"the largest node of the cluster has {largest:g}; lower its threads")
        task = ray.remote(run_after)
        refs = {}

        shared = shared or Sharing(str(root), cache_dir=_dvc_out(["cache", "dir"], root))
        for job in jobs:  # DAG order: every upstream ref exists before its readers are submitted
            ups = [refs[u] for u in job.upstream if u in refs]
            resources = sized[job.key]
            options = task.options(num_cpus=resources.cpus, num_gpus=resources.gpus, max_retries=retries,
                                   name=job.key)
            refs[job.key] = options.remote(shared, job.commit, job.entry, str(scratch), resources.cpus, job.stale,
                                            resources.gpus, *ups)
        waiting = list(refs.values())
        names = {ref: name for name, ref in refs.items()}
        return _collect(ray, waiting, names, len(jobs), log)
    except BaseException as exc:  # a failed entry or Ctrl-C
        log(f"mop-cluster: stopping ({type(exc).__name__}): shutting Ray down, which stops every entry")
        start = time.perf_counter()
        ray.shutdown()
        log(f"mop-cluster: Ray shut down in {time.perf_counter() - start:.1f} s")
        raise
    finally:  # the job's workers die with it, and their reapers take each entry's dvc repro and stage along
        ray.shutdown()  # (no ray.cancel: Ray 2.60 aborted on it); a no-op when already shut down


def _collect(ray, waiting, names, total: int, log) -> list[EntryResult]:
    results = []
    while waiting:
        ready, waiting = ray.wait(waiting, num_returns=1, timeout=1.0)  # short waits: Ctrl-C lands between
        if not ready:
            continue
        try:
            result = ray.get(ready[0])
        except Exception as exc:  # the entry's EntryFailed, or a worker lost beyond its retries
            cause, name = str(getattr(exc, "cause", None) or exc), names[ready[0]]
            raise ClusterError(cause if cause.startswith(f"{name}: ") else f"{name}: {cause}") from None
        results.append(result)
        log(f"mop-cluster: {names[ready[0]]} {'ran' if result.ran else 'restored'} in {result.seconds:.1f} s "
            f"(dvc repro {result.dvc_seconds:.1f} s) on {result.node} ({len(results)}/{total})")
    return results
