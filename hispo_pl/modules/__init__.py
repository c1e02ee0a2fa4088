"""LightningModules: the backbones and the continual methods built on them."""

from .hbc import BC, HBC, GoalConditionedBC
from .hispo import HiSPO, SubspacePolicy

__all__ = ["BC", "HBC", "GoalConditionedBC", "HiSPO", "SubspacePolicy"]
