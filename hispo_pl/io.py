"""Small file helpers: atomic writes, so a kill or a full disk never leaves a half-written
record or a truncated checkpoint in place of the file."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path


def atomic_save(path: str | Path, save: Callable[[Path], None]) -> None:
    """``save(tmp)`` writes the file at ``.NAME.PID.tmp`` beside ``path``, which then replaces
    ``path``: readers see the old file or the new one, never a part. The temporary file (which
    gets the mode of any new file) is removed if the write fails; an error of the file system
    names ``path``, not the writer's own scratch file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        save(tmp)
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        if err.errno is None:
            raise
        raise OSError(err.errno, err.strerror, str(path)) from err
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """:func:`atomic_save` of ``data``, flushed to the disk before it replaces ``path``."""

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())

    atomic_save(path, write)


def atomic_write_text(path: str | Path, text: str) -> None:
    """:func:`atomic_write_bytes` for text (UTF-8)."""
    atomic_write_bytes(path, text.encode())
