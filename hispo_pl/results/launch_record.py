"""The benchmark's record of a run it launched (``run.json``) as a type: :class:`LaunchRecord`.

Unlike the other run files, ``run.json`` has no one key order: a derived run names its source
first, a copied seed last, a branched run its source first and its task count last. A record
therefore keeps the keys it holds in the order they came (:attr:`LaunchRecord.order`; a key may
hold null), so a file read and written again is the same bytes; a key set afterwards is written
after them, in the fields' order, and keys the type does not know are kept. No torch here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from .json_fields import FORMAT_KEY, split_known

LAUNCH_KEYS = ("method", "seed", "stream", "steps_per_task", "argv", "command")
"""What every launch records, null where it does not know (no stream name, no budget)."""

LAUNCH_FORMAT = 1
"""The format number of ``run.json`` (:data:`~hispo_pl.results.json_fields.FORMAT_KEY`), its
first key whatever order the others have."""


@dataclass(kw_only=True)
class LaunchRecord:
    """A run's ``run.json``: how the benchmark launched it (method, seed, stream, steps per
    task, the fit's arguments and whole command), where (hispo-pl's ``version``, the
    ``machine``, the ``commit`` a repository's recorder adds; ``committed_in`` for runs
    launched before launches recorded one), what it was made from instead of trained
    (``derived_from``; ``branched_from`` and the ``branched_tasks`` it copied), the
    ``earlier_commits`` a resumed run also trained under (oldest first), and how its
    launch ended (``status``, for a run that left no results). Empty for a run the benchmark did
    not launch.

    Example:
        >>> record = LaunchRecord.from_json({"derived_from": "s/ftn/seed0", "method": "ft1"})
        >>> record.derived_from, list(record.replace(status="exit 1").to_json())
        ('s/ftn/seed0', ['derived_from', 'method', 'status'])
    """

    method: str | None = None
    seed: int | None = None
    stream: str | None = None
    steps_per_task: int | None = None
    argv: list[str] | None = None
    command: str | None = None
    version: str | None = None
    machine: dict[str, Any] | None = None
    commit: str | None = None
    committed_in: str | None = None
    derived_from: str | None = None
    branched_from: str | None = None
    branched_tasks: int | None = None
    earlier_commits: list[str | None] | None = None
    status: str | None = None
    extra: dict = field(default_factory=dict)
    order: tuple[str, ...] = field(default=(), compare=False, repr=False)
    """The keys the record holds, in the file's order (each written, null or not)."""

    @classmethod
    def launched(cls, **launch: Any) -> LaunchRecord:
        """A launch's record: the keys of :data:`LAUNCH_KEYS`, each written (null or not).

        Raises:
            TypeError: a key of :data:`LAUNCH_KEYS` is missing, or another is given."""
        if set(launch) != set(LAUNCH_KEYS):
            raise TypeError(f"a launch records {', '.join(LAUNCH_KEYS)}; got {', '.join(launch)}")
        return cls.from_json({k: launch[k] for k in LAUNCH_KEYS})

    def holds(self, key: str) -> bool:
        """Whether the record has ``key`` (written even when null)."""
        return key in self.to_json()

    def replace(self, **changes: Any) -> LaunchRecord:
        """The record with fields changed; a field it did not hold is written after the others."""
        return dataclasses.replace(self, **changes)

    def without(self, *keys: str) -> LaunchRecord:
        """The record without ``keys``."""
        return LaunchRecord.from_json({k: v for k, v in self.to_json().items() if k not in keys})

    def merged(self, later: LaunchRecord | Mapping[str, Any]) -> LaunchRecord:
        """This record updated with ``later``'s keys, as a dict is: a key both hold keeps its
        place with ``later``'s value; ``later``'s other keys follow, in its order."""
        more = later.to_json() if isinstance(later, LaunchRecord) else dict(later)
        return LaunchRecord.from_json({**self.to_json(), **more})

    def to_json(self) -> dict:
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out = {k: (self.extra[k] if k in self.extra else values[k]) for k in self.order}
        out |= {
            name: value
            for name, value in values.items()
            if name not in ("extra", "order") and name not in out and value is not None
        }
        return out | {k: v for k, v in self.extra.items() if k not in out}

    @classmethod
    def from_json(cls, record: Mapping[str, Any]) -> LaunchRecord:
        known, extra = split_known(cls, {k: v for k, v in record.items() if k != "order"})
        if "order" in record:
            extra["order"] = record["order"]
        return cls(**known, extra=extra, order=tuple(k for k in record if k != FORMAT_KEY))
