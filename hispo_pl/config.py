"""Typed configs shared by every method: the backbone network and the optimiser.

A method takes them as ``backbone`` and ``optim`` (``--model.init_args.backbone.low_hidden 128``,
``--model.init_args.optim.lr 1e-3``) and stores them in its hyperparameters as plain dicts, so
a checkpoint still loads with ``weights_only=True``. No torch here: reports and scripts
import it freely.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Literal

BackboneKind = Literal["hbc", "bc"]
Schedule = Literal["cosine", "constant"]


@dataclass(frozen=True)
class BackboneConfig:
    """The single-task network that every method parameterises in its own way (one per task,
    a subspace of anchors, progressive columns, low-rank offsets). The defaults are the house
    backbone every method config uses, so a method config names only what differs from it.

    Attributes:
        kind: ``hbc``, a high policy over subgoal offsets and a low one over actions; or ``bc``,
            one flat policy over actions on the high policy's inputs, ``low_hidden`` wide.
        high_hidden: width of the high policy.
        low_hidden: width of the low policy (of the flat policy for ``bc``).
        dropout: dropout of every hidden layer.
        high_log_std: a fixed log-std makes the high policy's loss a squared error on the
            subgoal; ``None`` learns it.
        low_log_std: the same for the low policy's action (continuous entries).
        low_obs: whether the low policy sees the observation (``False``: only the features
            of the relative subgoal). Linked from ``--data.low_inputs``.
        low_velocity: whether the low policy sees the velocity of the sensed position. Linked from
            ``--data.low_inputs``.
        high_obs: whether the high (and flat) policy sees the observation; ``False``: the
            velocity of the sensed position in its place (an observation variant then reaches
            it only where the family senses its position through the observation). Linked
            from ``--data.high_inputs``.
        binary_actions: leading action entries that are buttons (Bernoulli). Linked from the
            data.
    """

    kind: BackboneKind = "hbc"
    high_hidden: int = 64
    low_hidden: int = 256
    dropout: float = 0.1
    high_log_std: float | None = 0.0
    low_log_std: float | None = 0.0
    low_obs: bool = True
    low_velocity: bool = False
    high_obs: bool = True
    binary_actions: int = 0

    def __post_init__(self) -> None:
        if self.kind not in ("hbc", "bc"):
            raise ValueError(f"unknown backbone kind {self.kind!r}; expected 'hbc' or 'bc'")

    @property
    def reads_observation(self) -> bool:
        """Whether any of its policies reads the observation (the flat one reads the high
        policy's inputs): else no observation variant (IO, PO) reaches it."""
        return self.high_obs or (self.kind == "hbc" and self.low_obs)

    @classmethod
    def of(cls, value: BackboneConfig | Mapping | None) -> BackboneConfig:
        """The config itself, or one built from a dict (as checkpoints store it)."""
        return _coerce(cls, value)


@dataclass(frozen=True)
class OptimConfig:
    """Adam over a task's trainable parameters, restarted at every task.

    Attributes:
        lr: learning rate (the house default is faster than the paper's 3e-4 at our step
            budgets, docs/method.md).
        schedule: ``cosine`` anneals it over ``trainer.max_steps``; ``constant`` keeps it.
        captured: run each training step as one program over static buffers (losses,
            backward, fused Adam and the schedule, no host synchronisation per step), captured
            once per task as a CUDA graph and replayed on CUDA, run eagerly elsewhere
            (:mod:`hispo_pl.nn.program`); off: the usual step. With ``--data.group N`` one
            Trainer step trains N batches (docs/performance.md).
    """

    lr: float = 1e-3
    schedule: Schedule = "cosine"
    captured: bool = False

    @classmethod
    def of(cls, value: OptimConfig | Mapping | None) -> OptimConfig:
        """The config itself, or one built from a dict (as checkpoints store it)."""
        return _coerce(cls, value)


def _coerce(cls, value):
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        return cls(**value)
    raise TypeError(f"expected a {cls.__name__} or a dict, got {type(value).__name__}")


def plain(config: BackboneConfig | OptimConfig) -> dict:
    """A config as the plain dict a checkpoint's hyperparameters hold."""
    return asdict(config)
