"""Errors a user can act on: ``hispo-pl`` prints their message as one paragraph and exits 2,
without a traceback (tracebacks are kept for bugs)."""

from __future__ import annotations


class UserError(Exception):
    """A mistake in the command line, the configuration, the data or a file the user pointed
    at. The message says what was wrong and what to do."""

    exit_code = 2


class ConfigError(UserError, ValueError):
    """An argument or configuration value outside its valid range, caught before training."""


class CheckpointError(UserError, ValueError):
    """A file that is not a readable hispo-pl checkpoint (corrupt, truncated, unsafe, or
    written by something else)."""


class RunDirError(UserError, ValueError):
    """A run directory that cannot be used as asked: another stream or configuration, or held
    by another run."""


class LinkedFileError(UserError, ValueError):
    """A file to copy that is a symbolic link: a copy carries only the files of the folder it
    copies, never one a link points to elsewhere."""


class TrainingDivergedError(UserError, FloatingPointError):
    """A loss or a weight that stopped being finite; nothing non-finite is saved."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, with what was kept and how to go on as its message."""


class ResumableWork:
    """Marks the errors and interrupts raised inside it as leaving work that a rerun of the
    same command resumes (a stream's finished tasks, a benchmark's finished runs), so that the
    message for a full disk or a stop says so there, and only there.

    Example:
        >>> try:
        ...     with ResumableWork():
        ...         raise OSError(28, "No space left on device")
        ... except OSError as err:
        ...     resumable(err)
        True
    """

    def __enter__(self) -> ResumableWork:
        return self

    def __exit__(self, kind, err, traceback) -> None:
        if isinstance(err, OSError | KeyboardInterrupt):
            err.resumable = True


def resumable(err: BaseException) -> bool:
    """Whether ``err`` was raised inside :class:`ResumableWork`."""
    return getattr(err, "resumable", False) is True
