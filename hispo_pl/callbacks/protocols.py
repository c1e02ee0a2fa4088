"""The check every callback makes in ``setup``: its module implements the protocol the callback
talks to it through (the protocols live with the modules), else an error that names a module
that does."""

from __future__ import annotations

from typing import TypeVar

import lightning as L

from ..modules.hispo import SubspacePolicy

P = TypeVar("P")


def require(
    pl_module: L.LightningModule, protocol: type[P], who: str, needs: str, example: str
) -> P:
    """``pl_module`` as ``protocol``; a TypeError says that callback ``who`` needs ``needs``,
    as ``hispo_pl.modules.<example>`` has it.

    Example:
        >>> from hispo_pl.modules import HBC
        >>> require(HBC(4, 2), SubspacePolicy, "Pruning", "subspaces", "HiSPO")
        Traceback (most recent call last):
        TypeError: Pruning needs subspaces (the SubspacePolicy protocol, e.g. ...HiSPO), got HBC
    """
    if not isinstance(pl_module, protocol):
        raise TypeError(
            f"{who} needs {needs} (the {protocol.__name__} protocol, e.g. "
            f"hispo_pl.modules.{example}), got {type(pl_module).__name__}"
        )
    return pl_module


def require_subspace_policy(pl_module: L.LightningModule, who: str) -> SubspacePolicy:
    """HiSPO's callbacks (and CSPO's, CSP's) talk to a module with subspaces of policies."""
    return require(pl_module, SubspacePolicy, who, "a module with subspaces of policies", "HiSPO")
