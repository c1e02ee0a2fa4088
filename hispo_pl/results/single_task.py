"""A single-task fit's file as a type: :class:`TaskFitResult` (``result.json``). No torch here."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields

from .json_fields import split_known

EVALUATION = ("success", "episode_length", "flip_rate", "step")
"""What a rollout evaluation measures, in the file's order."""


@dataclass(kw_only=True)
class TaskFitResult:
    """A single-task fit's final evaluation (``result.json``): the method's class and the task,
    the dataset it trained on and its episodes (None: a file from before they were recorded),
    the episodes and wall seconds of the evaluation, its success rate, mean episode length,
    button flip rate and training step, and every evaluation before it (``curve``, each point
    with the keys of :data:`EVALUATION`; None: a file from before curves were recorded)."""

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
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"}
        optional = ("dataset", "dataset_episodes", "curve")
        return {k: v for k, v in out.items() if v is not None or k not in optional} | self.extra

    @classmethod
    def from_json(cls, record: dict) -> TaskFitResult:
        """The result in ``record``.

        Raises:
            KeyError: ``record`` lacks a key every result has (named in the message)."""
        known, extra = split_known(cls, record)
        required = [f.name for f in fields(cls) if f.default is MISSING and f.name != "extra"]
        missing = [k for k in required if k not in known]
        if missing:
            raise KeyError(f"no {', '.join(missing)}")
        return cls(**known, extra=extra)
