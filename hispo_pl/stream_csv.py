"""A stream's CSV logs with one meaning per ``step`` column.

A CSV file has one ``step`` column, while a stream logs at two clocks: its training curves at
the task's gradient steps (``task_02/train/loss``, ``task_02/eval/success``: every per-task
value carries its task's prefix) and its stream-level values at the number of tasks trained
(``stream/PER``, ``anchors/low/count``, ``search/low/l_prev``). :class:`StreamCSVLogger`
keeps the first in the run's ``metrics.csv`` and writes the second to ``stream/metrics.csv``
beside it, whose ``step`` counts the tasks trained.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from lightning.pytorch.loggers import CSVLogger
from typing_extensions import override

STREAM_FOLDER = "stream"
_PER_TASK = re.compile(r"^task_\d+/")


def at_gradient_steps(key: str) -> bool:
    """Whether a logged value is one of a task's curves, at its gradient steps: its key has
    the task's prefix (``task_02/...``), or it is Lightning's ``epoch`` beside them."""
    return bool(_PER_TASK.match(key)) or key == "epoch"


def split_by_clock(metrics: Mapping) -> tuple[dict, dict]:
    """``metrics`` as (the tasks' curves, the stream-level values)."""
    curves = {k: v for k, v in metrics.items() if at_gradient_steps(k)}
    return curves, {k: v for k, v in metrics.items() if k not in curves}


class StreamCSVLogger(CSVLogger):
    """Lightning's CSV logger for a stream: the tasks' curves in ``metrics.csv`` (step: the
    task's gradient step), the stream-level values in ``stream/metrics.csv`` (step: tasks
    trained). Made from the user's configured :class:`CSVLogger` by :meth:`like`."""

    @classmethod
    def like(cls, logger: CSVLogger) -> StreamCSVLogger:
        """The same logs (folder, name, version, prefix, flushing) as ``logger``."""
        return cls(
            save_dir=logger.save_dir,
            name=logger.name,
            version=logger.version,
            prefix=logger._prefix,
            flush_logs_every_n_steps=logger._flush_logs_every_n_steps,
        )

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._stream: CSVLogger | None = None

    @property
    def stream_logger(self) -> CSVLogger:
        """The logger of ``stream/metrics.csv``, made on first use."""
        if self._stream is None:
            self._stream = CSVLogger(save_dir=self.log_dir, name="", version=STREAM_FOLDER)
        return self._stream

    @override
    def log_metrics(self, metrics, step: int | None = None) -> None:
        curves, stream = split_by_clock(metrics)
        if curves:
            super().log_metrics(curves, step)
        if stream:
            self.stream_logger.log_metrics(stream, step)
            self.stream_logger.save()  # a few rows per task: written at once

    @override
    def save(self) -> None:
        super().save()
        if self._stream is not None:
            self._stream.save()
