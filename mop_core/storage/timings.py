"""Wall-clock times and machine facts of every stage run, kept apart from what the runs produce.

A stage writes ``results/timings/<stage>.json`` (or ``results/timings/<family>/<run>.json`` for the
runs of a matrix stage): seconds, throughput, the step a run resumed from, and the machine (package
versions, torch threads, device). They are DVC metrics that no stage depends on, and no checkpoint,
curve or metrics file holds a time or a version: a forced rerun that reproduces a run's weights
changes only its timing file, so every stage after it stays up to date (and the run cache, keyed by
what determines the outputs, can hand a run to another machine).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import torch

from mop_core.storage.artifacts import package_versions
from mop_core.storage.files import write_json

PIPELINE_ORDER = ("collect", "relabel", "teachers", "multitask", "students", "eval", "shared_computation")


def cpu_model() -> str:
    """The processor's model name (/proc/cpuinfo; elsewhere ``platform.processor()``): two 2-core machines
    of other models differ ~2x in speed, and their floating-point paths give other datasets from one seed."""
    import platform

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_facts(device: str | torch.device = "cpu") -> dict[str, Any]:
    """What a time depends on besides the work: the device, the processor (and the vector ISA torch uses on
    it), torch's threads, the cores, the packages (one pip-style string, ``torch==2.13.0 dm-control==1.0.50
    ...``: one column in ``dvc metrics show``)."""
    versions = " ".join(f"{name}=={version}" for name, version in package_versions().items())
    facts = {"device": str(device), "cpu": cpu_model(), "threads": torch.get_num_threads(),
             "cpus": os.cpu_count() or 0, "versions": versions,
             # the vector ISA torch's CPU kernels dispatch to (AVX512, AVX2, ...): two machines sold as one model
             # may differ in it, and the study's CPU float path (TD3's datasets) has differed across sessions
             "cpu_capability": torch.backends.cpu.get_cpu_capability()}
    if torch.device(device).type == "cuda":  # which card a GPU time was measured on
        facts["gpu"] = torch.cuda.get_device_name(torch.device(device))
        facts["cuda_matmul"] = "tf32" if torch.backends.cuda.matmul.allow_tf32 else "fp32"  # study.cuda_matmul
    return facts


def write_timing(path: str | os.PathLike, seconds: float, device: str | torch.device = "cpu",
                 **extra: float | int | dict) -> dict[str, Any]:
    """Write a timing record: ``seconds`` (rounded to 0.1 s), any rates or counts in ``extra``, the machine."""
    record = {"seconds": round(float(seconds), 1), **extra, **machine_facts(device)}
    write_json(path, record)
    return record


def per_second(count: float, seconds: float) -> float:
    return round(count / max(seconds, 1e-9), 1)


def stage_time_table(root: str | os.PathLike) -> str:
    """A markdown table of the seconds each stage's runs took (the ``results/timings`` tree under ``root``):
    one row per stage, matrix runs summed, with their count."""
    root = Path(root)
    rows: dict[str, tuple[float, int]] = {}
    for path in root.rglob("*.json"):
        stage = path.relative_to(root).parts[0].removesuffix(".json")
        total, runs = rows.get(stage, (0.0, 0))
        record = json.loads(path.read_text())  # a group of runs trained together: one file, "runs" of them
        rows[stage] = (total + float(record.get("seconds", 0.0)), runs + int(record.get("runs", 1)))
    order = {stage: i for i, stage in enumerate(PIPELINE_ORDER)}
    rows = dict(sorted(rows.items(), key=lambda item: (order.get(item[0], len(order)), item[0])))
    lines = ["| stage | runs | seconds |", "|---|---|---|"]
    lines += [f"| {stage} | {runs} | {total:.0f} |" for stage, (total, runs) in rows.items()]
    total = sum(seconds for seconds, _ in rows.values())
    return "\n".join([*lines, f"| **total** | | **{total:.0f}** ({total / 60:.1f} min) |"])


if __name__ == "__main__":  # python -m mop_core.storage.timings [results/timings]
    import sys

    print(stage_time_table(sys.argv[1] if len(sys.argv) > 1 else "results/timings"))
