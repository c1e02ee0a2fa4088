"""What a run's files hold, as types: :class:`Decision` (one line of ``decisions.jsonl``, one
class per kind of decision), :class:`StreamResults` (``results.json``) and :class:`TaskResult`
(a single-task fit's ``result.json``). :class:`~hispo_pl.rundir.RunDir` reads and writes them.

Each type writes its JSON keys in the order the files have always had them, so a file read and
written again is the same bytes; keys a type does not know are kept (``extra``) and written
last. A new kind of decision is one class here, listed in :data:`DECISION_KINDS`: its fields,
how the console states its comparison, and its table's columns. No torch here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np

from .metrics import METRICS, mean_std

Column = tuple[str, str, Callable[[Any], str]]
"""A table column: header, Markdown alignment (``---`` or ``---:``), the cell of a record."""


def _value(value: float | None, digits: int = 4) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def _text(value: Any) -> str:
    return "" if value is None else str(value)


def _ratio(num: float | None, den: float | None, digits: int = 3) -> str:
    """``num / den``, empty when either is unknown (or the denominator is 0)."""
    return "" if num is None or not den else f"{num / den:.{digits}f}"


def _json_fields(obj: Any) -> dict:
    """The dataclass's fields in declaration order (the file's key order), then ``extra``."""
    out = {f.name: getattr(obj, f.name) for f in fields(obj) if f.name != "extra"}
    return {**out, **obj.extra}


def _split(cls: type, record: dict) -> tuple[dict, dict]:
    """``record``'s keys that are fields of ``cls``, and the rest (kept as ``extra``)."""
    names = {f.name for f in fields(cls)} - {"extra"}
    return {k: v for k, v in record.items() if k in names}, {
        k: v for k, v in record.items() if k not in names
    }


@dataclass(kw_only=True)
class Decision:
    """A task-end decision on one subspace (0-based ``task``); ``decision`` is the outcome as
    written: ``first`` / ``keep`` / ``prune`` for a rule on a new anchor, ``zero-shot`` /
    ``train`` for the zero-shot test."""

    task: int
    subspace: str
    decision: str
    extra: dict = field(default_factory=dict)

    LEGEND: ClassVar[str] = ""
    """How to read :meth:`comparison` (printed beside the console's decision lines)."""
    COLUMNS: ClassVar[tuple[Column, ...]] = ()
    """This kind's columns in :func:`decisions_table`."""

    @classmethod
    def reads(cls, record: dict) -> bool:
        """Whether a ``decisions.jsonl`` record is of this kind."""
        raise NotImplementedError

    @property
    def kind(self) -> str:
        """``first``, ``keep``, ``prune``, ``zero-shot`` or ``critic``."""
        return self.decision

    @property
    def tolerance(self) -> float | None:
        """The tolerance the rule applied to this subspace (None: not a pruning rule's)."""
        return None

    def comparison(self) -> str | None:
        """The two sides the rule compared, for the console (None: nothing compared)."""
        return None

    def to_json(self) -> dict:
        return _json_fields(self)

    @classmethod
    def from_json(cls, record: dict) -> Decision:
        """The record as the kind that reads it (:data:`DECISION_KINDS`, first match); keys
        it lacks take their defaults (a record of an older hispo-pl).

        Raises:
            ValueError: no kind reads the record, or it has no task, subspace or decision."""
        kind = next((k for k in DECISION_KINDS if k.reads(record)), None)
        missing = [k for k in ("task", "subspace", "decision") if k not in record]
        if kind is None or missing:
            raise ValueError(f"not a decision record: {record}")
        known, extra = _split(kind, record)
        return kind(**known, extra=extra)


@dataclass(kw_only=True)
class LossDecision(Decision):
    """HiSPO's rule on a new anchor: prune iff ``L_prev <= (1 + eps) · L_curr`` (imitation
    losses on the task's held-out episodes; ``*_train`` on its training episodes)."""

    eps: float | None = None
    anchors: int | None = None
    l_curr: float | None = None
    alpha_curr: list[float] | None = None
    l_prev: float | None = None
    alpha_prev: list[float] | None = None
    l_trained: float | None = None
    l_curr_train: float | None = None
    l_prev_train: float | None = None
    l_window: float | None = None
    improvement: float | None = None

    LEGEND = "L_prev / L_curr vs 1 + eps"
    COLUMNS = (
        ("task", "---:", lambda d: str(d.task + 1)),
        ("subspace", "---", lambda d: d.subspace),
        ("L_prev", "---:", lambda d: _value(d.l_prev)),
        ("L_curr", "---:", lambda d: _value(d.l_curr)),
        ("L_prev / L_curr", "---:", lambda d: _ratio(d.l_prev, d.l_curr)),
        ("ε", "---:", lambda d: _text(d.eps)),
        ("train L_prev / L_curr", "---:", lambda d: _ratio(d.l_prev_train, d.l_curr_train)),
        ("convergence", "---:", lambda d: "" if d.improvement is None else f"{d.improvement:+.1%}"),
        ("decision", "---", lambda d: d.decision),
        ("anchors", "---:", lambda d: _text(d.anchors)),
    )

    @classmethod
    def reads(cls, record: dict) -> bool:
        return record.get("decision") in ("first", "keep", "prune") and "rule" not in record

    @property
    def tolerance(self) -> float | None:
        return self.eps

    def comparison(self) -> str | None:
        if not self.l_curr or self.l_prev is None or self.eps is None:
            return None
        return f"{self.l_prev / self.l_curr:.2f} vs {1 + self.eps:.2f}"


@dataclass(kw_only=True)
class CriticDecision(Decision):
    """CSP's rule: keep the new anchor iff the critic values the grown subspace's best point
    above ``W_prev + eps · |W_prev|``; the imitation losses of both points and the critic's
    action-dependence diagnostic are read out beside it."""

    rule: str = "critic"
    eps: float | None = None
    anchors: int | None = None
    w_curr: float | None = None
    alpha_curr: list[float] | None = None
    w_prev: float | None = None
    alpha_prev: list[float] | None = None
    l_curr: float | None = None
    l_prev: float | None = None
    q_action_std: float | None = None
    q_state_std: float | None = None
    action_dependence: float | None = None
    q_data: float | None = None
    q_policy: float | None = None
    q_uniform: float | None = None

    LEGEND = "W_curr vs W_prev + eps |W_prev|"
    COLUMNS = (
        ("task", "---:", lambda d: str(d.task + 1)),
        ("W_prev", "---:", lambda d: _value(d.w_prev)),
        ("W_curr", "---:", lambda d: _value(d.w_curr)),
        ("ε", "---:", lambda d: _text(d.eps)),
        ("L_prev / L_curr", "---:", lambda d: _ratio(d.l_prev, d.l_curr)),
        ("Q std over actions", "---:", lambda d: _value(d.q_action_std)),
        ("Q std over states", "---:", lambda d: _value(d.q_state_std)),
        ("action dependence", "---:", lambda d: _value(d.action_dependence, 3)),
        ("decision", "---", lambda d: d.decision),
        ("anchors", "---:", lambda d: _text(d.anchors)),
    )

    @classmethod
    def reads(cls, record: dict) -> bool:
        return record.get("rule") == "critic"

    @property
    def kind(self) -> str:
        return "critic"

    @property
    def tolerance(self) -> float | None:
        return self.eps

    def comparison(self) -> str | None:
        if self.w_prev is None or self.w_curr is None or self.eps is None:
            return None
        return f"W {self.w_curr:.3f} vs {self.w_prev + self.eps * abs(self.w_prev):.3f}"


@dataclass(kw_only=True)
class ZeroShotDecision(Decision):
    """The PAC test before a task: the previous subspace's best point ``alpha`` is taken
    (``zero-shot``) iff it predicts within ``eps`` (per policy) on a share ``>= 1 - delta`` of
    the task's data, else the task trains (``train``). ``steps_skipped`` and
    ``time_saved_s`` are written only when every subspace transferred."""

    pac_rate: dict[str, float] = field(default_factory=dict)
    eps: dict[str, float] = field(default_factory=dict)
    delta: float | None = None
    anchors: int | None = None
    alpha: list[float] | None = None
    steps_skipped: int | None = None
    time_saved_s: float | None = None

    COLUMNS = (
        ("task", "---:", lambda d: str(d.task + 1)),
        ("subspace", "---", lambda d: d.subspace),
        ("PAC rate", "---", lambda d: ", ".join(f"{p} {r:.3f}" for p, r in d.pac_rate.items())),
        ("1 − δ", "---:", lambda d: "" if d.delta is None else f"{1 - d.delta:.2f}"),
        ("decision", "---", lambda d: d.decision),
        ("anchors", "---:", lambda d: _text(d.anchors)),
    )

    @classmethod
    def reads(cls, record: dict) -> bool:
        return record.get("decision") in ("zero-shot", "train")

    @property
    def kind(self) -> str:
        return "zero-shot"

    def to_json(self) -> dict:
        out = _json_fields(self)
        if self.steps_skipped is None:  # not skipped: the file has neither key
            del out["steps_skipped"], out["time_saved_s"]
        return out


DECISION_KINDS: tuple[type[Decision], ...] = (CriticDecision, ZeroShotDecision, LossDecision)
"""Every kind of decision record, in the order a record is tried against them."""


def decisions_table(
    kind: type[Decision],
    runs: Sequence[tuple[tuple[str, ...], Sequence[Decision]]],
    run_columns: Sequence[tuple[str, str]] = (),
) -> list[str]:
    """The Markdown lines of the table of ``kind``'s decisions (none when there is none): one
    row per decision of each run, led by the run's own cells (``run_columns``: header and
    alignment of each, e.g. method and seed; none for one run)."""
    rows = [
        "| " + " | ".join([*cells, *(cell(d) for _, _, cell in kind.COLUMNS)]) + " |"
        for cells, decisions in runs
        for d in decisions
        if type(d) is kind
    ]
    if not rows:
        return []
    columns = [*run_columns, *((h, a) for h, a, _ in kind.COLUMNS)]
    header = "| " + " | ".join(h for h, _ in columns) + " |"
    return [header, "|" + "".join(f"{a}|" for _, a in columns), *rows]


@dataclass(kw_only=True)
class StreamResults:
    """A finished stream (``results.json``): its tasks, the success matrix ``R`` (fractions;
    None above the diagonal), wall and phase times per task, the datasets it read, the metrics
    of :data:`~hispo_pl.metrics.METRICS` it has, the stored bytes, MEM after each task, anchors
    and anchor weights per subspace, and ``R`` as printed. ``None``: a file from before that
    key existed."""

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
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        for of_model in (False, True):
            if of_model and self.stored_bytes is not None:
                out["stored_bytes"] = self.stored_bytes
            out |= {
                m.name: self.metrics[m.name]
                for m in METRICS
                if m.of_model == of_model and m.name in self.metrics
            }
        for name in ("mem_per_task", "anchors", "alphas"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return {**out, "table": self.table, **self.extra}

    @classmethod
    def from_json(cls, record: dict) -> StreamResults:
        names = {m.name for m in METRICS}
        metrics = {k: v for k, v in record.items() if k in names}
        known, extra = _split(cls, {k: v for k, v in record.items() if k not in names})
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


@dataclass(kw_only=True)
class TaskResult:
    """A single-task fit's final evaluation (``result.json``): the method, the task, the
    dataset it trained on, the evaluation's episodes, the fit's seconds and the evaluation's
    values (``success``, ``episode_length``, ``flip_rate``, ``step``)."""

    method: str
    task: str
    dataset: str | None = None
    dataset_episodes: int | None = None
    episodes: int | None = None
    seconds: float | None = None
    evaluation: dict[str, float] = field(default_factory=dict)

    @property
    def success(self) -> float:
        return self.evaluation["success"]

    def to_json(self) -> dict:
        out: dict = {"method": self.method, "task": self.task}
        if self.dataset is not None:  # a fit from before datasets were recorded has neither
            out |= {"dataset": self.dataset, "dataset_episodes": self.dataset_episodes}
        return {**out, "episodes": self.episodes, "seconds": self.seconds, **self.evaluation}

    @classmethod
    def from_json(cls, record: dict) -> TaskResult:
        known, evaluation = _split(cls, record)
        known.pop("evaluation", None)
        return cls(**known, evaluation=evaluation)
