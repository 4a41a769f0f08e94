"""A run's resume file, shared by the offline and online training loops (mop_core.learning.training,
mop_core.learning.online): the fingerprint that ties it to one configuration and its data, the
divergence check before it is written, and the read that ignores a foreign or unreadable file (the
run then restarts at step 0 with a warning)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import torch

from mop_core.learning.runtime import TrainingDivergedError
from mop_core.storage.artifacts import load_checkpoint, save_checkpoint

RESUME_KIND = "training_resume"


def run_fingerprint(payload: dict) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def try_resume(path: Path, fingerprint: str) -> dict | None:
    """The resume state at ``path`` if it belongs to this exact run, else None (a clean restart)."""
    if not path.is_file():
        return None
    try:
        state = load_checkpoint(path, RESUME_KIND)
    except Exception as err:  # unreadable or foreign: restart rather than fail
        print(f"warning: ignoring resume file {path}: {err}")
        return None
    if state.get("fingerprint") != fingerprint:
        print(f"warning: {path} belongs to another configuration or dataset; restarting from step 0")
        return None
    return state


def non_finite_tensor(state) -> str | None:
    """The key of the first floating tensor holding NaN or inf in a (nested) state dict, else None."""
    if isinstance(state, torch.Tensor):
        return "" if state.is_floating_point() and not torch.isfinite(state).all() else None
    items = state.items() if isinstance(state, dict) else enumerate(state) if isinstance(state, (list, tuple)) else ()
    for key, value in items:
        found = non_finite_tensor(value)
        if found is not None:
            return f"{key}.{found}".rstrip(".")
    return None


def check_finite(agent_state: dict, desc: str, step: int, kept: str = "") -> None:
    """Stop a run whose weights hold a NaN or inf (:class:`TrainingDivergedError` naming ``desc``, the
    tensor and ``step``; ``kept``: what survives, e.g. the last good resume file)."""
    bad = non_finite_tensor(agent_state)
    if bad is not None:
        raise TrainingDivergedError(f"{desc}: non-finite weights ({bad}) at step {step}; stopped{kept}")


def write_resume(path: Path, fingerprint: str, step: int, agent_state: dict, seconds: float, desc: str,
                 **state) -> None:
    """The resume file of a run at update ``step``: its weights (checked finite first: a diverged run
    never overwrites the last good file), the ``seconds`` trained so far and the loop's own ``state``
    (generators, curve, losses of the window in progress, ...), read back by :func:`try_resume`."""
    check_finite(agent_state, desc, step)
    save_checkpoint(path, {"kind": RESUME_KIND, "fingerprint": fingerprint, "step": step, "agent": agent_state,
                           "seconds": seconds, **state})
