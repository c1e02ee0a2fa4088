"""The kinds of line in ``decisions.jsonl``: one :class:`Decision` class per kind, each the
result of the search it decided on (:class:`SearchResult`, :class:`CriticSearchResult`) with
the outcome, written by the callbacks that decide and read back by :class:`~hispo_pl.rundir.
RunDir`. A new kind is one class here, listed in :data:`DECISION_KINDS`: its fields, how the
console states its comparison, and its table's columns. No torch here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from .json_fields import found_fields, header_first, json_fields, split_known

Column = tuple[str, str, Callable[[Any], str]]
"""A table column: header, Markdown alignment (``---`` or ``---:``), the cell of a record."""


def _value(value: float | None, digits: int = 4) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def _text(value: Any) -> str:
    return "" if value is None else str(value)


def _ratio(num: float | None, den: float | None, digits: int = 3) -> str:
    """``num / den``, empty when either is unknown (or the denominator is 0)."""
    return "" if num is None or not den else f"{num / den:.{digits}f}"


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
        return json_fields(self)

    @classmethod
    def of(cls, search: Any, **outcome: Any) -> Decision:
        """The decision taken on ``search`` (a search's result, e.g. :class:`SearchResult`,
        whose fields this kind has), with the ``outcome``: ``task``, ``subspace``,
        ``decision`` and this kind's own fields (``eps``, ``anchors``)."""
        return cls(**found_fields(search), **outcome)

    @classmethod
    def from_json(cls, record: dict) -> Decision:
        """The record as the kind that reads it (:data:`DECISION_KINDS`, first match); keys
        it lacks take their defaults (None: not measured), as a record built in code may.

        Raises:
            ValueError: no kind reads the record, or it has no task, subspace or decision."""
        kind = next((k for k in DECISION_KINDS if k.reads(record)), None)
        missing = [k for k in ("task", "subspace", "decision") if k not in record]
        if kind is None or missing:
            raise ValueError(f"not a decision record: {record}")
        known, extra = split_known(kind, record)
        return kind(**known, extra=extra)


@dataclass(kw_only=True)
class SearchResult:
    """What HiSPO's search (:class:`~hispo_pl.callbacks.DirichletEvaluation`) found in one
    subspace on the current task: the best points of the grown subspace (``curr``) and of the
    previous one (``prev``), with their losses on the task's held-out episodes (what the rule
    compares) and on its training episodes (``*_train``). A :class:`LossDecision` is this
    with the rule's outcome."""

    l_curr: float | None = None
    alpha_curr: list[float] | None = None
    l_prev: float | None = None
    alpha_prev: list[float] | None = None
    l_trained: float | None = None  # the trained weights' loss, when refine_current moved them
    l_curr_train: float | None = None
    l_prev_train: float | None = None
    l_window: float | None = None  # L_curr when the convergence window opened
    improvement: float | None = None  # relative fall of L_curr over the window (convergence)


@dataclass(kw_only=True)
class LossDecision(SearchResult, Decision):
    """HiSPO's rule on a new anchor: prune iff ``L_prev <= (1 + eps) · L_curr``, on the
    search's result (:class:`SearchResult`)."""

    eps: float | None = None
    anchors: int | None = None

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

    def to_json(self) -> dict:
        return header_first(json_fields(self), ("task", "subspace", "decision", "eps", "anchors"))

    @property
    def tolerance(self) -> float | None:
        return self.eps

    def comparison(self) -> str | None:
        if not self.l_curr or self.l_prev is None or self.eps is None:
            return None
        return f"{self.l_prev / self.l_curr:.2f} vs {1 + self.eps:.2f}"


@dataclass(kw_only=True)
class CriticSearchResult:
    """What CSP's critic search (:class:`~hispo_pl.callbacks.CriticEvaluation`) found in one
    subspace on the current task's held-out episodes.

    ``w_curr`` / ``alpha_curr``: the best point of the grown subspace (the paper's
    ``W(α_new)``, ``α_new``); ``w_prev`` / ``alpha_prev``: the best of the previous subspace
    (``W(α_old)``, ``α_old``, last weight 0). ``l_curr`` / ``l_prev``: the imitation loss of
    those two points (what CSPO's rule would compare), for reading the critic's choices against
    the data. ``q_*`` and ``action_dependence``: the critic's action-dependence diagnostic
    (:meth:`~hispo_pl.modules.CSP.critic_diagnostic`) at ``alpha_curr``, averaged over the
    batches. A :class:`CriticDecision` is this with the rule's outcome."""

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


@dataclass(kw_only=True)
class CriticDecision(CriticSearchResult, Decision):
    """CSP's rule: keep the new anchor iff the critic values the grown subspace's best point
    above ``W_prev + eps · |W_prev|``, on the critic search's result
    (:class:`CriticSearchResult`)."""

    rule: str = "critic"
    eps: float | None = None
    anchors: int | None = None

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

    def to_json(self) -> dict:
        header = ("task", "subspace", "decision", "rule", "eps", "anchors")
        return header_first(json_fields(self), header)

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
        out = json_fields(self)
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


# HiSPO's rule as TensorBoard draws it: the new anchor is pruned iff L_prev / L_curr is at or
# below 1 + eps. A ratio and its line stay near 1 whatever the losses' scale, where the losses
# themselves (0.03 for one subspace, 1.9 for the other) would crowd a chart's axis. '+' and '/'
# cannot be written in a tag's last part.
RULE_RATIO = "L_prev_over_L_curr"
RULE_LINE = "1_plus_eps"


def rule_metrics(decisions: Sequence[Decision]) -> dict[str, float]:
    """``search/<subspace>/L_prev_over_L_curr`` and ``search/<subspace>/1_plus_eps`` of each
    loss-rule decision that compared two losses (tasks after the first)."""
    metrics = {}
    for d in decisions:
        if isinstance(d, LossDecision) and d.l_prev is not None and d.l_curr and d.eps is not None:
            metrics[f"search/{d.subspace}/{RULE_RATIO}"] = d.l_prev / d.l_curr
            metrics[f"search/{d.subspace}/{RULE_LINE}"] = 1.0 + d.eps
    return metrics
