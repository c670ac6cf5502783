"""Atomic file writes: a reader (or a resumed run) sees the old file or the new one, never a torn one.

The content goes to a temporary file in the same directory, is flushed to disk, and replaces the target
with `os.replace` (atomic on POSIX), so a crash or kill -9 mid-write leaves the previous version.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text(path: Path, text: str) -> None:
    write_bytes(path, text.encode())
