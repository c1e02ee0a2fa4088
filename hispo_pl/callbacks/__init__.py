"""Callbacks that carry out the method (shipped as ``hispo_pl.callbacks``)."""

from .anchors import AnchorExtension, SubspacePruning
from .critic_pruning import CriticEvaluation, CriticPruning
from .loss_search import DirichletEvaluation
from .networks import TaskNetworks, WeightConsolidation
from .rollout import RolloutEvaluation
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
