"""Files written atomically (a reader never sees half a file) and JSON read with errors naming the file."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
from pathlib import Path
from typing import Any, Iterator

from mop_core.config import InputFileError, OutputFileError, first_line


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling of ``path``; on success rename it onto ``path`` (atomic on POSIX).

    On failure the temporary file is removed and an existing ``path`` is left untouched, so a
    reader never sees a half-written file under the final name. A write that fails for lack of
    space (``ENOSPC``, or torch's ``unexpected pos`` for a short write) raises OutputFileError naming
    ``path``. Temporary names match ``.dvcignore``'s ``.*.tmp-*``: a leftover never changes a hash.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        yield tmp
        os.replace(tmp, path)
    except (OSError, RuntimeError) as err:
        if getattr(err, "errno", None) == errno.ENOSPC or "unexpected pos" in str(err):
            free = shutil.disk_usage(path.parent).free
            raise OutputFileError(f"{path}: could not be written, no space left on device ({free / 2**20:.0f} MiB "
                                  f"free in {path.parent} now); the previous file, if any, is untouched") from err
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


def write_json(path: str | os.PathLike, payload: Any) -> None:
    """Atomically write ``payload`` as indented JSON."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(payload, indent=2, sort_keys=True) + "\n")


def read_json(path: str | os.PathLike) -> Any:
    """A JSON file the stages wrote; a missing, empty or garbled file raises InputFileError naming it."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: file not found")
    try:
        return json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as err:
        raise InputFileError(f"{path}: not valid JSON (empty, truncated or edited?): {first_line(err)}") from None
