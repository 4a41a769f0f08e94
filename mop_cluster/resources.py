"""What each stage entry asks the cluster for: CPUs from the threads its params declare, a GPU share.

One table maps a stage family (the name before ``@``) to the params.yaml keys that size its processes;
an entry asks for the product of those keys' values (collect: workers x threads per worker) or their
maximum (stages that first roll out in processes, then compute on threads). A family absent from the
table runs on one CPU. Ray then never starts more entries at once than a node's CPUs can hold, so the
threads of the running entries never exceed the cores.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import prod
from pathlib import Path

import yaml

# family -> (how the values combine, the dotted params keys)
CPU_KEYS: dict[str, tuple[str, tuple[str, ...]]] = {
    "collect": ("product", ("collect.parallel.workers", "collect.parallel.threads_per_worker")),
    "train_teachers": ("max", ("train_teachers.threads",)),
    "train_relabelled_teachers": ("max", ("train_teachers.threads",)),
    "train_multitask": ("max", ("train_teachers.threads",)),
    "compose": ("max", ("state_shift.workers",)),
    "distill": ("max", ("distill.threads",)),
    "state_shift": ("max", ("state_shift.workers", "state_shift.measure.threads")),
    "eval": ("max", ("eval.workers",)),
    "shared_computation": ("max", ("shared_computation.workers", "shared_computation.threads")),
}
# families that train or run networks, so share a GPU when one is asked for (--gpus-per-run)
GPU_FAMILIES = ("train_teachers", "train_relabelled_teachers", "train_multitask", "distill")


@dataclass(frozen=True)
class EntryResources:
    cpus: int
    gpus: float


def family(entry: str) -> str:
    """``distill_width@8`` -> ``distill`` (every distill_* stage is sized by distill.threads)."""
    name = entry.split("@", 1)[0]
    return "distill" if name.startswith("distill") else name


def _value(params: dict, key: str, source: Path, auto_cpus: int) -> int:
    node = params
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(f"{source}: {key}: missing (mop_cluster.resources sizes entries by it)")
        node = node[part]
    if node == "auto":  # the worker tells the entry its CPUs (MOP_THREADS), which auto then resolves to
        return auto_cpus
    if not isinstance(node, int) or isinstance(node, bool) or node < 1:
        raise ValueError(f"{source}: {key}: expected a positive integer (threads or processes), got {node!r}")
    return node


def entry_resources(entries: list[str], params_file: Path, gpus_per_run: float = 0.0,
                    params: dict | None = None, auto_cpus: int = 2) -> dict[str, EntryResources]:
    """Each entry's CPUs and GPU share, read by the CPU_KEYS table from ``params`` (default: ``params_file``'s
    content; the file names them in errors). A ``threads: auto`` key counts ``auto_cpus``."""
    if params is None:  # a project without params.yaml: every entry one CPU
        params = yaml.safe_load(params_file.read_text()) or {} if params_file.exists() else {}
    sized = {}
    for entry in entries:
        how, keys = CPU_KEYS.get(family(entry), ("max", ()))
        values = [_value(params, key, params_file, auto_cpus) for key in keys] or [1]
        cpus = prod(values) if how == "product" else max(values)
        gpus = gpus_per_run if family(entry).startswith(GPU_FAMILIES) else 0.0
        sized[entry] = EntryResources(cpus=cpus, gpus=gpus)
    return sized
