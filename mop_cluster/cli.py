"""``mop-cluster repro``: the study's stale stage entries on a Ray cluster, then one restoring ``dvc repro``.

    mop-cluster repro                          # a local Ray cluster on this machine's cores
    mop-cluster repro --workers 2              # ... on 2 of them
    mop-cluster repro --address HOST:6379      # join a running cluster (ray start --head / --address,
                                               # KubeRay, Ray on Slurm); the workspace and its DVC cache
                                               # must be on a filesystem every node mounts
    mop-cluster repro --gpus-per-run 0.25      # 4 training entries share one GPU
    mop-cluster repro --address HOST:6379 --git-url URL --dvc-remote   # nodes that share no filesystem:
                                               # clones of URL (HEAD pushed there), outputs through the
                                               # workspace's default DVC remote
    mop-cluster exp run -S distill.learning_rate=3e-4,1e-3   # one DVC experiment per value (several -S:
                                               # their grid), every experiment's stale entries on the cluster
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from .coordinator import ClusterError, repro
from .experiments import exp_run
from .worker import EntryFailed

INSTALL = "pip install -e '.[cluster]'  (or: pip install 'ray>=2.9')"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mop-cluster", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("repro", help="run the stale entries on a Ray cluster, then dvc repro")
    run.add_argument("targets", nargs="*", help="stages or entries (stage@key), as dvc repro takes them: only "
                                                "what they read from runs (default: the whole pipeline)")
    exp = commands.add_parser("exp", help="DVC experiments on a Ray cluster").add_subparsers(dest="exp_command",
                                                                                           required=True)
    sweep = exp.add_parser("run", help="one DVC experiment per -S value, their stale entries on a Ray cluster")
    sweep.add_argument("-S", "--set-param", dest="sets", action="append", required=True, metavar="KEY=V1,V2",
                       help="a params.yaml key and its values (repeat for a grid)")
    for sub in (run, sweep):
        sub.add_argument("--address", help="a running Ray cluster's address (default: start one on this machine)")
        sub.add_argument("--workers", type=int, help="CPUs of the local cluster (default: every core)")
        sub.add_argument("--gpus-per-run", type=float, default=0.0, help="GPU share of each training entry")
        sub.add_argument("--retries", type=int, default=2, help="retries of an entry whose worker died")
        sub.add_argument("--auto-threads", type=int, default=2, help="CPUs of an entry whose threads are 'auto'")
        sub.add_argument("--root", type=Path, default=Path("."), help="the DVC workspace (default: here)")
        sub.add_argument("--git-url", help="where workers clone HEAD from (default: the workspace's path, on a "
                                           "filesystem every node mounts); push HEAD there first")
        sub.add_argument("--dvc-remote", action="store_true",
                         help="workers share no filesystem: outputs and run-cache records travel through the "
                              "workspace's default DVC remote (committed in .dvc/config) instead of its cache")
    return parser


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def _stop_on_signals() -> None:
    """SIGTERM (Slurm's scancel, Kubernetes, kill) stops the run as Ctrl-C does: Ray shut down, every entry's
    processes killed. Without this Python dies at once, Ray's workers die without their shutdown, and the
    entries' dvc repro live on (measured: a quick-study run stopped by SIGTERM left two `dvc repro` and their
    stages running). Once Ray runs, its own SIGTERM handler exits instead (SystemExit): the same path. SIGINT
    gets its handler back even when a shell started this in the background with SIGINT ignored."""
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, signal.default_int_handler)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.workers is not None and args.workers < 1:
        return _error(f"--workers: expected a positive number of CPUs, got {args.workers}")
    if args.auto_threads < 1:
        return _error(f"--auto-threads: expected a positive number of CPUs, got {args.auto_threads}")
    if not 0.0 <= args.gpus_per_run <= 1.0:
        return _error(f"--gpus-per-run: expected a share of one GPU in [0, 1], got {args.gpus_per_run}")
    try:
        import ray  # noqa: F401
    except ImportError:
        return _error(f"mop-cluster needs Ray, which is not installed: {INSTALL}")
    _stop_on_signals()
    if args.command == "exp":
        return _exp_run(args)
    try:
        run = repro(args.root, args.address, args.workers, args.gpus_per_run, args.retries,
                    auto_cpus=args.auto_threads, git_url=args.git_url, dvc_remote=args.dvc_remote,
                    targets=tuple(args.targets))
    except (ClusterError, EntryFailed, KeyError, ValueError) as exc:
        return _error(str(exc))
    except (KeyboardInterrupt, SystemExit):  # Ctrl-C; SIGTERM (Ray's handler, once Ray runs, exits)
        _error("interrupted: every entry stopped; those that finished are in the run cache, so a rerun "
               "continues from them")
        return 130
    ran = sum(result.ran for result in run.results)
    print(f"mop-cluster: {len(run.entries)} entries ({ran} ran on workers, {len(run.results) - ran} restored) "
          f"in {run.seconds:.1f} s; the workspace's dvc repro executed {len(run.final_ran)} stage(s)"
          + (f": {', '.join(run.final_ran)}" if run.final_ran else ""))
    redone = [stage for stage in run.final_ran if stage in run.entries]
    if redone:  # the run cache should have restored them: a dependency that differs between clones
        return _error(f"the workspace's dvc repro reran what workers ran: {', '.join(redone)}")
    return 0


def _exp_run(args) -> int:
    try:
        run = exp_run(args.root, args.sets, args.address, args.workers, args.gpus_per_run, args.retries,
                      auto_cpus=args.auto_threads, git_url=args.git_url, dvc_remote=args.dvc_remote)
    except (ClusterError, EntryFailed, KeyError, ValueError) as exc:
        return _error(str(exc).strip("'\""))
    except (KeyboardInterrupt, SystemExit):  # Ctrl-C; SIGTERM (Ray's handler, once Ray runs, exits)
        _error("interrupted: every entry stopped; those that finished are in the run cache")
        return 130
    ran = sum(result.ran for result in run.results)
    print(f"mop-cluster: {len(run.experiments)} experiment(s) ({ran} entries ran on workers, "
          f"{len(run.results) - ran} restored) in {run.seconds:.1f} s: "
          + ", ".join(f"{r.name} ({r.experiment.label})" for r in run.recorded))
    redone = [f"{stage} ({r.experiment.label})" for r in run.recorded for stage in r.ran
              if stage in r.experiment.entries]
    if redone:  # the run cache should have restored them
        return _error(f"dvc exp run reran what workers ran: {', '.join(redone)}")
    return 0


def _error(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
