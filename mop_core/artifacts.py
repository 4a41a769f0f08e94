"""Files the stages leave behind: checkpoints (atomic), learning curves (TSV), content hashes."""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from mop_core.data import atomic_path


@dataclass(frozen=True)
class RunPaths:
    """Where a training run writes: the final checkpoint, its metrics, its curve, and the resume file."""

    checkpoint: Path
    metrics: Path
    curve: Path
    resume: Path


def state_sha256(state: dict[str, torch.Tensor]) -> str:
    """SHA-256 of a state dict's tensors (names, shapes and bytes, in key order)."""
    digest = hashlib.sha256()
    for key in sorted(state):
        tensor = state[key].detach().cpu().contiguous()
        digest.update(f"{key}|{tuple(tensor.shape)}|{tensor.dtype}".encode())
        digest.update(tensor.numpy().tobytes())
    return digest.hexdigest()


def package_versions() -> dict[str, str]:
    names = ("mop_core", "torch", "dm-control", "mujoco", "numpy", "h5py")
    return {name: importlib.metadata.version(name) for name in names}


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> Path:
    """torch.save through a temporary file and a rename: a reader never sees half a checkpoint."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return Path(path)


def load_checkpoint(path: str | os.PathLike, kind: str) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint` and check its ``kind`` field."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    payload = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(payload, dict) or payload.get("kind") != kind:
        found = payload.get("kind") if isinstance(payload, dict) else type(payload).__name__
        raise ValueError(f"{path}: expected a {kind!r} checkpoint, found {found!r}")
    return payload


def write_curve(path: str | os.PathLike, rows: list[dict]) -> None:
    """Learning curve as TSV (one row per evaluation) for ``dvc plots``."""
    columns = list(rows[0])
    with atomic_path(path) as tmp:
        lines = ["\t".join(columns)] + ["\t".join(str(row[c]) for c in columns) for row in rows]
        tmp.write_text("\n".join(lines) + "\n")
