"""LightningModules: the backbones and, later, the continual methods built on them."""

from .hbc import BC, HBC, GoalConditionedBC

__all__ = ["BC", "HBC", "GoalConditionedBC"]
