"""LightningModules: the backbones and the continual methods built on them."""

from .columns import GrowingPolicy, NetworkPerTask
from .csp import CSP
from .cspo import CSPO
from .hbc import BC, HBC, GoalConditionedBC
from .hilow import HiLOW
from .hispo import HiSPO
from .pnn import PNN
from .regularized import ConsolidatingPolicy, RegularizedFineTuning

__all__ = [
    "BC",
    "CSP",
    "CSPO",
    "ConsolidatingPolicy",
    "GoalConditionedBC",
    "GrowingPolicy",
    "HBC",
    "HiLOW",
    "HiSPO",
    "NetworkPerTask",
    "PNN",
    "RegularizedFineTuning",
]
