"""A stream's run files as types: :class:`StreamResults` (``results.json``, a finished
stream) and :class:`Progress` (``progress.json``, the tasks finished so far). No torch here."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..metrics import METRICS, mean_std
from .json_fields import json_fields, split_known

RESULTS_FORMAT = 1
"""The format number of ``results.json`` (:data:`~hispo_pl.results.json_fields.FORMAT_KEY`)."""

RESULTS_KEYS = (
    "stream",
    "R",
    "wall_time_s",
    "phase_time_s",
    "datasets",
    "stored_bytes",
    "mem_per_task",
    "table",
)
"""The keys every ``results.json`` holds (null where not measured), besides its format number;
the metrics hold what the run measured, ``anchors`` and ``alphas`` a run with subspaces."""


@dataclass(kw_only=True)
class StreamResults:
    """A finished stream (``results.json``): its tasks, the success matrix ``R`` (fractions;
    None above the diagonal), wall and phase times per task, the datasets it read, the metrics
    of :data:`~hispo_pl.metrics.METRICS` it has, the stored bytes, MEM after each task, anchors
    and anchor weights per subspace (methods with subspaces only), and ``R`` as printed. The
    file holds every key of :data:`RESULTS_KEYS`, null where the value was not measured."""

    stream: list[str]
    R: list[list[float | None]]
    wall_time_s: list[float] | None = None
    phase_time_s: list[dict[str, float] | None] | None = None
    datasets: list[Any] | None = None
    metrics: dict[str, float] = field(default_factory=dict)
    stored_bytes: int | None = None
    anchors: dict[str, int] | None = None
    alphas: dict[str, list[list[float]]] | None = None
    table: str = ""
    mem_per_task: list[float | None] | None = None  # MEM after each task (None: not measured)
    extra: dict = field(default_factory=dict)

    @property
    def matrix(self) -> np.ndarray:
        """``R`` as a float array, NaN where the file has null."""
        return np.array([[np.nan if v is None else v for v in row] for row in self.R], dtype=float)

    def diagonal(self) -> list[float]:
        """Each task's success right after it was trained: FWT's reference when this is a
        from-scratch run."""
        return [float(self.R[k][k]) for k in range(len(self.R))]

    def to_json(self) -> dict:
        """The file's keys in its order: the metrics of the success matrix, then the stored
        bytes and the metrics measured on the model (MEM)."""
        out: dict = {"stream": self.stream, "R": self.R}
        for name in ("wall_time_s", "phase_time_s", "datasets"):
            out[name] = getattr(self, name)
        for of_model in (False, True):
            if of_model:
                out["stored_bytes"] = self.stored_bytes
            out |= {
                m.name: self.metrics[m.name]
                for m in METRICS
                if m.of_model == of_model and m.name in self.metrics
            }
        out["mem_per_task"] = self.mem_per_task
        for name in ("anchors", "alphas"):  # a run with subspaces
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return {**out, "table": self.table, **self.extra}

    @classmethod
    def from_json(cls, record: dict) -> StreamResults:
        names = {m.name for m in METRICS}
        metrics = {k: v for k, v in record.items() if k in names}
        known, extra = split_known(cls, {k: v for k, v in record.items() if k not in names})
        return cls(**known, metrics=metrics, extra=extra)


def summarize_runs(runs: Sequence[StreamResults]) -> dict[str, tuple[float, float]]:
    """Mean and (population) standard deviation over runs of each metric of :data:`METRICS`
    that every run has, as the paper's tables report them, and of the wall time of a whole
    stream in minutes (runs that recorded it)."""
    if not runs:
        raise ValueError("no runs to summarise")
    columns = {
        m.name: [r.metrics[m.name] for r in runs]
        for m in METRICS
        if all(m.name in r.metrics for r in runs)
    }
    if all(r.wall_time_s is not None for r in runs):
        columns["minutes"] = [sum(r.wall_time_s) / 60 for r in runs]
    return {k: mean_std(v) for k, v in columns.items()}


def fwt_reference(scratch: StreamResults | None, n_tasks: int) -> list[float] | None:
    """The per-task success FWT is measured against: the R diagonal of a from-scratch run of
    a stream as long (None: no such run)."""
    if scratch is None or len(scratch.R) != n_tasks:
        return None
    return scratch.diagonal()


PROGRESS_FORMAT = 1
"""The format number of ``progress.json`` (:data:`~hispo_pl.results.json_fields.FORMAT_KEY`)."""

PROGRESS_KEYS = (
    "stream",
    "rows",
    "wall_time_s",
    "phase_time_s",
    "datasets",
    "fingerprint",
    "mem_per_task",
)
"""The keys every ``progress.json`` holds, besides its format number."""


@dataclass(kw_only=True)
class Progress:
    """A stream's tasks finished so far (``progress.json``), what a rerun resumes from: per
    finished task its row of R, wall and phase times, the dataset it read and MEM after it;
    and the run's settings (``fingerprint``, flat ``dotted.key: value``; None: not checked).
    The file holds every key of :data:`PROGRESS_KEYS` (null where there is no value)."""

    stream: list[str]
    rows: list[list[float]] = field(default_factory=list)
    wall_time_s: list[float] = field(default_factory=list)
    phase_time_s: list[dict[str, float] | None] = field(default_factory=list)
    datasets: list[Any] = field(default_factory=list)
    fingerprint: dict | None = None
    mem_per_task: list[float | None] | None = None  # None until a task finished
    extra: dict = field(default_factory=dict)

    @property
    def done(self) -> int:
        """How many tasks are finished."""
        return len(self.rows)

    def finish_task(
        self,
        row: Sequence[float],
        seconds: float,
        phases: dict[str, float],
        dataset: Any,
        memory: float | None,
    ) -> None:
        """Record a finished task: its row of R, wall time, phase times, dataset and MEM."""
        mem = self.mem_per_task if self.mem_per_task is not None else []
        self.mem_per_task = [*mem, *[None] * (self.done - len(mem)), memory]
        self.rows.append(list(row))
        self.wall_time_s.append(seconds)
        self.phase_time_s.append(phases)
        self.datasets.append(dataset)

    def to_json(self) -> dict:
        return json_fields(self)

    @classmethod
    def from_json(cls, record: dict) -> Progress:
        known, extra = split_known(cls, record)
        return cls(**known, extra=extra)
