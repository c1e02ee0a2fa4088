"""Callbacks that carry out the method (shipped as ``hispo_pl.callbacks``)."""

from .rollout import RolloutEvaluation

__all__ = ["RolloutEvaluation"]
