"""The ``hispo-pl`` command.

- ``hispo-pl fit --config configs/hbc/pointmaze-umaze.yaml``: LightningCLI (fit / validate /
  ``--print_config`` / dotted overrides such as ``--trainer.max_steps 2000``).
- ``hispo-pl data generate pointmaze-umaze``: make a local expert dataset.
- ``hispo-pl data list``: the datasets stored locally.
- ``hispo-pl evaluate --ckpt RUN/task_04.ckpt --task pointmaze-medium-IO [--json]``: roll out
  any checkpoint on any task.
- ``hispo-pl render amazeville simpletown --out mazes.png [--dataset | --ckpt RUN/task_04.ckpt]``:
  mazes from above with a dataset's or a policy's trajectories (``hispo_pl.render``).
- ``hispo-pl benchmark --stream pointmaze-1 --methods all --seeds 3 --out results/pm1``: every
  method × seed as ``fit`` subprocesses, then the tables (``hispo_pl.benchmark``).

The verbs, their help and the errors of the whole command live here; ``fit`` runs through the
fit API (:mod:`hispo_pl.fit`, a stream's loop in :mod:`hispo_pl.cli_stream`), ``data``,
``evaluate`` and ``render`` in :mod:`hispo_pl.cli_verbs`, ``benchmark`` in
:mod:`hispo_pl.benchmark`. Each verb's module is imported when the verb runs, so help answers
without loading Lightning.
"""

from __future__ import annotations

import os
import sys


def _working_folder_first() -> bool:
    """Whether ``python -m`` put the working folder first on the import path (not under -P)."""
    if getattr(sys.flags, "safe_path", False) or not sys.path:
        return False
    return os.path.realpath(sys.path[0] or os.curdir) == os.getcwd()


if __name__ == "__main__" and _working_folder_first():
    # ``python -m hispo_pl.cli`` (how the benchmark starts every fit) puts the working folder
    # first on the import path. It is no place to import code from unless the user says so
    # (PYTHONPATH=., docs/extending.md): drop that entry before anything else is imported, so
    # a config's class_path naming a module there is refused, never run.
    del sys.path[0]

import errno  # noqa: E402
import warnings  # noqa: E402

from .errors import UserError, resumable  # noqa: E402
from .stopping import signals_stop_the_command, stop_exit_code  # noqa: E402


def _quiet_known_warnings() -> None:
    """Silence, once for the command, third-party notices that say nothing about the user's
    run: warnings about data loading that hispo-pl's sampler makes irrelevant, and what
    Lightning logs rather than warns: its advertising tips (litlogger, litmodels) and its
    "`Trainer.fit` stopped: `max_steps=N` reached" (the budget the task's header gave). (The
    Adroit hands' notice of gymnasium-robotics is dropped where it is imported,
    hispo_pl.envs.)"""
    import logging

    for pattern in (
        r".*IterableDataset.*has `__len__` defined.*",
        r".*does not have many workers.*",
        r".*treespec.*LeafSpec.*",
        r".*litlogger.*",
    ):
        warnings.filterwarnings("ignore", message=pattern)
    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, _NoTips) for f in logger.filters):
            logger.addFilter(_NoTips())


class _NoTips:
    """A logging filter that drops Lightning's ``💡 Tip:`` lines and its notice that a fit
    stopped at its step or epoch budget."""

    SAID_NOTHING = (
        "💡 Tip",
        "`Trainer.fit` stopped: `max_steps=",
        "`Trainer.fit` stopped: `max_epochs=",
    )

    def filter(self, record) -> bool:
        return not str(record.msg).lstrip().startswith(self.SAID_NOTHING)


def main(argv: list[str] | None = None) -> int:
    """The ``hispo-pl`` command. A user error (a bad value, spec, file or run directory) prints
    one paragraph and returns its exit code (2); anything else is a bug and keeps its
    traceback. After Ctrl-C (130) or SIGTERM (143) it says how to resume."""
    argv = sys.argv[1:] if argv is None else argv
    _quiet_known_warnings()
    prog = "hispo-pl" + (f" {argv[0]}" if argv and argv[0] in SUBCOMMANDS else "")
    received: list[int] = []  # the signal that stopped the command, if one did
    try:
        with signals_stop_the_command() as received:
            code = _dispatch(argv)
            sys.stdout.flush()  # a pipe closed early shows here, not as an error at exit
            return code
    except UserError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return err.exit_code
    except BrokenPipeError:  # the output went into a pipe that closed early (| head)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
        return 1
    except OSError as err:
        said = machine_error(err, resumable=resumable(err) or _launches_runs(argv))
        if said is None:
            raise
        print(f"{prog}: error: {said}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Exception) as err:
        stopped = stop_exit_code(prog, err, received)
        if stopped is None:  # not a stop: a bug, with its traceback
            raise
        return stopped


_MACHINE_ERRORS = {
    errno.ENOSPC: "no space is left on the device that holds it; free some (or write "
    "elsewhere) and rerun",
    errno.EDQUOT: "the disk quota is used up; free some space (or write elsewhere) and rerun",
    errno.EROFS: "it is on a read-only file system; give a writable directory",
    errno.EACCES: "permission denied; give a directory you can write (or fix its permissions)",
    errno.EPERM: "the operation is not permitted there; give a directory you own",
    errno.ENAMETOOLONG: "the name is too long for the file system; choose a shorter one",
    errno.EISDIR: "it is a directory where a file was expected; name a file",
    errno.ENOTDIR: "a part of the path is a file where a directory was expected",
    errno.EEXIST: "a file is in the way where a directory is needed",
}


def _launches_runs(argv: list[str]) -> bool:
    """Whether ``argv`` is a benchmark that launches runs, which a rerun resumes (not one
    that only reports or checks)."""
    return argv[:1] == ["benchmark"] and not {"--report-only", "--dry-run"} & set(argv)


def machine_error(err: OSError, resumable: bool = False) -> str | None:
    """One paragraph for an error of the machine rather than of hispo-pl (disk full,
    read-only, permission, a name too long), naming the path; None for anything else.
    ``resumable``: the command keeps what it finished (checkpoints and run files are written
    atomically), and the paragraph says so."""
    hint = _MACHINE_ERRORS.get(err.errno)
    if hint is None:
        return None
    where = f" {err.filename}" if err.filename else ""
    kept = " Finished work is kept: rerun the same command to resume." if resumable else ""
    return f"cannot use{where}: {hint} ({err.strerror}).{kept}"


VERBS: dict[str, str] = {
    "fit": "train one task or a stream of tasks from YAML configs (LightningCLI: --help, "
    "--print_config, dotted overrides)",
    "evaluate": "roll out a checkpoint's policy on any task and print its success",
    "data": "generate and list the local expert datasets (Minari)",
    "render": "draw mazes from above with a dataset's or a policy's trajectories",
    "benchmark": "run methods x seeds of a stream, then build the result tables",
    "config": "list, show or copy the shipped configs (streams, methods, single-task)",
}
SUBCOMMANDS = tuple(v for v in VERBS if v != "fit")
# Lightning's other entry points, and what they mean here
NOT_HERE = {
    "validate": "hispo-pl scores policies by rollouts: hispo-pl evaluate --ckpt RUN/task_XX.ckpt "
    "--task SPEC",
    "test": "hispo-pl scores policies by rollouts: hispo-pl evaluate --ckpt RUN/task_XX.ckpt "
    "--task SPEC",
    "predict": "a policy acts in an environment: hispo-pl evaluate or hispo-pl render --ckpt",
}


def usage() -> str:
    """``hispo-pl --help``: every verb with one line, and where to start."""
    width = max(map(len, VERBS))
    lines = [
        "usage: hispo-pl VERB [options]   (hispo-pl VERB --help for its options)",
        "",
        "Continual offline RL with hierarchical subspaces of policies (HiSPO).",
        "",
        "verbs:",
        *(f"  {verb:<{width}}  {text}" for verb, text in VERBS.items()),
        "",
        "start with:",
        "  hispo-pl config copy configs   (outside a checkout: the shipped configs, here)",
        "  hispo-pl fit --config configs/demo.yaml --config configs/methods/hispo.yaml",
        "  hispo-pl config list",
    ]
    return "\n".join(lines)


def _dispatch(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    if argv[0] in NOT_HERE:
        raise UserError(f"no {argv[0]!r} verb here; {NOT_HERE[argv[0]]}")
    if argv[0] in ("data", "evaluate", "render"):
        from .cli_verbs import data_main, evaluate_main, render_main

        verb_main = {"data": data_main, "evaluate": evaluate_main, "render": render_main}
        return verb_main[argv[0]](argv[1:])
    if argv[0] == "config":
        from .config_files import config_main

        return config_main(argv[1:])
    if argv[0] == "benchmark":
        from .benchmark import main as benchmark_main

        return benchmark_main(argv[1:])
    if argv[0] != "fit" and not argv[0].startswith("-"):
        raise UserError(f"unknown verb {argv[0]!r}; the verbs are {', '.join(VERBS)}")
    from .fit import run_fit

    return run_fit(argv)


if __name__ == "__main__":
    sys.exit(main())
