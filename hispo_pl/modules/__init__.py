"""LightningModules: the backbones and the continual methods built on them."""

from .columns import GrowingPolicy, NetworkPerTask
from .hbc import BC, HBC, GoalConditionedBC
from .hispo import HiSPO, SubspacePolicy
from .pnn import PNN
from .regularized import ConsolidatingPolicy, RegularizedFineTuning

__all__ = [
    "BC",
    "ConsolidatingPolicy",
    "GoalConditionedBC",
    "GrowingPolicy",
    "HBC",
    "HiSPO",
    "NetworkPerTask",
    "PNN",
    "RegularizedFineTuning",
    "SubspacePolicy",
]
