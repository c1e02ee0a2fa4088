"""``python -m lab migrate [FOLDER]``: rewrite the run files of a folder tree (default
``docs/results``) from every earlier form into the current one, so that hispo-pl's readers,
which take the current format only, read them.

This module is the one place that knows the earlier forms. A file of the current format is
written back as it is (the record types promise the same bytes), so running the migration twice
changes nothing the second time; values are never recomputed, every number stays as it was.

=====================  ===========================================================================
``results.json``       no format number; before phase times, datasets or MEM per task were
                       recorded: ``phase_time_s``, ``datasets``, ``mem_per_task`` written as null
``result.json``        no format number; before datasets and curves were recorded: ``dataset``,
                       ``dataset_episodes`` and ``curve`` written as null
``run.json``           no format number
``progress.json``      no format number; before phase times and datasets were recorded: null for
                       each finished task; no ``mem_per_task`` or ``fingerprint``: null; a
                       fingerprint with callbacks keyed by list position
                       (``trainer.callbacks[2].init_args.eps_low``) or flat model keys
                       (``model.init_args.lr``): keyed as :func:`~hispo_pl.run_checks.
                       run_fingerprint` keys them now
``decisions.jsonl``    has no format number (each line names its kind); a record written
                       without some key of its kind gets null there; a line that is no record
                       (cut by a kill) is kept as it is
=====================  ===========================================================================

A folder whose ``run.lock`` names a live process (a run in progress) is skipped, with a note.
"""

from __future__ import annotations

import json
import os
import re
import socket
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path

from hispo_pl.config import BackboneConfig
from hispo_pl.errors import UserError
from hispo_pl.io import atomic_write_text
from hispo_pl.results import (
    FORMAT_KEY,
    Decision,
    LaunchRecord,
    Progress,
    StreamResults,
    TaskFitResult,
)
from hispo_pl.run_checks import callback_labels
from hispo_pl.run_files import RUN_FILES, run_file_text
from hispo_pl.rundir import RunDir

DECISIONS = RunDir.DECISIONS
NAMES = (*RUN_FILES, DECISIONS)
"""The files the migration rewrites, wherever they are in the tree."""


class MigrationError(UserError, ValueError):
    """A run file that no earlier form describes (not JSON, a newer format, keys missing)."""


# --- earlier fingerprints (progress.json) -------------------------------------------------------

_POSITIONAL_CALLBACK = re.compile(r"trainer\.callbacks\[(\d+)\]\.(.+)")
_MODEL = "model.init_args."
# a flat model key of a fingerprint written before the backbone and optimiser configs -> its key
_FLAT_MODEL_KEYS = {
    **{f.name: f"backbone.{f.name}" for f in fields(BackboneConfig) if f.name != "kind"},
    "hidden": "backbone.low_hidden",  # flat BC's one width
    "backbone": "backbone.kind",  # a ``backbone: bc`` string
    "lr": "optim.lr",
    "lr_schedule": "optim.schedule",
}


def class_keyed_callbacks(fingerprint: Mapping) -> dict:
    """A fingerprint whose callbacks are keyed by list position
    (``trainer.callbacks[2].init_args.eps_low``) with the class labels
    :func:`~hispo_pl.run_checks.run_fingerprint` writes (``trainer.callbacks[SubspacePruning]
    .init_args.eps_low``); other keys unchanged, in their order.

    Example:
        >>> class_keyed_callbacks({"trainer.callbacks[0].class_path": "x.RolloutEvaluation",
        ...                        "trainer.callbacks[0].init_args.episodes": 2})
        {'trainer.callbacks[RolloutEvaluation].class_path': 'x.RolloutEvaluation', \
'trainer.callbacks[RolloutEvaluation].init_args.episodes': 2}
    """
    positional = {}
    for key in fingerprint:
        match = _POSITIONAL_CALLBACK.fullmatch(key)
        if match:
            positional[key] = (int(match.group(1)), match.group(2))
    paths = {i: fingerprint[k] for k, (i, rest) in positional.items() if rest == "class_path"}
    order = sorted(paths)
    labels = dict(zip(order, callback_labels([paths[i] for i in order]), strict=True))
    out = {}
    for key, value in fingerprint.items():
        if key in positional and positional[key][0] in labels:
            i, rest = positional[key]
            key = f"trainer.callbacks[{labels[i]}].{rest}"
        out[key] = value
    return out


def nested_model_keys(fingerprint: Mapping) -> dict:
    """A fingerprint with flat model keys (``model.init_args.lr``, ``...low_hidden``,
    ``...backbone: bc``) renamed into the configs' (``model.init_args.optim.lr``,
    ``...backbone.low_hidden``, ``...backbone.kind``); other keys unchanged, in their order.

    Example:
        >>> nested_model_keys({"model.init_args.lr": 0.001, "data.batch_size": 64})
        {'model.init_args.optim.lr': 0.001, 'data.batch_size': 64}
    """
    out = {}
    for key, value in fingerprint.items():
        name = key[len(_MODEL) :] if key.startswith(_MODEL) else None
        if name in _FLAT_MODEL_KEYS:
            key = _MODEL + _FLAT_MODEL_KEYS[name]
        out[key] = value
    return out


# --- each file: its record as the current format holds it --------------------------------------


def _results(record: dict, earlier: bool) -> dict:
    if earlier:
        for key in ("phase_time_s", "datasets", "stored_bytes", "mem_per_task"):
            record.setdefault(key, None)  # not recorded then
    return StreamResults.from_json(record).to_json()


def _result(record: dict, earlier: bool) -> dict:
    if earlier:
        for key in ("dataset", "dataset_episodes", "curve"):
            record.setdefault(key, None)  # not recorded then
    try:
        return TaskFitResult.from_json(record).to_json()
    except KeyError as err:
        raise MigrationError(f"it has {err.args[0]}, and no earlier form lacked it") from None


def _launch(record: dict, earlier: bool) -> dict:
    return LaunchRecord.from_json(record).to_json()


def _progress(record: dict, earlier: bool) -> dict:
    if earlier:
        rows = record.get("rows")
        tasks = len(rows) if isinstance(rows, list) else 0
        for key in ("phase_time_s", "datasets"):
            record.setdefault(key, [None] * tasks)  # not recorded for these tasks
        record.setdefault("fingerprint", None)  # not checked
        record.setdefault("mem_per_task", None)  # not measured
        if isinstance(record["fingerprint"], Mapping):
            record["fingerprint"] = nested_model_keys(class_keyed_callbacks(record["fingerprint"]))
    missing = [k for k in ("stream", "rows") if not isinstance(record.get(k), list)]
    if missing:
        raise MigrationError(f"it has no list {', '.join(missing)}")
    return Progress.from_json(record).to_json()


CURRENT: dict[str, Callable[[dict, bool], dict]] = {
    RunDir.RESULTS: _results,
    RunDir.RESULT: _result,
    RunDir.RUN_RECORD: _launch,
    RunDir.PROGRESS: _progress,
}
"""Per JSON run file: its record (format number left out) as the current format holds it,
given whether the file is of an earlier form (no format number)."""


def migrated_text(name: str, text: str) -> str:
    """The text of run file ``name`` (``results.json``, ``decisions.jsonl``...) in the current
    format, from ``text`` in any earlier form; ``text`` itself when it is current.

    Raises:
        MigrationError: the file is of no known form (not JSON, a newer format, keys missing).
    """
    if name == DECISIONS:
        return "".join(_decision_line(line) for line in text.splitlines(keepends=True))
    try:
        record = json.loads(text)
    except ValueError as err:
        raise MigrationError(f"it is not readable JSON ({err})") from None
    if not isinstance(record, dict):
        raise MigrationError(f"it holds a JSON {type(record).__name__}, not an object")
    number = RUN_FILES[name][0]
    earlier = FORMAT_KEY not in record
    found = record.pop(FORMAT_KEY, None)
    if not earlier and (found != number or isinstance(found, bool)):
        raise MigrationError(f"it is of format {json.dumps(found)}; this lab knows up to {number}")
    return run_file_text(name, CURRENT[name](record, earlier))


def _decision_line(line: str) -> str:
    """A ``decisions.jsonl`` line as the current writer writes its record; a line that is no
    record (cut by a kill, or of no known kind) as it is."""
    try:
        record = json.loads(line)
        decision = Decision.from_json(record) if isinstance(record, dict) else None
    except ValueError:
        decision = None
    if decision is None:
        return line
    return json.dumps(decision.to_json()) + ("\n" if line.endswith("\n") else "")


# --- a folder tree -----------------------------------------------------------------------------


def live_holder(folder: Path) -> str | None:
    """Who holds ``folder``'s ``run.lock`` when that is a live process (a run in progress):
    the lock's line (pid, host, start, command); None when no run holds it. A holder on
    another machine cannot be checked and counts as live."""
    try:
        text = (folder / RunDir.LOCK).read_text().strip()
    except (FileNotFoundError, NotADirectoryError):
        return None
    match = re.match(r"pid (\d+) on (\S+),", text)
    if match is None:  # emptied when its run ended
        return None
    pid, host = int(match.group(1)), match.group(2)
    if host != socket.gethostname():
        return text
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:  # alive, another user's
        return text
    return text


@dataclass
class Migration:
    """What a migration did: files rewritten and already current (by name), folders skipped
    because a live run holds them, and files it could not read (path: why)."""

    rewritten: Counter = field(default_factory=Counter)
    current: Counter = field(default_factory=Counter)
    paths: list[Path] = field(default_factory=list)
    skipped: list[tuple[Path, str]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


def migrate_tree(root: Path, write: bool = True) -> Migration:
    """Rewrite every run file under ``root`` in the current format (``write=False``: only
    find out which would change). A path that vanishes meanwhile is passed over.

    Raises:
        MigrationError: ``root`` is not a folder."""
    root = Path(root)
    if not root.is_dir():
        raise MigrationError(f"{root}: no such folder")
    done = Migration()
    for folder, dirs, files in os.walk(root):
        dirs.sort()
        names = [n for n in NAMES if n in files]
        if not names:
            continue
        path = Path(folder)
        holder = live_holder(path)
        if holder is not None:
            done.skipped.append((path, holder))
            continue
        for name in names:
            file = path / name
            try:
                text = file.read_text()
            except FileNotFoundError:  # removed meanwhile
                continue
            try:
                new = migrated_text(name, text)
            except MigrationError as err:
                done.problems.append(f"{file}: {err}")
                continue
            if new == text:
                done.current[name] += 1
                continue
            done.rewritten[name] += 1
            done.paths.append(file)
            if write and file.parent.is_dir():
                atomic_write_text(file, new)
    return done


def _counts(counter: Counter) -> str:
    return ", ".join(f"{counter[n]} {n}" for n in NAMES if counter[n]) or "none"


def migrate(root: Path, check: bool = False) -> int:
    """``python -m lab migrate``: migrate ``root`` and say what was done; with ``check``,
    only say what would change. Returns the exit status: 1 when ``check`` finds files to
    migrate, else 0.

    Raises:
        MigrationError: a file could not be migrated (each named above the message)."""
    done = migrate_tree(root, write=not check)
    for folder, holder in done.skipped:
        print(f"[lab] skipped {folder}: a live run holds it ({holder})")
    for problem in done.problems:
        print(f"[lab] cannot migrate {problem}")
    verb = "to migrate" if check else "migrated"
    print(f"[lab] {verb} under {root}: {_counts(done.rewritten)}; current: {_counts(done.current)}")
    if done.problems:
        raise MigrationError(f"{len(done.problems)} run files under {root} of no known form")
    return 1 if check and done.rewritten else 0
