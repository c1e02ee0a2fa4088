"""What a run's files hold, as types: :class:`Decision` (one line of ``decisions.jsonl``, one
class per kind of decision, each the result of the search it decided on with the outcome),
:class:`StreamResults` (``results.json``), :class:`Progress` (``progress.json``),
:class:`LaunchRecord` (``run.json``) and :class:`TaskFitResult` (``result.json``).
:class:`~hispo_pl.rundir.RunDir` reads and writes them.

Each type writes its JSON keys in the order the files have always had them, so a file read and
written again is the same bytes; keys a type does not know are kept (``extra``) and written
last. No torch here.
"""

from .decision_kinds import (
    DECISION_KINDS,
    RULE_LINE,
    RULE_RATIO,
    Column,
    CriticDecision,
    CriticSearchResult,
    Decision,
    LossDecision,
    SearchResult,
    ZeroShotDecision,
    decisions_table,
    rule_metrics,
)
from .launch import LAUNCH_KEYS, LaunchRecord
from .single_task import TaskFitResult
from .stream import Progress, StreamResults, fwt_reference, summarize_runs

__all__ = [
    "DECISION_KINDS",
    "LAUNCH_KEYS",
    "RULE_LINE",
    "RULE_RATIO",
    "Column",
    "CriticDecision",
    "CriticSearchResult",
    "Decision",
    "LaunchRecord",
    "LossDecision",
    "Progress",
    "SearchResult",
    "StreamResults",
    "TaskFitResult",
    "ZeroShotDecision",
    "decisions_table",
    "fwt_reference",
    "rule_metrics",
    "summarize_runs",
]
