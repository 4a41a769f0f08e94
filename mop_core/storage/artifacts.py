"""Files the stages leave behind: checkpoints (atomic), learning curves (TSV), content hashes."""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
from pathlib import Path
from typing import Any

import torch

from mop_core.config import InputFileError, first_line
from mop_core.storage.files import atomic_path


def state_sha256(state: dict[str, torch.Tensor]) -> str:
    """SHA-256 of a state dict's tensors (names, shapes and bytes, in key order)."""
    digest = hashlib.sha256()
    for key in sorted(state):
        tensor = state[key].detach().cpu().contiguous()
        digest.update(f"{key}|{tuple(tensor.shape)}|{tensor.dtype}".encode())
        digest.update(tensor.numpy().tobytes())
    return digest.hexdigest()


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (InputFileError if it is missing)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: file not found")
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def package_versions() -> dict[str, str]:
    names = ("mop_core", "torch", "dm-control", "mujoco", "numpy", "h5py")
    return {name: importlib.metadata.version(name) for name in names}


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> Path:
    """torch.save through a temporary file and a rename: a reader never sees half a checkpoint."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return Path(path)


def read_torch_file(path: str | os.PathLike) -> Any:
    """``torch.load`` of a file the stages wrote; a missing, empty, truncated or foreign file raises
    InputFileError naming it (torch's own errors, e.g. ``EOFError: Ran out of input``, do not)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: checkpoint not found")
    if path.stat().st_size == 0:
        raise InputFileError(f"{path}: empty file (an interrupted copy?); rerun the stage that writes it")
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # torch raises EOFError, UnpicklingError, RuntimeError... for a damaged file
        raise InputFileError(f"{path}: not a readable torch checkpoint (truncated or corrupt?): "
                             f"{first_line(err)}") from None


def load_checkpoint(path: str | os.PathLike, kind: str) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint` and check its ``kind`` field."""
    payload = read_torch_file(path)
    if not isinstance(payload, dict) or payload.get("kind") != kind:
        found = payload.get("kind") if isinstance(payload, dict) else type(payload).__name__
        raise InputFileError(f"{path}: expected a {kind!r} checkpoint, found {found!r}")
    return payload


def write_curve(path: str | os.PathLike, rows: list[dict]) -> None:
    """Learning curve as TSV (one row per evaluation) for ``dvc plots``."""
    columns = list(rows[0])
    with atomic_path(path) as tmp:
        lines = ["\t".join(columns)] + ["\t".join(str(row[c]) for c in columns) for row in rows]
        tmp.write_text("\n".join(lines) + "\n")


def read_curve(path: str | os.PathLike) -> list[dict[str, str]]:
    """The rows of a learning-curve TSV (:func:`write_curve`), values as strings."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: learning curve not found")
    try:
        header, *lines = path.read_text().splitlines()
    except (ValueError, UnicodeDecodeError) as err:  # an empty file unpacks to nothing
        raise InputFileError(f"{path}: not a learning-curve TSV (empty or garbled): {first_line(err)}") from None
    keys = header.split("\t")
    if "step" not in keys:
        raise InputFileError(f"{path}: not a learning-curve TSV (no 'step' column in the header {header[:60]!r})")
    for number, line in enumerate(lines, start=2):
        if len(line.split("\t")) != len(keys):
            raise InputFileError(f"{path}: line {number} has {len(line.split(chr(9)))} columns, the header "
                                 f"{len(keys)} (truncated?)")
    return [dict(zip(keys, line.split("\t"))) for line in lines]

