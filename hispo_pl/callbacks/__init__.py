"""Callbacks that carry out the method (shipped as ``hispo_pl.callbacks``)."""

from .critic import CriticEvaluation, CriticPruning
from .networks import TaskNetworks, WeightConsolidation
from .rollout import RolloutEvaluation
from .search import DirichletEvaluation
from .subspace import AnchorExtension, SubspacePruning
from .transfer import ZeroShotTransfer

__all__ = [
    "AnchorExtension",
    "CriticEvaluation",
    "CriticPruning",
    "DirichletEvaluation",
    "RolloutEvaluation",
    "SubspacePruning",
    "TaskNetworks",
    "WeightConsolidation",
    "ZeroShotTransfer",
]
