"""Load the thesis's reference implementation, pinned, for side-by-side benchmarks (not vendored).

The reference is the thesis's own code, github.com/jaevanlith/mop at commit
:data:`REFERENCE_COMMIT`. Get it once with::

    git clone https://github.com/jaevanlith/mop /path/to/reference
    git -C /path/to/reference checkout 8269599f820ebbd92482dfa975019f8c054b5c7f

and pass ``--reference /path/to/reference`` (or set ``MOP_REFERENCE``). A ``git archive`` export of
that commit works too: the pin is checked by the SHA-256 of every file the benchmarks import
(:data:`PINNED_FILES`), so a checkout of another commit is refused rather than measured.

What the loader changes, and nothing else:
- the modules are compiled with ``optimize=1``, which drops ``assert`` statements: the reference
  asserts a batch of exactly 1024 rows in its actor and Q-loss steps, so no other size would run;
- ``Tensor.cuda()`` returns the tensor itself while :func:`on_cpu` is active: the reference moves
  tensors with unconditional ``.cuda()`` calls and would not run on a CPU otherwise;
- ``hydra`` and ``torchmetrics`` are replaced by empty stand-ins when they are not installed: the
  reference imports them at module level but no code path measured here calls them.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
import sys
import types
from dataclasses import dataclass
from pathlib import Path

import torch

REFERENCE_URL = "https://github.com/jaevanlith/mop"
REFERENCE_COMMIT = "8269599f820ebbd92482dfa975019f8c054b5c7f"
PINNED_FILES = {  # sha256 of each file at REFERENCE_COMMIT
    "utils.py": "cf6da831ad360a08e90bf524000f0c3c01e5a5cb87af163150488a2091cb9c17",
    "replay_buffer.py": "659d5ce817c96c2c094e1730fd19eed479879801da0bfb246329d5667aef62c1",
    "agent/pbrl.py": "fbcdceadee06a816308b77750fce524f1aec017f1101ad071cf4cb4b8a17cf8b",
    "agent/td3.py": "ea77b6653cd2b67af5cb077be15d236cfbbe433e239f430832568669c6066b14",
    "agent/mop.py": "1ac7c4446d03c12e65a3fbbd235a184d20c5fe4c8b0aeec19cea93f5bbc6ca88",
}
HOW_TO_GET = (f"git clone {REFERENCE_URL} DIR && git -C DIR checkout {REFERENCE_COMMIT}; "
              "then pass --reference DIR or set MOP_REFERENCE=DIR")


class ReferenceError(RuntimeError):
    """The reference checkout is missing or is not the pinned commit."""


@dataclass(frozen=True)
class Reference:
    """The reference's modules, imported from a verified checkout."""

    root: Path
    utils: types.ModuleType
    replay_buffer: types.ModuleType
    pbrl: types.ModuleType
    td3: types.ModuleType
    mop: types.ModuleType


def reference_dir(cli_value: str | None) -> Path | None:
    """The checkout named on the command line, else by ``MOP_REFERENCE``, else None."""
    value = cli_value or os.environ.get("MOP_REFERENCE")
    return Path(value).expanduser().resolve() if value else None


def verify(root: Path) -> None:
    """Raise :class:`ReferenceError` unless every pinned file exists with its pinned hash."""
    if not root.is_dir():
        raise ReferenceError(f"--reference: {root} is not a directory; {HOW_TO_GET}")
    for name, digest in PINNED_FILES.items():
        path = root / name
        if not path.is_file():
            raise ReferenceError(f"--reference: {path} is missing; expected the reference at commit "
                                 f"{REFERENCE_COMMIT[:12]} ({HOW_TO_GET})")
        actual = hashlib.sha256(path.read_bytes()).hexdigest()
        if actual != digest:
            raise ReferenceError(f"--reference: {path} differs from commit {REFERENCE_COMMIT[:12]} "
                                 f"(sha256 {actual[:12]}, pinned {digest[:12]}); {HOW_TO_GET}")


def _stand_in(name: str) -> None:
    """Register an empty module ``name`` (and its parents) unless the real one is importable."""
    if importlib.util.find_spec(name.split(".")[0]) is not None:
        return
    parts = name.split(".")
    for i in range(1, len(parts) + 1):
        sys.modules.setdefault(".".join(parts[:i]), types.ModuleType(".".join(parts[:i])))


def _load(root: Path, relative: str, module_name: str) -> types.ModuleType:
    path = root / relative
    module = types.ModuleType(module_name)
    module.__file__ = str(path)
    sys.modules[module_name] = module  # before exec: the reference imports its own modules by name
    exec(compile(path.read_text(), str(path), "exec", optimize=1), module.__dict__)
    return module


def load(root: Path) -> Reference:
    """Import the reference's modules from ``root`` after checking the pin (see the module docstring)."""
    verify(root)
    _stand_in("hydra")
    _stand_in("torchmetrics.functional.retrieval")
    retrieval = sys.modules.get("torchmetrics.functional.retrieval")
    if retrieval is not None and not hasattr(retrieval, "retrieval_normalized_dcg"):
        def unavailable(*_args, **_kwargs):
            raise ReferenceError("torchmetrics is not installed: the reference's NDCG is not available")
        retrieval.retrieval_normalized_dcg = unavailable
    utils = _load(root, "utils.py", "utils")
    replay_buffer = _load(root, "replay_buffer.py", "replay_buffer")
    agent = types.ModuleType("agent")
    agent.__path__ = [str(root / "agent")]
    sys.modules["agent"] = agent
    pbrl = _load(root, "agent/pbrl.py", "agent.pbrl")
    td3 = _load(root, "agent/td3.py", "agent.td3")
    mop = _load(root, "agent/mop.py", "agent.mop")
    return Reference(root, utils, replay_buffer, pbrl, td3, mop)


@contextlib.contextmanager
def on_cpu():
    """While active, ``Tensor.cuda()`` is the identity when no GPU is present (see the module docstring)."""
    if torch.cuda.is_available():
        yield
        return
    original = torch.Tensor.cuda
    torch.Tensor.cuda = lambda self, *args, **kwargs: self
    try:
        yield
    finally:
        torch.Tensor.cuda = original
