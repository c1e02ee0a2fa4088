"""What a stream prints: a header and a summary line per task, training progress as lines when
the output is not a terminal, Lightning's own notices once per stream rather than per task, and
the results and decisions at the stream's end."""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import lightning as L
from lightning.pytorch.callbacks import TQDMProgressBar

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


def say(message: str) -> None:
    print(f"[hispo-pl] {message}", flush=True)


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


class TaskProgressBar(TQDMProgressBar):
    """One bar per task over its gradient steps (Lightning's own restarts at every epoch of
    ``steps_per_epoch`` batches), labelled with the task: ``task 2/4: 37%|███ | 2220/6000``."""

    def __init__(self, label: str, refresh_rate: int = 10):
        super().__init__(refresh_rate=refresh_rate)
        self.label = label

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
            bar.refresh()
            bar.set_postfix(self.get_metrics(trainer, pl_module))

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.train_progress_bar.set_postfix(self.get_metrics(trainer, pl_module))

    def get_metrics(self, trainer: L.Trainer, pl_module: L.LightningModule) -> dict:
        """The progress bar's values without Lightning's ``v_num`` (the logger's version,
        ``seed0`` cut to ``eed0``): the run directory is printed once, not on every bar."""
        metrics = super().get_metrics(trainer, pl_module)
        metrics.pop("v_num", None)
        return metrics


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


def print_stream_results(results: dict) -> None:
    typed = StreamResults.from_json(results)
    print(f"[hispo-pl] stream {' -> '.join(typed.stream)}")
    print(typed.table)
    print("[hispo-pl] " + metrics_line(typed))
    if typed.anchors:
        print(f"[hispo-pl] anchors per subspace: {typed.anchors}")
    run_dir = RunDir(results["run_dir"])
    decisions = run_dir.decisions()
    legend = decision_legend(decisions)
    for line in decision_lines(decisions):
        print(f"[hispo-pl] {line}  ({legend})")
    print(f"[hispo-pl] wall time per task (s): {[round(t) for t in typed.wall_time_s or []]}")
    print(f"[hispo-pl] results: {run_dir.results_file}")
    if any(Path(results["run_dir"]).glob("events.out.tfevents.*")):
        print(f"[hispo-pl] curves and decisions: tensorboard --logdir {results['run_dir']}")
        print(f"[hispo-pl] the stream at a glance, unsmoothed: {TENSORBOARD_GLANCE}")
