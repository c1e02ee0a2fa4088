"""The per-task record: what a task's callbacks found, handed on through the module.

A callback writes what it measured into ``module.task_record``; the next callback and the
loop read it there, never another callback's attributes. The record is fresh at every fit
and never saved: the decisions it leads to are (anchors, anchor weights, ``decisions.jsonl``,
the rows of R in ``progress.json``). No torch here.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any


@dataclass
class TaskRecord:
    """What the current task's callbacks found so far.

    Attributes:
        searches: per subspace, the task-end search's result (written by the search callback,
            read by the pruning callback that follows it).
        convergence_window: the share of steps over which the search measured whether
            ``L_curr`` still fell (None: not measured).
        evaluation: the latest rollout evaluation of the current task (``success``,
            ``episode_length``, ``flip_rate``, ``step``), over ``episodes`` episodes.
        episodes: episodes of that evaluation.
        curve: every evaluation of the current task in order (periodic ones, then the one at
            the task's end), each as ``evaluation``: a single-task run's learning curve.
        success_row: at a stream task's end, the success on every task of the stream (a row
            of R, read by the loop).
        rollouts: at a stream task's end, that task's scored rollouts with their paths (a
            ``RolloutResult``; the loop draws some of them for TensorBoard).
        seconds: wall time the callbacks spent so far, per phase (``search``, ``evaluation``):
            the loop reports it beside the training's.
    """

    searches: dict[str, Any] = field(default_factory=dict)
    convergence_window: float | None = None
    evaluation: dict[str, float] | None = None
    episodes: int | None = None
    curve: list[dict[str, float]] = field(default_factory=list)
    success_row: list[float] | None = None
    rollouts: Any = None
    seconds: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def timed(self, phase: str) -> Iterator[None]:
        """Add the block's wall time to ``seconds[phase]``."""
        start = time.perf_counter()
        try:
            yield
        finally:
            elapsed = time.perf_counter() - start
            self.seconds[phase] = self.seconds.get(phase, 0.0) + elapsed
