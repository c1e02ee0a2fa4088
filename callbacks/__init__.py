"""Callbacks that carry out the method (shipped as ``hispo_pl.callbacks``)."""

from .networks import TaskNetworks, WeightConsolidation
from .rollout import RolloutEvaluation
from .subspace import AnchorExtension, DirichletEvaluation, SubspacePruning, ZeroShotTransfer

__all__ = [
    "AnchorExtension",
    "DirichletEvaluation",
    "RolloutEvaluation",
    "SubspacePruning",
    "TaskNetworks",
    "WeightConsolidation",
    "ZeroShotTransfer",
]
