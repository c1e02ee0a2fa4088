"""How a JSON run file is read and written: its format number first, the keys its record
type requires, and one-line errors that name the file (:class:`~hispo_pl.rundir.RunDir`
reads and writes every run file through these). No torch here."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from .errors import RunDirError
from .results import (
    LAUNCH_FORMAT,
    PROGRESS_FORMAT,
    RESULT_FORMAT,
    RESULTS_FORMAT,
    RESULTS_KEYS,
    StreamResults,
)
from .results.json_fields import FORMAT_KEY, format_problem, missing_keys, stamped

MIGRATE = "python -m lab migrate"
"""The repository's command that rewrites run files of an older format into the current one."""


def read_json_object(path: Path, holds: str) -> dict:
    """The JSON object in ``path``, which ``holds`` what is named (for the message).

    Raises:
        RunDirError: the file is not JSON, or its JSON is not an object."""
    try:
        value = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as err:
        raise RunDirError(f"{path} is not readable JSON ({err}); it should hold {holds}") from None
    if not isinstance(value, dict):
        raise RunDirError(
            f"{path} holds a JSON {type(value).__name__}, not an object; it should hold {holds}"
        )
    return value


def read_run_file(path: Path, holds: str, number: int, keys: Sequence[str] = ()) -> dict:
    """The JSON object in ``path``, a run file of format ``number`` holding every key of
    ``keys``, without its format number.

    Raises:
        RunDirError: the file is not a JSON object, is of another format (what to run to
            migrate it named), or lacks a key."""
    record = read_json_object(path, holds)
    problem = format_problem(record, number)
    if problem is not None:
        raise RunDirError(
            f"{path} {problem}; it should hold {holds} in format {number}: rewrite it with "
            f"`{MIGRATE} {path.parent}` in the hispo-pl repository"
        )
    missing = missing_keys(record, keys)
    if missing:
        raise RunDirError(f"{path} has no {', '.join(missing)}; it should hold {holds}")
    return {k: v for k, v in record.items() if k != FORMAT_KEY}


RUN_FILES = {
    "results.json": (RESULTS_FORMAT, 1, ""),
    "progress.json": (PROGRESS_FORMAT, 1, ""),
    "result.json": (RESULT_FORMAT, 2, "\n"),
    "run.json": (LAUNCH_FORMAT, 1, ""),
}
"""Each JSON run file's format number, JSON indent and what follows the JSON, by name."""


def run_file_text(name: str, record: dict) -> str:
    """The text of the JSON run file ``name`` holding ``record`` (a type's ``to_json()``): its
    format number first, then the record's keys in their order.

    Example:
        >>> run_file_text("run.json", {"method": "ft1"})
        '{\\n "format": 1,\\n "method": "ft1"\\n}'
    """
    number, indent, end = RUN_FILES[name]
    return json.dumps(stamped(number, record), indent=indent) + end


def require_lists(path: Path, record: dict, keys: Sequence[str], holds: str) -> None:
    missing = [k for k in keys if not isinstance(record.get(k), list)]
    if missing:
        raise RunDirError(f"{path} has no list {', '.join(missing)}; it should hold {holds}")


def results_problem(results: dict) -> str | None:
    """Why a stream's ``results.json`` cannot be tabulated, or None: R must be a square
    matrix with one row per task of the stream it names, of success rates in [0, 1] (None:
    not measured yet).

    Example:
        >>> results_problem({"stream": ["a"], "R": [[-1e9]]})
        'R holds -1000000000.0, not a success rate in [0, 1]'
        >>> results_problem({"stream": ["a", "b"], "R": [[1.0, None], [0.5, 0.25]]}) is None
        True
    """
    R, stream = results.get("R"), results.get("stream")
    if not isinstance(R, list) or not all(isinstance(row, list) for row in R):
        return "no matrix R"
    if any(len(row) != len(R) for row in R):
        return f"R is not square ({[len(row) for row in R]} entries in its {len(R)} rows)"
    if not isinstance(stream, list) or len(stream) != len(R):
        n = len(stream) if isinstance(stream, list) else "no"
        return f"R has {len(R)} rows for a stream of {n} tasks"
    values = [v for row in R for v in row if v is not None]
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        return "R holds values that are not numbers"
    wrong = [v for v in values if not 0 <= v <= 1]  # NaN too: it is no number in [0, 1]
    if wrong:
        return f"R holds {wrong[0]}, not a success rate in [0, 1]"
    return None


def read_results_file(path: Path) -> StreamResults:
    """A stream's ``results.json`` at ``path``, checked with :func:`results_problem`.

    Raises:
        RunDirError: the file is not JSON, not an object, not of format
            :data:`~hispo_pl.results.RESULTS_FORMAT`, or its R does not fit its stream."""
    results = read_run_file(path, "a finished stream's results", RESULTS_FORMAT, RESULTS_KEYS)
    problem = results_problem(results)
    if problem is not None:
        raise RunDirError(f"{path} cannot be tabulated: {problem}")
    return StreamResults.from_json(results)
