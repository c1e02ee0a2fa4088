"""LightningModules: the backbones and the continual methods built on them."""

from .columns import GrowingPolicy, NetworkPerTask
from .hbc import BC, HBC, GoalConditionedBC
from .hispo import HiSPO, SubspacePolicy

__all__ = [
    "BC",
    "HBC",
    "GoalConditionedBC",
    "GrowingPolicy",
    "HiSPO",
    "NetworkPerTask",
    "SubspacePolicy",
]
