"""``hispo-pl fit`` on a stream: the :class:`~hispo_pl.loop.ContinualLoop` built from
LightningCLI's parsed configuration, with its run directory, per-task Trainers and datamodules."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from .data.datamodule import TaskDataModule
from .errors import ConfigError, RunDirError
from .results import StreamResults, fwt_reference
from .run_checks import plain_config, run_fingerprint
from .run_files import read_results_file
from .rundir import RunDir, task_label
from .tasks import Task

if TYPE_CHECKING:
    from lightning.pytorch.cli import LightningCLI


def stream_run_dir(logger, root: str, stream, seed) -> Path:
    """Where a stream's files go: the logger's own directory when it has one (TensorBoard,
    CSV: ``runs/<name>/seed<S>``), else ``<root>/runs/<stream>/seed<S>`` (MLflow, W&B...)."""
    log_dir = getattr(logger, "log_dir", None) if logger is not None else None
    if log_dir:
        return Path(log_dir)
    name = stream if isinstance(stream, str) else "stream"
    number = seed if isinstance(seed, int) and not isinstance(seed, bool) else 0
    return Path(root) / "runs" / name / f"seed{number}"


def scratch_diagonal(path: Path, n_tasks: int) -> list[float]:
    """The R diagonal of a from-scratch run's ``results.json`` (FWT's reference), checked
    before anything trains: readable, and of a stream as long as this one.

    Raises:
        ConfigError: the file is missing or malformed, or its stream has another length."""
    if not path.is_file():
        raise ConfigError(f"--scratch_results {path}: no such file (a stream's results.json)")
    try:
        results = read_results_file(path)
    except RunDirError as err:
        raise ConfigError(f"--scratch_results: {err}") from None
    reference = fwt_reference(results, n_tasks)
    if reference is None:
        raise ConfigError(
            f"--scratch_results {path}: its stream has {len(results.R)} tasks, this one "
            f"{n_tasks}; give the results.json of a from-scratch run (scn) of the same stream"
        )
    return reference


def task_datamodules(
    datamodule: TaskDataModule, data_args: dict
) -> Callable[[Task], TaskDataModule]:
    """The loop's ``make_datamodule``: each task's datamodule with the stream's data settings
    and the stream's tasks as ``datamodule`` parsed them (no spec is parsed again)."""

    def make_datamodule(task: Task) -> TaskDataModule:
        return TaskDataModule(**{**data_args, "task": task, "stream": datamodule.tasks})

    return make_datamodule


class FinishedStream(NamedTuple):
    """A stream the fit ran to its end: its results and the directory that holds its files."""

    results: StreamResults
    run_dir: RunDir


def run_stream_from_cli(cli: LightningCLI, model, datamodule) -> FinishedStream:
    """Build the ContinualLoop from the parsed config (per-task datamodules share the data
    settings, per-task Trainers share the callbacks and the stream's logger) and run it."""
    from lightning.pytorch.callbacks import ModelCheckpoint, ModelSummary, ProgressBar
    from lightning.pytorch.cli import SaveConfigCallback

    from .loop import ContinualLoop
    from .metrics import module_bytes

    config = cli.config[cli.subcommand]
    data_args = dict(config["data"])
    # the method's callbacks, shared by every task's Trainer; each Trainer adds its own defaults
    defaults = (SaveConfigCallback, ModelCheckpoint, ModelSummary, ProgressBar)
    callbacks = [cb for cb in cli.trainer.callbacks if not isinstance(cb, defaults)]
    seed = config.get("seed_everything")  # the int LightningCLI seeded with, or False
    run_dir = stream_run_dir(
        cli.trainer.logger, cli.trainer.default_root_dir, config["data"]["stream"], seed
    )

    # a CSV file has one step column: the stream-level values get a file of their own
    from lightning.pytorch.loggers import CSVLogger

    from .stream_csv import StreamCSVLogger

    loggers = cli.trainer.loggers
    stream_loggers = [StreamCSVLogger.like(lg) if type(lg) is CSVLogger else lg for lg in loggers]
    logger_args = {} if stream_loggers == loggers else {"logger": stream_loggers}

    first_trainer = [True]

    def make_trainer(k: int):
        """Task ``k``'s Trainer: the model summary once per stream, progress as lines when the
        output is not a terminal, and Lightning's accelerator lines left to the command's
        first Trainer (they would repeat)."""
        from .console import StopWhenAsked, lightning_notices_held, plain_summary, task_progress

        extra: dict = {} if first_trainer[0] else {"enable_model_summary": False}
        first_trainer[0] = False
        max_steps = config["trainer"].get("max_steps") or 0
        label = f"task {task_label(k)}/{len(datamodule.tasks)}"
        bar = config["trainer"].get("enable_progress_bar") is not False
        task_callbacks = [*task_progress(callbacks, label, max_steps, bar), StopWhenAsked()]
        if not any(isinstance(cb, ProgressBar) for cb in task_callbacks):
            extra["enable_progress_bar"] = False  # lines, or no bar: not Lightning's either
        with lightning_notices_held():
            trainer = cli.instantiate_trainer(
                callbacks=task_callbacks,
                enable_checkpointing=False,
                default_root_dir=run_dir,
                **logger_args,
                **extra,
            )
        trainer.callbacks = plain_summary(trainer.callbacks)
        return trainer

    make_datamodule = task_datamodules(datamodule, data_args)
    reference = module_bytes(model.reference_model())  # MEM's unit: one single-task model
    scratch = None
    if config.get("scratch_results"):
        scratch = scratch_diagonal(Path(config["scratch_results"]), len(datamodule.tasks))
    import yaml

    plain = plain_config({k: v for k, v in config.as_dict().items() if k != "config"})
    loop = ContinualLoop(
        datamodule.tasks,
        model,
        make_datamodule,
        make_trainer,
        run_dir,
        reference,
        scratch,
        seed=seed if isinstance(seed, int) and not isinstance(seed, bool) else None,
        fingerprint=run_fingerprint(plain),
        config_text=yaml.safe_dump(plain, sort_keys=False),
        checkpoint_every=int(config.get("checkpoint_every") or 0),
    )
    results = loop.run()
    _save_config_if_no_task_trained(cli, RunDir(run_dir))
    return FinishedStream(results, RunDir(run_dir))


def _save_config_if_no_task_trained(cli: LightningCLI, run_dir: RunDir) -> None:
    """Lightning's ``config.yaml``, as a task's Trainer saves it, for a fit that trained no
    task: a stream whose every task was done before (a tolerance tree's branch copied whole)
    starts no Trainer, and its run files would lack the configuration."""
    if run_dir.config_file.exists():
        return
    from .io import replace_link

    replace_link(run_dir.config_file)
    subcommand = cli.subcommand
    cli._parser(subcommand).save(
        cli.config.get(str(subcommand), cli.config), str(run_dir.config_file), skip_none=False
    )
