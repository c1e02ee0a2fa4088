"""What a run's files hold, as types: :class:`Decision` (one line of ``decisions.jsonl``, one
class per kind of decision, each the result of the search it decided on with the outcome),
:class:`StreamResults` (``results.json``), :class:`Progress` (``progress.json``),
:class:`LaunchRecord` (``run.json``) and :class:`TaskFitResult` (``result.json``).
:class:`~hispo_pl.rundir.RunDir` reads and writes them.

Each type writes its JSON keys in the order the files have always had them, so a file read and
written again is the same bytes; keys a type does not know are kept (``extra``) and written
last. Each JSON file starts with its format number (``"format": 1``; the constants
:data:`RESULTS_FORMAT`, :data:`PROGRESS_FORMAT`, :data:`LAUNCH_FORMAT`, :data:`RESULT_FORMAT`),
which :class:`~hispo_pl.rundir.RunDir` requires: ``python -m lab migrate`` rewrites older files.
``decisions.jsonl`` has none: each line is a record that names its own kind. No torch here.
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
from .json_fields import FORMAT_KEY
from .launch_record import LAUNCH_FORMAT, LAUNCH_KEYS, LaunchRecord
from .single_task import RESULT_FORMAT, RESULT_KEYS, TaskFitResult
from .stream import (
    PROGRESS_FORMAT,
    PROGRESS_KEYS,
    RESULTS_FORMAT,
    RESULTS_KEYS,
    Progress,
    StreamResults,
    fwt_reference,
    summarize_runs,
)

__all__ = [
    "DECISION_KINDS",
    "FORMAT_KEY",
    "LAUNCH_FORMAT",
    "LAUNCH_KEYS",
    "PROGRESS_FORMAT",
    "PROGRESS_KEYS",
    "RESULTS_FORMAT",
    "RESULTS_KEYS",
    "RESULT_FORMAT",
    "RESULT_KEYS",
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
