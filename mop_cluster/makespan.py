"""How long a study takes on N workers: list scheduling of its stage entries over the DVC DAG.

Each entry occupies one worker (a device, or a node's cores) for its duration, and starts once every
entry it reads from has finished. Ready entries start longest-remaining-path first (the critical path's
entries before the rest). The result is the makespan, the critical path (the longest chain of dependent
entries: no number of workers beats it) and the utilisation (busy worker-seconds / (N x makespan)).

Durations come from a run's timing records (``results/timings`` and the dvc.lock naming them: measured)
or, for a profile never run here, from ``mop_core.plan``'s per-stage estimate split evenly over the
stage's entries (estimated).

    python -m mop_cluster.makespan --record record --workers 1 4 16 64
    python -m mop_cluster.makespan --profile profiles/thesis.yaml --rates benchmarks/gpu/rates.json --workers 1 4 16 64
"""

from __future__ import annotations

import argparse
import heapq
import json
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .dag import StageGraph, stage_graph

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Schedule:
    workers: int
    makespan: float
    critical_path: float
    serial: float          # the sum of every entry's seconds: one worker
    utilisation: float


def _remaining(graph: StageGraph, seconds: dict[str, float]) -> dict[str, float]:
    """Each entry's own seconds plus the longest chain of entries that read from it."""
    readers: dict[str, list[str]] = {name: [] for name in graph.upstream}
    for name, ups in graph.upstream.items():
        for up in ups:
            readers[up].append(name)
    rest: dict[str, float] = {}
    for name in reversed(graph.order()):
        rest[name] = seconds[name] + max((rest[r] for r in readers[name]), default=0.0)
    return rest


def schedule(graph: StageGraph, seconds: dict[str, float], workers: int) -> Schedule:
    """List scheduling on ``workers`` identical workers, longest remaining path first."""
    rest = _remaining(graph, seconds)
    waiting = {name: set(ups) for name, ups in graph.upstream.items()}
    ready = [(-rest[name], name) for name, ups in waiting.items() if not ups]
    heapq.heapify(ready)
    running: list[tuple[float, str]] = []
    now, free = 0.0, workers
    while ready or running:
        while ready and free:
            _, name = heapq.heappop(ready)
            heapq.heappush(running, (now + seconds[name], name))
            free -= 1
        now, done = heapq.heappop(running)
        free += 1
        for name, ups in waiting.items():
            if done in ups:
                ups.discard(done)
                if not ups:
                    heapq.heappush(ready, (-rest[name], name))
    serial = sum(seconds.values())
    return Schedule(workers, now, max(rest.values(), default=0.0), serial, serial / (workers * now) if now else 0.0)


def measured_seconds(record: Path, graph: StageGraph) -> dict[str, float]:
    """Each entry's seconds from a run's timing records: ``record``/dvc.lock names each entry's timing file
    (its output under results/timings/), ``record``/results/timings holds it. An entry without one: 0."""
    import yaml

    lock = yaml.safe_load((record / "dvc.lock").read_text())["stages"]
    seconds = {}
    for name in graph.upstream:
        paths = [out["path"] for out in lock.get(name, {}).get("outs", [])
                 if out["path"].startswith("results/timings/") and out["path"].endswith(".json")]
        files = [record / path for path in paths if (record / path).is_file()]
        seconds[name] = sum(json.loads(file.read_text())["seconds"] for file in files)
    return seconds


def unrecorded(record: Path, graph: StageGraph) -> list[str]:
    """The entries of ``graph`` that ``record``/dvc.lock lacks: a partial run (they count 0 seconds)."""
    import yaml

    lock = yaml.safe_load((record / "dvc.lock").read_text())["stages"]
    return [name for name in graph.upstream if name not in lock]


def profile_graph(profile: Path) -> StageGraph:
    """The DAG dvc.yaml expands under ``profile`` (its matrix entries), read in a scratch DVC project."""
    with tempfile.TemporaryDirectory() as scratch:
        shutil.copy(ROOT / "dvc.yaml", scratch)
        shutil.copy(profile, Path(scratch) / "params.yaml")
        subprocess.run(["dvc", "init", "--no-scm", "-q"], cwd=scratch, check=True)
        return stage_graph(Path(scratch))


def estimated_seconds(profile: Path, rates_file: Path, graph: StageGraph) -> dict[str, float]:
    """mop_core.plan's hours per stage, split evenly over the stage's entries; stages it does not estimate
    (params, relabel, student_inputs, state_shift, report: seconds to minutes) count 0."""
    import yaml

    from mop_core.plan import Rates, stage_hours

    hours = stage_hours(yaml.safe_load(profile.read_text()), Rates.from_json(json.loads(rates_file.read_text())))
    stages = [name.partition("@")[0] for name in graph.upstream]
    return {name: hours.get(name.partition("@")[0], (0, 0.0))[1] * 3600 / stages.count(name.partition("@")[0])
            for name in graph.upstream}


def table(graph: StageGraph, seconds: dict[str, float], workers: list[int]) -> str:
    lines = ["| workers | makespan (h) | critical path (h) | serial (h) | speed-up | utilisation |",
             "|---|---|---|---|---|---|"]
    for n in workers:
        s = schedule(graph, seconds, n)
        lines.append(f"| {n} | {s.makespan / 3600:.2f} | {s.critical_path / 3600:.2f} | {s.serial / 3600:.2f} | "
                     f"{s.serial / s.makespan:.1f}x | {s.utilisation:.0%} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", type=Path, help="a run's dvc.lock and results/timings, e.g. record/ "
                                                    "(measured seconds; the DAG of --profile, default this "
                                                    "checkout's params.yaml)")
    parser.add_argument("--profile", type=Path, help="a params file whose DAG to use (and, with --rates, whose "
                                                     "estimated seconds)")
    parser.add_argument("--rates", type=Path, help="with --profile: a JSON of benchmarks/bench_rates.py")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 4, 16, 64])
    args = parser.parse_args(argv)
    if bool(args.record) == bool(args.rates) or (args.rates and not args.profile):
        parser.error("give --record DIR [--profile FILE], or --profile FILE with --rates FILE")
    if args.record:
        graph = profile_graph(args.profile) if args.profile else stage_graph(ROOT)
        seconds, how = measured_seconds(args.record, graph), f"measured ({args.record})"
        missing = unrecorded(args.record, graph)
        if missing:
            how += f"; {len(missing)} entries not in its dvc.lock count 0 (a partial run): {', '.join(missing)}"
    else:
        graph = profile_graph(args.profile)
        seconds, how = estimated_seconds(args.profile, args.rates, graph), f"estimated ({args.rates})"
    print(f"{len(graph.upstream)} entries, seconds {how}\n")
    print(table(graph, seconds, args.workers))


if __name__ == "__main__":
    main()
