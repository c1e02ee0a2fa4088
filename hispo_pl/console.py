"""What a stream prints: a header and a summary line per task, training progress as lines when
the output is not a terminal, Lightning's own notices once per stream rather than per task, and
the results and decisions at the stream's end."""

from __future__ import annotations

import contextlib
import logging
import shutil
import sys
import textwrap
import time
from collections.abc import Mapping, Sequence
from numbers import Number

import lightning as L
from lightning.pytorch.callbacks import ModelSummary, RichModelSummary, TQDMProgressBar
from tqdm.utils import disp_len

from .metrics import METRICS
from .progress import duration, interactive
from .results import Decision, StreamResults
from .rundir import RunDir, task_label
from .stopping import stop_requested

# Lightning's start-of-fit notices (accelerator lines, tips) go through these loggers
LIGHTNING_NOTICES = (
    "lightning.pytorch.utilities.rank_zero",
    "lightning.fabric.utilities.rank_zero",
    "lightning.fabric.utilities.seed",
)

TENSORBOARD_GLANCE = "http://localhost:6006/#custom_scalars&_smoothingWeight=0"
"""TensorBoard's Custom Scalars tab with smoothing off: a stream's values are a few points,
which TensorBoard's default smoothing would draw away from what was measured."""


PREFIX = "[hispo-pl] "


def say(message: str) -> None:
    """Print ``message`` after the command's prefix (:func:`terminal_line`)."""
    print(terminal_line(PREFIX + message), flush=True)


def terminal_line(line: str, width: int | None = None) -> str:
    """``line`` as printed: on a terminal (or with ``width``), wrapped between words to the
    terminal's width, its continuation lines indented under the text after the prefix; in a
    log or a pipe one line per message, whole, for grep."""
    if width is None:
        if not interactive():
            return line
        width = shutil.get_terminal_size().columns
    if len(line) <= width:
        return line
    indent = " " * len(PREFIX) if line.startswith(PREFIX) else ""
    return textwrap.fill(
        line,
        width=width,
        subsequent_indent=indent,
        break_long_words=False,  # a path or an address stays whole
        break_on_hyphens=False,
    )


@contextlib.contextmanager
def lightning_notices_once():
    """Within: :func:`quiet_lightning_notices` holds until the block ends (the levels are then
    restored, so a later stream in the same process shows them again)."""
    levels = {name: logging.getLogger(name).level for name in LIGHTNING_NOTICES}
    try:
        yield
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


@contextlib.contextmanager
def lightning_notices_held():
    """Within: Lightning's notices are held back, e.g. while a stream builds a task's Trainer
    (its accelerator lines, "GPU available: ...", repeat those of the command's first one)."""
    with lightning_notices_once():
        quiet_lightning_notices()
        yield


def quiet_lightning_notices() -> None:
    """After the first task: Lightning's notices have been shown once; keep its warnings."""
    for name in LIGHTNING_NOTICES:
        logging.getLogger(name).setLevel(logging.WARNING)


def decision_parts(decisions: Sequence[Decision]) -> list[str]:
    """``low prune (1.05 vs 1.10)`` for each kept or pruned subspace: the two sides its rule
    compared (:meth:`~hispo_pl.results.Decision.comparison`)."""
    parts = []
    for d in decisions:
        comparison = d.comparison() if d.decision in ("keep", "prune") else None
        if comparison is not None:
            parts.append(f"{d.subspace} {d.decision} ({comparison})")
    return parts


def task_header(k: int, n: int, task: str, steps: int) -> str:
    return f"task {task_label(k)}/{n}: {task}, {steps} steps"


def task_summary(
    k: int,
    n: int,
    seconds: float,
    row: list[float],
    decisions: Sequence[Decision],
    phases: dict[str, float] | None = None,
) -> str:
    """After task ``k``: time (and where it went), success on it and on the tasks before, each
    subspace's decision."""
    line = f"task {task_label(k)}/{n} done in {duration(seconds)}"
    if phases:
        line += " (" + ", ".join(f"{name} {duration(s)}" for name, s in phases.items()) + ")"
    line += f": success {100 * row[k]:.0f} %"
    if k:
        line += f" (earlier tasks: mean {100 * sum(row[:k]) / k:.0f} %)"
    parts = decision_parts([d for d in decisions if d.task == k])
    return line + ("; " + ", ".join(parts) if parts else "")


class StepLines(L.Callback):
    """Training progress as a line every ``every`` steps (for logs and pipes, where a progress
    bar would be one long line of carriage returns): step, share done, loss, steps/s. On
    stderr, with every other progress (:mod:`hispo_pl.progress`)."""

    def __init__(self, label: str, every: int):
        self.label, self.every = label, max(1, every)
        self._start = 0.0
        self._first = 0

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._start, self._first = time.perf_counter(), trainer.global_step

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        if step % self.every and step != trainer.max_steps:
            return
        rate = (step - self._first) / max(time.perf_counter() - self._start, 1e-9)
        loss = outputs["loss"] if isinstance(outputs, dict) else outputs
        loss_text = f", loss {float(loss):.4f}" if loss is not None else ""
        share = 100 * step / trainer.max_steps if trainer.max_steps > 0 else 0.0
        print(
            f"[hispo-pl] {self.label} step {step}/{trainer.max_steps} ({share:.0f} %){loss_text}, "
            f"{rate:.1f} steps/s",
            file=sys.stderr,
            flush=True,
        )


def step_lines(label: str, max_steps: int | None) -> StepLines | None:
    """Progress as lines, one every tenth of the steps, where the output is not a terminal
    (a log or a pipe) and the run has a step budget; else ``None`` (a bar can redraw)."""
    if not max_steps or max_steps <= 0 or interactive():
        return None
    return StepLines(label, every=max(1, max_steps // 10))


def short_metric_name(key: str) -> str:
    """The name a progress bar shows for a logged value: its last path part, less ``loss_``
    (``task_01/train/loss_high`` -> ``high``, ``task_01/train/loss`` -> ``loss``)."""
    name = key.rsplit("/", 1)[-1]
    return name.removeprefix("loss_") or name


def fit_postfix(values: Mapping[str, str], room: int | None) -> dict[str, str]:
    """The leading ``values`` whose ``, name=value`` parts fit in ``room`` characters (all of
    them when ``room`` is None: no width to fit); the others are left to the loggers."""
    if room is None:
        return dict(values)
    kept, used = {}, 0
    for name, value in values.items():
        used += len(f", {name}={value}")
        if used > room:
            break
        kept[name] = value
    return kept


MIN_BAR_CELLS = 10
"""The narrowest bar :class:`TaskProgressBar` leaves when it fits its values to a terminal
(the width tqdm draws a bar when it has no terminal width to fill)."""


def postfix_room(bar) -> int | None:
    """How many characters a tqdm ``bar`` can give its postfix and still draw
    :data:`MIN_BAR_CELLS` cells in its terminal's width, three kept back for the rate and
    times, which grow; None when the bar has no width to fit."""
    info = bar.format_dict  # a dynamic-width bar reads its terminal's width here
    ncols = info.get("ncols")
    if not ncols:
        return None
    bare = bar.format_meter(**{**info, "postfix": None, "ncols": None})  # a 10-cell bar
    return ncols - disp_len(bare) - 3


class TaskProgressBar(TQDMProgressBar):
    """One bar per task over its gradient steps (Lightning's own restarts at every epoch of
    ``steps_per_epoch`` batches), labelled with the task: ``task 2/4: 37%|███ | 2220/6000``.

    Its values fit the terminal: short names (:func:`short_metric_name`), and only as many
    as leave the bar :data:`MIN_BAR_CELLS` cells. The bar is closed at the task's last step,
    so its time and rate are those of training, not of the search and evaluation after it."""

    def __init__(self, label: str, refresh_rate: int = 10):
        super().__init__(refresh_rate=refresh_rate)
        self.label = label

    @property
    def train_description(self) -> str:
        return self.label

    def on_train_epoch_start(self, trainer: L.Trainer, *_) -> None:
        bar = self.train_progress_bar
        if bar.total != trainer.max_steps:  # the task's first epoch: one bar for every step
            bar.reset(total=trainer.max_steps)
            bar.n = trainer.global_step
            bar.set_description(self.label)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        bar, step = self.train_progress_bar, trainer.global_step
        if self._should_update(step, trainer.max_steps):
            bar.n = step
            self.show_metrics(trainer, pl_module)
        if 0 < trainer.max_steps <= step:  # training is over: the bar as it ends, kept
            bar.close()

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not self.train_progress_bar.disable:
            self.show_metrics(trainer, pl_module)

    def show_metrics(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Redraw the bar with the values that fit beside it."""
        bar = self.train_progress_bar
        values = {
            name: bar.format_num(v) if isinstance(v, Number) else str(v)
            for name, v in self.get_metrics(trainer, pl_module).items()
        }
        bar.set_postfix(fit_postfix(values, postfix_room(bar)))

    def get_metrics(self, trainer: L.Trainer, pl_module: L.LightningModule) -> dict:
        """The progress bar's values by short name, without Lightning's ``v_num`` (the
        logger's version, ``seed0`` cut to ``eed0``): the run directory is printed once, not
        on every bar."""
        metrics = super().get_metrics(trainer, pl_module)
        metrics.pop("v_num", None)
        short: dict = {}
        for key, value in metrics.items():
            short.setdefault(short_metric_name(key), value)
        return short


class ParameterSummary(ModelSummary):
    """Lightning's model summary in one line: the module's parameters and its top-level parts
    (``[hispo-pl] HiSPO: 145 K parameters (0.58 MB): policies 145 K, scores 2``). Lightning's
    table has a FLOPs column and total, counted over a forward pass of
    ``example_input_array``; a policy fed a batch of several tensors has none, so they read 0."""

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._max_depth and trainer.is_global_zero:
            say(parameter_line(type(pl_module).__name__, pl_module))


def parameter_line(name: str, module) -> str:
    """``HiSPO: 145 K parameters (0.58 MB): policies 145 K, scores 2``; the trainable ones
    are counted when some are not (``145 K parameters, 97 K trainable``)."""
    from lightning.pytorch.utilities.model_summary import summarize
    from lightning.pytorch.utilities.model_summary.model_summary import (
        get_human_readable_count as count,
    )

    summary = summarize(module, max_depth=1)
    total, trainable = summary.total_parameters, summary.trainable_parameters
    line = f"{name}: {count(total)} parameters"
    if trainable != total:
        line += f", {count(trainable)} trainable"
    line += f" ({summary.model_size:.2f} MB)"
    layers = zip(summary.layer_names, summary.param_nums, strict=True)
    parts = [f"{layer} {count(n)}" for layer, n in layers]
    return line + (": " + ", ".join(parts) if parts else "")


def plain_summary(callbacks: list) -> list:
    """``callbacks`` with Lightning's default model summary (a table with a FLOPs column that
    reads 0 here) replaced by :class:`ParameterSummary`; a summary of the user's own class
    stays."""
    return [
        ParameterSummary() if type(cb) in (ModelSummary, RichModelSummary) else cb
        for cb in callbacks
    ]


class StopWhenAsked(L.Callback):
    """Raise ``KeyboardInterrupt`` at the next training step, or at the task's end, when a
    signal asked the command to stop and a finaliser swallowed the interrupt it raised."""

    def _check(self) -> None:
        if stop_requested():
            raise KeyboardInterrupt

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self._check()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        self._check()

    def on_train_end(self, trainer, pl_module) -> None:
        self._check()


def task_progress(callbacks: list, label: str, max_steps: int | None, bar: bool) -> list:
    """``callbacks`` with a task's training progress as the policy wants it: lines in a log or
    a pipe (:func:`step_lines`), else one bar over the task's steps (:class:`TaskProgressBar`)
    in place of Lightning's per-epoch one; ``bar=False`` (the user turned the bar off): no
    bar. A progress bar of the user's own class stays."""
    from lightning.pytorch.callbacks import RichProgressBar

    kept = [cb for cb in callbacks if type(cb) not in (TQDMProgressBar, RichProgressBar)]
    lines = step_lines(label, max_steps)
    if lines is not None:
        return [*kept, lines]
    if bar and max_steps and max_steps > 0:
        return [*kept, TaskProgressBar(label)]
    return kept


def decision_lines(decisions: Sequence[Decision]) -> list[str]:
    """One line per task after the first: each subspace's keep / prune decision and the two
    sides its rule compared."""
    lines = []
    for t in sorted({d.task for d in decisions}):
        parts = decision_parts([d for d in decisions if d.task == t])
        if parts:
            lines.append(f"task {task_label(t)}: " + ", ".join(parts))
    return lines


def decision_legend(decisions: Sequence[Decision]) -> str:
    """How to read the compared sides of :func:`decision_lines`, for each rule that compared."""
    return "; ".join(dict.fromkeys(d.LEGEND for d in decisions if d.comparison()))


def metrics_line(results: StreamResults) -> str:
    """``PER 81.0  BWT -2.1  MEM 1.93 models``: every metric the stream has."""
    parts = [
        f"{m.name} {m.format(results.metrics[m.name])}" + ("" if m.percent else " models")
        for m in METRICS
        if m.name in results.metrics
    ]
    return "  ".join(parts)


def stream_line(specs: Sequence[str], datasets: Sequence[dict | None] | None) -> str:
    """``pointmaze-umaze-N[500] -> pointmaze-umaze-PA[500]``: the stream's tasks by spec, but
    a task that read a named Minari dataset by its maze and variant and that dataset with the
    episodes it holds (the spec's ``[episodes]`` counted nothing), said once when every task
    read the same: ``pointmaze-umaze-N -> pointmaze-umaze-PO, from umaze-v1 (5 episodes)``."""
    from .data.datasets import DatasetUse, dataset_id_of
    from .tasks import parse_task

    names, sources = [], []
    for k, spec in enumerate(specs):
        used = datasets[k] if datasets and k < len(datasets) else None
        task = parse_task(spec)
        if not used or used.get("dataset") == dataset_id_of(task):  # our data: the spec says it
            names.append(spec)
            sources.append(None)
        else:
            names.append(f"{task.family}-{task.maze}-{task.variant}")
            sources.append(str(DatasetUse(used["dataset"], used["episodes"])))
    if sources and sources[0] is not None and len(set(sources)) == 1:
        return " -> ".join(names) + f", from {sources[0]}"
    named = zip(names, sources, strict=True)
    return " -> ".join(name if src is None else f"{name} from {src}" for name, src in named)


def print_stream_results(results: StreamResults, run_dir: RunDir) -> None:
    """A finished stream: its tasks, R, metrics, anchors, decisions and where its files are."""
    say(f"stream {stream_line(results.stream, results.datasets)}")
    print(results.table)
    say(metrics_line(results))
    if results.anchors:
        say(f"anchors per subspace: {results.anchors}")
    decisions = run_dir.decisions()
    legend = decision_legend(decisions)
    for line in decision_lines(decisions):
        say(f"{line}  ({legend})")
    say(f"wall time per task (s): {[round(t) for t in results.wall_time_s or []]}")
    say(f"results: {run_dir.results_file}")
    if any(run_dir.path.glob("events.out.tfevents.*")):
        say(f"curves and decisions: tensorboard --logdir {run_dir}")
        say(f"the stream at a glance, unsmoothed: {TENSORBOARD_GLANCE}")
