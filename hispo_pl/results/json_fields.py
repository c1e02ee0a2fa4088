"""How the run files' types write and read their JSON: a dataclass's fields in declaration
order (the file's key order), keys a type does not know kept as its ``extra`` and written last,
so a file read and written again is the same bytes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import fields
from typing import Any


def json_fields(obj: Any) -> dict:
    """The dataclass's fields in declaration order (the file's key order), then ``extra``."""
    out = {f.name: getattr(obj, f.name) for f in fields(obj) if f.name != "extra"}
    return {**out, **obj.extra}


def split_known(cls: type, record: dict) -> tuple[dict, dict]:
    """``record``'s keys that are fields of ``cls``, and the rest (kept as ``extra``)."""
    names = {f.name for f in fields(cls)} - {"extra"}
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
