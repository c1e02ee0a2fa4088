"""How the run files' types write and read their JSON: a dataclass's fields in declaration
order (the file's key order), keys a type does not know kept as its ``extra`` and written last,
so a file read and written again is the same bytes; and the format number each JSON run file
carries (:data:`FORMAT_KEY`, one constant per file type beside its type), which
:class:`~hispo_pl.rundir.RunDir` writes first and requires on reading."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import fields
from typing import Any

FORMAT_KEY = "format"
"""The key of a JSON run file's format number (its first key). A reader refuses a file without
the number its type writes; ``python -m lab migrate`` rewrites older files."""


def stamped(number: int, record: dict) -> dict:
    """``record`` as a file of format ``number`` holds it: the number first.

    Example:
        >>> stamped(1, {"stream": ["a"]})
        {'format': 1, 'stream': ['a']}
    """
    return {FORMAT_KEY: number, **{k: v for k, v in record.items() if k != FORMAT_KEY}}


def format_problem(record: dict, number: int) -> str | None:
    """Why ``record`` is not a file of format ``number`` (said after the file's name), or None.

    Example:
        >>> format_problem({"stream": ["a"]}, 1)
        'has no format number (an older hispo-pl wrote it)'
        >>> format_problem({"format": 1}, 1) is None
        True
    """
    found = record.get(FORMAT_KEY)
    if FORMAT_KEY not in record:
        return "has no format number (an older hispo-pl wrote it)"
    if found != number or isinstance(found, bool):
        return f"is of format {json.dumps(found)}, not {number}"
    return None


def missing_keys(record: dict, keys: Sequence[str]) -> list[str]:
    """The keys of ``keys`` that ``record`` lacks (a file's key holds null when a value was not
    measured; the key itself is always there)."""
    return [k for k in keys if k not in record]


def json_fields(obj: Any) -> dict:
    """The dataclass's fields in declaration order (the file's key order), then ``extra``."""
    out = {f.name: getattr(obj, f.name) for f in fields(obj) if f.name != "extra"}
    return {**out, **obj.extra}


def split_known(cls: type, record: dict) -> tuple[dict, dict]:
    """``record``'s keys that are fields of ``cls``, and the rest (kept as ``extra``); the
    format number belongs to the file, not the record, and is left out."""
    names = {f.name for f in fields(cls)} - {"extra"}
    record = {k: v for k, v in record.items() if k != FORMAT_KEY}
    return {k: v for k, v in record.items() if k in names}, {
        k: v for k, v in record.items() if k not in names
    }


def found_fields(obj: Any) -> dict:
    """The fields of dataclass instance ``obj`` by name (a shallow copy, unlike ``asdict``)."""
    return {f.name: getattr(obj, f.name) for f in fields(obj)}


def header_first(record: dict, header: Sequence[str]) -> dict:
    """``record`` with the keys of ``header`` first, in that order."""
    rest = {k: v for k, v in record.items() if k not in header}
    return {**{k: record[k] for k in header}, **rest}
