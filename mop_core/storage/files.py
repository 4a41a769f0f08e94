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
from mop_core.storage.layout import RECORD_KEYS


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


def read_record(path: str | os.PathLike) -> dict:
    """A result record a later stage reads (:func:`read_json`), refused by name unless it is a JSON object
    with the keys its writer always writes (mop_core.storage.layout.RECORD_KEYS): an emptied ``{}`` or a
    list is not a record."""
    record = read_json(path)
    if not isinstance(record, dict):
        raise InputFileError(f"{path}: expected a JSON object (the stage's record), found a {type(record).__name__}; "
                             "rerun the stage that writes it")
    missing = [key for key in RECORD_KEYS.get(Path(path), ()) if key not in record]
    if missing:
        raise InputFileError(f"{path}: record without {', '.join(repr(k) for k in missing)} (emptied or edited?); "
                             "rerun the stage that writes it")
    return record
