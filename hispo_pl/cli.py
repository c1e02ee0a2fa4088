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

``fit`` lives here (a stream's loop is built in :mod:`hispo_pl.cli_stream`); ``data``,
``evaluate`` and ``render`` in :mod:`hispo_pl.commands`.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
import time
import warnings
from pathlib import Path

import torch
from lightning.pytorch.cli import LightningCLI

from .cli_errors import dotted_flags, parse_error_line, unknown_flag, without_flag
from .cli_stream import run_stream_from_cli
from .commands import data_main, evaluate_main, flip_note, render_main, set_num_threads
from .console import print_stream_results
from .data.datamodule import TaskDataModule
from .errors import ConfigError, Interrupted, UserError
from .modules.hbc import GoalConditionedBC
from .presets import apply_preset
from .run_checks import METHOD_KNOBS, apply_method_knobs, validate_config
from .rundir import RunDir
from .tasks import unseen_variant_tasks, unseen_variants_message


class HispoCLI(LightningCLI):
    """LightningCLI with task-derived model sizes and a printed result at the end of ``fit``."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_argument(
            "--num_threads",
            type=int,
            default=0,
            help="torch.set_num_threads (0: torch default); see docs/performance.md.",
        )
        parser.add_argument(
            "--scratch_results",
            type=str | None,
            default=None,
            help="streams: results.json of a from-scratch run (SC1/SCN) of the same stream; its "
            "diagonal is R_scratch for FWT",
        )
        parser.add_argument(
            "--checkpoint_every",
            type=int,
            default=1000,
            help="streams: save the task in progress every N steps (task_XX.partial.ckpt); a "
            "rerun resumes it from there (0: only finished tasks are kept)",
        )
        parser.add_argument(
            "--preset",
            type=str | None,
            default=None,
            help="paper: the paper's hyperparameters, inputs and HiSPO rules over the configs' "
            "(docs/method.md lists both); the budget stays the stream config's",
        )
        for flag, (text, _) in METHOD_KNOBS.items():
            kind = float if flag.startswith("eps") else int
            parser.add_argument(f"--{flag}", type=kind | None, default=None, help=text)
        for dim in ("obs_dim", "action_dim", "goal_dim"):
            parser.link_arguments(f"data.{dim}", f"model.init_args.{dim}", apply_on="instantiate")
        for name in ("binary_actions", "low_obs", "low_velocity", "high_obs"):  # data's choice
            target = f"model.init_args.backbone.{name}"
            parser.link_arguments(f"data.{name}", target, apply_on="instantiate")

    def init_parser(self, **kwargs):
        """Parsers that raise their errors, for :meth:`parse_arguments` to say in one line."""
        return super().init_parser(**{**kwargs, "exit_on_error": False})

    def parse_arguments(self, parser, args) -> None:
        """LightningCLI's parsing; an error is one line (an unknown flag with the closest
        known one) rather than the usage of every flag.

        Raises:
            ConfigError: what did not parse."""
        from argparse import ArgumentError

        try:
            super().parse_arguments(parser, args)
        except ArgumentError as err:
            message = str(err)
            known = self._known_flags(parser, args, message)
            raise ConfigError(parse_error_line(message, known)) from None

    def _known_flags(self, parser, args, message: str) -> list[str]:
        """The flags ``hispo-pl fit`` takes, for the closest match to an unknown one: the
        parser's own, and every key of the configuration parsed without the unknown flag
        (the method's and the callbacks' arguments included)."""
        from argparse import ArgumentError

        fit = getattr(self, "_subcommand_parsers", {}).get("fit", parser)
        known = [s for a in fit._actions for s in a.option_strings if s.startswith("--")]
        flag = unknown_flag(message)
        if flag is None or args is None:
            return known
        try:
            config = parser.parse_args(without_flag(list(args), flag))
        except ArgumentError:
            return known
        return known + dotted_flags(config.get("fit", config).as_dict())

    def _parse_ckpt_path(self) -> None:
        """Take the model's hyperparameters from ``--ckpt_path`` as LightningCLI does, but
        safely: a stream refuses the flag, an unreadable file is a user error rather than a
        traceback, and a class the file names is never imported."""
        if not self.config.get("subcommand"):
            return
        config = self.config[self.config.subcommand]
        ckpt_path = config.get("ckpt_path")
        if ckpt_path and (config.get("data") or {}).get("stream"):
            validate_config(config.as_dict())  # says how a stream resumes
        if not (ckpt_path and Path(ckpt_path).is_file()):
            return
        from .modules.hbc import checkpoint_model_hparams, read_checkpoint

        # Lightning's own version hands the file's ``_class_path`` to the parser, which imports
        # it; here only the methods already imported can be named
        hparams = checkpoint_model_hparams(read_checkpoint(ckpt_path), ckpt_path)
        if hparams:
            update = {self.config.subcommand: {"model": hparams}}
            self.config = self.parser.parse_object(update, self.config)

    def before_instantiate_classes(self) -> None:
        config = self.config.get(self.subcommand, self.config)
        apply_preset(config, config.get("preset"))
        apply_method_knobs(config)
        validate_config(config.as_dict())
        set_num_threads(config.get("num_threads", 0))
        logger = config.get("trainer", {}).get("logger")
        # a stream's run directory must be the same on a rerun, so that it resumes
        is_stream = bool(config.get("data", {}).get("stream"))
        if is_stream and logger and logger.get("init_args", {}).get("version", "") is None:
            logger["init_args"]["version"] = f"seed{config.get('seed_everything') or 0}"

    def fit(self, model, datamodule, **kwargs) -> None:
        """One task: ``trainer.fit``. A stream: the ContinualLoop, a fresh Trainer per task."""
        refuse_unseen_variants(model, datamodule)
        if datamodule.stream is None:
            from .console import task_progress
            from .loop import fit_interruptibly

            bar = self.trainer.progress_bar_callback is not None
            callbacks = self.trainer.callbacks
            label = datamodule.describe()
            self.trainer.callbacks = task_progress(callbacks, label, self.trainer.max_steps, bar)
            start = time.perf_counter()
            fit_interruptibly(self.trainer, model, datamodule, **kwargs)
            self.fit_seconds = time.perf_counter() - start
            return
        self.stream_results = run_stream_from_cli(self, model, datamodule)

    def after_fit(self) -> None:
        if self.datamodule.stream is not None:
            print_stream_results(self.stream_results)
            return
        record = self.model.task_record
        if record.evaluation is None:  # no RolloutEvaluation callback
            return
        last, task = record.evaluation, self.datamodule.task
        print(
            f"[hispo-pl] {type(self.model).__name__} on {self.datamodule.describe()}: success "
            f"{100 * last['success']:.1f}% over {record.episodes} episodes, mean episode "
            f"length {last['episode_length']:.1f}{flip_note(last['flip_rate'])}, after "
            f"{last['step']} steps ({self.fit_seconds:.0f} s with evaluations)"
        )
        if self.trainer.log_dir:
            used = self.datamodule.dataset_use
            write_task_result(self.trainer.log_dir, self.model, task, self.fit_seconds, used)
            print(f"[hispo-pl] TensorBoard logs: {self.trainer.log_dir}")


def refuse_unseen_variants(model, datamodule: TaskDataModule) -> None:
    """Refuse a run whose observation-variant tasks no policy of the model would tell from
    their N task (the datamodule refuses inputs that no level reads; here the flat policy,
    which reads only the high policy's inputs)."""
    tasks = datamodule.tasks or [datamodule.task]
    unseen = unseen_variant_tasks(tasks, model.backbone_config.reads_observation)
    if unseen:
        inputs = f"with {datamodule.inputs_summary} and a flat policy (it reads the high inputs),"
        raise ConfigError(unseen_variants_message(unseen, inputs))


def write_task_result(log_dir: str, model, task, seconds: float, used=None) -> None:
    """``result.json`` beside a single-task run's logs: its final evaluation (the module's
    task record) and the dataset it trained on (``used``, a
    :class:`~hispo_pl.data.datasets.DatasetUse`), for tables
    (``benchmarks/single_task_table.py``) without parsing TensorBoard files."""
    record = model.task_record
    result = {
        "method": type(model).__name__,
        "task": str(task),
        **({"dataset": used.dataset, "dataset_episodes": used.episodes} if used else {}),
        "episodes": record.episodes,
        "seconds": round(seconds, 1),
        **{k: float(v) for k, v in record.evaluation.items()},
    }
    RunDir(log_dir).write_result(result)


def check_fit_args(argv: list[str]) -> str | None:
    """Whether ``hispo-pl fit`` would accept ``argv`` (``["fit", "--config", ...]``): the
    configuration is parsed, checked (:func:`validate_config`) and its classes instantiated,
    without training or touching data. Returns the error message, or None."""
    import contextlib
    import io

    from .console import lightning_notices_once, quiet_lightning_notices

    args = argv[1:] if argv and argv[0] == "fit" else list(argv)
    errors = io.StringIO()
    threads = torch.get_num_threads()
    try:
        with (
            contextlib.redirect_stderr(errors),
            contextlib.redirect_stdout(io.StringIO()),
            lightning_notices_once(),  # its seed and accelerator lines are not a run's
        ):
            quiet_lightning_notices()
            run_lightning_cli(args, run=False)
    except SystemExit as exit:
        if exit.code:
            lines = [ln for ln in errors.getvalue().splitlines() if ln.strip()]
            return lines[-1] if lines else f"exit {exit.code}"
    except UserError as err:
        return str(err)
    finally:
        torch.set_num_threads(threads)
    return None


def run_lightning_cli(args: list[str] | None = None, run: bool = True) -> HispoCLI:
    """``hispo-pl fit``'s LightningCLI; ``run=False`` parses, checks and instantiates only."""
    return HispoCLI(
        model_class=GoalConditionedBC,
        datamodule_class=TaskDataModule,
        subclass_mode_model=True,
        args=args,
        trainer_defaults={"accelerator": "cpu", "devices": 1},
        save_config_kwargs={"overwrite": True},
        parser_kwargs={"allow_abbrev": False},  # --trainer.max_step is a typo, not max_steps
        run=run,
    )


def _quiet_known_warnings() -> None:
    """Silence, once for the command, third-party notices that say nothing about the user's
    run: warnings about data loading that hispo-pl's sampler makes irrelevant, and Lightning's
    advertising tips (litlogger, litmodels), which it logs rather than warns. (The Adroit
    hands' notice of gymnasium-robotics is dropped where it is imported, hispo_pl.envs.)"""
    import logging

    for pattern in (
        r".*IterableDataset.*has `__len__` defined.*",
        r".*does not have many workers.*",
        r".*treespec.*LeafSpec.*",
        r".*litlogger.*",
        r".*LightningCLI's args parameter.*",
    ):
        warnings.filterwarnings("ignore", message=pattern)
    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, _NoTips) for f in logger.filters):
            logger.addFilter(_NoTips())


class _NoTips:
    """A logging filter that drops Lightning's ``💡 Tip:`` lines."""

    def filter(self, record) -> bool:
        return not str(record.msg).lstrip().startswith("💡 Tip")


def main(argv: list[str] | None = None) -> int:
    """The ``hispo-pl`` command. A user error (a bad value, spec, file or run directory) prints
    one paragraph and returns its exit code (2); anything else is a bug and keeps its
    traceback. After Ctrl-C (130) or SIGTERM (143) it says how to resume."""
    argv = sys.argv[1:] if argv is None else argv
    _quiet_known_warnings()
    prog = "hispo-pl" + (f" {argv[0]}" if argv and argv[0] in SUBCOMMANDS else "")
    received: list[int] = []  # the signal that stopped the command, if one did
    try:
        with terminate_as_interrupt() as received:
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
        said = machine_error(err, resumable=not argv or argv[0] in ("fit", "benchmark"))
        if said is None:
            raise
        print(f"{prog}: error: {said}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:
        hint = str(err) if isinstance(err, Interrupted) else "interrupted"
        print(f"\n{prog}: {hint}", file=sys.stderr)
        return 128 + (received[0] if received else signal.SIGINT)


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


@contextlib.contextmanager
def terminate_as_interrupt():
    """SIGTERM (``kill``, a scheduler's stop, the benchmark stopping its runs) ends a command
    the way Ctrl-C does: a stream keeps what it finished and says how to resume, a benchmark
    stops its runs. Lightning alone only notes a SIGTERM that arrives during a training step,
    and a stream's next task forgets it. Yields the list the signal's number is put in."""
    received: list[int] = []

    def interrupt(signum, frame):
        received.append(signum)
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread: leave signals alone
        yield received
        return
    try:
        yield received
    finally:
        signal.signal(signal.SIGTERM, previous)


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
    if argv[0] == "data":
        return data_main(argv[1:])
    if argv[0] == "evaluate":
        return evaluate_main(argv[1:])
    if argv[0] == "render":
        return render_main(argv[1:])
    if argv[0] == "config":
        from .config_files import config_main

        return config_main(argv[1:])
    if argv[0] == "benchmark":
        from .benchmark import main as benchmark_main

        return benchmark_main(argv[1:])
    if argv[0] != "fit" and not argv[0].startswith("-"):
        raise UserError(f"unknown verb {argv[0]!r}; the verbs are {', '.join(VERBS)}")
    from .config_files import check_config_files

    check_config_files(argv)
    try:
        run_lightning_cli(argv)
    except KeyboardInterrupt as err:
        if isinstance(err, Interrupted):
            raise
        raise Interrupted(
            "interrupted: a single-task fit does not resume; its TensorBoard logs so far are "
            "kept (streams resume: rerun the same command)"
        ) from None
    return 0


if __name__ == "__main__":
    sys.exit(main())
