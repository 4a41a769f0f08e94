"""``mop-cluster repro``: the study's stale stage entries on a Ray cluster, then one restoring ``dvc repro``.

    mop-cluster repro                          # a local Ray cluster on this machine's cores
    mop-cluster repro --workers 2              # ... on 2 of them
    mop-cluster repro --address HOST:6379      # join a running cluster (ray start --head / --address,
                                               # KubeRay, Ray on Slurm); the workspace and its DVC cache
                                               # must be on a filesystem every node mounts
    mop-cluster repro --gpus-per-run 0.25      # 4 training entries share one GPU
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .coordinator import ClusterError, repro
from .worker import EntryFailed

INSTALL = "pip install -e '.[cluster]'  (or: pip install 'ray>=2.9')"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mop-cluster", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("repro", help="run the stale entries on a Ray cluster, then dvc repro")
    run.add_argument("--address", help="a running Ray cluster's address (default: start one on this machine)")
    run.add_argument("--workers", type=int, help="CPUs of the local cluster (default: every core)")
    run.add_argument("--gpus-per-run", type=float, default=0.0, help="GPU share of each training entry")
    run.add_argument("--retries", type=int, default=2, help="retries of an entry whose worker died")
    run.add_argument("--root", type=Path, default=Path("."), help="the DVC workspace (default: here)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.workers is not None and args.workers < 1:
        return _error(f"--workers: expected a positive number of CPUs, got {args.workers}")
    if not 0.0 <= args.gpus_per_run <= 1.0:
        return _error(f"--gpus-per-run: expected a share of one GPU in [0, 1], got {args.gpus_per_run}")
    try:
        import ray  # noqa: F401
    except ImportError:
        return _error(f"mop-cluster needs Ray, which is not installed: {INSTALL}")
    try:
        run = repro(args.root, args.address, args.workers, args.gpus_per_run, args.retries)
    except (ClusterError, EntryFailed, KeyError, ValueError) as exc:
        return _error(str(exc))
    ran = sum(result.ran for result in run.results)
    print(f"mop-cluster: {len(run.entries)} entries ({ran} ran on workers, {len(run.results) - ran} restored) "
          f"in {run.seconds:.1f} s; the workspace's dvc repro executed {len(run.final_ran)} stage(s)"
          + (f": {', '.join(run.final_ran)}" if run.final_ran else ""))
    redone = [stage for stage in run.final_ran if stage in run.entries]
    if redone:  # the run cache should have restored them: a dependency that differs between clones
        return _error(f"the workspace's dvc repro reran what workers ran: {', '.join(redone)}")
    return 0


def _error(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
