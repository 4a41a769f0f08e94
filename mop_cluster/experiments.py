"""``mop-cluster exp run -S key=v1,v2``: one DVC experiment per value, its stale entries on the cluster.

Per combination of the ``-S`` values (several ``-S`` make a grid, as ``dvc exp run --queue -S`` does):
1. a commit on top of HEAD whose params.yaml holds the values (git plumbing: the workspace, its index
   and its branches are not touched; a ref ``refs/mop-cluster/<commit>`` keeps it from git's gc);
2. the entries it makes stale: those whose params in HEAD's dvc.lock differ from the commit's params.yaml,
   those the lock lacks (a value that adds matrix entries), and everything downstream of them (its
   ``own`` entries); and the workspace's stale ones, which no value changes: those are the same in every
   combination and run once, at HEAD, for all of them;
3. every combination's entries go to Ray at once, each in a clone at its combination's commit sharing the
   DVC cache (the ``repro`` workers);
4. then, one combination at a time, ``dvc exp run --temp -S ...`` in the workspace, whose dvc.lock lacks
   the run's entries meanwhile (:func:`~mop_cluster.worker.drop_lock_entries`: a matching lock entry whose
   outputs this cache lacks would make DVC run it again): DVC restores every stage from the run cache and
   records a real experiment (``dvc exp show``, ``exp push``, ``exp apply``). The workspace's files,
   dvc.lock included, stay as they were.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .coordinator import Job
from .dag import StageGraph, stage_graph, stale_entries
from .worker import drop_lock_entries, stages_ran, write_atomic


@dataclass(frozen=True)
class Experiment:
    """One combination of values: ``key=value`` strings as given, the commit that holds them, the entries
    it needs run (DAG order) and of those its ``own``: the ones its values change (the others are HEAD's)."""

    sets: tuple[str, ...]
    commit: str = ""
    entries: tuple[str, ...] = ()
    upstream: dict[str, tuple[str, ...]] = field(default_factory=dict)
    own: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        return " ".join(self.sets)


def sweep(specs: list[str]) -> list[tuple[str, ...]]:
    """``["a=1,2", "b=x"]`` -> ``[("a=1", "b=x"), ("a=2", "b=x")]``: the grid of every -S's values, by DVC's
    own sweep parser (``dvc exp run --queue -S``: Hydra's override grammar, ``choice(...)``, ``range(...)``)."""
    from dvc.utils.hydra import get_hydra_sweeps
    from hydra.errors import OverrideParseException

    try:
        grid = get_hydra_sweeps({"params.yaml": list(specs)})
    except OverrideParseException as exc:
        raise ValueError(f"-S {' -S '.join(specs)}: expected key=value or key=v1,v2,... ({exc})".splitlines()[0]
                         ) from None
    return [tuple(point["params.yaml"]) for point in grid]


def set_values(text: str, sets: tuple[str, ...]) -> str:
    """params.yaml's ``text`` with ``sets`` applied by DVC's own code (``dvc exp run -S``: values typed as
    it types them, comments kept). A key params.yaml lacks is refused: it would make a key no stage reads."""
    from dvc.exceptions import InvalidArgumentError
    from dvc.utils.hydra import apply_overrides

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "params.yaml"
        path.write_text(text)
        try:
            apply_overrides(path, list(sets))
        except InvalidArgumentError as exc:
            cause = str(exc.__cause__ or exc).splitlines()[0]
            raise KeyError(f"-S {' -S '.join(sets)}: not a params.yaml key or value ({cause})") from None
        return path.read_text()


def _git(args: list[str], root: Path, env: dict | None = None, stdin: str | None = None) -> str:
    return subprocess.run(["git", *args], cwd=root, check=True, capture_output=True, text=True, input=stdin,
                          env=None if env is None else os.environ | env).stdout.strip()


IDENTITY = {"GIT_AUTHOR_NAME": "mop-cluster", "GIT_AUTHOR_EMAIL": "mop-cluster@localhost",
            "GIT_COMMITTER_NAME": "mop-cluster", "GIT_COMMITTER_EMAIL": "mop-cluster@localhost"}


def experiment_commit(root: Path, head: str, sets: tuple[str, ...]) -> str:
    """A commit on ``head`` whose params.yaml holds ``sets``, written without touching the workspace."""
    text = set_values(_git(["show", f"{head}:params.yaml"], root) + "\n", sets)
    blob = _git(["hash-object", "-w", "--stdin"], root, stdin=text)
    with tempfile.TemporaryDirectory() as tmp:
        index = {"GIT_INDEX_FILE": str(Path(tmp) / "index")}
        _git(["read-tree", head], root, index)
        _git(["update-index", "--cacheinfo", f"100644,{blob},params.yaml"], root, index)
        tree = _git(["write-tree"], root, index)
    commit = _git(["commit-tree", tree, "-p", head, "-m", f"mop-cluster exp run -S {' -S '.join(sets)}"], root,
                  IDENTITY)
    _git(["update-ref", f"refs/mop-cluster/{commit}", commit], root)
    return commit


def _params_changed(clone: Path) -> set[str]:
    """Entries of ``clone`` whose params differ from what its dvc.lock recorded, or that the lock lacks."""
    from dvc.dependency.param import ParamsDependency
    from dvc.repo import Repo

    lock = yaml.safe_load((clone / "dvc.lock").read_text()) if (clone / "dvc.lock").exists() else {}
    locked = set((lock or {}).get("stages", {}))
    changed = set()
    with Repo(str(clone)) as repo:
        for stage in repo.index.stages:
            if stage.name not in locked:
                changed.add(stage.name)
                continue
            if any(isinstance(dep, ParamsDependency) and dep.status() for dep in stage.deps):
                changed.add(stage.name)
    return changed


def plan_experiment(root: Path, commit: str, sets: tuple[str, ...], workspace_stale: set[str],
                    scratch: Path) -> Experiment:
    """The entries the commit makes stale, in DAG order, and its graph's edges (read in a throw-away clone)."""
    scratch.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="plan-", dir=scratch) as tmp:
        clone = Path(tmp) / "clone"
        _git(["clone", "-q", "--shared", "--no-checkout", str(root), str(clone)], scratch)
        _git(["checkout", "-q", commit], clone)
        graph: StageGraph = stage_graph(clone)
        own = graph.downstream_closure(_params_changed(clone) & set(graph.upstream))
        closure = own | graph.downstream_closure(workspace_stale & set(graph.upstream))
        order = graph.order()
    return Experiment(sets, commit, tuple(name for name in order if name in closure), graph.upstream,
                      tuple(name for name in order if name in own))


def plan_experiments(root: Path, head: str, specs: list[str], scratch: Path) -> list[Experiment]:
    """Every combination of ``specs``: its commit and the entries it needs run."""
    workspace_stale = set(stale_entries(root, stage_graph(root)))
    experiments = []
    for sets in sweep(specs):
        commit = experiment_commit(root, head, sets)
        experiments.append(plan_experiment(root, commit, sets, workspace_stale, scratch))
    return experiments


def experiment_jobs(head: str, experiments: list[Experiment]) -> list[Job]:
    """The Ray jobs of ``experiments``, upstream first: an entry that no value changes is one job at ``head``
    for every combination (keyed by its name), the others one per combination (``entry (label)``). Each
    clone's dvc.lock loses every entry the run executes."""
    shared = {name: e.upstream[name] for e in experiments for name in e.entries if name not in e.own}
    stale = tuple(dict.fromkeys(name for e in experiments for name in e.entries))
    jobs = [Job(name, head, name, tuple(u for u in ups if u in shared), stale) for name, ups in shared.items()]
    for e in experiments:
        for entry in e.own:
            ups = tuple(f"{u} ({e.label})" if u in e.own else u for u in e.upstream[entry] if u in e.entries)
            jobs.append(Job(f"{entry} ({e.label})", e.commit, entry, ups, stale))
    return jobs


@dataclass(frozen=True)
class Recorded:
    """What ``dvc exp run`` made of one combination: its experiment's name and the stages it executed."""

    experiment: Experiment
    name: str
    ran: tuple[str, ...]


def record_experiment(root: Path, experiment: Experiment, pull: bool = False) -> Recorded:
    """``dvc exp run --temp -S ...`` in ``root``: with every entry in the run cache it executes nothing
    (``pull``: the run cache and outputs come from the default DVC remote, where the workers pushed them)."""
    args = ["dvc", "exp", "run", "--temp", *(["--pull"] if pull else [])]
    for item in experiment.sets:
        args += ["-S", item]
    result = subprocess.run(args, cwd=root, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed:\n{result.stdout[-2000:]}{result.stderr[-2000:]}")
    out = result.stdout + result.stderr
    ran = tuple(stages_ran(out))
    name = next((line.split(": ", 1)[1].strip() for line in out.splitlines()
                 if line.startswith("Ran experiment(s): ")), "")
    return Recorded(experiment, name, ran)


@dataclass
class ExperimentsRun:
    experiments: list[Experiment]
    results: list = field(default_factory=list)  # the workers' EntryResults
    recorded: list[Recorded] = field(default_factory=list)
    seconds: float = 0.0


def exp_run(root: Path, specs: list[str], address: str | None = None, workers: int | None = None,
            gpus_per_run: float = 0.0, retries: int = 2, log=print, auto_cpus: int = 2,
            git_url: str | None = None, dvc_remote: bool = False) -> ExperimentsRun:
    """One experiment per combination of ``specs``' values: the stale entries of all of them on a Ray
    cluster, then ``dvc exp run --temp`` per combination, restoring them (see the module docstring).
    With ``git_url`` the combinations' commits are pushed there (``refs/mop-cluster/<commit>``) for the
    workers to fetch; ``dvc_remote`` as in ``coordinator.repro``."""
    import time

    import ray

    from .coordinator import SCRATCH, ClusterError, _check_committed, coordinator_lock, run_on_ray, sharing
    from .resources import entry_resources

    root = root.resolve()
    start = time.perf_counter()
    with coordinator_lock(root):
        head = _check_committed(root)
        shared = sharing(root, head, git_url, dvc_remote)
        experiments = plan_experiments(root, head, specs, root / SCRATCH)
        if git_url:  # the workers clone git_url: the combinations' commits must be there
            for experiment in experiments:
                ref = f"refs/mop-cluster/{experiment.commit}"
                _git(["push", "-q", git_url, f"{experiment.commit}:{ref}"], root)
        jobs = experiment_jobs(head, experiments)
        sized = {}
        for commit, label in [(head, "HEAD")] + [(e.commit, e.label) for e in experiments]:
            mine = [job for job in jobs if job.commit == commit]
            params = yaml.safe_load(_git(["show", f"{commit}:params.yaml"], root)) if mine else {}
            resources = entry_resources([job.entry for job in mine], Path(f"params.yaml ({label})"), gpus_per_run,
                                        params, auto_cpus)
            sized |= {job.key: resources[job.entry] for job in mine}
        shared_count = sum(job.commit == head for job in jobs)
        log(f"mop-cluster: {len(experiments)} experiment(s), {len(jobs)} entries to run: {shared_count} that no "
            "value changes, once for all; " + "; ".join(f"{e.label} ({len(e.own)})" for e in experiments))
        run = ExperimentsRun(experiments)
        if jobs:
            if shared.remote:  # the up-to-date entries' outputs, which the workers' entries read
                subprocess.run(["dvc", "push", "-q"], cwd=root, capture_output=True, text=True)
            run.results = run_on_ray(ray, root, jobs, sized, address, workers, gpus_per_run, retries,
                                     root / SCRATCH, log, shared)
        lock = root / "dvc.lock"
        kept = lock.read_bytes() if lock.exists() else None
        drop_lock_entries(lock, [job.entry for job in jobs])  # see the module docstring, step 4
        try:
            for experiment in experiments:
                try:
                    recorded = record_experiment(root, experiment, pull=shared.remote is not None)
                except RuntimeError as exc:
                    raise ClusterError(str(exc)) from None
                run.recorded.append(recorded)
                log(f"mop-cluster: experiment {recorded.name or '?'} ({experiment.label}) recorded; dvc exp run "
                    f"executed {len(recorded.ran)} stage(s)" + (f": {', '.join(recorded.ran)}" if recorded.ran else ""))
        finally:
            if kept is not None:
                write_atomic(lock, kept)
        run.seconds = time.perf_counter() - start
        return run
