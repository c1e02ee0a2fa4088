"""Checkpoint keys of the callbacks: Lightning stores a callback's ``state_dict`` under its
``state_key`` (the class name by default), so two instances of one class in a Trainer would
overwrite each other's entry. :class:`KeyedState` keys it on the class and the arguments that
tell two instances apart, as Lightning's ``EarlyStopping`` does, and still reads an entry
written under the bare class name by an earlier hispo-pl."""

from __future__ import annotations

from collections.abc import MutableMapping
from typing import Any, ClassVar

import lightning as L
from typing_extensions import override


def adopt_legacy_state(states: MutableMapping | None, key: str, legacy: str) -> None:
    """Copy the entry stored under ``legacy`` (a class name, as checkpoints had it) to ``key``
    when ``key`` has none, so the callback's ``load_state_dict`` receives it."""
    if states is not None and key not in states and legacy in states:
        states[key] = states[legacy]


class KeyedState(L.Callback):
    """A callback whose checkpoint entry is ``ClassName{arg: value, ...}`` over the attributes
    named in :attr:`state_args` (its constructor's arguments that change what it does).

    Example:
        >>> class Probe(KeyedState):
        ...     state_args = ("episodes",)
        ...     def __init__(self, episodes: int):
        ...         self.episodes = episodes
        >>> Probe(10).state_key
        "Probe{'episodes': 10}"
    """

    state_args: ClassVar[tuple[str, ...]] = ()

    @property
    @override
    def state_key(self) -> str:
        return self._generate_state_key(**self._state_arguments())

    def _state_arguments(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.state_args}

    @override
    def on_load_checkpoint(
        self, trainer: L.Trainer, pl_module: L.LightningModule, checkpoint: dict[str, Any]
    ) -> None:
        # Lightning calls every callback's on_load_checkpoint before any load_state_dict
        adopt_legacy_state(checkpoint.get("callbacks"), self.state_key, type(self).__qualname__)
