"""The fit API: ``hispo-pl fit``'s LightningCLI and the functions that run, or only check, a
fit from its arguments: one task (``trainer.fit``) or a stream (the
:class:`~hispo_pl.loop.ContinualLoop`, built in :mod:`hispo_pl.cli_stream`). The command line
(:mod:`hispo_pl.cli`) and the benchmark (:mod:`hispo_pl.benchmark`) both call it.
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import torch
from lightning.pytorch.cli import LightningCLI, SaveConfigCallback

from .cli_common import NUM_THREADS_FLAGS, flip_note, set_num_threads
from .cli_errors import (
    class_problem_line,
    dotted_flags,
    parse_error_line,
    unknown_flag,
    without_flag,
)
from .cli_stream import run_stream_from_cli
from .console import StopWhenAsked, print_stream_results, say
from .data.datamodule import TaskDataModule
from .errors import ConfigError, Interrupted, UserError
from .io import replace_link
from .methods import all_knobs
from .modules.hbc import GoalConditionedBC
from .presets import apply_preset, given_keys, kept_note
from .results import TaskFitResult
from .run_checks import apply_method_knobs, validate_config
from .rundir import RunDir
from .tasks import unseen_variant_tasks, unseen_variants_message


class SaveConfig(SaveConfigCallback):
    """Lightning's ``config.yaml`` beside a run's logs, with a link at its place replaced
    rather than written through (Lightning opens the name as it is)."""

    def setup(self, trainer, pl_module, stage: str) -> None:
        if trainer.log_dir is not None:
            replace_link(Path(trainer.log_dir) / self.config_filename)
        super().setup(trainer, pl_module, stage)


class HispoCLI(LightningCLI):
    """LightningCLI with task-derived model sizes and a printed result at the end of ``fit``."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_argument(
            *NUM_THREADS_FLAGS,
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
            "(docs/method.md lists both); the budget stays the stream config's, and a dotted "
            "flag given here wins over the preset",
        )
        for flag, knob in all_knobs().items():
            parser.add_argument(f"--{flag}", type=knob.kind | None, default=None, help=knob.help)
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

        self.command_line = list(args) if isinstance(args, list | tuple) else sys.argv[1:]
        try:
            super().parse_arguments(parser, args)
        except ArgumentError as err:
            message = str(err)
            known = self._known_flags(parser, args, message)
            raise ConfigError(parse_error_line(message, known)) from None

    def instantiate_classes(self) -> None:
        """LightningCLI's; a class of the configuration that cannot be made (a logger whose
        package is not installed, a Trainer on an accelerator this machine lacks) is one line
        naming it and the reason.

        Raises:
            ConfigError: the class and why it could not be made."""
        from lightning.fabric.utilities.exceptions import MisconfigurationException

        try:
            super().instantiate_classes()
        except MisconfigurationException as err:  # e.g. a GPU asked for where torch sees none
            raise ConfigError(f"the Trainer cannot be made as configured: {err}") from None
        except ValueError as err:
            config = self.config.get(self.subcommand, self.config) if self.subcommand else None
            plain = config.as_dict() if hasattr(config, "as_dict") else None
            line = class_problem_line(str(err), plain)
            if line is None:
                raise
            raise ConfigError(line) from None

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
        # a look at the keys, never an answer: without --print_config, and without the request
        # the failed parse left on the parser (jsonargparse would print the config and exit 0)
        rest = [a for a in without_flag(list(args), flag) if a.split("=")[0] != "--print_config"]
        vars(parser).pop("print_config", None)
        try:
            config = parser.parse_args(rest)
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
        if ckpt_path is None or _lightning_checkpoint_name(str(ckpt_path)):
            return
        if not Path(ckpt_path).is_file():
            raise ConfigError(
                f"--ckpt_path {str(ckpt_path)!r}: no such checkpoint file; give a run's "
                "task_XX.ckpt (or leave the flag out to train from scratch)"
            )
        from .modules.hbc import checkpoint_model_hparams, read_checkpoint

        # Lightning's own version hands the file's ``_class_path`` to the parser, which imports
        # it; here only the methods already imported can be named
        hparams = checkpoint_model_hparams(read_checkpoint(ckpt_path), ckpt_path)
        if hparams:
            update = {self.config.subcommand: {"model": hparams}}
            self.config = self.parser.parse_object(update, self.config)

    def before_instantiate_classes(self) -> None:
        config = self.config.get(self.subcommand, self.config)
        given = given_keys(getattr(self, "command_line", []))
        kept = apply_preset(config, config.get("preset"), given)
        if kept:
            print(kept_note(config["preset"], kept))
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
        if not datamodule.tasks:
            from .console import plain_summary, task_progress
            from .loop import fit_interruptibly

            bar = self.trainer.progress_bar_callback is not None
            callbacks = plain_summary(self.trainer.callbacks)
            label = datamodule.describe()
            progress = task_progress(callbacks, label, self.trainer.max_steps, bar)
            self.trainer.callbacks = [*progress, StopWhenAsked()]
            start = time.perf_counter()
            try:
                fit_interruptibly(self.trainer, model, datamodule, **kwargs)
            except KeyboardInterrupt:
                raise Interrupted(
                    "interrupted: a single-task fit does not resume; its TensorBoard logs so far "
                    "are kept (streams resume: rerun the same command)"
                ) from None
            self.fit_seconds = time.perf_counter() - start
            return
        self.stream_results = run_stream_from_cli(self, model, datamodule)

    def after_fit(self) -> None:
        if self.datamodule.tasks:
            print_stream_results(*self.stream_results)
            return
        record = self.model.task_record
        if record.evaluation is None:  # no RolloutEvaluation callback
            return
        last, task = record.evaluation, self.datamodule.task
        say(
            f"{type(self.model).__name__} on {self.datamodule.describe()}: success "
            f"{100 * last['success']:.1f}% over {record.episodes} episodes, mean episode "
            f"length {last['episode_length']:.1f}{flip_note(last['flip_rate'])}, after "
            f"{last['step']} steps ({self.fit_seconds:.0f} s with evaluations)"
        )
        if self.trainer.log_dir:
            used = self.datamodule.dataset_use
            write_task_result(self.trainer.log_dir, self.model, task, self.fit_seconds, used)
            say(f"TensorBoard logs: {self.trainer.log_dir}")


def _lightning_checkpoint_name(ckpt_path: str) -> bool:
    """Whether ``ckpt_path`` is one of Lightning's names for a checkpoint it finds itself
    (``last``, ``hpc``, ``best``, a model registry's), not a file path."""
    return ckpt_path in ("last", "hpc", "best") or ckpt_path.startswith("registry")


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
    task record), every evaluation before it (``curve``: step, success, episode length, with
    ``RolloutEvaluation(eval_every=N)``) and the dataset it trained on (``used``, a
    :class:`~hispo_pl.data.datasets.DatasetUse`), for tables
    (``benchmarks/single_task_table.py``) without parsing TensorBoard files."""
    record = model.task_record
    result = TaskFitResult(
        method=type(model).__name__,
        task=str(task),
        dataset=used.dataset if used else None,
        dataset_episodes=used.episodes if used else None,
        episodes=record.episodes,
        seconds=round(seconds, 1),
        **{k: float(v) for k, v in record.evaluation.items()},
        curve=[{k: float(v) for k, v in point.items()} for point in record.curve],
    )
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
    with warnings.catch_warnings():  # ``args``, not the process's command line, is the config
        warnings.filterwarnings("ignore", message=".*LightningCLI's args parameter.*")
        return HispoCLI(
            model_class=GoalConditionedBC,
            datamodule_class=TaskDataModule,
            subclass_mode_model=True,
            args=args,
            trainer_defaults={"accelerator": "cpu", "devices": 1},
            save_config_callback=SaveConfig,
            save_config_kwargs={"overwrite": True},
            parser_kwargs={"allow_abbrev": False},  # --trainer.max_step is a typo, not max_steps
            run=run,
        )


def run_fit(argv: list[str]) -> int:
    """``hispo-pl fit ARGS``: check the config files it names, then fit. Ctrl-C stops a
    single-task fit with a line that says what is kept, a stream with how to resume, and a
    fit that was not training (reading its configuration, printing its results) with both."""
    from .config_files import check_config_files

    check_config_files(argv)
    try:
        run_lightning_cli(argv)
    except KeyboardInterrupt as err:
        if isinstance(err, Interrupted):
            raise
        raise Interrupted(
            "interrupted outside training: what was saved is kept; rerun the same command (a "
            "stream resumes from its finished tasks, a single-task fit starts over)"
        ) from None
    return 0
