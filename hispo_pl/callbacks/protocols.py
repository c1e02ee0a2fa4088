"""What each callback needs from its module, one small protocol per need (as d3rlpy's pluggable
pieces are), and the check every callback makes in ``setup``: its module implements the
protocol it talks to it through, else an error that names a module that does. A module
implements them by having the members (``HiSPO``, ``CSPO``, ``HiLOW``, ``CSP``); it need not
name them."""

from __future__ import annotations

from typing import Protocol, TypeVar, runtime_checkable

import lightning as L
import torch
from torch import Tensor

from ..nn.subspace import AnchorInit

P = TypeVar("P")


@runtime_checkable
class SubspaceNames(Protocol):
    """Named subspaces of policies, each with its anchors, on the task being trained."""

    subspace_names: tuple[str, ...]
    task_index: int

    def n_anchors(self, subspace: str) -> int: ...
    def transferred(self, subspace: str) -> bool: ...


@runtime_checkable
class WeightedSubspaces(Protocol):
    """What the loop writes of a module with subspaces into ``results.json``: each subspace's
    anchors and the anchor weights of every task so far."""

    subspace_names: tuple[str, ...]

    def n_anchors(self, subspace: str) -> int: ...
    def task_alphas(self, subspace: str) -> Tensor: ...


@runtime_checkable
class ExtendableSubspaces(SubspaceNames, Protocol):
    """What :class:`~hispo_pl.callbacks.AnchorExtension` needs: a new anchor per subspace."""

    def grown(self, subspace: str) -> bool: ...
    def add_anchor(self, subspace: str, default_init: AnchorInit = "mean") -> None: ...


@runtime_checkable
class SearchableSubspaces(SubspaceNames, Protocol):
    """What a search of anchor weights needs (:class:`~hispo_pl.callbacks.DirichletEvaluation`):
    the trained weights, and a loss for each of K candidate weights on a batch."""

    def current_alpha(self, subspace: str) -> Tensor: ...
    def score_alphas(self, subspace: str, alphas: Tensor, batch: dict[str, Tensor]) -> Tensor: ...


@runtime_checkable
class PrunableSubspaces(Protocol):
    """What a pruning rule needs to carry out its decision (:class:`~hispo_pl.callbacks.
    SubspacePruning`, :class:`~hispo_pl.callbacks.CriticPruning`)."""

    task_index: int

    def n_anchors(self, subspace: str) -> int: ...
    def prune_last_anchor(self, subspace: str) -> None: ...
    def set_task_alpha(self, task: int, subspace: str, alpha: Tensor) -> None: ...
    def freeze_all(self) -> None: ...


@runtime_checkable
class TransferableSubspaces(SearchableSubspaces, Protocol):
    """What :class:`~hispo_pl.callbacks.ZeroShotTransfer` needs: how far a point's predictions
    are from the data, and taking that point for the task."""

    def prediction_distances(
        self, subspace: str, alpha: Tensor, batch: dict[str, Tensor]
    ) -> dict[str, Tensor]: ...
    def transfer(self, subspace: str, alpha: Tensor) -> None: ...


@runtime_checkable
class CriticScoredSubspaces(SearchableSubspaces, Protocol):
    """What :class:`~hispo_pl.callbacks.CriticEvaluation` needs on top of a search: the
    critic's value of mixed policies and its action-dependence diagnostic."""

    def critic_values(self, alphas: Tensor, batch: dict[str, Tensor]) -> Tensor: ...
    def critic_diagnostic(
        self,
        alpha: Tensor,
        batch: dict[str, Tensor],
        n_actions: int,
        generator: torch.Generator | None = None,
    ) -> dict[str, float]: ...


def require(
    pl_module: L.LightningModule, protocol: type[P], who: str, needs: str, example: str
) -> P:
    """``pl_module`` as ``protocol``; a TypeError says that callback ``who`` needs ``needs``,
    as ``hispo_pl.modules.<example>`` has it.

    Example:
        >>> from hispo_pl.modules import HBC
        >>> require(HBC(4, 2), PrunableSubspaces, "Pruning", "subspaces", "HiSPO")
        Traceback (most recent call last):
        TypeError: Pruning needs subspaces (the PrunableSubspaces protocol, e.g. ...HiSPO), got HBC
    """
    if not isinstance(pl_module, protocol):
        raise TypeError(
            f"{who} needs {needs} (the {protocol.__name__} protocol, e.g. "
            f"hispo_pl.modules.{example}), got {type(pl_module).__name__}"
        )
    return pl_module


def require_subspaces(pl_module: L.LightningModule, protocol: type[P], who: str) -> P:
    """HiSPO's callbacks (and CSPO's, CSP's) talk to a module with subspaces of policies."""
    return require(pl_module, protocol, who, "a module with subspaces of policies", "HiSPO")
