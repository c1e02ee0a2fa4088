"""Small file helpers: atomic writes, so a kill or a full disk never leaves a half-written
record or a truncated checkpoint in place of the file, and writes that stay inside the folder
they were asked to write: a symbolic link where a file or folder goes is replaced, never
followed, and a link among the files to copy is refused.

Every file hispo-pl writes for a user (run files, exports, reports, figures, manifests) goes
through one of these."""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
from collections.abc import Callable
from pathlib import Path
from typing import IO

from .errors import LinkedFileError, UserError


def replace_link(path: str | Path) -> None:
    """Remove ``path`` if it is a symbolic link, so that what is written there next makes a
    new file in its folder instead of writing where the link points; a line says so."""
    path = Path(path)
    if path.is_symlink():
        target = os.readlink(path)
        path.unlink()
        print(
            f"[hispo-pl] {path} was a symbolic link to {target}; hispo-pl writes a new file "
            "there instead, and nothing where the link pointed",
            file=sys.stderr,
        )


LIGHTNING_FILES = ("hparams.yaml", "checkpoints")  # what Lightning writes in a log folder


def files_in_log_dir(trainer) -> None:
    """Keep what Lightning writes by name in a Trainer's log folder inside it: its
    ``hparams.yaml`` (written when no file is there, so through a dangling link) and its
    ``checkpoints/`` folder; a link at either name is replaced (:func:`replace_link`).
    (``config.yaml``: :class:`~hispo_pl.fit.SaveConfig`; event files get a new name each.)"""
    log_dir = trainer.log_dir
    if log_dir:
        for name in LIGHTNING_FILES:
            replace_link(Path(log_dir) / name)


def atomic_save(path: str | Path, save: Callable[[Path], None]) -> None:
    """``save(tmp)`` writes the file at ``.NAME.PID.tmp`` beside ``path``, which then replaces
    ``path``: readers see the old file or the new one, never a part, and a link at ``path`` is
    replaced, not written through. The temporary file (which gets the mode of any new file)
    is removed if the write fails; an error of the file system names ``path``, not the
    writer's own scratch file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        _discard(tmp)  # a file planted at the scratch name is never written through
        save(tmp)
        os.replace(tmp, path)
    except OSError as err:
        _discard(tmp)
        if err.errno is None:
            raise
        raise OSError(err.errno, err.strerror, str(path)) from err
    except BaseException:
        _discard(tmp)
        raise


def _discard(tmp: Path) -> None:
    """Remove ``tmp`` (a link too) if it is there: a read-only disk refuses even the removal
    of a missing file."""
    if os.path.lexists(tmp):
        tmp.unlink()


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """:func:`atomic_save` of ``data``, flushed to the disk before it replaces ``path``."""

    def write(tmp: Path) -> None:
        with open(tmp, "xb") as f:  # a new file: never one that appeared at the name
            f.write(data)
            f.flush()
            os.fsync(f.fileno())

    atomic_save(path, write)


def atomic_write_text(path: str | Path, text: str) -> None:
    """:func:`atomic_write_bytes` for text (UTF-8)."""
    atomic_write_bytes(path, text.encode())


def write_figure(fig, path: str | Path, **savefig_kwargs) -> None:
    """A matplotlib figure saved atomically at ``path`` (its format named by the suffix)."""
    fmt = Path(path).suffix.lstrip(".").lower() or None
    atomic_save(path, lambda tmp: fig.savefig(tmp, format=fmt, **savefig_kwargs))


@contextlib.contextmanager
def named_errors(path: str | Path):
    """An error of the file system raised without a path inside (a write to an open file: a
    full disk) names ``path``, so the message says which file."""
    try:
        yield
    except OSError as err:
        if err.filename is not None or err.errno is None:
            raise
        raise OSError(err.errno, err.strerror, str(path)) from err


def open_append(path: str | Path, mode: str = "a") -> IO:
    """``path`` opened to add to its end (``mode`` ``"a"`` or ``"a+"``), created if missing;
    a link there is replaced by a new file rather than appended through. Write to it inside
    :func:`named_errors`."""
    replace_link(path)
    flags = os.O_CREAT | os.O_APPEND | (os.O_RDWR if "+" in mode else os.O_WRONLY)
    return os.fdopen(os.open(path, flags | getattr(os, "O_NOFOLLOW", 0), 0o666), mode)


def remove_tree(path: str | Path) -> None:
    """Remove the folder ``path`` and what it holds, if it is there; a link there is removed
    itself, never what it points to."""
    path = Path(path)
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.is_dir():
        shutil.rmtree(path)


def make_folder(path: str | Path) -> Path:
    """``path`` made as a folder with its parents, if missing.

    Raises:
        UserError: a place where no folder can be made (``/proc/x``), named."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileNotFoundError as err:
        raise UserError(
            f"cannot make the folder {path}: {err.filename or path} does not exist and cannot "
            "be made; give a folder you can write"
        ) from None
    return path


def real_folder(path: str | Path, root: str | Path) -> Path:
    """``path`` made as real folders under ``root`` (made too, :func:`make_folder`): a link
    on the way is replaced by a folder, so what is written there stays inside ``root``."""
    path, current = Path(path), make_folder(root)
    for part in path.relative_to(root).parts:
        current = current / part
        replace_link(current)
        current.mkdir(exist_ok=True)
    return path


def refuse_linked(paths) -> None:
    """Refuse to copy ``paths`` when one is a symbolic link.

    Raises:
        LinkedFileError: naming the first link, before anything is copied."""
    for path in paths:
        if Path(path).is_symlink():
            raise LinkedFileError(
                f"{path} is a symbolic link; hispo-pl copies only real files: replace the link "
                "by the file itself, or remove it"
            )


def copy_files(pairs) -> list[Path]:
    """Copy each ``(source, destination)`` of ``pairs`` atomically; nothing is copied when a
    source is a link (:func:`refuse_linked`). Returns the destinations. Make the
    destinations' folders with :func:`real_folder` first."""
    pairs = list(pairs)
    refuse_linked([src for src, _ in pairs])
    for src, dst in pairs:
        atomic_write_bytes(dst, Path(src).read_bytes())
    return [Path(dst) for _, dst in pairs]
