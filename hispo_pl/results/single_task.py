"""A single-task fit's file as a type: :class:`TaskFitResult` (``result.json``). No torch here."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from .json_fields import json_fields, missing_keys, split_known

EVALUATION = ("success", "episode_length", "flip_rate", "step")
"""What a rollout evaluation measures, in the file's order."""


RESULT_FORMAT = 1
"""The format number of ``result.json`` (:data:`~hispo_pl.results.json_fields.FORMAT_KEY`)."""


@dataclass(kw_only=True)
class TaskFitResult:
    """A single-task fit's final evaluation (``result.json``): the method's class and the task,
    the dataset it trained on and its episodes, the episodes and wall seconds of the
    evaluation, its success rate, mean episode length, button flip rate and training step, and
    every evaluation before it (``curve``, each point with the keys of :data:`EVALUATION`).
    The file holds every field's key; ``dataset``, ``dataset_episodes`` and ``curve`` are null
    where they were not recorded."""

    method: str
    task: str
    dataset: str | None = None
    dataset_episodes: int | None = None
    episodes: int
    seconds: float
    success: float
    episode_length: float
    flip_rate: float
    step: float
    curve: list[dict[str, float]] | None = None
    extra: dict = field(default_factory=dict)

    @property
    def evaluation(self) -> dict[str, float]:
        """The final evaluation as a curve's point."""
        return {k: getattr(self, k) for k in EVALUATION}

    def to_json(self) -> dict:
        return json_fields(self)

    @classmethod
    def from_json(cls, record: dict) -> TaskFitResult:
        """The result in ``record``.

        Raises:
            KeyError: ``record`` lacks a key every result has (named in the message)."""
        known, extra = split_known(cls, record)
        missing = missing_keys(known, RESULT_KEYS)
        if missing:
            raise KeyError(f"no {', '.join(missing)}")
        return cls(**known, extra=extra)


RESULT_KEYS = tuple(f.name for f in fields(TaskFitResult) if f.name != "extra")
"""The keys every ``result.json`` holds, besides its format number."""
