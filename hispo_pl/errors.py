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
