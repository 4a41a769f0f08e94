"""mop-cluster: the tiny study serial vs on a local Ray cluster, and the makespan on N workers.

1. (unless ``--makespan-only``) the tiny study (profiles/tiny.yaml) in two fresh copies of this checkout, one by
   ``dvc repro``, one by ``mop-cluster repro --workers W``, on this machine; wall times, their ratio, and
   the cluster's overhead per entry (a task's seconds outside its ``dvc repro``: clone, cache set-up,
   clean-up) and Ray's start. The workers' entries run at the tiny profile's threads (1 or 2).
2. The makespan of the quick study (measured: record/'s timing records), of the evidence profile (measured:
   record/evidence/'s) and of the thesis profile
   (estimated: mop_core.plan's stage hours at benchmarks/gpu/rates.json, the H200's rates at the thesis's
   network sizes, split evenly over each stage's entries) on 1, 4, 16, 64 workers (mop_cluster.makespan).

Run: ``python benchmarks/bench_cluster.py [--makespan-only] [--workers 2]``
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from bad_inputs import committed_project  # noqa: E402

from mop_cluster.dag import stage_graph  # noqa: E402
from mop_cluster.makespan import (  # noqa: E402
    estimated_seconds,
    measured_seconds,
    profile_graph,
    table,
    unrecorded,
)

WORKERS = [1, 4, 16, 64]


def measure(workers: int) -> None:
    env = os.environ | {"MOP_PROGRESS": "0", "RAY_USAGE_STATS_ENABLED": "0"}
    with tempfile.TemporaryDirectory() as scratch:
        serial = committed_project(ROOT, Path(scratch) / "serial")
        start = time.perf_counter()
        subprocess.run(["dvc", "repro"], cwd=serial, env=env, check=True, capture_output=True)
        serial_s = time.perf_counter() - start
        cluster = committed_project(ROOT, Path(scratch) / "cluster")
        start = time.perf_counter()
        out = subprocess.run(["mop-cluster", "repro", "--workers", str(workers)], cwd=cluster, env=env, check=True,
                             capture_output=True, text=True).stdout
        cluster_s = time.perf_counter() - start
    lines = [line for line in out.splitlines()
             if line.startswith("mop-cluster: ") and (" ran in " in line or " restored in " in line)]
    tasks = [float(line.split(" in ")[1].split(" s ")[0]) for line in lines]
    dvc = [float(line.split("(dvc repro ")[1].split(" s)")[0]) for line in lines]
    print(f"tiny study, {os.cpu_count()} cores: dvc repro {serial_s:.0f} s; mop-cluster repro --workers {workers} "
          f"{cluster_s:.0f} s (ratio serial / cluster {serial_s / cluster_s:.2f})")
    print(f"{len(tasks)} entries; their tasks took {sum(tasks):.0f} s together against the serial run's "
          f"{serial_s:.0f} s: {(sum(tasks) - serial_s) / max(len(tasks), 1):.1f} s more per entry (clone, dvc start, "
          "upstream restored from the cache, clean-up, entries sharing the cores); the rest of the cluster's wall "
          "time is Ray's start and the workspace's closing dvc repro")
    print(f"outside dvc repro (clone, cache set-up, clean-up): {(sum(tasks) - sum(dvc)) / max(len(tasks), 1):.2f} s "
          f"per entry; the rest of the difference is dvc repro's own start and two entries sharing {os.cpu_count()} "
          "cores")
    print([line for line in out.splitlines() if line.startswith("mop-cluster: ")][-1])


def makespans() -> None:
    print("\nquick study (params.yaml), seconds measured by record/'s run:\n")
    print(table(stage_graph(ROOT), measured_seconds(ROOT / "record", stage_graph(ROOT)), WORKERS))
    evidence, record = ROOT / "profiles" / "evidence.yaml", ROOT / "record" / "evidence"
    graph = profile_graph(evidence)
    missing = unrecorded(record, graph)
    print(f"\nevidence profile, {len(graph.upstream)} entries, seconds measured by record/evidence/'s run on 2 cores"
          + (f" ({len(missing)} entries it did not reach count 0: a partial run)" if missing else "") + ":\n")
    print(table(graph, measured_seconds(record, graph), WORKERS))
    rates = ROOT / "benchmarks" / "gpu" / "rates.json"
    for name in ("thesis",):
        profile = ROOT / "profiles" / f"{name}.yaml"
        graph = profile_graph(profile)
        print(f"\n{name} profile, {len(graph.upstream)} entries, seconds estimated at {rates.relative_to(ROOT)} "
              "(one H200 per worker):\n")
        print(table(graph, estimated_seconds(profile, rates, graph), WORKERS))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--makespan-only", action="store_true", help="skip timing the tiny study (~10 min on 2 cores)")
    parser.add_argument("--workers", type=int, default=2, help="the local cluster's CPUs")
    args = parser.parse_args()
    if not args.makespan_only:
        measure(args.workers)
    makespans()


if __name__ == "__main__":
    main()
