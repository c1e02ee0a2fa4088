"""Checkpoint keys of the callbacks: Lightning stores a callback's ``state_dict`` under its
``state_key`` (the class name by default), so two instances of one class in a Trainer would
overwrite each other's entry. :class:`KeyedState` keys it on the class and the arguments that
tell two instances apart, as Lightning's ``EarlyStopping`` does."""

from __future__ import annotations

from typing import Any, ClassVar

import lightning as L
from typing_extensions import override


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
